"""`simulate`: a headless run of a scene, one CSV row per sample.

    simulate --scene FILE --duration S --sample-rate HZ --out FILE.csv
             [--method NAME] [--dt S] [--rtol R] [--atol A] [--record DIR] [--set KEY=VALUE]…
             [--view [PORT] | --view browser [--view-port PORT]] [--view-host HOST]
             [--linger S]

Columns: t, x, y, yaw, theta_R, theta_L, q1, l1, …, qn, ln, v, omega, qd1, ld1, …, qdn, ldn,
energy (T + V, J) (`headless.csv_columns`); LF line ends. Without --scene the embedded paper
scene runs. End-stop impacts, if any, go to FILE.impacts.csv beside the output, only when FILE
is a regular file (``--out /dev/null`` writes nothing else). The last line printed is the run's
summary; its real-time factor counts the simulation only (from the first sample that advanced
time on: start-up and compiling are left out).

Faults: a write error (disk full, ``/dev/full``) is one line, status 2, and the partial CSV is
removed; SIGINT (status 130) and SIGTERM (status 143) stop the run, keep the rows written so far
and close a ``--record`` bag.

``--view [PORT]`` shows the run live in Foxglove (live_view.py: a Foxglove WebSocket server on
PORT, default 8765, no ROS needed): every sample is published when the wall clock reaches it,
the run paced to real time, so the CSV and the bag are the same as without it. The server
listens on ``--view-host`` (default 127.0.0.1, this machine only; 0.0.0.0 lets another machine
connect). After the run it keeps serving the last state until Ctrl-C or SIGTERM (status 0), or
for ``--linger`` seconds; its stop never waits on a client (live_view.CLOSE_WAIT).

``--view browser`` shows it in a web browser instead (view/browser.py: a local page on
``--view-port``, default 8080, drawing the robot from its URDF, with T + V and the impacts),
paced and lingering the same way; the line ``view: http://HOST:PORT/`` gives its address.
"""
from __future__ import annotations

import argparse
import csv
import os
import stat
import threading
import time
from pathlib import Path

from ..runtime import cli
from ..runtime.progress import Progress
from ..scene import limits, schema
from ..scene.errors import UserError
from ..scene.limits import DURATION, SAMPLE_RATE
from ..scene.loading import check_work, load_scene, make_integrator
from ..scene.overrides import parse_assignments, scene_with

DEFAULT_VIEW_PORT = 8765           # --view without a port: Foxglove's default
BROWSER = "browser"                # --view browser: the browser view


def view_choice(text: str):
    """--view's value: a port number (the Foxglove view) or ``browser``."""
    if text == BROWSER:
        return BROWSER
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r} (a port number, or "
                                         f"{BROWSER})") from None


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="simulate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=cli.path,
                        help="scene YAML (default: the embedded paper scene)")
    parser.add_argument("--duration", type=float, help="simulated seconds (default: the scene's)")
    parser.add_argument("--sample-rate", type=float, default=100.0, help="CSV rows per second")
    parser.add_argument("--out", type=cli.path, default="run.csv",
                        help="CSV file to write (default run.csv)")
    parser.add_argument("--method", help="integrator (overrides the scene)")
    parser.add_argument("--dt", type=float, help="fixed step (s)")
    parser.add_argument("--rtol", type=float, help="relative tolerance of adaptive methods")
    parser.add_argument("--atol", type=float, help="absolute tolerance of adaptive methods")
    parser.add_argument("--record", type=cli.path, metavar="DIR",
                        help="also record a rosbag2 (MCAP) bag to DIR")
    parser.add_argument("--view", type=view_choice, nargs="?", const=DEFAULT_VIEW_PORT,
                        metavar="PORT|browser",
                        help="show the run live, paced to real time: in Foxglove (a WebSocket "
                             f"server on PORT, default {DEFAULT_VIEW_PORT}; 0: any free port), "
                             "or with 'browser' in a web page (--view-port)")
    parser.add_argument("--view-port", type=int, default=None, metavar="PORT",
                        help="with --view browser: the page's port (default 8080; 0: any free "
                             "port)")
    parser.add_argument("--view-host", default=None, metavar="HOST",
                        help="address the live view listens on (default 127.0.0.1: this "
                             "machine only; 0.0.0.0: every interface, for another machine)")
    parser.add_argument("--linger", type=float, default=None, metavar="S",
                        help="with --view: keep serving S seconds after the run (default: "
                             "until Ctrl-C)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="set a scene key path, e.g. robot.arm.links[0].mass_per_length=1.2 "
                             "(value read as YAML; repeatable)")
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    if args.set:
        scene = scene_with(scene.document, parse_assignments(args.set), scene.name)
    settings = make_integrator(scene.integrator, args.method, args.dt, args.rtol, args.atol,
                               prefix="--")
    if args.duration is None:
        duration, duration_key = scene.duration, "duration"
    else:
        duration = schema.number(args.duration, "--duration", positive=True, hi=DURATION[1])
        duration_key = "--duration"
    rate = schema.number(args.sample_rate, "--sample-rate", lo=SAMPLE_RATE[0], hi=SAMPLE_RATE[1])
    check_work(duration, settings, duration_key, "--dt" if args.dt is not None else "integrator.dt",
               rate, "--sample-rate")
    out = Path(args.out)
    view = None
    if args.view is None and (args.view_host is not None or args.linger is not None):
        raise UserError("--view-host" if args.view_host is not None else "--linger",
                        "needs --view")
    if args.view_port is not None and args.view != BROWSER:
        raise UserError("--view-port", "needs --view browser (a Foxglove port is --view PORT)")
    linger = None if args.linger is None else schema.number(
        args.linger, "--linger", lo=0.0, hi=limits.LINGER[1])
    if args.view == BROWSER:
        view = _browser(args, scene, rate, duration)
    elif args.view is not None:
        from ..ros.live_view import DEFAULT_HOST, PacedView
        schema.integer(args.view, "--view", lo=limits.PORT[0], hi=limits.PORT[1])
        view = PacedView(args.view, scene, rate, duration, args.view_host or DEFAULT_HOST)
        print(f"live view: {view.url} (Foxglove: open connection, Foxglove WebSocket)",
              flush=True)
    # The engine loads after the view has started: a browser loads the page meanwhile.
    from ..runtime.headless import csv_columns, csv_row, run, summary_line
    with CsvOutput(out) as output:
        recorder = None
        if args.record:
            from ..recording.headless import HeadlessRecorder
            recorder = HeadlessRecorder(args.record, scene, settings, rate, duration)
        output.writerow(csv_columns(scene.robot.n_links))

        def on_sample(sim):
            row = [repr(value) for value in csv_row(sim)]
            if view:
                view.sample(sim)
            with cli.critical():   # a signal stops the run between samples' writes, not inside
                output.writerow(row)
                if recorder:
                    recorder.sample(sim)

        start = time.perf_counter()
        progress = Progress("simulate", duration, "s", rate_unit="s per wall s")
        try:
            sim = run(scene, duration, rate, settings, on_sample, progress)
        except BaseException:
            if view:
                view.close()
            raise
        finally:
            progress.close()
            if recorder:
                recorder.close()
        wall = time.perf_counter() - start
        if view and hasattr(view, "finish"):   # the browser view: the last sample drawn
            view.finish()
        if sim.impacts and output.regular:
            output.write_impacts(out.with_suffix(".impacts.csv"), sim.impacts)
    simulated, wall = sim.timing or (sim.t, wall)
    print(summary_line(sim, wall, simulated), flush=True)
    if view:
        _linger(view, linger)
    return 0


