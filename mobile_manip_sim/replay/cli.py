"""`replay`: play a recorded bag back onto ROS topics, or re-simulate it and compare.

    replay BAG [--rate R] [--loop] [--topics T ...] [--start-offset S] [--wait-for-subscribers]
    replay BAG --resimulate [--tolerance TOL]
    replay BAG|RUN.csv --view browser [--view-port PORT] [--view-host HOST] [--scene FILE]

Playback: `play` (like ``ros2 bag play --clock``). Re-simulation: `resimulate` (status 1 if a
difference exceeds ``--tolerance``, default 0: bit for bit). Browser view
(`view.browser.Player`): a local web page on ``--view-port`` (default 8080) playing the bag (or
a CSV of `simulate`, its scene from ``--scene``) with a time slider, play / pause and a speed,
until Ctrl-C or SIGTERM (status 0).

A missing, unreadable or non-rosbag2 bag, a bag with no complete message, an unknown topic, a
bag whose messages do not fit its own scene (another robot) → one line, status 2.
"""
from __future__ import annotations

import math
import sys

from mobile_manip_sim.recording.bag_format import first_message
from mobile_manip_sim.recording.bag_reader import open_bag
from mobile_manip_sim.replay.play import play
from mobile_manip_sim.replay.resimulate import resimulate
from mobile_manip_sim.runtime import cli
from mobile_manip_sim.scene.errors import UserError

RATES = (1e-6, 1e6)   # playback speed factors: a second of the bag in 11.6 days … 1 µs


def main(argv=None) -> int:
    return cli.run(_main, argv)


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag", type=cli.path, help="bag directory (or its .mcap file)")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="playback speed factor (1e-6 to 1e6)")
    parser.add_argument("--loop", action="store_true", help="play again from the start, forever")
    parser.add_argument("--topics", nargs="+", metavar="T", help="play only these topics")
    parser.add_argument("--start-offset", type=float, default=0.0, metavar="S",
                        help="start S seconds (of recorded time) into the bag")
    parser.add_argument("--wait-for-subscribers", action="store_true",
                        help="start only when every played topic has a subscriber")
    parser.add_argument("--resimulate", action="store_true",
                        help="re-run the simulation from the bag and compare the states")
    parser.add_argument("--tolerance", type=float, default=0.0,
                        help="largest accepted difference with --resimulate (default 0)")
    parser.add_argument("--view", choices=["browser"],
                        help="show the run in a web browser (a bag, or a CSV of simulate)")
    parser.add_argument("--view-port", type=int, default=None, metavar="PORT",
                        help="with --view browser: the page's port (default 8080; 0: any free)")
    parser.add_argument("--view-host", default=None, metavar="HOST",
                        help="with --view browser: the address it listens on (default "
                             "127.0.0.1: this machine only; 0.0.0.0: every interface)")
    parser.add_argument("--scene", type=cli.path, metavar="FILE",
                        help="with --view browser and a CSV: the run's scene (default: the "
                             "embedded paper scene)")
    args = parser.parse_args(argv)
    for given, name in ((args.view_port, "--view-port"), (args.view_host, "--view-host"),
                        (args.scene, "--scene")):
        if given is not None and args.view is None:
            raise UserError(name, "needs --view browser")
    if args.view is not None:
        if args.resimulate:
            raise UserError("--view", "plays a run; --resimulate compares one: give one of them")
        return view(args)
    if not RATES[0] <= args.rate <= RATES[1]:   # 5e-324 would play for ever; NaN is refused
        raise UserError("--rate", f"must be in [{RATES[0]:g}, {RATES[1]:g}], got {args.rate}")
    if not (math.isfinite(args.start_offset) and args.start_offset >= 0):
        raise UserError("--start-offset", f"must be a number ≥ 0, got {args.start_offset}")
    if not args.tolerance >= 0:   # inf is allowed: compare, report, never fail
        raise UserError("--tolerance", f"must be ≥ 0, got {args.tolerance}")
    bag = open_bag(args.bag)
    first_message(bag)
    if bag.recovered:
        print(f"replay: warning: {bag.path} has no summary (a recording that was killed?): "
              f"using its complete chunks; `mcap recover` may save more", file=sys.stderr)
    if args.resimulate:
        # SIGINT and SIGTERM wait for the end of a message's decoding (`critical`); play leaves
        # them to rclpy, which it runs under.
        with cli.stop_signals():
            return resimulate(bag, args.tolerance)
    return play(bag, args.topics, args.rate, args.loop, args.start_offset,
                args.wait_for_subscribers)


def view(args) -> int:
    """`--view browser`: serve the page until Ctrl-C or SIGTERM."""
    import threading

    from mobile_manip_sim.ros.live_view import check_host
    from mobile_manip_sim.scene import limits, schema
    from mobile_manip_sim.view.browser import DEFAULT_HOST, DEFAULT_PORT, Player
    from mobile_manip_sim.view.recorded import load

    port = DEFAULT_PORT if args.view_port is None else schema.integer(
        args.view_port, "--view-port", lo=limits.PORT[0], hi=limits.PORT[1])
    host = check_host(args.view_host or DEFAULT_HOST, "--view-host")
    with cli.stop_signals():
        recording = load(args.bag, args.scene)
        player = Player(recording, port, host, port_key="--view-port")
        try:
            print(f"view: {player.url}", flush=True)
            print(f"replay: {len(recording.t)} samples, {recording.t[-1] - recording.t[0]:.3f} s; "
                  f"serving until Ctrl-C", flush=True)
            threading.Event().wait()
        except (KeyboardInterrupt, cli.Terminated):
            pass
        finally:
            player.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
