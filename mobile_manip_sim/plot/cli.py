"""`plot`: the seed paper's figures, and an energy balance, from any run.

    plot RUN --out DIR [--scene FILE]

RUN is a CSV written by `simulate` (its impacts, if any, beside it in ``RUN.impacts.csv``; its
scene given by ``--scene`` or the embedded paper scene) or a recorded bag (a rosbag2 directory
or one ``.mcap`` file; its scene from the bag's ``scene.yaml`` attachment unless ``--scene``
overrides it). DIR receives one PNG per figure and an ``index.html`` showing them all
(`figures.plot`); the energy balance is explained in `energy`.
"""
from __future__ import annotations

from ..runtime import cli
from .figures import plot


def _main(argv) -> int:
    parser = cli.ArgumentParser(prog="plot", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=cli.path, metavar="RUN",
                        help="a CSV from simulate, a bag directory or an .mcap file")
    parser.add_argument("--out", type=cli.path, required=True, metavar="DIR",
                        help="directory for the figures")
    parser.add_argument("--scene", metavar="FILE",
                        help="the run's scene (default: a bag's own, or the embedded paper scene)")
    args = parser.parse_args(argv)
    figures = plot(args.run, args.out, args.scene)
    print(f"wrote {len(figures)} figures and index.html to {args.out}")
    return 0


def main(argv=None) -> int:
    return cli.run(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
