"""Scenes and helpers shared by the engine tests: small variations of the paper's robot.

Scenes are built as documents (the parsed YAML) and validated by `parse_scene`, exactly as a
scene file would be, so every test also exercises the scene format.
"""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import yaml

from mobile_manip_sim.engine.simulation import Simulation
from mobile_manip_sim.scene.loading import parse_scene

CONFIG = Path(__file__).resolve().parents[2] / "config"
PAPER_SCENE = CONFIG / "paper_two_link.yaml"
_PAPER = yaml.safe_load(PAPER_SCENE.read_text())

# The paper's first joint: axis horizontal, perpendicular to the base's symmetry plane.
HORIZONTAL_AXIS = [math.pi / 2, 0.0, 0.0]


def paper_doc(**top) -> dict:
    """The paper scene as a document; keyword arguments replace top-level sections."""
    doc = copy.deepcopy(_PAPER)
    doc.update(copy.deepcopy(top))
    return doc


def one_link_doc(*, joint_rpy=HORIZONTAL_AXIS, stroke=(0.0, 1.0), joints=(0.3, 0.5),
                 velocity=(0.0, 0.0, 0.0, 0.0), wheel_efforts=(0.0, 0.0), joint_efforts=(0.0, 0.0),
                 effects=None) -> dict:
    """The paper's base carrying its first rod alone (1 m, 1 kg), gravity off unless `effects`
    says."""
    doc = paper_doc()
    link = doc["robot"]["arm"]["links"][0]
    link["joint_rpy"] = list(joint_rpy)
    link["stroke"] = list(stroke)
    doc["robot"]["arm"]["links"] = [link]
    doc["robot"].pop("limits")   # the paper robot's motors: for its two links
    doc["initial"] = {"joints": list(joints), "velocity": list(velocity)}
    doc["efforts"] = {"wheels": list(wheel_efforts), "joints": list(joint_efforts)}
    doc["effects"] = dict(effects or {})
    return doc


def base_only_doc(*, velocity=(0.0, 0.0), wheel_efforts=(0.0, 0.0), effects=None) -> dict:
    doc = paper_doc()
    doc["robot"]["arm"] = {"links": []}
    doc["robot"].pop("limits")   # the paper robot's motors: for its two links
    doc["initial"] = {"velocity": list(velocity)}
    doc["efforts"] = {"wheels": list(wheel_efforts)}
    doc["effects"] = dict(effects or {})
    return doc


def simulation(doc: dict, method: str | None = None, **settings) -> Simulation:
    """A Simulation of the document, with its integrator replaced by `method` and `settings`."""
    doc = copy.deepcopy(doc)
    if method is not None:
        doc["integrator"] = {"method": method, **settings}
    return Simulation(parse_scene(doc))


def sampled(sim: Simulation, t_end: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Advance to t_end sampling (q, u, W) at `rate` Hz: (times, states), the start included."""
    count = int(round(t_end * rate))
    times = np.arange(count + 1) / rate
    states = np.empty((count + 1, sim.s.size))
    for i, t in enumerate(times):
        sim.advance_to(t)
        states[i] = sim.s
    return times, states

