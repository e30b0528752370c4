"""The report's Markdown pieces: durations, error figures, tables and verdicts, as every section
of REPORT.md writes them (report.py and the sections that studies write themselves)."""
from __future__ import annotations

import math


def seconds(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    if value < 1e-6:
        return f"{value * 1e9:.0f} ns"
    if value < 1e-3:
        return f"{value * 1e6:.2f} µs"
    if value < 1.0:
        return f"{value * 1e3:.2f} ms"
    return f"{value:.2f} s"


def sci(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:.1e}"


def table(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |"
              for row in rows]
    return "\n".join(lines)


def verdict(ok: bool, how: str) -> str:
    return f"**PASS** ({how})" if ok else f"**MISS** ({how})"
