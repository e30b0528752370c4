"""The arm controllers: what each mode costs per 1 kHz rk4 step beside effort mode,
and how well it tracks.

The paper robot without wheel torques, gravity on, end stops off (so that no run pays for
impacts the others do not), 2 s at 1 kHz rk4 in one `Simulation.sample` call (100 Hz samples):
effort mode holds the efforts that balance gravity at the initial pose (no controller stage);
position mode holds that pose; velocity mode turns joint 1 at 0.1 rad/s; joint_trajectory mode
follows a 1 Hz sinusoid about the pose (amplitudes 0.2 rad, 0.05 m, 0.3 rad, 0.05 m) sent as
quintic points every 10 ms. Default gains (`arm_control.default_controller`). Tracking error:
q − q_ref at the samples, the reference read back from the engine's own
(`Simulation.arm_reference`).
CPU time of this thread, best of the repeats.
"""
from __future__ import annotations

import copy
import time

import numpy as np

from ..dynamics import Dynamics
from ..engine.simulation import Simulation
from ..scene.arm_controller import ArmController
from ..scene.coordinates import ARM_Q
from ..scene.loading import load_scene, parse_scene
from .tables import seconds, table, verdict

DURATION = 2.0          # s simulated
DT = 1e-3               # s, rk4
SAMPLE_RATE = 100.0     # Hz
TARGET = 1.15           # a controller adds ≤ 15 % to a step
AMPLITUDE = np.array([0.2, 0.05, 0.3, 0.05])
MODES = (("effort", "none", "efforts that balance gravity at the initial pose, held"),
         ("position", "none", "hold the initial pose"),
         ("position", "gravity", "hold the initial pose"),
         ("velocity", "gravity", "joint 1 at 0.1 rad/s"),
         ("joint_trajectory", "none", "1 Hz sinusoid, quintic points every 10 ms"),
         ("joint_trajectory", "gravity", "1 Hz sinusoid, quintic points every 10 ms"),
         ("joint_trajectory", "computed_torque", "1 Hz sinusoid, quintic points every 10 ms"))


def scene():
    doc = copy.deepcopy(load_scene().document)
    q0 = np.array(doc["initial"]["joints"])
    full = np.concatenate([np.zeros(5), q0])
    hold = Dynamics(load_scene().robot, gravity=doc["effects"]["gravity"],
                    wheel_inertia=True).inverse_dynamics(full, np.zeros(6), np.zeros(6))[2:]
    doc["efforts"] = {"wheels": [0.0, 0.0], "joints": hold.tolist()}
    doc["effects"].pop("stroke_limits")
    doc["integrator"] = {"method": "rk4", "dt": DT}
    return parse_scene(doc, "paper_two_link")


def prepared(base, mode: str, feedforward: str) -> Simulation:
    """A simulation at t = 0 with the mode's command given."""
    if mode == "effort":
        return Simulation(base)
    document = copy.deepcopy(base.document)
    document["efforts"]["joints"] = [0.0] * 4
    sim = Simulation(parse_scene(document, base.name),
                     arm_controller=ArmController(mode, feedforward=feedforward))
    q0 = sim.q[ARM_Q].copy()
    if mode == "velocity":
        sim.set_arm_velocities([0.1, 0.0, 0.0, 0.0])
    elif mode == "joint_trajectory":
        w, T = 2.0 * np.pi, np.arange(1, int(DURATION * 100) + 1) * 0.01
        sim.set_arm_trajectory(T, q0 + np.outer(np.sin(w * T), AMPLITUDE),
                               np.outer(w * np.cos(w * T), AMPLITUDE),
                               np.outer(-w * w * np.sin(w * T), AMPLITUDE))
    return sim


def tracking(sim: Simulation, times) -> tuple[float, float]:
    """RMS and max of q − q_ref over the samples and joints (rad or m): `sim` advanced from its
    start to each sample time, its reference read there."""
    errors = []
    for t in times:
        sim.advance_to(t)
        errors.append(sim.q[ARM_Q] - sim.arm_reference()[0])
    errors = np.array(errors)
    return float(np.sqrt(np.mean(errors ** 2))), float(np.abs(errors).max())


def measure(progress, quick: bool = False) -> list:
    """Rows: (mode, feedforward, what it does, CPU per step, rhs per step, RMS, max)."""
    base = scene()
    times = np.arange(1, int(DURATION * SAMPLE_RATE) + 1) / SAMPLE_RATE
    repeats = 2 if quick else 25
    prepared(base, "joint_trajectory", "computed_torque").sample(times[:2])   # warm the caches
    best = np.full(len(MODES), np.inf)
    for _ in range(repeats):   # round robin: a slow spell of the machine hits every mode alike
        for i, (mode, feedforward, _) in enumerate(MODES):
            sim = prepared(base, mode, feedforward)
            start = time.thread_time()
            sim.sample(times)
            best[i] = min(best[i], time.thread_time() - start)
    rows = []
    for i, (mode, feedforward, what) in enumerate(MODES):
        sim = prepared(base, mode, feedforward)
        rms, worst = (np.nan, np.nan) if mode == "effort" else tracking(sim, times)
        sim.advance_to(times[-1])
        per_step = best[i] / sim.steps
        rows.append((mode, feedforward, what, per_step, sim.rhs_evaluations / sim.steps, rms,
                     worst))
        progress(f"{mode} {feedforward}: {per_step * 1e6:.2f} µs per step, tracking RMS "
                 f"{rms:.2e}, max {worst:.2e}")
    return rows


def section(rows, number: int = 8) -> str:
    """The report's section: a table per mode and the ≤ 15 % target."""
    effort = rows[0][3]
    lines = [f"## {number}. Arm controllers", "",
             __doc__.split("\n\n")[1].strip().replace("\n", " "), ""]
    body = []
    for mode, feedforward, what, per_step, rhs, rms, worst in rows:
        tracked = "—" if mode == "effort" else f"{rms:.1e} / {worst:.1e}"
        body.append((mode, "—" if mode == "effort" else feedforward, what, seconds(per_step),
                     f"{per_step / effort:.2f}×", f"{rhs:.0f}", tracked))
    lines += [table(("arm", "feedforward", "command", "CPU per step", "vs effort",
                     "rhs per step", "tracking RMS / max (rad, m)"), body), ""]
    pid = [row for row in rows[1:] if row[1] != "computed_torque"]
    lines += ["| target | measured in this run | verdict |", "|---|---|---|",
              _target("a controller (PID, no or gravity feedforward) adds ≤ 15 % to a 1 kHz rk4 "
                      "step", pid, effort),
              _target("the same, computed torque included", rows[1:], effort), ""]
    return "\n".join(lines)


def _target(what: str, rows, effort: float) -> str:
    """A target row: the costliest of `rows` against effort mode's step."""
    mode, feedforward, _, per_step = max(rows, key=lambda row: row[3])[:4]
    added = per_step / effort - 1.0
    return (f"| {what} | costliest: {mode} {feedforward}, {seconds(per_step)} vs "
            f"{seconds(effort)} | {verdict(per_step <= TARGET * effort, f'{added:+.0%}')} |")
