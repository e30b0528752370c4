"""DIR/REPORT.md and its plots: the stability atlas (failure rate per method and step or
tolerance), population work–precision (CPU per run against energy error over the population)
and histograms of the final state."""
from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import numpy as np

from ..scene.loading import FIXED_STEP_METHODS
from .spec import Spec

HISTOGRAM_COLUMNS = 8


def settings(table, spec: Spec) -> list[tuple[str, str, float]]:
    """Each row's (method, "dt" or "rtol", value): the varied column if any, else the scene's."""
    base = spec.document["integrator"]

    def column(key):
        name = f"integrator.{key}"
        if name in table.column_names:
            return table.column(name).to_pylist()
        return [base[key]] * table.num_rows

    methods, dts, rtols = column("method"), column("dt"), column("rtol")
    return [(str(m), "dt", _number(d)) if m in FIXED_STEP_METHODS else (str(m), "rtol", _number(r))
            for m, d, r in zip(methods, dts, rtols, strict=True)]


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def write(directory: Path, table, spec: Spec) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory = Path(directory)
    rows = settings(table, spec)
    ok = np.array([s == "ok" for s in table.column("status").to_pylist()])
    lines = ["# Sweep report", "",
             f"{table.num_rows} runs of `{spec.document.get('name', 'scene')}` "
             f"for {spec.duration:g} s: "
             f"{int(ok.sum())} ok, {int((~ok).sum())} failed.", ""]
    if spec.varied:
        lines += ["Varied: " + ", ".join(f"`{path}`" for path in spec.varied) + ".", ""]
    lines += _atlas(plt, directory, rows, ok)
    lines += _work_precision(plt, directory, table, rows, ok)
    lines += _histograms(plt, directory, table, ok)
    errors = Counter(e for e in table.column("error").to_pylist() if e)
    if errors:
        lines += ["## Failures", "", "| runs | error |", "|---:|---|"]
        lines += [f"| {n} | {message.replace('|', '/')} |" for message, n in errors.most_common(10)]
        lines += [""]
    path = directory / "REPORT.md"
    path.write_text("\n".join(lines))
    return path


def _label(kind: str, value: float) -> str:
    return f"{kind}={value:.0e}"


def _atlas(plt, directory, rows, ok) -> list[str]:
    methods = sorted({m for m, _, _ in rows})
    steps = sorted({(k, v) for _, k, v in rows},
                   key=lambda kv: (kv[0], -kv[1] if not math.isnan(kv[1]) else 0))
    rate = np.full((len(methods), len(steps)), np.nan)
    for i, method in enumerate(methods):
        for j, (kind, value) in enumerate(steps):
            chosen = [k for k, r in enumerate(rows) if r[0] == method and r[1] == kind
                      and (r[2] == value or math.isnan(r[2]) and math.isnan(value))]
            if chosen:
                rate[i, j] = 1.0 - ok[chosen].mean()
    figure, axes = plt.subplots(figsize=(1.2 + 1.1 * len(steps), 1.0 + 0.5 * len(methods)))
    image = axes.imshow(rate, cmap="RdYlGn_r", vmin=0.0, vmax=1.0, aspect="auto")
    for i in range(len(methods)):
        for j in range(len(steps)):
            if not np.isnan(rate[i, j]):
                axes.text(j, i, f"{100 * rate[i, j]:.0f}%", ha="center", va="center", fontsize=8)
    axes.set_xticks(range(len(steps)), [_label(*s) for s in steps], rotation=30, ha="right",
                    fontsize=8)
    axes.set_yticks(range(len(methods)), methods, fontsize=8)
    axes.set_title("failure rate (stability atlas)", fontsize=9)
    figure.colorbar(image, ax=axes, fraction=0.05)
    figure.tight_layout()
    figure.savefig(directory / "atlas.png", dpi=90)
    plt.close(figure)
    table = ["| method | step / tolerance | runs | failed |", "|---|---|---:|---:|"]
    for method in methods:
        for kind, value in steps:
            chosen = [k for k, r in enumerate(rows)
                      if r[0] == method and r[1] == kind and r[2] == value]
            if chosen:
                table.append(f"| {method} | {_label(kind, value)} | {len(chosen)} | "
                             f"{int((~ok[chosen]).sum())} |")
    return ["## Stability atlas", "", "Share of failed runs per integrator and step (fixed-step "
            "methods) or relative tolerance (adaptive ones), over everything else the sweep "
            "varies.",
            "", "![stability atlas](atlas.png)", "", *table, ""]


