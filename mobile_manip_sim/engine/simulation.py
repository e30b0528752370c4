"""`Simulation`: one scene being stepped in simulated time, the one interface every adapter uses
(headless `simulate`, the ROS node, replay, benchmarks).

    sim = Simulation(scene)
    sim.set_efforts(wheels=[0.1, 0.2], joints=[...])   # zero-order hold from now on
    sim.advance_to(0.01)                              # lands exactly on t = 0.01 s
    sim.q, sim.u, sim.t, sim.energy_error(), sim.impacts, sim.stats()

Commands change only between calls to `advance_to`, so a run is a pure function of the scene
and the command sequence: repeating it gives bit-identical states.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..dynamics import Dynamics
from ..dynamics.jit import Bound
from ..effects import settings as effect_settings
from ..methods import METHODS
from ..errors import UserError
from ..scene import IntegratorSettings, Scene
from . import fixed_step, layout, stepping
from .adaptive import CompiledSolver
from .step_watch import StepWatch
from .events import MAX_IMPACTS_PER_STEP, N_SAMPLES, crossing_in_step, hermite_turns, holding_margin
from .stops import (LOG_HELD, Impact, impact, make_impact_scratch, make_stops, relock, release,
                    release_at_root)
from .system import (KI, KP, RHS_EVALS, TARGET_L, TARGET_R, TORQUE_LIMIT, VELOCITY_MODE, System,
                     wheel_speed_torques)

def scipy_solver(method: str):
    """SciPy's solver class for an adaptive method, imported only when one is used (~56 MB)."""
    from scipy import integrate
    return getattr(integrate, METHODS[method].stepper.split(":")[1])
DEFAULT_WHEEL_SPEED_GAINS = (0.5, 5.0)   # kp N·m·s/rad, ki N·m/rad (see set_wheel_speed_gains)
SCIPY_MIN_RTOL = 100 * np.finfo(float).eps   # SciPy's own floor; passed as is, it warns on stderr


class SimulationError(RuntimeError):
    """The numbers went bad (NaN/Inf): says when and which quantity."""


class StepLimitError(SimulationError):
    """radau/bdf cannot follow the solution (`step_watch`): the settings named by `key` and the
    efforts are to blame, so adapters treat it like a user error (status 2)."""

    def __init__(self, key: str, problem: str):
        super().__init__(f"{key}: {problem}")
        self.key, self.problem = key, problem


ImpactDetail = namedtuple("ImpactDetail", "q u_before u_after free held")


