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

import numpy as np
from scipy import integrate

from ..dynamics import Dynamics
from ..errors import UserError
from ..scene import IntegratorSettings, Scene
from . import fixed_step
from .stops import Impact, apply_impact, crossing_in_step, hermite_turns, locate, release_wanted
from . import layout
from .system import (KI, KP, RHS_EVALS, TARGET_L, TARGET_R, TORQUE_LIMIT, VELOCITY_MODE, System,
                     wheel_speed_torques)

ADAPTIVE = {"rk45": integrate.RK45, "dop853": integrate.DOP853, "radau": integrate.Radau,
            "bdf": integrate.BDF}
DEFAULT_WHEEL_SPEED_GAINS = (0.5, 5.0)   # kp N·m·s/rad, ki N·m/rad (see set_wheel_speed_gains)
MAX_IMPACTS_PER_STEP = 64   # a guard against Zeno: beyond it the rod is held at rest


class SimulationError(RuntimeError):
    """The numbers went bad (NaN/Inf): says when and which quantity."""


class Simulation:
    def __init__(self, scene: Scene, integrator: IntegratorSettings | None = None):
        self.scene = scene
        self.settings = integrator or scene.integrator
        model, effects = scene.robot, scene.effects
        self.model = model
        self.dynamics = Dynamics(model, gravity=effects.gravity, tip_mass=effects.payload or 0.0,
                                 wheel_inertia=effects.wheel_inertia)
        self.system = System(self.dynamics, _damping(scene), _locked_indices(scene))
        self.nq, self.nu = model.n_q, model.n_u
        n = model.n_links
        self.stop_law = effects.stroke_limits
        self.watched = np.full(n if self.stop_law else 0, True)
        self.resting = np.zeros(n, dtype=np.int64)
        self.stroke = np.array(model.stroke)
        size = layout.state_size(self.nu)
        self._out = np.zeros(size)
        self._stages = np.zeros((4, size))
        self._forces = np.zeros(size)
        self._method = fixed_step.METHOD_IDS.get(self.settings.method)
        self.set_wheel_speed_gains(*DEFAULT_WHEEL_SPEED_GAINS)
        self.reset()

    # --- state ---------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scene's initial state at t = 0, with the scene's efforts."""
        u0 = np.array(self.scene.initial_u, dtype=float)
        u0[list(self.system.permanently_locked)] = 0.0
        self.s = np.concatenate([self.scene.initial_q, u0, [0.0, 0.0], [0.0]])
        self.system.control[VELOCITY_MODE] = 0.0
        self._t0, self._k = 0.0, 0
        self.resting[:] = 0
        self.watched[:] = True
        self.system.set_locked(())
        self.impacts: list[Impact] = []
        self._run = (0, 0, 0, 0.0)   # rod, stop, count and first time of the latest run of impacts
        self.impact_energy_lost = 0.0
        self.steps = 0
        self.system.counters[:] = 0
        self._h_last = None
        self.set_efforts(self.scene.wheel_efforts, self.scene.joint_efforts)
        self.energy0 = self.total_energy()

    @property
    def t(self) -> float:
        return self._t0 + self._k * self.settings.dt if self.settings.fixed_step else self._t0

    @property
    def q(self) -> np.ndarray:
        return self.s[:self.nq]

    @property
    def u(self) -> np.ndarray:
        return self.s[self.nq:self.nq + self.nu]

    @property
    def work(self) -> float:
        """Work done by efforts and dissipation since t = 0 (J)."""
        return float(self.s[-1])

    def total_energy(self) -> float:
        T, V = self.dynamics.energy(self.q, self.u)
        return T + V

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
        limits = self.scene.effects.effort_limits or {}
        if wheels is not None:
            self.wheel_efforts = _command(wheels, 2, "wheels", limits.get("wheels"))
            self._wheel_mode(velocity=False)
        if joints is not None:
            self.joint_efforts = _command(joints, self.nu - 2, "joints", limits.get("joints"))
        Q = self.system.Q_cmd
        Q[0], Q[1] = self.dynamics.wheel_forces(*self.wheel_efforts)
        Q[2:] = self.joint_efforts
        # The steppers look for a release only after a step: a new command that pulls a resting
        # rod off its stop must free it here, at the step boundary where the command changes,
        # or the rod would stay held for one more step (a lag of a whole dt in fixed-step runs).
        if self.resting.any() and release_wanted(self.system.tuple, self.s, self.resting,
                                                 self._out, self._forces):
            self._release()

    def set_base_velocity(self, v: float, omega: float) -> None:
        """Drive the base at forward speed v (m/s) and yaw rate ω (rad/s) from now on: the wheel
        torques come from the wheel-speed PI loop (`set_wheel_speed_gains`) inside the simulated
        system, recomputed at every evaluation of the right-hand side and clipped to the wheel
        effort limits. `set_efforts(wheels=...)` returns the wheels to torque commands."""
        target = _command([v, omega], 2, "cmd_vel", None)
        r, b = self.model.base.wheel_radius, self.model.base.half_track
        control = self.system.control
        control[TARGET_R] = (target[0] + b * target[1]) / r
        control[TARGET_L] = (target[0] - b * target[1]) / r
        self._wheel_mode(velocity=True)

    def set_wheel_speed_gains(self, kp: float, ki: float, torque_limit: float = math.inf) -> None:
        """Gains of the wheel-speed PI loop: kp (N·m·s/rad) on the speed error, ki (N·m/rad) on
        its integral; torques within ±torque_limit (N·m) and the scene's wheel effort limits."""
        for name, value in (("kp", kp), ("ki", ki)):
            if not (math.isfinite(value) and value >= 0.0):
                raise UserError(f"wheel_speed.{name}", f"must be a finite number ≥ 0, got {value!r}")
        if not torque_limit > 0.0:
            raise UserError("wheel_speed.torque_limit", f"must be positive, got {torque_limit!r}")
        limits = (self.scene.effects.effort_limits or {}).get("wheels")
        if limits is not None:
            torque_limit = min(torque_limit, float(np.min(limits)))
        control = self.system.control
        control[KP], control[KI], control[TORQUE_LIMIT] = kp, ki, torque_limit

    def _wheel_mode(self, velocity: bool) -> None:
        control = self.system.control
        if velocity and not control[VELOCITY_MODE]:
            e = layout.controller(self.nq, self.nu)
            self.s[e:e + 2] = 0.0   # a fresh loop: no integral carried over from an earlier one
        control[VELOCITY_MODE] = 1.0 if velocity else 0.0

    def wheel_torques(self) -> np.ndarray:
        """(τ_R, τ_L) acting now, N·m: the commanded ones, or the PI loop's in velocity mode."""
        if not self.velocity_mode:
            return np.array(self.wheel_efforts, dtype=float)
        return np.array(wheel_speed_torques(self.system.data, self.s))

    @property
    def velocity_mode(self) -> bool:
        return bool(self.system.control[VELOCITY_MODE])

    # --- stepping ------------------------------------------------------------------------
    def advance_to(self, t_end: float) -> None:
        """Integrate from the current time to exactly t_end (s)."""
        if t_end < self.t:
            raise UserError("t_end", f"{t_end} is before the current time {self.t}")
        if self.settings.fixed_step:
            self._advance_fixed(t_end)
        else:
            self._advance_adaptive(t_end)

    def _advance_fixed(self, t_end: float) -> None:
        dt = self.settings.dt
        steps = (t_end - self._t0) / dt
        whole = math.floor(steps + 1e-9)
        while self._k < whole:
            done, why = fixed_step.run(self._method, self.system.tuple, self.s, dt, whole - self._k,
                                       (self.watched, self.resting, self.stroke),
                                       self._out, self._stages, self._forces)
            self._k += done
            self.steps += done
            if why == fixed_step.CROSSING:
                self._step_with_events(dt)
                self._k += 1
                self.steps += 1
            elif why == fixed_step.RELEASE:
                s_start = self.s.copy()
                h_release, self.s = self._locate_release(lambda dh: self._step(s_start, dh), dt)
                self._step_with_events(dt - h_release)
                self._k += 1
                self.steps += 1
            elif why == fixed_step.NOT_FINITE:
                self._fail()
        if steps - whole > 1e-9:  # t_end is off the grid: a last, shorter step
            self._step_with_events(t_end - self.t)
            self.steps += 1
            self._t0, self._k = t_end, 0

    def _step(self, s, h) -> np.ndarray:
        out = np.empty_like(s)
        fixed_step.step(self._method, self.system.tuple, s, h, out, self._stages)
        return out

    def _step_with_events(self, h: float) -> None:
        """One step of length h in which end stops may be hit (and hit again)."""
        t_start = self.t
        for _ in range(MAX_IMPACTS_PER_STEP):
            out = self._step(self.s, h)
            if not np.all(np.isfinite(out)):
                self._fail()
            if not crossing_in_step(self.s, out, h, self.system.tuple, self.watched, self.stroke,
                                    self._stages[0], self._stages[1]):
                self.s = out
                return
            hit = self._first_crossing(lambda dh, s0=self.s.copy(): self._step(s0, dh), h)
            if hit is None:  # the interpolant dipped, the step itself did not
                self.s = out
                return
            h_hit, k, side, state = hit
            self.s = state
            h -= h_hit
            t_start += h_hit
            self._impact(k, side, t_start)
            if h <= 1e-15 * self.settings.dt:
                return
        # Zeno guard: this many impacts in one step are a rod chattering against its stop with
        # ever smaller rebounds. Hold it there (it leaves when the net force pulls it away) and
        # finish the step with it held; stepping on regardless would carry it through the stop.
        if not self.resting[k - 1]:
            self._impact(k, side, t_start, hold=True)
        self._step_with_events(h)

    def _first_crossing(self, state_at, h):
        """Earliest (h', rod, side, state) where a watched rod meets a stop within h, or None."""
        samples = [h * j / 16 for j in range(1, 17)]
        # A rod that crosses and comes back between two samples would be missed: add the instants
        # where each rod's Hermite path over the step (the one `crossing_in_step` flagged) turns.
        end_state = state_at(h)
        for k in np.flatnonzero(self.watched) + 1:
            i_l, i_ld = 4 + 2 * k, self.nq + 2 * k + 1
            turns, _, _ = hermite_turns(self.s[i_l], self.s[i_ld], end_state[i_l], end_state[i_ld], h)
            samples += [tau for tau in turns if 0.0 < tau < h]
        samples.sort()
        best = None
        for k in np.flatnonzero(self.watched) + 1:
            i_l = 4 + 2 * k
            for side, stop in ((-1, self.stroke[k - 1, 0]), (1, self.stroke[k - 1, 1])):
                def g(dh, i_l=i_l, side=side, stop=stop):
                    return (stop - state_at(dh)[i_l]) * side if dh > 0 else (stop - self.s[i_l]) * side
                # Bracket the first crossing between samples: an interpolant's round-off right
                # after an impact must not pass for a new crossing at h' ≈ 0.
                end = next((j for j, x in enumerate(samples) if g(x) < 0.0), None)
                if end is None:
                    continue
                h_hit = locate(g, samples[end - 1] if end else 0.0, samples[end])
                if best is None or h_hit < best[0]:
                    best = (h_hit, int(k), side, state_at(h_hit))
        if best is not None:
            best[3][4 + 2 * best[1]] = self.stroke[best[1] - 1, 0 if best[2] < 0 else 1]
        return best

    def _impact(self, k: int, side: int, t: float, hold: bool = False) -> None:
        """Rod k (1-based) meets its lower (side −1) or upper (+1) stop at time t (s): the impact
        law, then a rebound or rest. ``hold`` stops it at rest whatever its speed."""
        law = self.stop_law
        j = 2 * k + 1
        u_before = self.u.copy()
        # A crossing located with the rod at the stop but not moving into it is found at the very
        # instant the rod left: its rebound is too small to resolve in time, i.e. the rod is
        # pressed against the stop. Hold it there; ignoring the crossing would restart the event
        # loop at this same instant forever (a Zeno stall, e.g. with rest_speed 0).
        hold = hold or side * u_before[j] <= 0.0
        T_before, _ = self.dynamics.energy(self.q, u_before)
        if hold or law.law == "impulse" and abs(law.restitution * u_before[j]) < law.rest_speed:
            restitution = 0.0
        else:
            restitution = law.restitution
        free = [int(i) for i in self.system.free if i >= 0]
        u_after = apply_impact(self.dynamics, free, self.q, u_before, k, restitution, law.law)
        resting = hold or abs(u_after[j]) < law.rest_speed
        if resting:
            u_after[j] = 0.0
        self.s[self.nq:self.nq + self.nu] = u_after
        T_after, _ = self.dynamics.energy(self.q, u_after)
        self.impact_energy_lost += T_before - T_after
        # Plain Python numbers (not numpy scalars), so records serialise anywhere (CSV, YAML, bags).
        self.impacts.append(Impact(float(t), k, "lower" if side < 0 else "upper", float(u_before[j]),
                                   float(u_after[j]), float(T_before - T_after), bool(resting)))
        if resting:
            self.resting[k - 1] = side
            self.watched[k - 1] = False
            self._relock()
            if release_wanted(self.system.tuple, self.s, self.resting, self._out, self._forces):
                self._release()

    def _chattering(self, k: int, side: int, h: float) -> bool:
        """Zeno guard of the adaptive methods (the fixed-step one counts impacts per step): rod k
        hitting the same stop MAX_IMPACTS_PER_STEP times in a row within one step length h (s) is
        chattering with ever smaller rebounds, down to round-off and on forever; hold it."""
        k_run, side_run, count, t_first = self._run
        if (k_run, side_run) == (k, side) and self._t0 - t_first < h:
            count += 1
        else:
            count, t_first = 1, self._t0
        self._run = (k, side, count, t_first)
        return count >= MAX_IMPACTS_PER_STEP

    def _relock(self) -> None:
        self.system.set_locked(tuple(2 * (k + 1) + 1 for k in np.flatnonzero(self.resting)))

    def _holding_margin(self, state) -> float:
        """min over resting rods of the force the stop pushes with (> 0: all still held)."""
        forces = self.system.constraint_forces(state)
        return min(-self.resting[k] * forces[layout.u_l(k + 1)] for k in np.flatnonzero(self.resting))

    def _locate_release(self, state_at, h: float):
        """The instant in (0, h] at which a resting rod's stop would start to pull, found like an
        impact (Illinois on the holding force along the step), and the state there with that rod
        freed. Deciding at the end of the step instead would hold the rod up to a step too long."""
        h_release = locate(lambda dh: self._holding_margin(state_at(dh) if dh > 0 else self.s), 0.0, h)
        state = state_at(h_release)
        forces = self.system.constraint_forces(state)
        for k in np.flatnonzero(self.resting):
            if self.resting[k] * forces[layout.u_l(k + 1)] >= 0.0:
                self.resting[k] = 0
                self.watched[k] = True
        self._relock()
        return h_release, state

    def _release(self) -> None:
        """Free every resting rod that its stop would have to pull."""
        release_wanted(self.system.tuple, self.s, self.resting, self._out, self._forces)
        for k in np.flatnonzero(self.resting):
            if self.resting[k] * self._forces[layout.u_l(k + 1)] > 0.0:
                self.resting[k] = 0
                self.watched[k] = True
        self._relock()

    def _advance_adaptive(self, t_end: float) -> None:
        solver_class = ADAPTIVE[self.settings.method]
        system = self.system

        def fun(_t, y):
            return system.derivative(y)

        while t_end - self._t0 > 1e-15 * max(1.0, abs(t_end)):
            first = min(self._h_last, t_end - self._t0) if self._h_last else None
            solver = solver_class(fun, self._t0, self.s, t_end, rtol=self.settings.rtol,
                                  atol=self.settings.atol, first_step=first)
            restart = False
            while solver.status == "running" and not restart:
                s_before, t_before = solver.y.copy(), solver.t
                message = solver.step()
                if solver.status == "failed":
                    raise SimulationError(f"t = {t_before:.9g} s: {self.settings.method} failed: {message}")
                self.steps += 1
                self._h_last = solver.t - t_before
                if not np.all(np.isfinite(solver.y)):
                    self.s = solver.y
                    self._fail()
                if self.watched.size and crossing_in_step(s_before, solver.y, solver.t - t_before,
                                                          system.tuple, self.watched, self.stroke,
                                                          self._stages[0], self._stages[1]):
                    dense = solver.dense_output()
                    self.s = s_before
                    hit = self._first_crossing(lambda dh: dense(t_before + dh), solver.t - t_before)
                    if hit is not None:
                        h_hit, k, side, state = hit
                        self.s, self._t0 = state, t_before + h_hit
                        self._impact(k, side, self._t0,
                                     hold=self._chattering(k, side, solver.t - t_before))
                        restart = True
                        continue
                if self.resting.any() and release_wanted(system.tuple, solver.y, self.resting,
                                                         self._out, self._forces):
                    dense = solver.dense_output()
                    self.s = s_before
                    h_release, self.s = self._locate_release(lambda dh: dense(t_before + dh),
                                                             solver.t - t_before)
                    self._t0 = t_before + h_release
                    restart = True
                    continue
                self.s, self._t0 = solver.y.copy(), solver.t
        self._t0 = t_end

    def _fail(self) -> None:
        bad = [i for i, value in enumerate(self.s) if not math.isfinite(value)]
        raise SimulationError(f"t = {self.t:.9g} s: state became non-finite (entries {bad}); "
                              f"try a smaller dt or tighter tolerances")

    def stats(self) -> dict:
        return {"t": self.t, "steps": self.steps, "rhs_evaluations": self.rhs_evaluations,
                "impacts": len(self.impacts), "energy_error": self.energy_error()}


