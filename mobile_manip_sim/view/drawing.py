"""What the browser view draws, read from a URDF (ours from `ros.urdf`, or any bag's
/robot_description): the link tree, each link's visual shapes (box, cylinder, sphere; meshes are
left out and counted) with their colours, and each prismatic joint's stroke — the segment its
child's origin travels along, from the lower limit to the upper one, in the parent's frame.

No kinematics here: where each link is comes from /tf-shaped transforms (`frames.FrameTree` for a
run of ours, the bag's /tf otherwise), each one parent → child, which the view hands to the
browser's scene graph as is.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import NamedTuple

import numpy as np

from ..ros.frames import rpy_quaternion
from ..scene.errors import UserError

GREY = (0.6, 0.6, 0.6, 1.0)   # a visual without a colour


class Visual(NamedTuple):
    """One shape of a link, in the link's frame: ``kind`` box | cylinder | sphere, ``size`` (box:
    x, y, z; cylinder: radius, length along z; sphere: radius), m; ``rgba`` in [0, 1]."""

    kind: str
    size: tuple
    xyz: tuple
    wxyz: tuple
    rgba: tuple


class Stroke(NamedTuple):
    """A prismatic joint's stroke: the ends (m) of the segment its child's origin travels along,
    in the ``parent`` link's frame."""

    joint: str
    parent: str
    child: str
    lower: tuple
    upper: tuple


class Drawing(NamedTuple):
    """A robot to draw: ``root`` (the link no joint carries), ``parent`` (link → its parent
    link), ``visuals`` (link → its shapes), ``strokes``, ``meshes`` (mesh visuals left out)."""

    name: str
    root: str
    parent: dict
    visuals: dict
    strokes: list
    meshes: int

    def path(self, link: str) -> str:
        """The scene-graph name of ``link``: its chain from the root, so that each link's pose
        is relative to its parent's, as /tf gives it ('/' inside a frame name becomes '|')."""
        chain = [link]
        while chain[-1] in self.parent:
            chain.append(self.parent[chain[-1]])
        return "/" + "/".join(name.replace("/", "|") for name in reversed(chain))

    def extent(self) -> float:
        """A length (m) the size of the robot, where a camera stands back to: the farthest any
        shape reaches from its link's origin, plus every stroke's farthest end (rods in a row)."""
        reach = [np.linalg.norm(v.xyz) + max(v.size) for shapes in self.visuals.values()
                 for v in shapes]
        return float(max(reach, default=0.2) + sum(np.linalg.norm(s.upper)
                                                    for s in self.strokes))


def _floats(text, count: int, what: str) -> tuple:
    try:
        values = tuple(float(v) for v in (text or "").split())
    except ValueError:
        values = ()
    if len(values) != count or not all(np.isfinite(values)):
        raise UserError("/robot_description", f"{what}: {text!r} is not {count} numbers")
    return values


def _origin(element) -> tuple[tuple, tuple]:
    """(xyz, rotation as x y z w) of an ``<origin>`` child (identity when absent)."""
    origin = element.find("origin")
    if origin is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
    xyz = _floats(origin.get("xyz", "0 0 0"), 3, "origin xyz")
    return xyz, rpy_quaternion(*_floats(origin.get("rpy", "0 0 0"), 3, "origin rpy"))


def _rotate(q, v) -> np.ndarray:
    """v turned by the unit quaternion q (x, y, z, w)."""
    u, w = np.array(q[:3]), q[3]
    v = np.asarray(v, dtype=float)
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def _colour(visual, materials: dict) -> tuple:
    material = visual.find("material")
    if material is None:
        return GREY
    color = material.find("color")
    if color is not None:
        return _floats(color.get("rgba"), 4, "material color")
    return materials.get(material.get("name"), GREY)


def read_urdf(text: str) -> Drawing:
    """The `Drawing` of a URDF (XML text); a `UserError` naming /robot_description when it is
    not one (not XML, no link, a joint naming an unknown link, a loop)."""
    try:
        robot = ET.fromstring(text)
    except (ET.ParseError, TypeError, ValueError) as error:
        raise UserError("/robot_description", f"not a URDF ({error})") from None
    links = [link.get("name") for link in robot.findall("link")]
    if robot.tag != "robot" or not links:
        raise UserError("/robot_description", "not a URDF (no <robot> with a <link>)")
    materials = {}
    for material in robot.findall("material"):
        color = material.find("color")
        if color is not None:
            materials[material.get("name")] = _floats(color.get("rgba"), 4, "material color")
    parent, strokes = {}, []
    for joint in robot.findall("joint"):
        name = joint.get("name")
        child, up = joint.find("child"), joint.find("parent")
        if child is None or up is None or child.get("link") not in links or \
                up.get("link") not in links:
            raise UserError("/robot_description", f"joint {name!r} joins links that are not "
                                                  f"in the URDF")
        parent[child.get("link")] = up.get("link")
        limit = joint.find("limit")
        if joint.get("type") == "prismatic" and limit is not None:
            xyz, rotation = _origin(joint)
            axis_element = joint.find("axis")
            axis = _floats(axis_element.get("xyz"), 3, f"joint {name} axis") \
                if axis_element is not None else (1.0, 0.0, 0.0)
            ends = [tuple(np.add(xyz, _rotate(rotation, np.multiply(axis, float(
                limit.get(side, 0.0)))))) for side in ("lower", "upper")]
            strokes.append(Stroke(name, up.get("link"), child.get("link"), *ends))
    roots = [link for link in links if link not in parent]
    if len(roots) != 1:
        raise UserError("/robot_description", f"not a tree: {len(roots)} links have no parent")
    for link in links:   # a loop would never reach the root
        seen = {link}
        while link in parent:
            link = parent[link]
            if link in seen:
                raise UserError("/robot_description", f"joints make a loop through {link!r}")
            seen.add(link)
    visuals, meshes = {}, 0
    for link in robot.findall("link"):
        shapes = []
        for visual in link.findall("visual"):
            geometry = visual.find("geometry")
            shape = geometry[0] if geometry is not None and len(geometry) else None
            if shape is None or shape.tag not in ("box", "cylinder", "sphere"):
                meshes += 1
                continue
            if shape.tag == "box":
                size = _floats(shape.get("size"), 3, "box size")
            elif shape.tag == "cylinder":
                size = (_floats(shape.get("radius"), 1, "cylinder radius")[0],
                        _floats(shape.get("length"), 1, "cylinder length")[0])
            else:
                size = _floats(shape.get("radius"), 1, "sphere radius")
            xyz, (x, y, z, w) = _origin(visual)
            shapes.append(Visual(shape.tag, size, xyz, (w, x, y, z),
                                 _colour(visual, materials)))
        visuals[link.get("name")] = shapes
    return Drawing(robot.get("name", "robot"), roots[0], parent, visuals, strokes, meshes)
