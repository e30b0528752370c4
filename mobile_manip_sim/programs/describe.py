"""``describe [--scene FILE] [--ros2-control]``: print the URDF of a scene's robot (the embedded
paper scene by default), e.g. for ``robot_state_publisher --ros-args -p
robot_description:="$(describe)"``; with ``--ros2-control`` it carries a ``<ros2_control>`` block
for ros2_control's topic-based hardware interface (docs/ros.md)."""
from __future__ import annotations

import sys

from ..ros.urdf import ARM_INTERFACES, WHEEL_INTERFACES, robot_description
from ..runtime import cli
from ..scene.loading import load_scene


def _main(argv: list[str] | None) -> int:
    parser = cli.ArgumentParser(prog="describe", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", metavar="FILE",
                        help="scene file (YAML); default: the embedded paper_two_link scene")
    parser.add_argument("--ros2-control", action="store_true",
                        help="append a <ros2_control> block for joint_state_topic_hardware_"
                             "interface (the node's joint-command and joint-state topics)")
    parser.add_argument("--wheel-interface", choices=WHEEL_INTERFACES, default="velocity",
                        help="the wheels' command interface in that block (default: velocity, "
                             "for diff_drive_controller; the node's base_command must match)")
    parser.add_argument("--arm-interface", choices=ARM_INTERFACES, default="position",
                        help="the arm joints' command interface in that block (default: "
                             "position, for joint_trajectory_controller; the node's "
                             "arm_controller must match)")
    parser.add_argument("--frame-prefix", default="", metavar="PREFIX",
                        help="prefix of every link name (the node's frame_prefix)")
    args = parser.parse_args(argv)
    block = None
    if args.ros2_control:
        block = {"wheels": args.wheel_interface, "arm": args.arm_interface}
    sys.stdout.write(robot_description(load_scene(args.scene), prefix=args.frame_prefix,
                                       ros2_control=block))
    return 0


def main(argv: list[str] | None = None) -> int:
    return cli.run(_main, argv)


if __name__ == "__main__":
    raise SystemExit(main())
