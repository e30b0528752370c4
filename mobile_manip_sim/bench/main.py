"""`bench`: measure what accuracy costs, how the dynamics scale, how we compare with Pinocchio,
and how the hard cases behave; write ``REPORT.md`` and PNG plots.

    bench --out bench/            # the full run, about 10 minutes
    bench --out /tmp/b --quick    # a smoke run: short sweeps, one repeat
    bench --out /tmp/m --only mujoco --quick   # the MuJoCo section alone, under a minute
    bench --out /tmp/c --only controllers      # the arm controllers' section alone
    bench --out /tmp/b --only batch            # many runs in one call (the batch) alone
    bench --out /tmp/l --only lanes_fd         # one dynamics evaluation in vector lanes alone
    bench --out bench/ --only derivatives      # exact Jacobians: updates its section in place
    bench --out /tmp/s --only start            # start times: imports, simulate, the node's /odom
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from ..runtime import cli
from ..runtime.progress import Progress as Ticker
from ..scene.errors import UserError


class Progress:
    """Numbered section headers and one line per measurement, on stderr, with elapsed time; on
    a terminal, a line of sections done, rate and time to go whenever a measurement has been
    silent for a while (`progress.Progress`)."""

    def __init__(self, sections: int, stream=sys.stderr):
        self.sections = sections
        self.start = time.perf_counter()
        self.index = 0
        self.ticker = Ticker("bench", sections, "sections", rate_unit="sections/min", per=60.0,
                             lines=True, stream=stream)

    def section(self, title: str) -> None:
        self.index += 1
        self.ticker.update(self.index - 1)
        self._write(f"[{self.index}/{self.sections}] {title}")

    def __call__(self, line: str) -> None:
        self._write(f"      {line}")

    def _write(self, text: str) -> None:
        # A Ctrl-C that third-party code swallowed (seen once: the bench ran on to its end,
        # status 0) is raised here, at the next line, by the shared stop handler.
        cli.raise_dropped_stop()
        self.ticker.note(f"{time.perf_counter() - self.start:7.1f} s  {text}")


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=cli.path, default="bench",
                        help="directory for REPORT.md and the plots (default bench)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: short sweeps, one repeat")
    parser.add_argument("--only", choices=("mujoco", "controllers", "batch", "lanes_fd",
                                           "derivatives", "start"),
                        help="run one section alone (REPORT.md holds only it; derivatives: "
                             "its section of an existing REPORT.md is replaced)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError("--out", f"cannot create {out} ({error.strerror})") from None

    from ..scene.loading import load_scene
    from . import (
        controllers,
        effects,
        engine_targets,
        hard_cases,
        report,
        scaling,
        versus,
        versus_mujoco,
        work_precision,
    )
    from .scenes import paper_document, random_arm_scene, scene_file

    results = {"quick": args.quick, "started": time.time(), "only": args.only}
    if args.only == "mujoco":
        progress = Progress(1)
        _mujoco_section(versus_mujoco, results, progress, args.quick)
        return _write(report, results, out, progress)
    if args.only == "controllers":
        progress = Progress(1)
        progress.section("arm controllers: cost per step and tracking")
        results["controllers"] = controllers.measure(progress, quick=args.quick)
        return _write(report, results, out, progress)
    if args.only == "batch":
        progress = Progress(1)
        _batch_section(results, progress, args.quick)
        return _write(report, results, out, progress)
    if args.only == "lanes_fd":
        progress = Progress(1)
        _lanes_fd_section(results, progress, args.quick)
        return _write(report, results, out, progress)
    if args.only == "start":
        progress = Progress(1)
        _start_section(results, progress, args.quick)
        return _write(report, results, out, progress)
    if args.only == "derivatives":
        progress = Progress(1)
        _derivatives_section(results, progress, args.quick)
        path = report.replace_section(out / "REPORT.md", report.derivatives_section(results))
        progress(f"wrote {path}")
        progress.ticker.close()
        print(path)
        return 0
    progress = Progress(12)

    progress.section("work–precision: paper scene, hard scene, 20-link random arm")
    results["wp"] = []
    for scene in (load_scene(), scene_file("hard_impacts.yaml"), random_arm_scene()):
        wp = work_precision.sweep(scene, progress, quick=args.quick)
        work_precision.plot(wp, out / f"work_precision_{scene.name}.png")
        results["wp"].append(wp)

    progress.section("cost of each effect (paper scene)")
    results["effects"] = effects.measure(paper_document(), progress, quick=args.quick)

    progress.section("scaling with the number of links")
    results["scaling"] = scaling.measure(progress, quick=args.quick)
    scaling.plot(results["scaling"], out / "scaling.png")

    progress.section("against the peer (projected Pinocchio)")
    if versus.peers.available():
        results["per_evaluation"] = versus.per_evaluation(progress, quick=args.quick)
        results["whole_run"] = versus.whole_run(progress, quick=args.quick)
    else:
        progress("pinocchio is not installed: peer comparison skipped")

    progress.section("fixed-step 1 kHz real-time factor")
    results["realtime"] = versus.realtime(progress, quick=args.quick)

    _mujoco_section(versus_mujoco, results, progress, args.quick)
    paper = next((wp for wp in results["wp"] if wp.scene == "paper_two_link"), None)
    results["engine"] = engine_targets.measure(progress, paper)

    progress.section("hard cases")
    results["hard"] = []
    for _name, case in hard_cases.all_cases(quick=args.quick):
        start = time.perf_counter()
        result = case()
        results["hard"].append(result)
        progress(f"{result.name}: {'within bounds' if result.passed else 'OUT OF BOUNDS'} "
                 f"({time.perf_counter() - start:.1f} s)")

    progress.section("arm controllers: cost per step and tracking")
    results["controllers"] = controllers.measure(progress, quick=args.quick)

    _batch_section(results, progress, args.quick)
    _lanes_fd_section(results, progress, args.quick)
    _derivatives_section(results, progress, args.quick)
    _start_section(results, progress, args.quick)
    return _write(report, results, out, progress)


def _start_section(results, progress, quick: bool) -> None:
    from . import start
    progress.section("start times: the engine's import, a warm simulate, the node's first /odom")
    results["start"] = start.measure(progress, quick=quick)


def _derivatives_section(results, progress, quick: bool) -> None:
    from . import derivatives
    progress.section("exact Jacobians against MuJoCo's finite differences; the core's dynamics")
    results["derivatives"] = derivatives.measure(progress, quick=quick)


def _lanes_fd_section(results, progress, quick: bool) -> None:
    from . import lanes_fd
    progress.section("one dynamics evaluation per lane: vector lanes against the scalar kernel")
    results["lanes_fd"] = lanes_fd.measure(progress, quick=quick)


def _batch_section(results, progress, quick: bool) -> None:
    from . import batch
    progress.section("many runs in one call: the batch, the sweep command, MuJoCo rollout")
    results["batch"] = batch.measure(progress, quick=quick)


def _mujoco_section(versus_mujoco, results, progress, quick: bool) -> None:
    progress.section("against MuJoCo (equivalent unconstrained model)")
    if versus_mujoco.mujoco_peer.available():
        results["mujoco"] = versus_mujoco.measure(progress, quick=quick)
    else:
        progress("mujoco is not installed: MuJoCo comparison skipped")


def _write(report, results, out, progress) -> int:
    results["finished"] = time.time()
    path = report.write(results, out)
    progress(f"wrote {path}")
    progress.ticker.close()
    print(path)
    return 0


def main(argv=None) -> int:
    return cli.run(_main, argv, sigterm=True)   # SIGINT 130, SIGTERM 143, either noted


if __name__ == "__main__":
    raise SystemExit(main())
