"""REPORT.md from the bench results: the speed targets first, then one section per study."""
from __future__ import annotations

import datetime
import math
import os
import platform
from pathlib import Path

from .scaling import LINKS, growth_order
from .tables import sci, seconds, table, verdict
from .versus import ACCURACY, SEED_SECONDS
from .work_precision import TARGETS


def _machine() -> str:
    cpu = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = []
    for name in ("numpy", "scipy", "pinocchio", "mujoco", "matplotlib"):
        try:
            module = __import__(name)
            versions.append(f"{name} {module.__version__}")
        except ImportError:
            versions.append(f"{name} (not installed)")
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return (f"{cpu}, {os.cpu_count()} logical cores; Python {platform.python_version()}; "
            f"{', '.join(versions)}. Load average at the end of the run: "
            f"{load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1 / 5 / 15 min).")


def _targets(results) -> tuple[str, list]:
    rows, notes = [], []
    per = results.get("per_evaluation")
    if per:
        times = per["times"]
        peer = times["Pinocchio: crba + rnea + projection + solve, from Python"]
        ours_py = times["ours: Dynamics.forward_dynamics (frames + articulated), from Python"]
        ours_c = times["ours: frames + articulated forward dynamics, compiled loop"]
        ratio = ours_py / peer
        rows.append(("One forward-dynamics evaluation of the paper robot ≤ ½ of Pinocchio's "
                     "(crba + rnea + solve from Python)",
                     f"ours from Python {seconds(ours_py)} vs Pinocchio {seconds(peer)}: "
                     f"ratio {ratio:.3f} (compiled loop: {seconds(ours_c)}, "
                     f"ratio {ours_c / peer:.4f})",
                     verdict(ratio <= 0.5, f"{0.5 / ratio:.1f}× inside the target" if ratio <= 0.5
                             else f"{ratio / 0.5:.1f}× too slow")))
    whole = results.get("whole_run")
    if whole:
        best = whole["best"]
        peer, ours_scipy, ours = (best["Pinocchio + SciPy DOP853"], best["ours + SciPy DOP853"],
                                  best["ours, Simulation"])
        if peer and ours:
            ratio = ours[1] / peer[1]
            rows.append((f"1.5 s paper run at largest state error ≤ {ACCURACY:g}: faster than "
                         f"Pinocchio + SciPy DOP853 (stroke limits removed, see §4)",
                         f"ours {seconds(ours[1])} ({ours[0]}) vs Pinocchio + SciPy "
                         f"{seconds(peer[1])} ({peer[0]}): ratio {ratio:.3f}"
                         + (f"; ours through the same SciPy DOP853: {seconds(ours_scipy[1])}, "
                            f"ratio {ours_scipy[1] / peer[1]:.3f}" if ours_scipy else ""),
                         verdict(ratio < 1.0, f"{1 / ratio:.1f}× faster" if ratio < 1.0
                                 else f"{ratio:.1f}× slower")))
        if ours:
            limit = SEED_SECONDS / 1000.0
            rows.append((f"the same run under 1/1000 of the seed's {SEED_SECONDS} s "
                         f"(= {seconds(limit)})",
                         f"ours {seconds(ours[1])} ({ours[0]}, "
                         f"{seconds(ours[1] / 1.5)} per simulated s)",
                         verdict(ours[1] < limit, f"{limit / ours[1]:.1f}× inside"
                                 if ours[1] < limit else f"{ours[1] / limit:.1f}× too slow")))
    paper = next((wp for wp in results.get("wp", []) if wp.scene == "paper_two_link"), None)
    if paper:
        pick = paper.recommend(ACCURACY)
        limit = SEED_SECONDS / 1000.0
        if pick:
            rows.append(("the paper scene as it is (end stops on), error ≤ 1e-6 against its "
                         "reference, under 1/1000 of 34.32 s",
                         f"{pick.method} {pick.run.setting}: {seconds(pick.run.cpu)} "
                         f"(error {sci(pick.error)})",
                         verdict(pick.run.cpu < limit, f"{limit / pick.run.cpu:.1f}× inside"
                                 if pick.run.cpu < limit
                                 else f"{pick.run.cpu / limit:.1f}× too slow")))
        else:
            best = min((p for p in paper.points if p.run.ok), key=lambda p: p.error, default=None)
            rows.append(("the paper scene as it is (end stops on), error ≤ 1e-6 against its "
                         "reference",
                         f"no setting reaches 1e-6 (best {sci(best.error) if best else '—'}): "
                         "see §1.1",
                         "**MISS** (accuracy floor, see §1.1)"))
    scaling = results.get("scaling")
    if scaling:
        order = growth_order(scaling["FD articulated"])
        rows.append(("forward dynamics grows no faster than O(n) up to 32 links",
                     f"fitted order {order:.2f} over n = 4 … 32 (articulated bodies)",
                     verdict(order <= 1.2, f"order {order:.2f} ≤ 1.2" if order <= 1.2
                             else f"order {order:.2f}")))
    for method, run, factor in results.get("realtime", []):
        if method in ("rk4", "semi_implicit_euler"):
            rows.append((f"fixed-step 1 kHz run of the paper scene ≥ 200× real time ({method})",
                         f"{seconds(run.cpu)} CPU for 1.5 s: {factor:.0f}× real time",
                         verdict(factor >= 200, f"{factor / 200:.2f}× the target" if factor >= 200
                                 else f"needs {200 / factor:.2f}× faster")))
    return table(("target", "measured in this run", "verdict"), rows), notes