def _work_precision(plt, directory, table, rows, ok) -> list[str]:
    cpu = np.array(table.column("cpu_s").to_pylist(), dtype=float)
    energy = np.abs(np.array([np.nan if v is None else v
                              for v in table.column("energy_error").to_pylist()], dtype=float))
    figure, axes = plt.subplots(figsize=(5.5, 4.0))
    text = ["| method | step / tolerance | ok runs | median CPU (ms) | median |energy error| (J) "
            "| 90th pct (J) |",
            "|---|---|---:|---:|---:|---:|"]
    for method in sorted({r[0] for r in rows}):
        points = []
        for kind, value in sorted({(r[1], r[2]) for r in rows if r[0] == method},
                                  key=lambda kv: -kv[1]):
            chosen = [k for k, r in enumerate(rows) if r[0] == method and r[2] == value and ok[k]]
            if not chosen:
                continue
            e = np.maximum(energy[chosen], 1e-17)
            points.append((np.median(e), np.percentile(e, 10), np.percentile(e, 90),
                           np.median(cpu[chosen])))
            text.append(f"| {method} | {_label(kind, value)} | {len(chosen)} | "
                        f"{1e3 * np.median(cpu[chosen]):.2f} | "
                        f"{np.median(e):.2e} | {np.percentile(e, 90):.2e} |")
        if points:
            p = np.array(points)
            axes.errorbar(p[:, 0], p[:, 3] * 1e3, xerr=[p[:, 0] - p[:, 1], p[:, 2] - p[:, 0]],
                          marker="o", capsize=3, label=method)
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xlabel("|energy error| at the end (J): median, bars 10–90 % of runs")
    axes.set_ylabel("CPU per run (ms), median")
    axes.set_title("population work–precision", fontsize=9)
    if axes.get_legend_handles_labels()[0]:
        axes.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(directory / "work_precision.png", dpi=90)
    plt.close(figure)
    return ["## Population work–precision", "", "Cost against accuracy over the whole population: "
            "the error is the energy balance at the end (T + V − W + impact losses − E0, zero for "
            "exact physics), so it needs no reference run.", "",
            "![population work-precision](work_precision.png)", "", *text, ""]


def _histograms(plt, directory, table, ok) -> list[str]:
    names = [n for n in table.column_names
             if n in ("x", "y", "yaw") or n[:1] in "ql" and n[1:].isdigit()]
    names = names[:HISTOGRAM_COLUMNS]
    if not ok.any() or not names:
        return []
    columns = min(4, len(names))
    rows = math.ceil(len(names) / columns)
    figure, grid = plt.subplots(rows, columns, figsize=(2.6 * columns, 2.0 * rows), squeeze=False)
    for axes, name in zip(grid.flat, names, strict=False):
        values = np.array(table.column(name).to_pylist(), dtype=float)[ok]
        axes.hist(values, bins=min(40, max(5, int(np.sqrt(len(values))))))
        axes.set_title(name, fontsize=8)
        axes.tick_params(labelsize=7)
    for axes in list(grid.flat)[len(names):]:
        axes.axis("off")
    figure.suptitle("final state over the ok runs", fontsize=9)
    figure.tight_layout()
    figure.savefig(directory / "final_state.png", dpi=90)
    plt.close(figure)
    return ["## Final state", "", "![final-state histograms](final_state.png)", ""]
