"""The engine targets that the other sections do not measure: what dop853's cost does as the
tolerance loosens, and the paper scene with its stops at error ≤ 1e-6. (The MuJoCo targets are in
§7; the start times, a warm `simulate` among them, in §12; the node's memory in bench/NODE.md.)"""
from __future__ import annotations

from ..scene.loading import load_scene, make_integrator
from .runs import simulate
from .scenes import without_stroke_limits


def measure(progress, paper_wp) -> dict:
    smooth = without_stroke_limits(load_scene())
    rhs = {}
    for rtol in (1e-4, 1e-10):
        run = simulate(smooth,
                       make_integrator(smooth.integrator, "dop853", rtol=rtol, atol=rtol / 100))
        rhs[rtol] = run.rhs_evaluations
        progress(f"dop853 rtol {rtol:g}, paper robot without stops: {run.rhs_evaluations} rhs")
    stops = [p for p in (paper_wp.points if paper_wp else [])
             if p.method == "dop853" and p.run.ok and p.error <= 1e-6]
    best = min(stops, key=lambda p: p.run.cpu, default=None)
    return {"rhs": rhs, "stops_best": best}


def rows(measured, verdict, seconds) -> list:
    out = []
    rhs = measured["rhs"]
    ratio = rhs[1e-4] / rhs[1e-10]
    out.append(("dop853, paper robot without stops, 100 Hz samples: rhs at rtol 1e-4 ≤ ¼ of "
                "those at 1e-10",
                f"{rhs[1e-4]} vs {rhs[1e-10]}: ratio {ratio:.2f}",
                verdict(ratio <= 0.25, f"{0.25 / ratio:.2f}× inside" if ratio <= 0.25 else
                        f"missed by {ratio / 0.25:.2f}×: 10 steps and 2 rejections at rtol 1e-4, "
                        "of which the first (0.009 s, the starting guess) and the ramp-up from it "
                        "do not shrink with rtol; 2 of its 9 sampled steps need the 3 extra "
                        "dense-output stages; SciPy's DOP853 gives 176/593 = 0.30")))
    best = measured["stops_best"]
    if best is None:
        out.append(("dop853, paper scene with its stops, largest state error ≤ 1e-6 in ≤ 2 ms CPU",
                    "no dop853 setting reached 1e-6", "**MISS**"))
    else:
        cpu = best.run.cpu
        out.append(("dop853, paper scene with its stops, largest state error ≤ 1e-6 in ≤ 2 ms CPU",
                    f"rtol {best.value:g}: {seconds(cpu)} (error {best.error:.1e}, "
                    f"{best.run.impacts} impacts)",
                    verdict(cpu <= 2e-3, f"{2e-3 / cpu:.1f}× inside" if cpu <= 2e-3 else
                            f"missed by {cpu / 2e-3:.2f}×: {best.run.rhs_evaluations} right-hand "
                            "sides at the sweep's loosest rtol within 1e-6 (the sweep steps rtol "
                            "by 100×), and one call from Python per 100 Hz sample")))
    return out
