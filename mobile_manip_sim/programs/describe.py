"""``describe [--scene FILE]``: print the URDF of a scene's robot (the embedded paper scene by
default), e.g. for ``robot_state_publisher --ros-args -p robot_description:="$(describe)"``."""
from __future__ import annotations

import sys

from ..ros.urdf import robot_description
from ..runtime import cli
from ..scene.loading import load_scene


def _main(argv: list[str] | None) -> int:
    parser = cli.ArgumentParser(prog="describe", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", metavar="FILE",
                        help="scene file (YAML); default: the embedded paper_two_link scene")
    args = parser.parse_args(argv)
    sys.stdout.write(robot_description(load_scene(args.scene)))
    return 0


def main(argv: list[str] | None = None) -> int:
    return cli.run(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
