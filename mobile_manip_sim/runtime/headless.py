"""The headless run: a scene simulated from its initial state over a grid of sample times, and
the CSV table of its samples. `simulate` writes it, a sweep runs it on Dask workers, the bench
and the plots read it.

Columns: t, x, y, yaw, theta_R, theta_L, q1, l1, …, qn, ln, v, omega, qd1, ld1, …, qdn, ldn,
energy (T + V, J): the time, q, u and the total energy (`csv_row`).

A scene with a ``controller:`` section drives the arm by it from t = 0 (`Simulation` applies
the section's command); the run then also measures how well the arm tracked its reference at
the samples (`Tracking`: RMS and max of q − q_ref per arm joint), in the summary line.
"""
from __future__ import annotations

import time

import numpy as np

from ..engine import layout
from ..engine.simulation import Simulation
from ..scene.coordinates import arm_width
from ..scene.loading import Scene
from .timeline import sample_times


def csv_columns(n_links: int) -> list[str]:
    """The header of a run's CSV table (see the module docstring)."""
    arm_q = [name for i in range(1, n_links + 1) for name in (f"q{i}", f"l{i}")]
    arm_u = [name for i in range(1, n_links + 1) for name in (f"qd{i}", f"ld{i}")]
    return ["t", "x", "y", "yaw", "theta_R", "theta_L", *arm_q, "v", "omega", *arm_u, "energy"]


def csv_row(sim: Simulation) -> list:
    """The simulation's present sample, in `csv_columns` order (written with ``repr``: exact)."""
    return [sim.t, *sim.q.tolist(), *sim.u.tolist(), sim.total_energy()]


class Tracking:
    """The arm's tracking error q − q_ref over the samples of a run (rad or m per joint)."""

    def __init__(self, n_arm: int):
        self.count, self.squares, self.max = 0, np.zeros(n_arm), np.zeros(n_arm)

    def sample(self, sim: Simulation) -> None:
        error = sim.q[layout.arm_q(0):] - sim.arm_reference()[0]
        self.count += 1
        self.squares += error * error
        self.max = np.maximum(self.max, np.abs(error))

    @property
    def rms(self) -> np.ndarray:
        return np.sqrt(self.squares / max(self.count, 1))

    def line(self) -> str:
        def values(array):
            return "[" + ", ".join(f"{v:.3g}" for v in array) + "]"
        return f"arm tracking error RMS {values(self.rms)}, max {values(self.max)} (rad, m)"


def hold_ledger(sim: Simulation) -> str:
    """"N holds removing E J" when the engine held impacts (`Simulation.holds`), else ""."""
    return f"{sim.holds} holds removing {sim.hold_energy:.3e} J" if sim.holds else ""


def summary_line(sim: Simulation, wall: float, simulated: float | None = None) -> str:
    """`wall` s of wall time spent on `simulated` s of simulated time (default: all of it); the
    impacts and, when the engine held any (`Simulation.holds`), how many and the energy they
    removed beyond the impact law — which the energy error then shows; with an arm controller,
    how well it tracked (`Tracking`)."""
    simulated = sim.t if simulated is None else simulated
    rtf = simulated / wall if wall > 0 else float("inf")
    holds = f"{hold_ledger(sim)}, " if sim.holds else ""
    line = (f"simulated {sim.t:.6g} s in {wall:.4g} s wall (real-time factor {rtf:.1f}), "
            f"{sim.steps} steps, {sim.rhs_evaluations} rhs evaluations, "
            f"{len(sim.impacts)} impacts, {holds}energy error {sim.energy_error():.3e} J")
    tracking = getattr(sim, "tracking", None)
    return line if tracking is None else f"{line}; {tracking.line()}"


def run(scene: Scene, duration: float, sample_rate: float, settings=None, on_sample=None,
        progress=None) -> Simulation:
    """Simulate `duration` s from the scene's initial state with its constant efforts, calling
    ``on_sample(sim)`` at every sample time (and ``progress.update(t)`` after it, if given: a
    `progress.Progress`, which also follows the simulated time between samples);
    returns the finished simulation. Its ``timing`` is (simulated s, wall s) from the end of the
    first sample that advanced time on, or None; its ``tracking`` the arm's `Tracking` when a
    controller drives the arm, else None."""
    sim = Simulation(scene, settings)
    if progress:
        progress.follow(lambda: sim.t)
    timing_from = None
    sim.tracking = Tracking(arm_width(sim.nu)) if sim.arm_controller.active else None
    for t in sample_times(duration, sample_rate):
        sim.advance_to(t)
        if sim.tracking:
            sim.tracking.sample(sim)
        if timing_from is None and sim.t > 0:
            timing_from = (sim.t, time.perf_counter())
        if on_sample:
            on_sample(sim)
        if progress:
            progress.update(t)
    sim.timing = None
    if timing_from is not None and sim.t > timing_from[0]:
        sim.timing = (sim.t - timing_from[0], time.perf_counter() - timing_from[1])
    return sim
