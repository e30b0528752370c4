"""Cost of each effect: the paper scene with every effect off, then each alone on, then all on.

Timed with RK4 at a fixed 1 kHz (the same steps whatever the physics, so the time is the cost
of the stages the effect adds) and with the scene's own DOP853 (rtol 1e-10), where an effect
also changes how many steps the physics needs.
"""
from __future__ import annotations

import copy

from ..scene.loading import EFFECT_NAMES, make_integrator, parse_scene
from .runs import simulate

# The value each effect takes when it is on (the paper scene's own where it has one).
EFFECT_VALUES = {
    "gravity": 10.0,
    "stroke_limits": {"restitution": 0.0, "law": "impulse"},
    "wheel_inertia": True,
    "joint_damping": 0.05,
    "wheel_damping": 0.01,
    "effort_limits": {"wheels": 0.15, "joints": [5.0, 5.0, 5.0, 5.0]},
    "locked_joints": ["arm_revolute_2"],
    "fixed_base": True,
    "payload": 0.5,
}


def variants(document: dict) -> list:
    """(label, scene) for: no effect, each effect alone, all effects."""
    def scene(effects, label):
        doc = copy.deepcopy(document)
        doc["effects"] = copy.deepcopy(effects)
        doc["name"] = label
        return parse_scene(doc, label)

    out = [("none", scene({}, "none"))]
    out += [(name, scene({name: EFFECT_VALUES[name]}, name)) for name in EFFECT_NAMES]
    out.append(("all", scene(dict(EFFECT_VALUES), "all")))
    return out


def measure(document: dict, progress, quick: bool = False) -> list:
    """Rows: (label, effects on, rk4 Run, dop853 Run)."""
    rows = []
    repeats = 1 if quick else 3
    for label, scene in variants(document):
        fixed = simulate(scene, make_integrator(scene.integrator, "rk4", dt=1e-3), repeats=repeats,
                         record=False)
        adaptive = simulate(scene,
                            make_integrator(scene.integrator, "dop853", rtol=1e-10, atol=1e-12),
                            repeats=repeats, record=False)
        rows.append((label, scene.effects.names_on(), fixed, adaptive))
        progress(f"effect {label}: rk4 1 kHz {fixed.cpu_per_second * 1e3:.2f} ms/s, "
                 f"dop853 {adaptive.cpu_per_second * 1e3:.2f} ms/s")
    return rows
