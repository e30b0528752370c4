"""Work–precision: every integrator over a sweep of dt or rtol, against a tight reference run.

Error is the largest |state − reference| (q and u, ∞-norm) over the 100 Hz samples; the
reference is DOP853 at rtol 1e-13, atol 1e-14. A second reference at rtol 1e-12 tells how far
the reference itself can be trusted (`reference_spread`).
Impacts and releases from a stop are located in time by the engine, so errors converge across
them and are measured over the whole run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..scene.loading import make_integrator
from ..scene.methods import METHODS
from .runs import Run, integrator, simulate

SWEEPS = {name: list(method.sweep) for name, method in METHODS.items()}
QUICK_SWEEPS = {method: values[::2] for method, values in SWEEPS.items()}
TARGETS = (1e-3, 1e-6, 1e-9)


@dataclass
class Point:
    method: str
    value: float          # dt (s) or rtol
    run: Run
    error: float          # largest state error against the reference, whole run


@dataclass
class WorkPrecision:
    scene: str
    reference: Run
    reference_spread: float
    points: list = field(default_factory=list)

    def by_method(self) -> dict:
        methods: dict = {}
        for point in self.points:
            methods.setdefault(point.method, []).append(point)
        return methods

    def recommend(self, target: float):
        """The cheapest (CPU per simulated second) setting whose error is within `target`."""
        good = [p for p in self.points if p.run.ok and p.error <= target]
        return min(good, key=lambda p: p.run.cpu) if good else None


def sweep(scene, progress, quick: bool = False, repeats: int = 2) -> WorkPrecision:
    progress(f"reference run: dop853 rtol 1e-13 ({scene.name})")
    reference = simulate(scene, make_integrator(scene.integrator, "dop853", rtol=1e-13, atol=1e-14))
    second = simulate(scene, make_integrator(scene.integrator, "dop853", rtol=1e-12, atol=1e-13))
    result = WorkPrecision(scene.name, reference, second.error_against(reference))
    for method, values in (QUICK_SWEEPS if quick else SWEEPS).items():
        for value in values:
            run = simulate(scene, integrator(scene, method, value), repeats=1 if quick else repeats)
            point = Point(method, value, run, run.error_against(reference))
            result.points.append(point)
            progress(f"{scene.name}: {method} {run.setting}: "
                     + (f"{run.cpu_per_second * 1e3:.2f} ms CPU per simulated s, "
                        f"error {point.error:.1e}" if run.ok else f"failed ({run.failure})"))
    return result


def plot(result: WorkPrecision, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.0, 5.0))
    markers = dict(zip(METHODS, "v^soDPX", strict=True))   # one per method, in the registry's order
    for method, points in result.by_method().items():
        good = [p for p in points if p.run.ok and math.isfinite(p.error)]
        if not good:
            continue
        ax.loglog([p.run.cpu_per_second for p in good], [max(p.error, 1e-16) for p in good],
                  marker=markers.get(method, "o"), label=method)
    for target in TARGETS:
        ax.axhline(target, color="0.8", lw=0.8, zorder=0)
    ax.axhline(max(result.reference_spread, 1e-16), color="r", ls=":", lw=1.0,
               label="reference spread (rtol 1e-12 vs 1e-13)")
    ax.set_xlabel("CPU seconds per simulated second")
    ax.set_ylabel("largest state error against the reference")
    ax.set_title(f"Work–precision: {result.scene}")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
