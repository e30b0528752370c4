"""`simulate`: a headless run of a scene, one CSV row per sample.

    simulate --scene FILE --duration S --sample-rate HZ --out FILE.csv
             [--method NAME] [--dt S] [--rtol R] [--atol A] [--record DIR] [--set KEY=VALUE]…

Columns: t, x, y, yaw, theta_R, theta_L, q1, l1, …, qn, ln, v, omega, qd1, ld1, …, qdn, ldn,
energy (T + V, J). Without --scene the embedded paper scene runs. End-stop impacts, if any,
go to FILE.impacts.csv beside the output. The last line printed is the run's summary.
"""
from __future__ import annotations

import csv
import sys
import time
from pathlib import Path

from . import cli
from .engine.simulation import Simulation
from .errors import UserError
from .scene import Scene, load_scene, make_integrator
from .sweep.overrides import parse_assignments, scene_with


def csv_columns(n_links: int) -> list[str]:
    arm_q = [name for i in range(1, n_links + 1) for name in (f"q{i}", f"l{i}")]
    arm_u = [name for i in range(1, n_links + 1) for name in (f"qd{i}", f"ld{i}")]
    return ["t", "x", "y", "yaw", "theta_R", "theta_L", *arm_q, "v", "omega", *arm_u, "energy"]


def sample_times(duration: float, sample_rate: float) -> list[float]:
    """k / rate for every k with k / rate ≤ duration, then duration itself if it is off the grid."""
    count = int(duration * sample_rate + 1e-9)
    times = [k / sample_rate for k in range(count + 1)]
    if duration - times[-1] > 1e-12 * max(1.0, duration):
        times.append(duration)
    return times


class Progress:
    """A one-line progress bar on stderr, only when stderr is a terminal."""

    def __init__(self, total: float, stream=sys.stderr):
        self.total, self.stream = total, stream
        self.active = stream.isatty()
        self._last = -1

    def update(self, done: float) -> None:
        if not self.active:
            return
        percent = int(100 * done / self.total) if self.total > 0 else 100
        if percent != self._last:
            self._last = percent
            bar = "#" * (percent // 4)
            self.stream.write(f"\r[{bar:<25}] {percent:3d}%  t = {done:.3f} s")
            self.stream.flush()

    def close(self) -> None:
        if self.active:
            self.stream.write("\n")


def summary_line(sim: Simulation, wall: float) -> str:
    rtf = sim.t / wall if wall > 0 else float("inf")
    return (f"simulated {sim.t:.6g} s in {wall:.3f} s wall (real-time factor {rtf:.1f}), "
            f"{sim.steps} steps, {sim.rhs_evaluations} rhs evaluations, {len(sim.impacts)} impacts, "
            f"energy error {sim.energy_error():.3e} J")


def run(scene: Scene, duration: float, sample_rate: float, settings=None, on_sample=None,
        progress: Progress | None = None) -> Simulation:
    """Simulate `duration` s from the scene's initial state with its constant efforts, calling
    ``on_sample(sim)`` at every sample time; returns the finished simulation."""
    sim = Simulation(scene, settings)
    for t in sample_times(duration, sample_rate):
        sim.advance_to(t)
        if on_sample:
            on_sample(sim)
        if progress:
            progress.update(t)
    return sim


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="simulate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", help="scene YAML (default: the embedded paper scene)")
    parser.add_argument("--duration", type=float, help="simulated seconds (default: the scene's)")
    parser.add_argument("--sample-rate", type=float, default=100.0, help="CSV rows per second")
    parser.add_argument("--out", default="run.csv", help="CSV file to write (default run.csv)")
    parser.add_argument("--method", help="integrator (overrides the scene)")
    parser.add_argument("--dt", type=float, help="fixed step (s)")
    parser.add_argument("--rtol", type=float, help="relative tolerance of adaptive methods")
    parser.add_argument("--atol", type=float, help="absolute tolerance of adaptive methods")
    parser.add_argument("--record", metavar="DIR", help="also record a rosbag2 (MCAP) bag to DIR")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="set a scene key path, e.g. robot.arm.links[0].mass_per_length=1.2 "
                             "(value read as YAML; repeatable)")
    args = parser.parse_args(argv)
    scene = load_scene(args.scene)
    if args.set:
        scene = scene_with(scene.document, parse_assignments(args.set), scene.name)
    settings = make_integrator(scene.integrator, args.method, args.dt, args.rtol, args.atol,
                               prefix="--")
    duration = scene.duration if args.duration is None else args.duration
    if not duration > 0:
        raise UserError("--duration", f"must be positive, got {duration}")
    if not args.sample_rate > 0:
        raise UserError("--sample-rate", f"must be positive, got {args.sample_rate}")
    out = Path(args.out)
    recorder = None
    if args.record:
        from .recording.headless import HeadlessRecorder
        recorder = HeadlessRecorder(args.record, scene, settings, args.sample_rate, duration)
    try:
        handle = out.open("w", newline="")
    except OSError as error:
        raise UserError(str(out), f"cannot write ({error.strerror})") from None
    progress = Progress(duration)
    start = time.perf_counter()
    with handle:
        writer = csv.writer(handle)
        writer.writerow(csv_columns(scene.robot.n_links))

        def on_sample(sim):
            writer.writerow([repr(sim.t), *map(repr, sim.q.tolist()), *map(repr, sim.u.tolist()),
                             repr(sim.total_energy())])
            if recorder:
                recorder.sample(sim)

        try:
            sim = run(scene, duration, args.sample_rate, settings, on_sample, progress)
        finally:
            progress.close()
            if recorder:
                recorder.close()
    wall = time.perf_counter() - start
    if sim.impacts:
        _write_impacts(out.with_suffix(".impacts.csv"), sim.impacts)
    print(summary_line(sim, wall))
    return 0


def _write_impacts(path: Path, impacts) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(impacts[0].as_dict()))
        writer.writeheader()
        for impact in impacts:
            writer.writerow(impact.as_dict())


def main(argv=None) -> int:
    return cli.run(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
