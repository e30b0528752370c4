"""Against MuJoCo, in the same run: fixed-step stepping cost of the equivalent unconstrained
model (`mujoco_peer.py`) beside ours through `Simulation`, for the speed targets against MuJoCo.

Both are timed two ways. In one compiled call: MuJoCo's `mujoco.rollout` (one trajectory, one
thread; it writes the state after every step) beside our `Simulation.sample` (every 100 Hz sample,
state and energy, in one call) — like for like, and the targets' figures. From Python, one call
per 100 Hz sample: a loop of `mj_step` reading qpos/qvel beside our `Simulation.advance_to`
(`runs.simulate`), what the node does. All times are CPU time of this thread
(`time.thread_time`), best of the repeats, ours and MuJoCo's timed in turn in each round; wall
time is kept beside it.

MuJoCo's model has no wheel–ground constraint and no end stops, so it steps a robot with the same
bodies and inertias but not the same motion: these are costs, not accuracies.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..engine.simulation import Simulation
from ..runtime.timeline import sample_times
from ..scene.coordinates import ARM_Q, ARM_U
from ..scene.loading import load_scene, make_integrator, parse_scene
from . import mujoco_peer
from .runs import integrator, simulate
from .scaling import growth_order
from .scenes import random_arm_scene, random_robot_document
from .tables import sci, seconds, table, verdict

ARM_LINKS = (8, 16, 32, 64)
LONG_RUN = 6.0   # s of the paper scene: past ~0.8 s both rods rest at their stops
METHODS = (("rk4", "RK4"), ("semi_implicit_euler", "Euler"))   # ours, MuJoCo's (semi-implicit)


@dataclass
class Timing:
    cpu: float
    wall: float


@dataclass
class Pair:
    """One scene, one method: ours and MuJoCo's two ways each, for `duration` simulated seconds."""
    scene: str
    method: str
    duration: float
    ours: Timing          # Simulation.sample: all samples in one compiled call
    per_sample: Timing    # Simulation.advance_to once per sample, from Python
    rollout: Timing
    python_loop: Timing

    def factor(self, timing: Timing) -> float:
        """Real-time factor: simulated seconds per CPU second."""
        return self.duration / timing.cpu

    @property
    def ratio(self) -> float:
        """Our time over MuJoCo rollout's (< 1: ours is faster)."""
        return self.ours.cpu / self.rollout.cpu


def _best_of_rounds(runs, repeats: int) -> list[Timing]:
    """Each of `runs` timed once per round, `repeats` rounds, best of the rounds each: ours and
    MuJoCo's take turns, so that a spell of load on this shared machine falls on both."""
    cpu, wall = [math.inf] * len(runs), [math.inf] * len(runs)
    for _ in range(repeats):
        for i, run in enumerate(runs):
            cpu0, wall0 = time.thread_time(), time.perf_counter()
            run()
            cpu[i] = min(cpu[i], time.thread_time() - cpu0)
            wall[i] = min(wall[i], time.perf_counter() - wall0)
    return [Timing(c, w) for c, w in zip(cpu, wall, strict=True)]


def _rollout_inputs(scene, integrator: str, dt: float, duration: float):
    """(model, data, initial full-physics state, constant controls, state output) of the scene's
    peer."""
    mujoco = mujoco_peer.mujoco
    peer = mujoco_peer.for_scene(scene, integrator, dt)
    model, data = peer.model, peer.data
    peer.set_state(scene.initial_q, scene.initial_u)
    data.ctrl[:] = peer.control(scene.wheel_efforts, scene.joint_efforts)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.zeros(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, initial, spec)
    nstep = int(round(duration / dt))
    control = np.tile(np.array(data.ctrl), (1, nstep, 1))
    return model, data, initial, control, np.zeros((1, nstep, initial.size))


