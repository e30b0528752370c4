"""The scene layer: scene files (YAML) → a validated, immutable `Scene` (schema, model,
controller section, overrides, effects), the coordinates' names, the limits, the method
registry and the one error type. No ROS, no I/O beyond reading a scene.

`load_scene` and `Scene` are the public face (``from mobile_manip_sim.scene import load_scene``).
"""
from .loading import Scene, load_scene

__all__ = ["Scene", "load_scene"]
