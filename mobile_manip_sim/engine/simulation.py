"""`Simulation`: one scene being stepped in simulated time, the one interface every adapter uses
(headless `simulate`, the ROS node, replay, benchmarks).

    sim = Simulation(scene)
    sim.set_efforts(wheels=[0.1, 0.2], joints=[...])   # zero-order hold from now on
    sim.advance_to(0.01)                              # lands exactly on t = 0.01 s
    sim.q, sim.u, sim.t, sim.energy_error(), sim.impacts, sim.stats()

With an arm controller (``Simulation(scene, arm_controller=ArmController(...))`` or the scene's
``controller:`` section) the arm takes references instead of efforts (`arm_commands.py`).
`set_state` puts the robot in any state (validated) between calls to `advance_to`.

Commands change only between calls to `advance_to`, so a run is a pure function of the scene
and the command sequence: repeating it gives bit-identical states.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from ..dynamics import Dynamics
from ..scene.arm_controller import ArmController
from ..scene.controller import control_rate as control_rate_of
from ..scene.controller import outside_stroke
from ..scene.coordinates import ARM_Q, ARM_U, OMEGA, V, arm_width
from ..scene.effects import settings as effect_settings
from ..scene.errors import SimulationError as SimulationError
from ..scene.errors import StepLimitError as StepLimitError
from ..scene.errors import UserError
from ..scene.limits import ANGLE, SPEED
from ..scene.loading import IntegratorSettings, Scene
from ..scene.methods import METHODS
from . import adaptive_stepping, layout, linearization, step_watch, stepping
from . import status as status_codes
from .arm_commands import ArmCommands
from .arm_control import arm_settings, feedforward_masses, for_robot, scene_arm_controller
from .base_commands import BaseCommands, command, finite_forces
from .core_calls import CoreCalls
from .impact_log import Impact, ImpactDetail, collect
from .sampled_controllers import SampledControllers, checked_control_rate
from .scipy_steps import ScipySteps
from .stops import make_stops
from .system import RHS_EVALS, WHEEL_VELOCITY_MODE, System

# semi-implicit Euler is symplectic between impacts only (bench/REPORT.md, "elastic drift")
ELASTIC_SEMI_IMPLICIT = ("semi_implicit_euler with end stops that rebound (restitution > 0): its "
                         "energy is not bounded (each impact moves it by O(dt)); use rk4 or an "
                         "adaptive method where energy matters")

# kp N·m·s/rad, ki N·m/rad (see set_wheel_speed_gains): with the paper's arm held in position
# mode, cmd_vel (0.3 m/s, 0.5 rad/s) is within 1e-4 of its target from 1 s on (with 0.5, 5.0 it is
# 8 % off at 1 s)
DEFAULT_WHEEL_SPEED_GAINS = (2.0, 20.0)


def hold_warning(line: str) -> None:
    warnings.warn(line, RuntimeWarning, stacklevel=4)


class Simulation(ArmCommands, BaseCommands, ScipySteps, CoreCalls, SampledControllers):
    def __init__(self, scene: Scene, integrator: IntegratorSettings | None = None,
                 arm_controller: ArmController | None = None, control_rate: float | None = None):
        """`arm_controller`: how the arm is driven; None takes the scene's ``controller:``
        section (and its command at t = 0), or effort mode when the scene has none.
        `control_rate`: the controllers' update rate (Hz; 0: continuous; core/include/mms/
        stepping.hpp); None takes the scene's ``controller.rate``."""
        self.scene = scene
        self.settings = integrator or scene.integrator
        model = scene.robot
        self.model = model
        self.effects = effects = effect_settings(scene)   # what the scene turns on (effects.py)
        self.dynamics = Dynamics(model, **effects.dynamics_options())
        self._arm_section = scene.controller if arm_controller is None else None
        self.arm_controller = for_robot(arm_controller or scene_arm_controller(scene.controller),
                                        model)
        arm = (arm_settings(self.arm_controller, effects.effort_limits)
               if self.arm_controller.active else None)
        self.control_rate = checked_control_rate(
            control_rate_of(scene.controller) if control_rate is None else control_rate)
        ff_masses = feedforward_masses(self.dynamics, self.arm_controller.model_error)
        self.system = System(self.dynamics, effects.generalized_damping(model.base), effects.locked,
                             arm, ff_masses, self.control_rate)
        self.sampled = self.control_rate > 0.0
        self.nq, self.nu = model.n_q, model.n_u
        self.stop_law = effects.stop_law
        if (self.settings.method == "semi_implicit_euler" and self.stop_law is not None
                and self.stop_law.restitution > 0.0):
            warnings.warn(ELASTIC_SEMI_IMPLICIT, RuntimeWarning, stacklevel=2)
        self.stops = make_stops(model, effects.stop_law, self.system.permanently_locked,
                                self.system.data.resting)
        self.watched, self.resting = self.stops.watched, self.stops.resting
        self.stroke = self.stops.stroke
        size = self.system.state(model.n_q * [0.0], self.nu * [0.0]).size
        self._scratch = stepping.make_scratch(size, model.n_links)
        self._clock = np.zeros(stepping.CLOCK_SIZE)
        self._clock[stepping.CLOCK_DT] = self.settings.dt
        # Whether the compiled stepper takes the method's steps itself (SciPy's radau and bdf: no,
        # stepped from Python and handed in, `scipy_steps.py`). Steps per compiled call: about
        # 20 ms of work, so signals, pause and reset act promptly (an adaptive step costs about
        # four fixed ones).
        budget = max(1, int(40_000 / (model.n_links + 2)))
        method = METHODS[self.settings.method]
        self._compiled_steps = method.compiled
        self._solve = None
        self._stepper = None   # made by `reset` (`_compiled_stepper`)
        if method.fixed_step:
            self._step_budget = budget
        else:
            self._solve = adaptive_stepping.make_solve(self.settings.rtol, self.settings.atol)
            self._step_budget = max(1, budget // 4)
        self.set_wheel_speed_gains(*DEFAULT_WHEEL_SPEED_GAINS)
        # says, on one line, that a hold removed more than the Zeno guard's bound (the node
        # replaces it by its logger's warning)
        self.hold_warning = hold_warning
        self.reset()

    # --- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scene's initial state at t = 0, with the scene's efforts."""
        u0 = np.array(self.scene.initial_u, dtype=float)
        u0[list(self.system.permanently_locked)] = 0.0
        self.s = self.system.state(self.scene.initial_q, u0)
        self.system.control[WHEEL_VELOCITY_MODE] = 0.0
        self._clock[:] = 0.0
        self._clock[stepping.CLOCK_DT] = self.settings.dt
        if self._solve is not None:
            adaptive_stepping.new_solve(self._solve)
        self.resting[:] = 0
        self.watched[:] = self.stop_law is not None
        self.stops.count[0] = 0
        self.stops.run[:] = 0.0   # no run of impacts for the Zeno guard
        self.stops.failed[0] = 0
        self._stepper = self._compiled_stepper()
        self._relock()
        self.impacts: list[Impact] = []
        self.impact_details: list[ImpactDetail] = []
        self.system.counters[:] = 0
        self._solver = None   # radau/bdf: SciPy's solver of the solve in progress
        self.wheel_efforts = None
        self.joint_efforts = np.zeros(arm_width(self.nu))
        self.set_efforts(self.scene.wheel_efforts,
                         None if self.arm_controller.active else self.scene.joint_efforts)
        if self.arm_controller.active:
            self._start_arm()
        self.system.held[:] = 0.0
        if self.controllers_sampled:   # what the first update, at t = 0, will hold
            self._preview_update()
        self._hold_pressed_rods()
        self.energy0 = self.total_energy()

    def set_state(self, q, u) -> None:
        """Put the robot in configuration ``q`` (n_q: x, y, θ, φ_R, φ_L, then q_k, l_k per
        link) moving with pseudo-velocities ``u`` (n_u: v, ω, then q̇_k, l̇_k) now, at the
        current time. Kept: t, the commands, the controllers' states (the wheel loop's and the
        arm PID's integrals, the arm's reference and its clock), the work W and the impact log.
        Every rod is free again (the stops watch it: one at or past a stop end moving into it
        is an impact at the next step); adaptive solves restart here; the energy balance's
        reference moves by the energy the new state has more or less, so `energy_error` stays
        the integration's. A UserError naming ``state.q[i]`` or ``state.u[i]`` for a value of
        the wrong shape, not finite, beyond the scene's bounds, a rod outside its stroke, or a
        velocity of a locked joint that is not zero."""
        q = self._state_vector(q, self.nq, "state.q", ANGLE)
        u = self._state_vector(u, self.nu, "state.u", SPEED)
        names = self.model.joint_names()
        found = outside_stroke(q[ARM_Q], np.asarray(self.model.stroke).reshape(-1, 2))
        if found is not None:
            i = layout.arm_q(found[0])
            raise UserError(f"state.q[{i}]", f"{names[2 + found[0]]}: {found[1]}")
        u_names = ["the base's v", "the base's ω", *names[ARM_U]]
        for k in self.system.permanently_locked:
            if u[k] != 0.0:
                raise UserError(f"state.u[{k}]", f"{u_names[k]} is locked by the scene: its "
                                                 f"velocity must be 0, got {u[k]:g}")
        before = self.total_energy()
        self.s[:self.nq], self.s[self.nq:self.nq + self.nu] = q, u
        self.resting[:] = 0
        self.watched[:] = self.stop_law is not None
        self.stops.run[:] = 0.0
        self._relock()
        self._hold_pressed_rods()
        self._solver = None
        self._restart()
        self.energy0 += self.total_energy() - before

    @staticmethod
    def _state_vector(values, size: int, key: str, bound: float) -> np.ndarray:
        try:
            array = np.array(values, dtype=float)
        except (TypeError, ValueError):
            raise UserError(key, f"expected {size} numbers, got "
                                 f"{str(values)[:60]}") from None
        if array.shape != (size,):
            raise UserError(key, f"expected {size} values, got shape {array.shape}")
        bad = np.flatnonzero(~np.isfinite(array) | (np.abs(array) > bound))
        if bad.size:
            i = int(bad[0])
            raise UserError(f"{key}[{i}]", f"must be finite and within ±{bound:g}, got "
                                           f"{array[i]}")
        return array

    @property
    def t(self) -> float:
        # the adaptive methods keep their time in CLOCK_T0 (CLOCK_K stays 0)
        clock = self._clock
        return float(clock[stepping.CLOCK_T0] + clock[stepping.CLOCK_K] * self.settings.dt)

    @property
    def steps(self) -> int:
        return int(self._clock[stepping.CLOCK_STEPS])

    @property
    def impact_energy_lost(self) -> float:
        """Energy the impact law removed since t = 0 (J): restitution < 1 and rests."""
        return float(self._clock[stepping.CLOCK_LOST])

    @property
    def hold_energy(self) -> float:
        """Energy the engine's holds removed beyond the impact law since t = 0 (J): not physics,
        so `energy_error` counts it as error (docs/model.md, "Resting, leaving, and no Zeno")."""
        return float(self._clock[stepping.CLOCK_HELD])

    @property
    def holds(self) -> int:
        """How many impacts the engine held (the Zeno guard, or a rod found at its stop not
        moving into it) since t = 0."""
        return int(self._clock[stepping.CLOCK_HOLDS])

    @property
    def q(self) -> np.ndarray:
        return self.s[:self.nq]

    @property
    def u(self) -> np.ndarray:
        return self.s[self.nq:self.nq + self.nu]

    @property
    def work(self) -> float:
        """Work done by efforts and dissipation since t = 0 (J)."""
        return float(self.s[layout.work(self.nq, self.nu)])

    def total_energy(self) -> float:
        return self._stepper.total_energy(self.s)

    def energy_error(self) -> float:
        """(T + V)(t) − (T + V)(0) − W(t) + the impact law's losses: zero for exact physics (J).
        Energy removed by holds is not a loss of the law: it shows here (as −`hold_energy`)."""
        return self.total_energy() - self.energy0 - self.work + self.impact_energy_lost

    def qdot(self) -> np.ndarray:
        return self.dynamics.configuration_rate(self.q, self.u)

    def acceleration(self) -> np.ndarray:
        """u̇ now: the right-hand side the integrator follows at the current state, with the
        efforts held and the rods at rest locked (the IMU's source). Not counted among the
        evaluations, and it leaves the run untouched (its scratch is rewritten by every step)."""
        counters = self.system.counters.copy()
        ds = self._stepper.derivative(self.s)
        self.system.counters[:] = counters
        return ds[self.nq:self.nq + self.nu]

    @property
    def rhs_evaluations(self) -> int:
        return int(self.system.counters[RHS_EVALS])

    # --- commands ------------------------------------------------------------------------
    def linearize(self, q=None, u=None):
        """(∂f/∂x, ∂f/∂τ) of ẋ = f(x, τ), x = (q, u), τ = (τ_R, τ_L, τ_1, F_1, …), at (q, u)
        (default: now), with the efforts, damping and locks in force: exact, by dual numbers
        (`linearization.py`)."""
        return linearization.linearize(self, q, u)

    def step_jacobians(self, q=None, u=None, dt=None):
        """(A, B) = (∂x⁺/∂x, ∂x⁺/∂τ) of one step of the run's fixed-step method (`linearize`'s
        x and τ; the closed loop's with an arm controller), the exact derivative of the step map,
        through the events the step holds (`linearization.py`)."""
        return linearization.step_jacobians(self, q, u, dt)

    def set_efforts(self, wheels=None, joints=None) -> None:
        """Hold these efforts from now on: wheels (τ_R, τ_L) N·m, joints (τ_1, F_1, …)."""
        if joints is not None and self.arm_controller.active:
            raise UserError("efforts.joints", f"the arm is driven by its "
                                              f"{self.arm_controller.mode} controller: it takes "
                                              f"references, not efforts")

        Q = self.system.Q_cmd
        before = Q.copy(), self.velocity_mode
        wheel_efforts, joint_efforts = self.wheel_efforts, self.joint_efforts
        if wheels is not None:
            wheel_efforts = self.effects.saturate(command(wheels, 2, "wheels"))
            finite_forces(lambda: self.dynamics.wheel_forces(*wheel_efforts), "wheels", wheels)
        if joints is not None:
            joint_efforts = self.effects.saturate(command(joints, arm_width(self.nu), "joints"), 2)
        self.wheel_efforts, self.joint_efforts = wheel_efforts, joint_efforts
        if wheels is not None:
            self.system.control[WHEEL_VELOCITY_MODE] = 0.0
        Q[V], Q[OMEGA] = self.dynamics.wheel_forces(*self.wheel_efforts)
        Q[ARM_U] = self.joint_efforts
        if not np.array_equal(before[0], Q) or before[1] != self.velocity_mode:
            self._command_changed()

    def _command_changed(self) -> None:
        """A discontinuity of the right-hand side: adaptive solvers restart here, and a resting
        rod that the new command pulls off its stop is freed at this very instant (the steppers
        look for releases only inside steps; otherwise it would stay held a whole step)."""
        self._restart()
        if self.resting.any() and self._holding_margin() < 0.0:
            self._release()
            if self.stops.failed[0]:
                self._contact_failed()

    # --- stepping ------------------------------------------------------------------------
    def advance_to(self, t_end: float) -> None:
        """Integrate from the current time to exactly t_end (s)."""
        if t_end < self.t:
            raise UserError("t_end", f"{t_end} is before the current time {self.t}")
        t_end = float(t_end)
        if not self._compiled_steps:
            while True:   # each update of sampled controllers due before t_end on the way
                t_update = self.next_update   # (one due at t_end: the next call's first act)
                self._advance_scipy(min(t_end, t_update))
                if t_update >= t_end:
                    return
                self._update_controllers()
        while True:
            status = self._stepper.advance(self.s, self._clock, t_end, self._step_budget)
            self._after_compiled(status)
            if status == status_codes.DONE:
                return

    def sample(self, times) -> np.ndarray:
        """Advance through the increasing sample times (s); row i = (s, T + V) at times[i]. One
        compiled call (Python is entered only per step budget), but for SciPy's radau/bdf."""
        times = np.ascontiguousarray(times, dtype=float)
        rows = np.empty((times.size, self.s.size + 1))
        if times.size and times[0] < self.t:
            raise UserError("t_end", f"{times[0]} is before the current time {self.t}")
        if not self._compiled_steps:
            for i, t in enumerate(times):
                self.advance_to(t)
                rows[i, :-1], rows[i, -1] = self.s, self.total_energy()
            return rows
        i = 0
        while i < times.size:
            status, i = self._stepper.advance_samples(self.s, self._clock, times, rows, i,
                                                      self._step_budget)
            self._after_compiled(status)
        return rows

    def _after_compiled(self, status: int) -> None:
        self._collect_impacts()
        if status == status_codes.NOT_FINITE:
            self._fail(self._scratch.out)
        if status == status_codes.CRAWLING:
            t_before, h = self._step_in_hand()
            self._cannot_follow(t_before, step_watch.describe(self._solve.watch, t_before, h))
        if status == status_codes.STALLED:   # as SciPy's "step below the spacing of t"
            h = self._stepper.next_step()
            self._cannot_follow(self.t, "a stage overflowed (its error estimate is NaN)"
                                if math.isnan(h) else
                                f"the step fell below 10 spacings of t (h = {h:.3g} s)")
        if status == status_codes.CONTACT_FAILED:
            self._contact_failed()
        if status == status_codes.CHATTER:
            raise SimulationError(f"t = {self.t:.9g} s: end stops chatter beyond what one step can "
                                  f"resolve (rods released and hitting again without end); "
                                  f"try a smaller dt or a larger effects.stroke_limits.rest_speed")

    def _contact_failed(self) -> None:
        raise SimulationError(f"t = {self.t:.9g} s: the end stops' contact solve found no "
                              f"impulses (a singular contact set); try a smaller dt or tighter "
                              f"tolerances")

    def _collect_impacts(self, stops=None) -> None:
        """Move the compiled stop log into `impacts` and `impact_details`; a hold that
        removed more than the Zeno guard's bound is said on one line (`hold_warning`). `stops`:
        a record with the stops' log fields to read instead (a batch lane's own log)."""
        collect(self.stops if stops is None else stops, self.impacts, self.impact_details,
                self.hold_warning)

    def _cannot_follow(self, t_before: float, problem: str) -> None:
        s = self.settings
        raise StepLimitError("integrator.rtol", f"t = {t_before:.9g} s: {s.method} cannot "
                             f"follow the solution: {problem.rstrip('.')}; check the efforts and "
                             f"the scene, or loosen integrator.rtol ({s.rtol:g}) and "
                             f"integrator.atol ({s.atol:g})")

    def _fail(self, state) -> None:
        bad = [i for i, value in enumerate(state) if not math.isfinite(value)]
        raise SimulationError(f"t = {self.t:.9g} s: state became non-finite (entries {bad}); "
                              f"try a smaller dt or tighter tolerances")

    def stats(self) -> dict:
        return {"t": self.t, "steps": self.steps, "rhs_evaluations": self.rhs_evaluations,
                "impacts": len(self.impacts), "holds": self.holds,
                "hold_energy": self.hold_energy, "energy_error": self.energy_error()}