def _browser(args, scene, rate: float, duration: float):
    """`--view browser`: the page, its address said on the first line."""
    from ..ros.live_view import check_host
    from ..ros.urdf import robot_description
    from ..view.browser import DEFAULT_HOST, DEFAULT_PORT, LiveBrowser
    from ..view.drawing import read_urdf

    port = DEFAULT_PORT if args.view_port is None else schema.integer(
        args.view_port, "--view-port", lo=limits.PORT[0], hi=limits.PORT[1])
    host = check_host(args.view_host or DEFAULT_HOST, "--view-host")
    view = LiveBrowser(scene, read_urdf(robot_description(scene)), port, host, rate, duration,
                       port_key="--view-port")
    print(f"view: {view.url}", flush=True)
    return view


def _linger(view, seconds: float | None) -> None:
    """After the run: the live view serves on for ``seconds`` (None: until Ctrl-C or SIGTERM,
    which end it with status 0), then stops without waiting on any client."""
    print(f"{'view' if hasattr(view, 'finish') else 'live view'}: still serving {view.url} "
          f"{'until Ctrl-C' if seconds is None else f'for {seconds:g} s'}", flush=True)
    try:
        threading.Event().wait(seconds)
    except (KeyboardInterrupt, cli.Terminated):
        pass
    finally:
        view.close()


class CsvOutput:
    """The CSV file (LF line ends) and its impacts file. A write error is a `UserError` naming
    the file; after an error the files written so far are removed (regular files only); after a
    signal (KeyboardInterrupt, `cli.Terminated`) they are closed with the rows written so far."""

    def __init__(self, path: Path):
        self.path = path
        self.written: list[Path] = []
        try:
            self.handle = path.open("w", newline="")
            self.regular = stat.S_ISREG(os.fstat(self.handle.fileno()).st_mode)
        except OSError as error:
            raise self._error(error) from None
        if self.regular:
            self.written.append(path)
        self.writer = csv.writer(self.handle, lineterminator="\n")

    def _error(self, error: OSError, path: Path | None = None) -> UserError:
        return UserError(schema.label(str(path or self.path), 160),
                         f"cannot write ({error.strerror or error})")

    def writerow(self, row) -> None:
        try:
            self.writer.writerow(row)
        except OSError as error:
            raise self._error(error) from None

    def write_impacts(self, path: Path, impacts) -> None:
        try:
            with path.open("w", newline="") as handle:
                self.written.append(path)
                writer = csv.DictWriter(handle, fieldnames=list(impacts[0].as_dict()),
                                        lineterminator="\n")
                writer.writeheader()
                for impact in impacts:
                    writer.writerow(impact.as_dict())
        except OSError as error:
            raise self._error(error, path) from None

    def __enter__(self) -> "CsvOutput":
        return self

    def __exit__(self, kind, error, traceback) -> None:
        try:
            self.handle.close()
        except OSError as close_error:
            if kind is None:
                self._remove()
                raise self._error(close_error) from None
        if kind is not None and not issubclass(kind, (KeyboardInterrupt, cli.Terminated)):
            self._remove()

    def _remove(self) -> None:
        for path in self.written:
            try:
                path.unlink()
            except OSError:
                pass


def main(argv=None) -> int:
    return cli.run(_main, argv, sigterm=True)


if __name__ == "__main__":
    raise SystemExit(main())
