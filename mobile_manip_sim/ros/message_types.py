"""The rclpy class of a ROS 2 message type name (``pkg/msg/Type``), for the readers of bags and
the CDR encoder.

A bag names its types, and the name chooses a Python module to import: so only names of the
form ``package/msg/Type`` whose package is one of KNOWN_PACKAGES (the ROS 2 message packages
of ros2/common_interfaces, ros2/geometry2, ros-controls' control_msgs and the ROS core) are
imported, and only a ROS message class is returned. Any other name is a `UserError` naming it,
before anything is imported (``..os/msg/X`` or ``this/msg/Zen`` import nothing)."""
from __future__ import annotations

import functools
import importlib
import re

from ..scene.errors import UserError
from ..scene.schema import label

KNOWN_PACKAGES = frozenset((
    "action_msgs", "actionlib_msgs", "builtin_interfaces", "control_msgs", "diagnostic_msgs",
    "geometry_msgs", "lifecycle_msgs", "nav_msgs", "rcl_interfaces", "rosgraph_msgs",
    "sensor_msgs", "shape_msgs", "statistics_msgs", "std_msgs", "stereo_msgs", "tf2_msgs",
    "trajectory_msgs", "unique_identifier_msgs", "visualization_msgs"))
TYPE_NAME = re.compile(r"([a-z][a-z0-9_]*)/msg/([A-Z][A-Za-z0-9]*)")


def type_problem(type_name) -> str | None:
    """Why ``type_name`` is not a message type this package may import, or None."""
    match = TYPE_NAME.fullmatch(type_name) if isinstance(type_name, str) else None
    if match is None:
        return "not a message type name (package/msg/Type)"
    if match.group(1) not in KNOWN_PACKAGES:
        return f"package {match.group(1)} is not a known ROS 2 message package"
    return None


@functools.lru_cache(maxsize=None)
def message_class(type_name: str):
    """The rclpy class of ``pkg/msg/Type``."""
    problem = type_problem(type_name)
    if problem is not None:
        raise UserError(label(type_name, 80), problem)
    package, _, name = type_name.partition("/msg/")
    try:
        found = getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError, ValueError):
        raise UserError(type_name, "message type not installed") from None
    if not hasattr(found, "get_fields_and_field_types"):
        raise UserError(type_name, "not a ROS 2 message class")
    return found