def _work_precision(wp, index) -> str:
    parts = [f"### 1.{index} {wp.scene}", "",
             f"![work–precision {wp.scene}](work_precision_{wp.scene}.png)", "",
             f"Reference: DOP853 rtol 1e-13 ({wp.reference.steps} steps, "
             f"{wp.reference.impacts} impacts, {seconds(wp.reference.cpu)}); it differs from "
             f"DOP853 rtol 1e-12 by {sci(wp.reference_spread)}"
             + ", the floor below which errors here mean nothing.", ""]
    rows = []
    for target in TARGETS:
        pick = wp.recommend(target)
        if pick:
            rows.append((f"≤ {target:g}", f"`{pick.method}` {pick.run.setting}",
                         seconds(pick.run.cpu_per_second), f"{pick.run.rhs_evaluations}",
                         sci(pick.error)))
        else:
            rows.append((f"≤ {target:g}", "not reached on this scene", "—", "—", "—"))
    parts += ["Recommended setting (cheapest run within each accuracy):", "",
              table(("accuracy", "setting", "CPU per simulated s", "rhs evaluations",
                     "error"), rows), ""]
    rows = []
    for p in wp.points:
        r = p.run
        errors = (sci(p.error),)
        if not r.ok:
            rows.append((p.method, r.setting, "failed", "—", "—", "—", "—",
                         *("—" for _ in errors), "—", "—"))
            continue
        rows.append((p.method, r.setting, seconds(r.cpu_per_second), seconds(r.wall_per_second),
                     r.rhs_evaluations, r.steps, r.impacts, *errors, sci(r.energy_error),
                     sci(r.constraint_residual)))
    error_columns = ("largest state error",)
    parts += ["<details><summary>every run</summary>", "",
              table(("method", "setting", "CPU / sim s", "wall / sim s", "rhs evals", "steps",
                     "impacts", *error_columns, "energy error (J)", "constraint residual (m/s)"),
                    rows),
              "", "</details>", ""]
    return "\n".join(parts)