def _command(values, size, group, limits) -> np.ndarray:
    try:
        array = np.array(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise UserError(f"efforts.{group}", f"expected {size} numbers, got {values!r}") from None
    if array.size != size:
        raise UserError(f"efforts.{group}", f"expected {size} values, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise UserError(f"efforts.{group}", f"values must be finite, got {array.tolist()}")
    if limits is not None:
        array = np.clip(array, -limits, limits)
    return array


def _damping(scene: Scene):
    """Diagonal viscous coefficients on u, or None when no damping effect is on."""
    effects, base = scene.effects, scene.robot.base
    if effects.joint_damping is None and effects.wheel_damping is None:
        return None
    c = np.zeros(scene.robot.n_u)
    if effects.wheel_damping:
        # Wheel torques −c θ̇ with θ̇_R/L = (v ± bω)/r, projected: Q_v = −2c v/r², Q_ω = −2c b² ω/r².
        c[0] = 2.0 * effects.wheel_damping / base.wheel_radius ** 2
        c[1] = 2.0 * effects.wheel_damping * base.half_track ** 2 / base.wheel_radius ** 2
    if effects.joint_damping is not None:
        c[2:] = effects.joint_damping
    return c


def _locked_indices(scene: Scene) -> list[int]:
    names = scene.robot.joint_names()[2:]
    locked = [2 + names.index(name) for name in scene.effects.locked_joints]
    if scene.effects.fixed_base:
        locked += [0, 1]
    return locked
