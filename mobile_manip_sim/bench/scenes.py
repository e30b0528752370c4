"""Scene documents the bench and the hard-case tests build on: the paper scene and its variants."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from ..scene.coordinates import u_size
from ..scene.loading import Scene, load_scene, parse_scene

CONFIG = Path(__file__).resolve().parents[1] / "config"


def paper_document() -> dict:
    """The paper scene (config/paper_two_link.yaml) as a document, every default filled in."""
    return copy.deepcopy(load_scene().document)


def scene_file(name: str) -> Scene:
    return load_scene(CONFIG / name)


def variant(doc: dict, *, efforts=None, effects=None, initial=None, duration=None, name=None,
            **robot_base) -> Scene:
    """A validated scene from `doc` with sections replaced (effects: the whole mapping)."""
    doc = copy.deepcopy(doc)
    if efforts is not None:
        doc["efforts"] = copy.deepcopy(efforts)
    if effects is not None:
        doc["effects"] = copy.deepcopy(effects)
    if initial is not None:
        doc["initial"].update(copy.deepcopy(initial))
    if duration is not None:
        doc["duration"] = duration
    if name is not None:
        doc["name"] = name
    doc["robot"]["base"].update(robot_base)
    return parse_scene(doc, doc.get("name", "scene"))


def without_stroke_limits(scene: Scene) -> Scene:
    doc = copy.deepcopy(scene.document)
    doc["effects"].pop("stroke_limits", None)
    doc["name"] = scene.name + "_no_stops"
    return parse_scene(doc, doc["name"])


def random_robot_document(n_links: int, seed: int, gravity: float = 10.0,
                          physical: bool = False) -> dict:
    """A random robot of n links: joint rotations, lengths, masses, inertias, base; a random
    initial state inside the strokes; no efforts.

    ``physical``: each cross-section inertia J = tr(B)·1 − B from the same random second moment
    B, so that it is one a mass distribution can have (A + B ≥ C, as MuJoCo requires); the rest
    of the document is the same as without it."""
    rng = np.random.default_rng(seed)
    links = []
    for _ in range(n_links):
        length = float(rng.uniform(0.3, 1.2))
        A = rng.normal(size=(3, 3)) * 0.01
        J = A @ A.T + 1e-4 * np.eye(3)
        if physical:
            J = np.trace(J) * np.eye(3) - J
        links.append({"length": length, "mass_per_length": float(rng.uniform(0.3, 3.0)),
                      "inertia_per_length": J.tolist(),
                      "joint_rpy": rng.uniform(-np.pi, np.pi, 3).tolist(),
                      "stroke": [0.0, length]})
    return {
        "name": f"random_{n_links}_links",
        "robot": {"base": {"mass": float(rng.uniform(4, 10)),
                           "yaw_inertia": float(rng.uniform(0.05, 0.5)),
                           "com_offset": float(rng.uniform(-0.2, 0.2)), "wheel_radius": 0.08,
                           "half_track": 0.145, "wheel_inertia": 0.001},
                  "arm": {"mount": [0.0, 0.0, 0.2], "links": links}},
        "initial": {"joints": [float(v) for link in links
                               for v in (rng.uniform(-1, 1),
                                         rng.uniform(0.2, 0.8) * link["length"])],
                    "velocity": (0.3 * rng.normal(size=u_size(n_links))).tolist()},
        "effects": {"gravity": gravity, "wheel_inertia": True},
    }


def random_arm_scene(n_links: int = 20, seed: int = 20, duration: float = 0.5) -> Scene:
    """The random arm of the work–precision study: `n_links` links with physical
    inertias (MuJoCo can build it), gravity, no efforts, no end stops, the base fixed: MuJoCo's
    peer of it is then the same system, so its errors against our reference are errors."""
    doc = random_robot_document(n_links, seed=seed, physical=True)
    doc["duration"] = duration
    doc["effects"]["fixed_base"] = True
    return parse_scene(doc, doc["name"])