def write(results, out: Path) -> Path:
    quick = " --quick (smoke run: short sweeps, one repeat)" if results["quick"] else ""
    finished = datetime.datetime.fromtimestamp(results["finished"]).strftime("%Y-%m-%d %H:%M")
    parts = ["# Benchmark report", "",
             f"Generated by `bench --out {out}`{quick} on {finished}, "
             f"in {(results['finished'] - results['started']) / 60:.1f} min.", "",
             "Machine: " + _machine(), "",
             "Times are CPU time of the one thread doing the work (`time.thread_time`), best of "
             "several repeats, with the BLAS thread pools pinned to one thread: on a shared "
             "machine they are what one core costs; wall times are listed beside them where they "
             "differ.", ""]
    if results.get("only") == "mujoco":   # `bench --only mujoco`: that section alone
        return _write_parts(parts + [_mujoco_section(results)], out)
    if results.get("only") == "controllers":
        return _write_parts(parts + [_controllers_section(results)], out)
    if results.get("only") == "batch":
        return _write_parts(parts + [_batch_section(results)], out)
    if results.get("only") == "lanes_fd":
        return _write_parts(parts + [_lanes_fd_section(results)], out)
    if results.get("only") == "start":
        return _write_parts(parts + [_start_section(results)], out)
    targets, _ = _targets(results)
    parts += ["## Speed targets", "", targets, "",
              "Ratios are between runs of this same bench invocation. Where a target is missed, "
              "the section it comes from says why (§5 for the real-time factor).", ""]

    if results.get("engine"):
        from .engine_targets import rows as engine_rows
        parts += ["## Engine targets", "",
                  table(("target", "measured in this run", "verdict"),
                        engine_rows(results["engine"], verdict, seconds)), "",
                  "The MuJoCo targets (1 kHz rk4 and semi-implicit Euler on the paper scene, 64 "
                  "links, cost order) are in §7; the node's memory in bench/NODE.md.", ""]

    parts += ["## 1. Work–precision", "",
              "Every integrator over a sweep of `dt` (fixed step) or `rtol` (adaptive, "
              "atol = rtol/100), advanced to 100 Hz samples as `simulate` does. Error: largest "
              "|state − reference| over the samples (q and u). Energy error: largest "
              "|T + V − W + impact losses − E₀|. Constraint residual: largest no-skid / no-slip "
              "residual (built into the kinematics: round-off).", "",
              "The adaptive methods integrate through the samples (read from the dense output) and "
              "restart only at a discontinuity: an impact, a release, a command change.", ""]
    for index, wp in enumerate(results.get("wp", []), start=1):
        parts.append(_work_precision(wp, index))

    parts += ["## 2. Cost of each effect", "",
              "The paper scene with no effect, each effect alone, and all on. RK4 at 1 kHz takes "
              "the same steps whatever the physics, so its column is the cost of the stages an "
              "effect adds; DOP853 (rtol 1e-10) also shows how an effect changes the work the "
              "physics needs (stroke limits add impacts, solver restarts and the resting rod's "
              "release checks). An effect that is off adds no stage: compare each row with "
              "`none`.", ""]
    rows = []
    for label, on, fixed, adaptive in results.get("effects", []):
        rows.append((label, ", ".join(on) or "—", seconds(fixed.cpu_per_second),
                     fixed.rhs_evaluations, seconds(adaptive.cpu_per_second),
                     adaptive.rhs_evaluations, adaptive.impacts))
    parts += [table(("variant", "effects on", "RK4 1 kHz: CPU / sim s", "rhs evals",
                     "DOP853: CPU / sim s", "rhs evals", "impacts"), rows), ""]

    scaling = results.get("scaling")
    if scaling:
        parts += ["## 3. Scaling with the number of links", "", "![scaling](scaling.png)", "",
                  "One evaluation, in the compiled core's own loop (in C++), on random robots "
                  "(random joint "
                  "orientations, lengths, masses, inertias). Fitted growth order = slope of log t "
                  "against log n over n = 4 … 32.", ""]
        rows = [(name, *[seconds(t) for t in values], f"{growth_order(values):.2f}")
                for name, values in scaling.items()]
        parts += [table(("evaluation", *[f"n = {n}" for n in LINKS], "order"), rows), ""]

    per, whole = results.get("per_evaluation"), results.get("whole_run")
    parts += ["## 4. Against the peer: projected Pinocchio", ""]
    if per:
        peer_call = per["times"]["Pinocchio: crba + rnea + projection + solve, from Python"]
        parts += ["The robot built as an ordinary multibody in Pinocchio (planar base joint, "
                  "wheel spin joints, revolute + prismatic per link) and projected on the "
                  "pseudo-velocities: M = Sᵀ M_full S (`crba`), h = Sᵀ h_full(q, S u) (`rnea`), "
                  "u̇ = M⁻¹(Q − h) (numpy), as a user of Pinocchio would write it in Python. "
                  f"It agrees with our M and h to {sci(per['agreement'])} (relative) on random "
                  "states.", "",
                  "### 4.1 One forward-dynamics evaluation of the paper robot", "",
                  table(("how", "time per evaluation", "÷ Pinocchio's from Python"),
                        [(k, seconds(v), f"{v / peer_call:.3f}")
                         for k, v in per["times"].items()]),
                  "",
                  "From Python, our cost is mostly the call itself (the arrays in and out of the "
                  "compiled core); in the core's own loop (in C++, as its integrators call it) it "
                  "is the recursion alone. Pinocchio's own C++ is fast too (the crba + rnea "
                  "line); its cost from Python is the two calls, the projection and the solve.",
                  ""]
    if whole:
        parts += ["### 4.2 The whole 1.5 s paper run at equal accuracy", "",
                  "Paper robot with its stroke limits removed for this comparison (SciPy's "
                  "`solve_ivp` knows no impacts; the rods slide past their stops, which the "
                  "dynamics allows). Reference: ours, DOP853 rtol 1e-13; Pinocchio + SciPy at "
                  f"rtol 1e-12 differs from it by {sci(whole['peer_vs_reference'])}. Target "
                  f"accuracy: largest state error ≤ {ACCURACY:g}.", ""]
        rows = []
        for name, entries in whole["rows"].items():
            for setting, cpu, error, evaluations in entries:
                mark = " ◀" if whole["best"][name] and whole["best"][name][0] == setting else ""
                rows.append((name, setting + mark, seconds(cpu), evaluations, sci(error)))
        parts += [table(("driver", "setting", "CPU for 1.5 s", "rhs evaluations",
                         "largest state error"), rows),
                  "", f"◀ = cheapest within {ACCURACY:g}. For reference, the seed paper needed "
                  f"{SEED_SECONDS} s for this run (MATLAB `ode45`, Core 2 Duo E7500 at 3 GHz).", ""]

    realtime = results.get("realtime", [])
    if realtime:
        parts += ["## 5. Fixed-step 1 kHz run of the paper scene", "",
                  table(("integrator", "CPU for 1.5 s", "wall for 1.5 s", "rhs evaluations",
                         "real-time factor"),
                        [(m, seconds(r.cpu), seconds(r.wall), r.rhs_evaluations, f"{f:.0f}×")
                         for m, r, f in realtime]),
                  "", "Sampled at 100 Hz as `simulate` does, and in one `advance_to(1.5)` call; "
                  "both include the two end-stop impacts (located and resolved by the compiled "
                  "core) and, once a rod rests, a release check after every step. The last row "
                  "of each method drops the end stops: what is left is the stepping loop and the "
                  "right-hand side alone.",
                  ""]
        runs = {label: run for label, run, _ in realtime}
        if all(k in runs for k in ("rk4", "rk4, one advance_to call",
                                   "rk4, no end stops, one advance_to call")):
            smooth, stops, sampled = (runs["rk4, no end stops, one advance_to call"].cpu,
                                      runs["rk4, one advance_to call"].cpu, runs["rk4"].cpu)
            per_step = smooth / 1500
            rhs = (seconds(per["times"]["ours: engine right-hand side, compiled loop"])
                   if per else "—")
            parts += [f"Where RK4's {seconds(sampled)} go: stepping with the right-hand side "
                      f"{seconds(smooth)} ({seconds(per_step)} per step, four right-hand sides "
                      f"of {rhs} each in the core's own loop); end stops (impacts, release "
                      f"checks) {seconds(stops - smooth)}; the 150 sampling calls "
                      f"{seconds(sampled - stops)}. A 200× real-time factor needs 7.5 ms in all.",
                      ""]

    parts += ["## 6. Hard cases", "",
              "Each case is also a test in `test/bench/test_hard_cases.py` (marker `hard`), which "
              "asserts the bounds shown here: finite state, rods within their strokes (1e-9 m), "
              "energy error within the integrator's promise (`hard_cases.energy_promise`: "
              "C·tol^p·E·(1 + T), tol = rtol or dt, p = 1 or the method's order, E the energy "
              "that flows in the run), and a step-count bound.", ""]
    rows = []
    for case in results.get("hard", []):
        for label, run, _value, bound in case.runs:
            promise = case.checks.get(f"{label}: energy error, J", (math.nan, math.nan))[1]
            extra = "; ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                              for k, v in case.figures.items())
            rows.append((case.name, run.setting, seconds(run.cpu), f"{run.steps} (≤ {bound})",
                         run.impacts, f"{sci(run.energy_error)} (≤ {sci(promise)})",
                         sci(run.stroke_violation), extra, "yes" if case.passed else "**no**"))
    parts += [table(("case", "setting", "CPU", "steps (bound)", "impacts",
                     "energy error, J (promise)", "outside stroke, m", "figures",
                     "within bounds"), rows), ""]
    if results.get("mujoco"):
        parts.append(_mujoco_section(results))
    if results.get("controllers"):
        parts.append(_controllers_section(results))
    if results.get("batch"):
        parts.append(_batch_section(results))
    if results.get("lanes_fd"):
        parts.append(_lanes_fd_section(results))
    if results.get("derivatives"):
        parts.append(derivatives_section(results))
    if results.get("start"):
        parts.append(_start_section(results))
    return _write_parts(parts, out)


