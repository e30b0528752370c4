"""The seed paper's figures, and the energy balance, of a `Run`: each function of `FIGURES` turns
a run into one matplotlib `Figure` (Agg, no pyplot state); `plot` draws them all and writes one
PNG per figure and an ``index.html`` showing them, and returns them by name so tests can
inspect their lines.
"""
from __future__ import annotations

import html
import textwrap
from pathlib import Path
from typing import Callable

import numpy as np
from matplotlib.figure import Figure

from ..dynamics import constraint_residuals
from ..recording.run import Run, dynamics_of, load_run
from ..scene.coordinates import YAW, X, Y, q_slide, q_turn, u_slide, u_turn
from ..scene.effects import settings as effect_settings
from ..scene.errors import UserError
from .energy import impact_losses, work

RESIDUAL_FLOOR = 1e-17      # |residual| plotted at least this, so exact zeros show on a log axis
HEADING_MARKS = 12          # about this many heading arrows along the base's path
FIGURE_SIZE = (8.0, 4.8)    # inches
DPI = 120


# --- quantities the figures show -----------------------------------------------------------

def plain(text) -> str:
    """``text`` (a scene's name, a file name) shown as written: matplotlib reads text between
    two ``$`` as mathtext, and a name such as ``$\\frac{$`` would fail the figure."""
    return str(text).replace("$", r"\$")


def residuals(run: Run) -> np.ndarray:
    """(N, 2) docs/model.md's constraint residuals (no skid, no slip) at each sample, m/s."""
    return np.array([constraint_residuals(run.scene.robot, q_k, qdot_k)
                     for q_k, qdot_k in zip(run.q, run.qdot, strict=True)])


def tip_path(run: Run) -> np.ndarray:
    """(N, 3) world position of the distal end of the last rod."""
    dynamics = dynamics_of(run.scene)
    return np.array([dynamics.tip_position(q_k) for q_k in run.q])


# --- figures ----------------------------------------------------------------------------------

def _figure(run: Run, what: str) -> tuple[Figure, object]:
    figure = Figure(figsize=FIGURE_SIZE, dpi=DPI, layout="constrained")
    figure.suptitle(f"{plain(run.scene.name)}: {what}")
    return figure, figure.add_subplot()


def _no_arm(axes) -> None:
    axes.text(0.5, 0.5, "no arm links in this scene", ha="center", va="center",
              transform=axes.transAxes)


def _color(i: int) -> str:
    return f"C{i % 10}"


def _arm_series(run: Run, what: str, column: Callable[[int], np.ndarray], symbol: str,
                joint: Callable[[int], int], unit: str, quantity: str) -> tuple[Figure, object]:
    """One curve per link of ``column(k)`` (rods k = 1 … n) against time; ``joint(k)`` is the
    index of its joint in `RobotModel.joint_names`."""
    figure, axes = _figure(run, what)
    names = run.joint_names()
    for k in range(1, run.n_links + 1):
        axes.plot(run.t, column(k), color=_color(k - 1),
                  label=f"${symbol}_{{{k}}}$  ({names[joint(k)]})")
    axes.set_xlabel("t (s)")
    axes.set_ylabel(f"{quantity} ({unit})")
    if run.n_links:
        axes.legend(loc="best")
    else:
        _no_arm(axes)
    axes.grid(True, alpha=0.3)
    return figure, axes


def figure_joint_angles(run: Run) -> Figure:
    """q_i(t): one curve per link."""
    return _arm_series(run, "joint angles", lambda k: run.q[:, q_turn(k)], "q",
                       u_turn, "rad", "joint angle")[0]


def figure_joint_rates(run: Run) -> Figure:
    """q̇_i(t): one curve per link."""
    return _arm_series(run, "joint rates", lambda k: run.u[:, u_turn(k)], r"\dot q",
                       u_turn, "rad/s", "joint rate")[0]


def figure_extensions(run: Run) -> Figure:
    """l_i(t): one curve per link, its two stroke ends dashed, each impacted link's impacts
    marked at their stop (one marker series per link with impacts)."""
    figure, axes = _arm_series(run, "rod extensions", lambda k: run.q[:, q_slide(k)], "l",
                               u_slide, "m", "rod extension")
    for i, (low, high) in enumerate(run.scene.robot.stroke):
        for end, value in (("min", low), ("max", high)):
            axes.axhline(value, color=_color(i), linestyle="--", linewidth=0.9,
                         label=f"stroke of $l_{{{i + 1}}}$" if end == "min" else None)
    for link, impacts in _impacts_by_link(run).items():
        stroke = run.scene.robot.stroke[link - 1]
        axes.plot([impact["time"] for impact in impacts],
                  [stroke[0] if impact["stop"] == "lower" else stroke[1] for impact in impacts],
                  linestyle="none", marker="X", markersize=9, color=_color(link - 1),
                  markeredgecolor="black", label=f"impact of rod {link}")
    if run.n_links:
        axes.legend(loc="best", fontsize="small")
    return figure


