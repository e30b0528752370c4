"""Scaling: one inverse- and one forward-dynamics evaluation for n = 1 … 32 links (random
robots), the recursive algorithms against non-recursive baselines, with fitted growth orders.

- inverse dynamics: the Gibbs–Appell recursion (O(n)) against Q = M u̇ + h with M assembled
  column by column (n_u recursive passes, O(n²));
- forward dynamics: the articulated-body recursion (O(n)) against h + M column by column +
  Cholesky (O(n³) eventually), and against h + composite-rigid-body M + Cholesky.

Each evaluation is timed in the compiled core's own loop (`core.Dynamics.time_dynamics`).
"""
from __future__ import annotations

import numpy as np

from ..dynamics import Dynamics
from ..scene.loading import parse_scene
from . import loops
from .scenes import random_robot_document

LINKS = (1, 2, 4, 8, 16, 32)
SERIES = {"ID recursive": "inverse", "ID by columns": "inverse_by_columns",
          "FD articulated": "forward", "FD composite + Cholesky": "forward_composite_cholesky",
          "FD by columns + Cholesky": "forward_by_columns_cholesky"}   # name → the core's


def measure(progress, quick: bool = False) -> dict:
    """{series: [seconds per evaluation for each n in LINKS]}: the compiled core's loops
    (`core.Dynamics.time_dynamics`)."""
    times = {name: [] for name in SERIES}
    target = 0.01 if quick else 0.1
    for n in LINKS:
        scene = parse_scene(random_robot_document(n, seed=100 + n), f"random_{n}")
        dyn = Dynamics(scene.robot, gravity=10.0, tip_mass=0.2)
        rng = np.random.default_rng(n)
        nu = scene.robot.n_u
        q = np.array(scene.initial_q)
        u, ud, Q = rng.normal(size=nu), rng.normal(size=nu), rng.normal(size=nu)
        core, g = dyn.core, dyn.gravity
        for name, what in SERIES.items():
            x = ud if what.startswith("inverse") else Q

            def timer(calls, what=what, x=x, core=core, q=q, u=u, g=g):
                return core.time_dynamics(what, q, u, x, g, calls)
            times[name].append(loops.per_call(timer, target=target))
        progress(f"scaling n = {n}: "
                 + ", ".join(f"{name} {times[name][-1] * 1e6:.2f} µs" for name in SERIES))
    return times


def growth_order(times, links=LINKS, smallest: int = 4) -> float:
    """Slope of log t against log n over n ≥ `smallest` (the asymptotic regime)."""
    n = np.array(links, dtype=float)
    t = np.array(times, dtype=float)
    keep = n >= smallest
    return float(np.polyfit(np.log(n[keep]), np.log(t[keep]), 1)[0])


def plot(times: dict, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    for name, values in times.items():
        ax.loglog(LINKS, np.array(values) * 1e6, marker="o",
                  label=f"{name} (order {growth_order(values):.2f})",
                  ls="-" if "recursive" in name or "articulated" in name else "--")
    n = np.array(LINKS, dtype=float)
    ref = times["FD articulated"][2] * 1e6
    ax.loglog(n, ref * n / n[2], color="0.6", lw=0.8, ls=":", label="O(n)")
    ax.set_xlabel("links n")
    ax.set_ylabel("µs per evaluation (the core's loop in C++)")
    ax.set_title("Inverse and forward dynamics against the number of links")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