def _controllers_section(results) -> str:
    from .controllers import section
    return section(results["controllers"], number=8)


def _batch_section(results) -> str:
    from .batch import section
    return section(results["batch"], number=9)


def _lanes_fd_section(results) -> str:
    from .lanes_fd import section
    return section(results["lanes_fd"], number=10)


def _mujoco_section(results) -> str:
    if not results.get("mujoco"):
        return "## 7. Against MuJoCo\n\nmujoco is not installed: skipped.\n"
    from .versus_mujoco import section
    return section(results["mujoco"], number=7)


DERIVATIVES_NUMBER = 11


def _start_section(results) -> str:
    from .start import section
    return section(results["start"], number=12)


def derivatives_section(results) -> str:
    from .derivatives import section
    return section(results["derivatives"], number=DERIVATIVES_NUMBER)


def replace_section(path: Path, text: str) -> Path:
    """Put a section into an existing REPORT.md in place of the one of the same number (or at
    its end): one section re-measured without the whole run."""
    head = text.split("\n", 1)[0]            # "## N. Title"
    number = head.split(".", 1)[0] + "."
    old = path.read_text() if path.exists() else ""
    lines = old.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(number + " ")), None)
    if start is None:
        new = old.rstrip("\n") + "\n\n" + text
    else:
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")),
                   len(lines))
        new = "\n".join(lines[:start] + text.rstrip("\n").split("\n") + [""] + lines[end:])
    path.write_text(new.rstrip("\n") + "\n")
    return path


def _write_parts(parts, out: Path) -> Path:
    path = out / "REPORT.md"
    path.write_text("\n".join(parts) + "\n")
    return path