def figure_extension_rates(run: Run) -> Figure:
    """l̇_i(t): one curve per link, and per impacted link its approach speeds l̇⁻ at the impacts."""
    figure, axes = _arm_series(run, "extension rates", lambda k: run.u[:, u_slide(k)],
                               r"\dot l", u_slide, "m/s", "extension rate")
    for link, impacts in _impacts_by_link(run).items():
        axes.plot([impact["time"] for impact in impacts],
                  [impact["ld_before"] for impact in impacts], linestyle="none", marker="o",
                  markerfacecolor="none", markersize=8, color=_color(link - 1),
                  label=f"rod {link} just before impact")
    if run.n_links:
        axes.legend(loc="best", fontsize="small")
    return figure


def _impacts_by_link(run: Run) -> dict[int, list[dict]]:
    by_link: dict[int, list[dict]] = {}
    for impact in run.impacts:
        by_link.setdefault(impact["link"], []).append(impact)
    return dict(sorted(by_link.items()))


def figure_base_path(run: Run) -> Figure:
    """The base's path (point A) in the x–y plane with heading arrows, the ground projection
    of the last rod's tip (when there is an arm), and where each starts. Equal aspect."""
    figure, axes = _figure(run, "path in the plane")
    x, y, yaw = run.q[:, X], run.q[:, Y], run.q[:, YAW]
    axes.plot(x, y, color="C0", label="base (axle midpoint A)")
    paths = [np.column_stack([x, y])]
    if run.n_links:
        tip = tip_path(run)[:, :2]
        axes.plot(tip[:, 0], tip[:, 1], color="C3",
                  label=f"tip of rod {run.n_links} (ground projection)")
        paths.append(tip)
    starts = np.array([path[0] for path in paths])
    axes.plot(starts[:, 0], starts[:, 1], linestyle="none", marker="o", markersize=6,
              color="black", markerfacecolor="white", label=f"start (t = {run.t[0]:.3g} s)")
    points = np.vstack(paths)
    extent = max(float(np.ptp(points[:, 0])), float(np.ptp(points[:, 1])), 0.05)
    marks = heading_marks(x, y)
    length = 0.07 * extent
    axes.quiver(x[marks], y[marks], length * np.cos(yaw[marks]), length * np.sin(yaw[marks]),
                angles="xy", scale_units="xy", scale=1.0, color="C0", width=0.003,
                label="heading")
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_aspect("equal", adjustable="datalim")
    axes.legend(loc="best", fontsize="small")
    axes.grid(True, alpha=0.3)
    return figure