def mujoco_runs(scene, integrator: str, dt: float, duration: float, sample_rate: float = 100.0):
    """(rollout, Python mj_step loop): calls that step `duration` s of the scene's peer with its
    efforts."""
    from mujoco import rollout

    mujoco = mujoco_peer.mujoco
    model, data, initial, control, state = _rollout_inputs(scene, integrator, dt, duration)
    spec, nstep = mujoco.mjtState.mjSTATE_FULLPHYSICS, state.shape[1]
    sensordata = np.zeros((1, nstep, model.nsensordata))

    def batch():
        rollout.rollout(model, data, initial[None, :], control, state=state, sensordata=sensordata)

    per_sample = int(round(1.0 / (sample_rate * dt)))
    samples = np.zeros((nstep // per_sample, model.nq + model.nv))

    def loop():
        mujoco.mj_setState(model, data, initial, spec)
        for k in range(nstep):
            mujoco.mj_step(model, data)
            if (k + 1) % per_sample == 0:
                j = (k + 1) // per_sample - 1
                samples[j, :model.nq] = data.qpos
                samples[j, model.nq:] = data.qvel

    return batch, loop


def trajectory(scene, integrator: str, dt: float, sample_rate: float = 100.0, repeats: int = 1):
    """(CPU s best of `repeats`, samples) of MuJoCo's rollout of a fixed-base scene, the samples in
    our layout (q, u) at the times `simulate` samples (t = 0 included)."""
    from mujoco import rollout

    if not scene.effects.fixed_base:
        raise ValueError("MuJoCo's trajectory is ours only with a fixed base")
    model, data, initial, control, state = _rollout_inputs(scene, integrator, dt, scene.duration)
    nstep = state.shape[1]
    per_sample = int(round(1.0 / (sample_rate * dt)))
    if abs(per_sample * dt * sample_rate - 1.0) > 1e-9 or nstep % per_sample:
        raise ValueError(f"dt {dt:g} does not divide the sample interval and the duration")
    timing, = _best_of_rounds((lambda: rollout.rollout(model, data, initial[None, :], control,
                                                      state=state),), repeats)
    sampled = np.vstack([initial[None, :], state[0, per_sample - 1::per_sample]])
    assert np.allclose(sampled[:, 0], np.arange(len(sampled)) / sample_rate)   # column 0 is time
    nq, n = scene.robot.n_q, model.nq
    samples = np.zeros((len(sampled), nq + scene.robot.n_u))
    samples[:, :nq] = scene.initial_q   # the welded base and still wheels; v = ω = 0
    samples[:, :nq][:, ARM_Q] = sampled[:, 1:1 + n]
    samples[:, nq:][:, ARM_U] = sampled[:, 1 + n:1 + 2 * n]
    return timing.cpu, samples


WP_SWEEPS = {"RK4": (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4),
             "Euler": (1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5)}


OURS_WP = {"rk4": WP_SWEEPS["RK4"], "semi_implicit_euler": WP_SWEEPS["Euler"],
           "dop853": (1e-4, 1e-6, 1e-8, 1e-10)}


def work_precision(scene, progress, quick: bool = False) -> dict:
    """On a fixed-base scene, MuJoCo's RK4 and Euler and our rk4, semi_implicit_euler and dop853
    over sweeps, each against our DOP853 rtol 1e-13 reference:
    {"scene", "mujoco": [(integrator, dt, CPU per simulated s, error)],
    "ours": [(method, setting, …)]}."""
    reference = simulate(scene, make_integrator(scene.integrator, "dop853", rtol=1e-13, atol=1e-14))
    repeats = 1 if quick else 2
    ours = []
    for method, values in OURS_WP.items():
        for value in (values[::2] if quick else values):
            run = simulate(scene, integrator(scene, method, value), repeats=repeats)
            ours.append((method, run.setting, run.cpu_per_second, run.error_against(reference)))
            progress(f"{scene.name}: ours {method} {run.setting}: "
                     f"{run.cpu_per_second * 1e3:.2f} ms CPU per simulated s, "
                     f"error {ours[-1][3]:.1e}")
    points = []
    for mj_method, values in WP_SWEEPS.items():
        for dt in (values[::2] if quick else values):
            cpu, samples = trajectory(scene, mj_method, dt, repeats=repeats)
            error = float(np.abs(samples - reference.samples[:len(samples)]).max())
            points.append((mj_method, dt, cpu / scene.duration, error))
            progress(f"{scene.name}: MuJoCo {mj_method} dt={dt:.0e}: "
                     f"{cpu / scene.duration * 1e3:.2f} ms CPU per simulated s, error {error:.1e}")
    return {"scene": scene.name, "mujoco": points, "ours": ours}


def pair(scene, method: str, mj_method: str, duration: float, repeats: int,
         dt: float = 1e-3) -> Pair:
    """Ours two ways (one `sample` call for every 100 Hz sample, from its initial state each time;
    one `advance_to` call per sample, `runs.simulate`) beside MuJoCo's two, rounds interleaved."""
    settings = make_integrator(scene.integrator, method, dt=dt)
    run = simulate(scene, settings, duration=duration, repeats=repeats, record=False)
    simulation = Simulation(scene, settings)
    times = np.fromiter(sample_times(duration, 100.0), float)[1:]

    def ours():
        simulation.reset()
        simulation.sample(times)
    rollout, loop = mujoco_runs(scene, mj_method, dt, duration)
    if run.ok:
        ours_t, rollout_t, loop_t = _best_of_rounds((ours, rollout, loop), repeats)
    else:
        ours_t = Timing(math.nan, math.nan)
        rollout_t, loop_t = _best_of_rounds((rollout, loop), repeats)
    per_sample = Timing(run.cpu, run.wall) if run.ok else Timing(math.nan, math.nan)
    return Pair(scene.name, method, duration, ours_t, per_sample, rollout_t, loop_t)


def random_arm(n_links: int):
    """The random arm of n links the scaling rows use (physical inertias, no efforts, no stops)."""
    doc = random_robot_document(n_links, seed=100 + n_links, physical=True)
    return parse_scene(doc, doc["name"])


def measure(progress, quick: bool = False) -> dict:
    """{"paper": [Pair rk4, Pair Euler], "arms": [Pair per n in ARM_LINKS], "order": {...}}"""
    repeats = 2 if quick else 15   # rounds: the paper rows cost milliseconds each
    scene = load_scene()
    simulate(scene, make_integrator(scene.integrator, "rk4", dt=1e-3), record=False)  # compile
    paper = []
    for method, mj_method in METHODS:
        p = pair(scene, method, mj_method, scene.duration, repeats)
        paper.append(p)
        progress(f"paper 1 kHz {method}: ours {p.ours.cpu * 1e3:.1f} ms "
                 f"({p.factor(p.ours):.0f}× real time), "
                 f"MuJoCo {mj_method} rollout {p.rollout.cpu * 1e3:.1f} ms, mj_step loop "
                 f"{p.python_loop.cpu * 1e3:.1f} ms: ours / rollout {p.ratio:.2f}")
    long = pair(scene, "rk4", "RK4", LONG_RUN, 1 if quick else 5)
    progress(f"paper {LONG_RUN:g} s 1 kHz rk4: ours {long.ours.cpu * 1e3:.1f} ms "
             f"({long.factor(long.ours):.0f}× real time), MuJoCo rollout "
             f"{long.rollout.cpu * 1e3:.1f} ms: ours / rollout {long.ratio:.2f}")
    arms = []
    for n in ARM_LINKS:
        p = pair(random_arm(n), "rk4", "RK4", 1.0, 1 if quick and n == 64 else 5)
        arms.append(p)
        progress(f"{n} links 1 s rk4: ours {p.ours.cpu * 1e3:.1f} ms, MuJoCo rollout "
                 f"{p.rollout.cpu * 1e3:.1f} ms, mj_step loop {p.python_loop.cpu * 1e3:.1f} ms: "
                 f"ours / rollout {p.ratio:.2f}")
    order = {"ours": growth_order([p.ours.cpu for p in arms], ARM_LINKS, smallest=8),
             "MuJoCo rollout": growth_order([p.rollout.cpu for p in arms], ARM_LINKS, smallest=8),
             "MuJoCo mj_step loop": growth_order([p.python_loop.cpu for p in arms], ARM_LINKS,
                                                 smallest=8)}
    progress("whole-run cost order 8 … 64 links: "
             + ", ".join(f"{k} {v:.2f}" for k, v in order.items()))
    wp = work_precision(random_arm_scene(), progress, quick=quick)
    return {"paper": paper, "long": long, "arms": arms, "order": order, "wp": wp}


def _verdict(misses) -> str:
    """PASS, or MISS with the factor by which each missed part is missed."""
    missed = [f"{what} short by {factor:.2f}×" for what, factor in misses if factor > 1.0]
    return verdict(not missed, "; ".join(missed) if missed else "all parts met")


def _target_table(rows) -> str:
    return table(("target", "measured in this run", "verdict"), rows)


def section(result, number: int = 7) -> str:
    """The report's MuJoCo section: one table per issue-10 target, then every timing."""
    rk4, euler = result["paper"]
    long, arms, order = result["long"], result["arms"], result["order"]
    parts = [f"## {number}. Against MuJoCo: fixed-step stepping", "",
             "MuJoCo " + (mujoco_peer.mujoco.__version__ if mujoco_peer.available() else "") +
             " stepping the equivalent unconstrained model (`bench/mujoco_peer.py`: planar base as "
             "slide x – slide y – hinge z, wheel hinges, each R-P pair a hinge then a slide, the "
             "same inertias; contacts, constraints and limits off; efforts through gear-1 motors). "
             "`test/bench/test_mujoco_peer.py` checks that its mass matrix projected on our "
             "pseudo-velocities is ours to 1e-12. It knows neither the rolling constraint nor the "
             "end stops, so it does less physics than our paper run: the rows compare cost, not "
             "accuracy. Targets compare one compiled call with one compiled call: MuJoCo `rollout` "
             "(batch stepping, one thread, state written every step) beside our "
             "`Simulation.sample` (state and energy written at every 100 Hz sample). From Python, "
             "one call per 100 Hz sample, as the node steps: a loop of `mj_step` reading the state "
             "beside our `Simulation.advance_to` (last table). CPU time of this thread, best of "
             "the repeats; ours and MuJoCo's are timed in turn in each round (15 rounds for the "
             "paper rows), so that a spell of load on the machine falls on both.", ""]

    def speedup(p):
        return p.rollout.cpu / p.ours.cpu

    # the compiled core's targets: rk4 ≥ 5× MuJoCo RK4, semi-implicit Euler ≥ 4× MuJoCo Euler,
    # 64 links ≥ 10× (at most 0.1× MuJoCo RK4's time)
    rk4_speedup, euler_speedup, arms_ratio = 5.0, 4.0, 0.1

    parts += [f"### {number}.1 1 kHz rk4, paper scene with stops, 100 Hz samples", "",
              _target_table([
                  (f"≥ 400× real time and ≥ {rk4_speedup:g}× MuJoCo RK4, first {p.duration:g} s"
                   if p is rk4 else
                   f"the same over {p.duration:g} s (rods resting at their stops)",
                   f"ours {seconds(p.ours.cpu)}: {p.factor(p.ours):.0f}× real time; MuJoCo RK4 "
                   f"rollout {seconds(p.rollout.cpu)} ({p.factor(p.rollout):.0f}×): ours is "
                   f"{speedup(p):.2f}× MuJoCo",
                   _verdict([("real-time factor", 400 / p.factor(p.ours)),
                             ("speed-up", rk4_speedup / speedup(p))]))
                  for p in (rk4, long)]), ""]
    parts += [f"### {number}.2 1 kHz semi_implicit_euler, paper scene", "",
              _target_table([(f"≥ 1000× real time and ≥ {euler_speedup:g}× MuJoCo Euler",
                              f"ours {seconds(euler.ours.cpu)}: "
                              f"{euler.factor(euler.ours):.0f}× real time; "
                              f"MuJoCo Euler rollout {seconds(euler.rollout.cpu)} "
                              f"({euler.factor(euler.rollout):.0f}×): ours is "
                              f"{speedup(euler):.2f}× MuJoCo",
                              _verdict([("real-time factor", 1000 / euler.factor(euler.ours)),
                                        ("speed-up", euler_speedup / speedup(euler))]))]), ""]
    big = arms[-1]
    parts += [f"### {number}.3 Random arms, 1 s at 1 kHz rk4", "",
              _target_table([
                  (f"{ARM_LINKS[-1]} links: ≤ {arms_ratio:g}× MuJoCo RK4's time",
                   f"ours {seconds(big.ours.cpu)} vs MuJoCo rollout {seconds(big.rollout.cpu)}: "
                   f"{big.ratio:.2f}×", _verdict([("time ratio", big.ratio / arms_ratio)])),
                  (f"whole-run cost order ≤ 1.2 from {ARM_LINKS[0]} to {ARM_LINKS[-1]} links",
                   f"ours {order['ours']:.2f} (MuJoCo rollout {order['MuJoCo rollout']:.2f})",
                   _verdict([("order", order["ours"] / 1.2)]))]), ""]
    parts += _work_precision_section(result["wp"], number)
    rows = [(p.scene, p.method, f"{p.duration:g} s", seconds(p.ours.cpu), seconds(p.ours.wall),
             f"{p.factor(p.ours):.0f}×", seconds(p.rollout.cpu), seconds(p.rollout.wall),
             f"{p.factor(p.rollout):.0f}×", f"{p.ratio:.2f}", seconds(p.per_sample.cpu),
             seconds(p.python_loop.cpu), f"{p.per_sample.cpu / p.python_loop.cpu:.2f}")
            for p in (rk4, euler, long, *arms)]
    parts += ["Every timing (one compiled call: ours `sample`, MuJoCo `rollout`; one call per "
              "sample from Python: ours `advance_to`, MuJoCo `mj_step`):", "",
              table(("scene", "method", "simulated", "ours CPU", "ours wall", "ours RTF",
                     "MuJoCo rollout CPU", "rollout wall", "rollout RTF", "ours / rollout",
                     "ours per-sample CPU", "MuJoCo mj_step loop CPU", "per-sample ours / MuJoCo"),
                    rows), "",
              "Fitted whole-run cost order over " + ", ".join(map(str, ARM_LINKS)) + " links: " +
              ", ".join(f"{k} {v:.2f}" for k, v in order.items()) + ". A miss is measured as the "
              "factor by which the figure falls short of its target.", ""]
    return "\n".join(parts)



def _work_precision_section(wp, number: int) -> list:
    from .work_precision import TARGETS
    parts = [f"### {number}.4 Work–precision beside MuJoCo: {wp['scene']} (base fixed)", "",
             "With the base welded in place nothing is constrained, so MuJoCo steps exactly our "
             "system (20 random links, gravity, no stops, 0.5 s). Error: largest "
             "|state − reference| over the 100 Hz samples, reference ours DOP853 rtol 1e-13. CPU "
             "per simulated second.", ""]
    rows = []
    for target in TARGETS:
        cells = [f"≤ {target:g}"]
        for entries, label in ((wp["ours"], "ours"), (wp["mujoco"], "MuJoCo")):
            good = [e for e in entries if e[3] <= target]
            best = min(good, key=lambda e: e[2]) if good else None
            setting = "—"
            if best:
                setting = (f"{best[0]} {best[1]}" if label == "ours"
                           else f"{best[0]} dt={best[1]:.0e}")
            cells += [setting, seconds(best[2]) if best else "not reached"]
        rows.append(cells)
    parts += ["Cheapest run within each accuracy:", "",
              table(("accuracy", "ours: setting", "ours: CPU / sim s", "MuJoCo: setting",
                     "MuJoCo: CPU / sim s"), rows), "",
              "<details><summary>every run</summary>", "",
              table(("who", "setting", "CPU / sim s", "largest state error"),
                    [("ours", f"{m} {setting}", seconds(cpu), sci(err))
                     for m, setting, cpu, err in wp["ours"]] +
                    [("MuJoCo", f"{m} dt={dt:.0e}", seconds(cpu), sci(err))
                     for m, dt, cpu, err in wp["mujoco"]]),
              "", "</details>", ""]
    return parts