class Simulation:
    def __init__(self, scene: Scene, integrator: IntegratorSettings | None = None):
        self.scene = scene
        self.settings = integrator or scene.integrator
        model = scene.robot
        self.model = model
        self.effects = effects = effect_settings(scene)   # what the scene turns on (effects.py)
        self.dynamics = Dynamics(model, **effects.dynamics_options())
        self.system = System(self.dynamics, effects.generalized_damping(model.base), effects.locked)
        self.nq, self.nu = model.n_q, model.n_u
        self.stop_law = effects.stop_law
        self.stops = make_stops(model, effects.stop_law, self.system.permanently_locked)
        self.watched, self.resting, self.stroke = self.stops.watched, self.stops.resting, self.stops.stroke
        size = layout.state_size(self.nu)
        self._scratch = stepping.make_scratch(size, model.n_links, make_impact_scratch(self.nu, model.n_links))
        self._clock = np.zeros(5)
        self._clock[stepping.DT] = self.settings.dt
        self._method = fixed_step.METHOD_IDS.get(self.settings.method)
        # Steps per compiled call: about 20 ms of work, so signals, pause and reset act promptly.
        self._step_budget = max(1, int(40_000 / (model.n_links + 2)))
        # the compiled calls of every sample, bound to this simulation's argument types
        self._advance = Bound(stepping.advance)
        self._advance_samples = Bound(stepping.advance_samples)
        self._total_energy = Bound(stepping.total_energy)
        self.set_wheel_speed_gains(*DEFAULT_WHEEL_SPEED_GAINS)
        self.reset()

    # --- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scene's initial state at t = 0, with the scene's efforts."""
        u0 = np.array(self.scene.initial_u, dtype=float)
        u0[list(self.system.permanently_locked)] = 0.0
        self.s = self.system.state(self.scene.initial_q, u0)
        self.system.control[VELOCITY_MODE] = 0.0
        self._clock[:] = 0.0
        self._clock[stepping.DT] = self.settings.dt
        self._t_adaptive = 0.0
        self.resting[:] = 0
        self.watched[:] = self.stop_law is not None
        self.stops.count[0] = 0
        relock(self.system.data, self.stops)
        self.impacts: list[Impact] = []
        self.impact_details: list[ImpactDetail] = []
        self._run = (0, 0, 0, 0.0)   # rod, stop, count and first time of the latest run of impacts
        self.system.counters[:] = 0
        self._h_last = None
        self._solver = None
        self._current = None
        self._step_watch = StepWatch()
        self.wheel_efforts = self.joint_efforts = None
        self.set_efforts(self.scene.wheel_efforts, self.scene.joint_efforts)
        self.energy0 = self.total_energy()

    @property
    def t(self) -> float:
        if self.settings.fixed_step:
            return float(self._clock[stepping.T0] + self._clock[stepping.K] * self.settings.dt)
        return float(self._t_adaptive)

    @property
    def steps(self) -> int:
        return int(self._clock[stepping.STEPS])

    @property
    def impact_energy_lost(self) -> float:
        return float(self._clock[stepping.LOST])

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
        return float(self._total_energy(self.system.data, self.s))

    def energy_error(self) -> float:
        """(T + V)(t) − (T + V)(0) − W(t) + impact losses: zero for exact physics (J)."""
        return self.total_energy() - self.energy0 - self.work + self.impact_energy_lost

    def qdot(self) -> np.ndarray:
        return self.dynamics.configuration_rate(self.q, self.u)

    @property
    def rhs_evaluations(self) -> int:
        return int(self.system.counters[RHS_EVALS])

    # --- commands ------------------------------------------------------------------------
    def set_efforts(self, wheels=None, joints=None) -> None:
        """Hold these efforts from now on: wheels (τ_R, τ_L) N·m, joints (τ_1, F_1, …)."""
        Q = self.system.Q_cmd
        before = Q.copy(), self.velocity_mode
        if wheels is not None:
            self.wheel_efforts = self.effects.saturate(_command(wheels, 2, "wheels"))
            self.system.control[VELOCITY_MODE] = 0.0
        if joints is not None:
            self.joint_efforts = self.effects.saturate(_command(joints, self.nu - 2, "joints"), 2)
        Q[0], Q[1] = self.dynamics.wheel_forces(*self.wheel_efforts)
        Q[2:] = self.joint_efforts
        if not np.array_equal(before[0], Q) or before[1] != self.velocity_mode:
            self._command_changed()

    def set_base_velocity(self, v: float, omega: float) -> None:
        """Drive the base at forward speed v (m/s) and yaw rate ω (rad/s) from now on: the wheel
        torques come from the wheel-speed PI loop (`set_wheel_speed_gains`) inside the simulated
        system, recomputed at every evaluation of the right-hand side and clipped to the wheel
        effort limits. `set_efforts(wheels=...)` returns the wheels to torque commands."""
        target = _command([v, omega], 2, "cmd_vel")
        r, b = self.model.base.wheel_radius, self.model.base.half_track
        control = self.system.control
        before = control.copy()
        control[TARGET_R] = (target[0] + b * target[1]) / r
        control[TARGET_L] = (target[0] - b * target[1]) / r
        if not control[VELOCITY_MODE]:
            e = layout.controller(self.nq, self.nu)
            self.s[e:e + 2] = 0.0   # a fresh loop: no integral carried over from an earlier one
            control[VELOCITY_MODE] = 1.0
        if not np.array_equal(before, control):
            self._command_changed()

    def set_wheel_speed_gains(self, kp: float, ki: float, torque_limit: float = math.inf) -> None:
        """Gains of the wheel-speed PI loop: kp (N·m·s/rad) on the speed error, ki (N·m/rad) on
        its integral; torques within ±torque_limit (N·m) and the scene's wheel effort limits."""
        for name, value in (("kp", kp), ("ki", ki)):
            if not (math.isfinite(value) and value >= 0.0):
                raise UserError(f"wheel_speed.{name}", f"must be a finite number ≥ 0, got {value!r}")
        if not torque_limit > 0.0:
            raise UserError("wheel_speed.torque_limit", f"must be positive, got {torque_limit!r}")
        if self.effects.effort_limits is not None:
            torque_limit = min(torque_limit, float(np.min(self.effects.effort_limits[:2])))
        control = self.system.control
        control[KP], control[KI], control[TORQUE_LIMIT] = kp, ki, torque_limit
        self._solver = self._current = None

    def wheel_torques(self) -> np.ndarray:
        """(τ_R, τ_L) acting now, N·m: the commanded ones, or the PI loop's in velocity mode."""
        if not self.velocity_mode:
            return np.array(self.wheel_efforts, dtype=float)
        return np.array(wheel_speed_torques(self.system.data, self.s))

    @property
    def velocity_mode(self) -> bool:
        return bool(self.system.control[VELOCITY_MODE])

    def _command_changed(self) -> None:
        """A discontinuity of the right-hand side: adaptive solvers restart here, and a resting
        rod that the new command pulls off its stop is freed at this very instant (the steppers
        look for releases only inside steps; otherwise it would stay held a whole step)."""
        self._solver = self._current = None
        scr = self._scratch
        if self.resting.any() and holding_margin(self.system.data, self.s, self.resting,
                                                 scr.stages[3], scr.forces) < 0.0:
            release(self.system.data, self.stops, self.s, scr.stages[3], scr.forces)

    # --- stepping ------------------------------------------------------------------------
    def advance_to(self, t_end: float) -> None:
        """Integrate from the current time to exactly t_end (s)."""
        if t_end < self.t:
            raise UserError("t_end", f"{t_end} is before the current time {self.t}")
        if self.settings.fixed_step:
            self._advance_fixed(t_end)
        else:
            self._advance_adaptive(t_end)

    def sample(self, times) -> np.ndarray:
        """Advance through the increasing sample times (s); row i = (s, T + V) at times[i]. One
        compiled call for fixed-step methods (Python is entered only per step budget)."""
        times = np.ascontiguousarray(times, dtype=float)
        rows = np.empty((times.size, self.s.size + 1))
        if times.size and times[0] < self.t:
            raise UserError("t_end", f"{times[0]} is before the current time {self.t}")
        if not self.settings.fixed_step:
            for i, t in enumerate(times):
                self.advance_to(t)
                rows[i, :-1], rows[i, -1] = self.s, self.total_energy()
            return rows
        i = 0
        while i < times.size:
            status, i = self._advance_samples(self._method, self.system.data, self.stops,
                                              self._scratch, self.s, self._clock, times, rows, i,
                                              self._step_budget)
            self._after_compiled(status)
        return rows

    def _advance_fixed(self, t_end: float) -> None:
        while True:
            status = self._advance(self._method, self.system.data, self.stops, self._scratch,
                                   self.s, self._clock, float(t_end), self._step_budget)
            self._after_compiled(status)
            if status == stepping.DONE:
                return

    def _after_compiled(self, status: int) -> None:
        self._collect_impacts()
        if status == stepping.NOT_FINITE:
            self._fail(self._scratch.out)
        if status == stepping.CHATTER:
            raise SimulationError(f"t = {self.t:.9g} s: end stops chatter beyond what one step can "
                                  f"resolve (rods released and hitting again without end); "
                                  f"try a smaller dt or a larger effects.stroke_limits.rest_speed")

    def _collect_impacts(self) -> None:
        """Move the compiled stop log into `impacts` (and `impact_details`)."""
        stops = self.stops
        for row in range(int(stops.count[0])):
            self.impacts.append(Impact.from_log(stops.log[row]))
            self.impact_details.append(ImpactDetail(
                stops.log_q[row].copy(), stops.log_u[row, 0].copy(), stops.log_u[row, 1].copy(),
                [int(i) for i in np.flatnonzero(stops.log_free[row])],
                bool(stops.log[row, LOG_HELD])))
        stops.count[0] = 0

    # --- adaptive methods: SciPy solvers kept across samples until a discontinuity ---------
    def _impact(self, k: int, side: int, t: float, hold: bool = False) -> None:
        scr = self._scratch
        self._clock[stepping.LOST] += impact(self.system.data, self.stops, self.s, k, side, t, hold,
                                             scr.impact, scr.stages[3], scr.forces)
        self._collect_impacts()

    def _chattering(self, k: int, side: int, h: float) -> bool:
        """Zeno guard of the adaptive methods (the fixed-step one counts impacts per step): rod k
        hitting the same stop MAX_IMPACTS_PER_STEP times in a row within one step length h (s) is
        chattering with ever smaller rebounds, down to round-off and on forever; hold it."""
        k_run, side_run, count, t_first = self._run
        if (k_run, side_run) == (k, side) and self._t_adaptive - t_first < h:
            count += 1
        else:
            count, t_first = 1, self._t_adaptive
        self._run = (k, side, count, t_first)
        return count >= MAX_IMPACTS_PER_STEP

    def _advance_adaptive(self, t_end: float) -> None:
        """Step one SciPy solver through the sample times, sampling its dense output; restart it
        only at a discontinuity (an impact, a release, a command change)."""
        while True:
            current = self._current
            if current is not None:
                t_before, t_after, dense, y_after, event = current
                t_stop = event[0] if event is not None else t_after
                if t_end <= t_stop:
                    if t_end == t_after and event is None:
                        self.s = y_after.copy()
                    elif t_end > self._t_adaptive:
                        self.s = dense(t_end)
                    self._t_adaptive = t_end
                    return
                if event is not None:
                    self._apply_event(event)
                    continue
            self._take_adaptive_step()

    def _take_adaptive_step(self) -> None:
        system = self.system
        if self._solver is None:
            settings = self.settings
            if METHODS[settings.method].stepper == "runge_kutta":
                self._solver = CompiledSolver(settings.method, system.data, self._t_adaptive,
                                              self.s, settings.rtol, settings.atol, self._h_last)
            else:
                derivative = system.derivative
                self._solver = scipy_solver(settings.method)(
                    lambda _t, y: derivative(y), self._t_adaptive, self.s.copy(), math.inf,
                    rtol=max(settings.rtol, SCIPY_MIN_RTOL), atol=settings.atol,
                    first_step=self._h_last)
        solver = self._solver
        s_before, t_before = solver.y.copy(), solver.t
        message = solver.step()
        if not isinstance(solver, CompiledSolver):
            self._check_scipy_step(solver, t_before, message)
        if solver.status == "failed":
            raise SimulationError(f"t = {t_before:.9g} s: {self.settings.method} failed: {message}")
        self._clock[stepping.STEPS] += 1
        h = solver.t - t_before
        self._h_last = h
        if not np.all(np.isfinite(solver.y)):
            self._fail(solver.y)
        dense = solver.dense_output()
        event = None
        scr = self._scratch
        if self.watched.any() and crossing_in_step(s_before, solver.y, h, system.data, self.watched,
                                                   self.stroke):
            hit = self._first_crossing(lambda dh: dense(t_before + dh), s_before, h)
            if hit is not None:
                event = (t_before + hit[0], "impact", hit, h)
        if event is None and self.resting.any() and holding_margin(
                system.data, solver.y, self.resting, scr.stages[3], scr.forces) < 0.0:
            h_release = locate_python(lambda dh: self._holding_margin(dense(t_before + dh) if dh > 0
                                                                      else s_before), 0.0, h)
            event = (t_before + h_release, "release", dense(t_before + h_release), h)
        # the step's end state, kept exactly (dense(t_after) may differ from it by round-off)
        self._current = (t_before, solver.t, dense, solver.y.copy(), event)

    def _check_scipy_step(self, solver, t_before: float, message) -> None:
        """radau/bdf: a failed step (below ten spacings of t) or a crawl (`step_watch`) is one
        StepLimitError naming the tolerances, instead of steps of 1e-18 s for ever."""
        problem = message if solver.status == "failed" else \
            self._step_watch.problem(t_before, solver.t - t_before)
        if problem:
            s = self.settings
            raise StepLimitError("integrator.rtol", f"t = {t_before:.9g} s: {s.method} cannot "
                                 f"follow the solution: {problem.rstrip('.')}; check the efforts and "
                                 f"the scene, or loosen integrator.rtol ({s.rtol:g}) and "
                                 f"integrator.atol ({s.atol:g})")

    def _apply_event(self, event) -> None:
        t_event, kind, detail, h = event
        self._t_adaptive = t_event
        if kind == "impact":
            _, k, side, state = detail
            self.s = state
            self._impact(k, side, t_event, hold=self._chattering(k, side, h))
        else:
            self.s = detail
            scr = self._scratch
            release_at_root(self.system.data, self.stops, self.s, scr.stages[3], scr.forces)
        self._solver = self._current = None

    def _holding_margin(self, state) -> float:
        scr = self._scratch
        return float(holding_margin(self.system.data, state, self.resting, scr.stages[3], scr.forces))

    def _first_crossing(self, state_at, s0, h):
        """Earliest (h', rod, side, state) where a watched rod meets a stop within h, or None."""
        samples = [h * j / N_SAMPLES for j in range(1, N_SAMPLES + 1)]
        end_state = state_at(h)
        for k in np.flatnonzero(self.watched) + 1:
            i_l, i_ld = layout.l(k), layout.ld(self.nq, k)
            turns, _, _ = hermite_turns(s0[i_l], s0[i_ld], end_state[i_l], end_state[i_ld], h)
            samples += [tau for tau in turns if 0.0 < tau < h]
        samples.sort()
        best = None
        for k in np.flatnonzero(self.watched) + 1:
            i_l = layout.l(k)
            for side, stop in ((-1, self.stroke[k - 1, 0]), (1, self.stroke[k - 1, 1])):
                def g(dh, i_l=i_l, side=side, stop=stop):
                    return (stop - state_at(dh)[i_l]) * side if dh > 0 else (stop - s0[i_l]) * side
                end = next((j for j, x in enumerate(samples) if g(x) < 0.0), None)
                if end is None:
                    continue
                h_hit = locate_python(g, samples[end - 1] if end else 0.0, samples[end])
                if best is None or h_hit < best[0]:
                    best = (h_hit, int(k), side, state_at(h_hit))
        if best is not None:
            best[3][layout.l(best[1])] = self.stroke[best[1] - 1, 0 if best[2] < 0 else 1]
        return best

    def _fail(self, state) -> None:
        bad = [i for i, value in enumerate(state) if not math.isfinite(value)]
        raise SimulationError(f"t = {self.t:.9g} s: state became non-finite (entries {bad}); "
                              f"try a smaller dt or tighter tolerances")

    def stats(self) -> dict:
        return {"t": self.t, "steps": self.steps, "rhs_evaluations": self.rhs_evaluations,
                "impacts": len(self.impacts), "energy_error": self.energy_error()}