def heading_marks(x: np.ndarray, y: np.ndarray, count: int = HEADING_MARKS) -> np.ndarray:
    """Indices of about ``count`` samples evenly spaced along the path (by arc length, so a
    slow start does not crowd them; by sample when the base hardly moves), first included."""
    step = np.hypot(np.diff(x), np.diff(y))
    arc = np.concatenate([[0.0], np.cumsum(step)])
    if arc[-1] < 1e-9:
        return np.arange(0, len(x), max(1, len(x) // count))
    targets = np.linspace(0.0, arc[-1], count + 1)[:-1]
    return np.unique(np.searchsorted(arc, targets))


def figure_constraints(run: Run) -> Figure:
    """|no-skid| and |no-slip| residuals (docs/model.md) on a log scale, floored at 1e-17."""
    figure, axes = _figure(run, "nonholonomic constraints")
    values = np.maximum(np.abs(residuals(run)), RESIDUAL_FLOOR)
    axes.semilogy(run.t, values[:, 0], color="C0",
                  label=r"no skid: $|\dot x \sin\psi - \dot y \cos\psi|$")
    axes.semilogy(run.t, values[:, 1], color="C1",
                  label=r"no slip: $|\dot x \cos\psi + \dot y \sin\psi"
                        r" - r(\dot\theta_R + \dot\theta_L)/2|$")
    axes.set_ylim(RESIDUAL_FLOOR / 3, max(1e-12, float(values.max()) * 30))
    axes.set_xlabel("t (s)")
    axes.set_ylabel(f"|residual| (m/s), floor {RESIDUAL_FLOOR:g}")
    axes.legend(loc="best", fontsize="small")
    axes.grid(True, which="major", alpha=0.3)
    source = ("rates from u through the constraints" if run.kind == "csv"
              else "recorded odometry twist and wheel velocities")
    axes.set_title(source, fontsize="small")
    return figure


def figure_energy(run: Run) -> Figure:
    """Top: T + V − E₀, the work W of efforts and damping, the impact losses L.
    Bottom: the balance (T + V − E₀) − W + L, zero for exact physics."""
    figure = Figure(figsize=(FIGURE_SIZE[0], FIGURE_SIZE[1] * 1.3), dpi=DPI, layout="constrained")
    figure.suptitle(f"{plain(run.scene.name)}: energy balance")
    top, bottom = figure.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    change = run.energy - run.energy[0]
    W, L = work(run), impact_losses(run)
    top.plot(run.t, change, color="C0", label=r"$T + V - E_0$")
    work_label = "W: work of efforts" + (" and damping" if _damped(run) else "")
    top.plot(run.t, W, color="C1", label=work_label)
    top.plot(run.t, L, color="C2", label="L: lost in impacts")
    top.set_ylabel("energy (J)")
    top.legend(loc="best", fontsize="small")
    top.grid(True, alpha=0.3)
    # two lines, each wrapped: one line ran past the figure's edges for a bag's longer source
    top.set_title("\n".join(textwrap.wrap(f"efforts: {plain(run.effort_source)}", 90) + [
        "W by the trapezoid rule at the sample rate, split at impacts"]), fontsize="small")
    bottom.plot(run.t, change - W + L, color="C3", label=r"$T + V - E_0 - W + L$")
    bottom.set_xlabel("t (s)")
    bottom.set_ylabel("balance (J)")
    bottom.legend(loc="best", fontsize="small")
    bottom.grid(True, alpha=0.3)
    return figure


def _damped(run: Run) -> bool:
    return effect_settings(run.scene).rate_damping is not None


# name → (function, caption); the PNG is <name>.png
FIGURES: dict[str, tuple[Callable[[Run], Figure], str]] = {
    "joint_angles": (figure_joint_angles, "Joint angles q_i(t)."),
    "joint_rates": (figure_joint_rates, "Joint rates q̇_i(t)."),
    "extensions": (figure_extensions, "Rod extensions l_i(t); dashed: the stroke ends; "
                                      "crosses: end-stop impacts."),
    "extension_rates": (figure_extension_rates, "Extension rates l̇_i(t); circles: the "
                                                "approach speed just before each impact."),
    "base_path": (figure_base_path, "The base's path in the plane with heading arrows, and "
                                    "the last rod's tip projected on the ground."),
    "constraints": (figure_constraints, "The two nonholonomic constraint residuals "
                                        "(|value|, floored at 1e-17 so exact zeros show)."),
    "energy": (figure_energy, "Energy balance: T + V − E₀ − W + L is zero for exact physics; "
                              "W is rebuilt from the samples (trapezoid rule), so it is "
                              "approximate at the sample rate."),
}


def make_figures(run: Run) -> dict[str, Figure]:
    return {name: function(run) for name, (function, _) in FIGURES.items()}


def write_figures(run: Run, figures: dict[str, Figure], out_dir) -> list[Path]:
    """Save each figure as ``<name>.png`` in out_dir, and an ``index.html`` showing them."""
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        paths = []
        for name, figure in figures.items():
            path = out_dir / f"{name}.png"
            figure.savefig(path)
            paths.append(path)
        (out_dir / "index.html").write_text(_index_html(run, figures), encoding="utf-8")
    except OSError as error:
        raise UserError(str(out_dir), f"cannot write ({error.strerror or error})") from None
    return paths


def _index_html(run: Run, figures: dict[str, Figure]) -> str:
    title = html.escape(f"{run.scene.name}: {run.source.name}")
    items = "\n".join(
        f'<figure id="{name}"><img src="{name}.png" alt="{html.escape(FIGURES[name][1])}">'
        f"<figcaption>{html.escape(FIGURES[name][1])}</figcaption></figure>"
        for name in figures)
    impacts = len(run.impacts)
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
figure {{ display: inline-block; margin: 0 1em 1.5em 0; vertical-align: top; }}
img {{ max-width: 100%; width: 760px; border: 1px solid #ddd; }}
figcaption {{ max-width: 760px; font-size: 0.9em; color: #333; }}
</style>
</head>
<body>
<h1>{title}</h1>
<p>{html.escape(run.kind)} run, {len(run.t)} samples from t = {run.t[0]:.6g} s to
{run.t[-1]:.6g} s, {run.n_links} links, {impacts} end-stop impact{'' if impacts == 1 else 's'};
efforts: {html.escape(run.effort_source)}.</p>
{items}
</body>
</html>
"""


def plot(run_path, out_dir, scene_path=None) -> dict[str, Figure]:
    """Load a run, draw every figure, write the PNGs and index.html; returns the figures."""
    run = load_run(run_path, scene_path)
    figures = make_figures(run)
    write_figures(run, figures, out_dir)
    return figures
