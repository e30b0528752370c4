"""The rclpy class of a ROS 2 message type name (``pkg/msg/Type``), for the readers of bags and
the CDR encoder."""
from __future__ import annotations

import functools
import importlib

from ..scene.errors import UserError


@functools.lru_cache(maxsize=None)
def message_class(type_name: str):
    """The rclpy class of ``pkg/msg/Type``."""
    package, _, name = type_name.partition("/msg/")
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError, ValueError):
        raise UserError(type_name, "message type not installed") from None