def locate_python(g, a: float, b: float, tol: float = 1e-13) -> float:
    """The root of g in (a, b] with g(a) ≥ 0 > g(b), by the Illinois method (the adaptive
    methods' event functions live on SciPy's dense output; `events.locate` is the compiled twin
    on the integrator's own step)."""
    h = b - a
    ga, gb = g(a), g(b)
    g_root = gb
    side = 0
    for _ in range(200):
        c = b - gb * (b - a) / (gb - ga) if gb != ga and ga != 0.0 else 0.5 * (a + b)
        if not a < c < b:
            c = 0.5 * (a + b)
        gc = g(c)
        if gc <= 0.0:
            b, gb, g_root = c, gc, gc
            if side == -1:
                ga *= 0.5
            side = -1
        else:
            a, ga = c, gc
            if side == 1:
                gb *= 0.5
            side = 1
        if -tol <= g_root <= 0.0 or b - a <= 1e-15 * h:
            break
    return b


def _command(values, size, group) -> np.ndarray:
    try:
        array = np.array(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise UserError(f"efforts.{group}", f"expected {size} numbers, got {values!r}") from None
    if array.size != size:
        raise UserError(f"efforts.{group}", f"expected {size} values, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise UserError(f"efforts.{group}", f"values must be finite, got {array.tolist()}")
    return array

