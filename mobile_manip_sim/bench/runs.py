"""One timed run of a scene, with the figures every section reports.

A run advances a `Simulation` to each sample time (100 Hz by default, as `simulate` does); only
the `advance_to` calls are timed. Between them, outside the clock, it records the state and the
checks: energy balance (`Simulation.energy_error`), the nonholonomic constraint residuals
(`dynamics.constraint_residuals`) and how far any rod is outside its stroke.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..dynamics import constraint_residuals
from ..engine.simulation import Simulation
from ..runtime.timeline import sample_times
from ..scene.coordinates import SLIDES_Q
from ..scene.errors import SimulationError
from ..scene.loading import IntegratorSettings, Scene, make_integrator
from ..scene.methods import METHODS


class Clock:
    """CPU time of this thread and wall time, started together."""

    def __init__(self):
        self.cpu0, self.wall0 = time.thread_time(), time.perf_counter()

    def read(self) -> tuple[float, float]:
        return time.thread_time() - self.cpu0, time.perf_counter() - self.wall0


@dataclass
class Run:
    scene: str
    method: str
    setting: str               # "dt=1e-3" or "rtol=1e-9"
    duration: float            # simulated s
    cpu: float = math.nan      # s of CPU (best of the repeats)
    wall: float = math.nan     # s of wall clock (best of the repeats)
    rhs_evaluations: int = 0
    steps: int = 0
    impacts: int = 0
    energy_error: float = math.nan          # J, largest |T + V − W + losses − E0| over samples
    constraint_residual: float = math.nan   # m/s, largest |no-skid| or |no-slip| over samples
    stroke_violation: float = 0.0           # m, largest distance of a rod outside its stroke
    energy_scale: float = 0.0               # J, largest T + |V − V0| + |W| over samples
    samples: np.ndarray | None = field(default=None, repr=False)   # (k, n_q + n_u) at sample times
    failure: str | None = None
    simulation: Simulation | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return self.failure is None

    @property
    def cpu_per_second(self) -> float:
        """CPU seconds per simulated second."""
        return self.cpu / self.duration

    @property
    def wall_per_second(self) -> float:
        return self.wall / self.duration

    def error_against(self, reference: "Run") -> float:
        """Largest |state − reference state| over the common samples (q and u, ∞-norm)."""
        if not self.ok or self.samples is None or reference.samples is None:
            return math.inf
        k = min(len(self.samples), len(reference.samples))
        return float(np.abs(self.samples[:k] - reference.samples[:k]).max()) if k else 0.0


def settings_label(settings: IntegratorSettings) -> str:
    return f"dt={settings.dt:.0e}" if settings.fixed_step else f"rtol={settings.rtol:.0e}"


def integrator(scene: Scene, method: str, value: float) -> IntegratorSettings:
    """`method` with dt = value (fixed step) or rtol = value, atol = value / 100 (adaptive)."""
    if METHODS[method].fixed_step:
        return make_integrator(scene.integrator, method, dt=value)
    return make_integrator(scene.integrator, method, rtol=value, atol=value * 1e-2)


def simulate(scene: Scene, settings: IntegratorSettings, duration: float | None = None,
             sample_rate: float = 100.0, repeats: int = 1, record: bool = True) -> Run:
    """Run `scene` with `settings`; the first repeat records the figures, all are timed."""
    duration = scene.duration if duration is None else duration
    run = Run(scene.name, settings.method, settings_label(settings), duration)
    times = list(sample_times(duration, sample_rate))
    best_cpu = best_wall = math.inf
    for repeat in range(repeats):
        sim = Simulation(scene, settings)
        n = scene.robot.n_links
        stroke = np.array(scene.robot.stroke)
        samples, energy, residual, outside, scale = [], 0.0, 0.0, 0.0, 0.0
        V0 = sim.dynamics.energy(sim.q, sim.u)[1]
        cpu = wall = 0.0
        try:
            for t in times:
                clock = Clock()
                sim.advance_to(t)
                dc, dw = clock.read()
                cpu += dc
                wall += dw
                if repeat == 0 and record:
                    samples.append(np.concatenate([sim.q, sim.u]))
                    energy = max(energy, abs(sim.energy_error()))
                    T, V = sim.dynamics.energy(sim.q, sim.u)
                    scale = max(scale, T + abs(V - V0) + abs(sim.work))
                    residual = max(residual,
                                   *map(abs, constraint_residuals(sim.model, sim.q, sim.qdot())))
                    if n and scene.effects.stroke_limits is not None:
                        l = sim.q[SLIDES_Q]
                        outside = max(outside,
                                      float(np.max(np.maximum(stroke[:, 0] - l, l - stroke[:, 1]))))
        except SimulationError as error:
            run.failure = str(error)
            run.simulation = sim
            return run
        best_cpu, best_wall = min(best_cpu, cpu), min(best_wall, wall)
        if repeat == 0:
            run.rhs_evaluations, run.steps = sim.rhs_evaluations, sim.steps
            run.impacts = len(sim.impacts)
            run.energy_error, run.constraint_residual = energy, residual
            run.stroke_violation = max(outside, 0.0)
            run.energy_scale = scale
            run.samples = np.array(samples) if record else None
            run.simulation = sim
    run.cpu, run.wall = best_cpu, best_wall
    return run
