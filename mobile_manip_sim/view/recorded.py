"""A recorded run as the browser view plays it (`browser.Player`): per sample, the link
transforms (parent → child, /tf-shaped), with the URDF to draw, T + V and the impacts.

- A CSV of `simulate` (`from_csv`; the scene from ``--scene``, else the embedded one): the
  run table of `recording.run`, each row's transforms from `frames.FrameTree`, the URDF
  `urdf.robot_description` of the scene.
- A bag (`from_bag`; ours, or any with /tf and /robot_description): /robot_description's last
  message at or before the first /tf, /tf_static, and a sample per distinct /tf stamp, holding
  every frame's latest transform then (/tf decoded without tf2_msgs, `cdr.tf_message_transforms`).
  T + V and the impacts when the bag is ours (its scene attached: `recording.run.load_bag`);
  none otherwise.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..recording.run import load_bag, load_csv
from ..ros.cdr import tf_message_transforms
from ..ros.frames import FrameTree, Transform
from ..ros.topics import DESCRIPTION_TOPIC, JOINT_STATES_TOPIC, TF_STATIC_TOPIC, TF_TOPIC
from ..ros.urdf import robot_description
from ..scene.errors import UserError
from .drawing import Drawing, read_urdf

STRING_TYPE = "std_msgs/msg/String"


class Recording(NamedTuple):
    drawing: Drawing
    t: np.ndarray               # s, increasing
    frames: list                # per sample: its transforms
    static: list                # the fixed transforms
    energy: np.ndarray | None   # T + V (J) per sample
    impacts: list               # dicts (time, link, stop, energy_lost, …)
    focus: tuple                # x, y where the robot starts


def from_csv(path, scene_path=None) -> Recording:
    run = load_csv(path, scene_path)
    tree = FrameTree(run.scene.robot)
    frames = [[tree.base_transform(q)] + tree.moving_transforms(q) for q in run.q]
    return Recording(read_urdf(robot_description(run.scene)), np.asarray(run.t, dtype=float),
                     frames, tree.static_transforms(), run.energy, run.impacts,
                     tuple(run.q[0, :2]))


def from_bag(path) -> Recording:
    from ..recording.bag_format import decode, read_scene
    from ..recording.bag_reader import open_bag

    bag = open_bag(path)
    topics = bag.topics()
    for topic in (TF_TOPIC, DESCRIPTION_TOPIC):
        if topic not in topics:
            raise UserError(str(path), f"no {topic} in the bag: the browser view draws the robot "
                                       f"from /tf and /robot_description (has: "
                                       f"{', '.join(sorted(topics)) or 'no topics'})")
    description, static, latest, stamps, frames = None, {}, {}, [], []
    for message in bag.messages([TF_TOPIC, TF_STATIC_TOPIC, DESCRIPTION_TOPIC]):
        if message.topic == DESCRIPTION_TOPIC:
            if description is None or not stamps:
                description = decode(message, STRING_TYPE).data
            continue
        try:
            transforms = tf_message_transforms(message.data)
        except (ValueError, UnicodeDecodeError) as error:
            raise UserError(message.topic, f"message at {message.log_time_ns} ns does not decode "
                                           f"as tf2_msgs/msg/TFMessage ({error})") from None
        if message.topic == TF_STATIC_TOPIC:
            static.update((child[1], Transform(*child)) for _, child in transforms)
            continue
        for _, transform in transforms:
            latest[transform[1]] = Transform(*transform)
        stamp = max(s for s, _ in transforms) if transforms else message.log_time_ns
        if stamps and stamp <= stamps[-1]:   # one sample per stamp, in order
            frames[-1] = list(latest.values())
            continue
        stamps.append(stamp)
        frames.append(list(latest.values()))
    if description is None or not frames:
        missing = TF_TOPIC if description is not None else DESCRIPTION_TOPIC
        raise UserError(str(path), f"no complete message on {missing}")
    drawing = read_urdf(description)
    t = np.array(stamps, dtype=np.int64) * 1e-9
    energy, impacts = None, []
    if JOINT_STATES_TOPIC in topics and read_scene(bag) is not None:
        run = load_bag(path)   # ours: T + V from its states, the impacts it recorded
        energy, impacts = np.interp(t, run.t, run.energy), run.impacts
    root = next((f for f in frames[0] if f.child == drawing.root), None)
    focus = (root.translation[0], root.translation[1]) if root else (0.0, 0.0)
    return Recording(drawing, t, frames, list(static.values()), energy, impacts, focus)


def load(path, scene_path=None) -> Recording:
    """A CSV of `simulate` (.csv), a bag directory or an .mcap file."""
    path = Path(path)
    if not path.exists():
        raise UserError(str(path), "no such file or directory")
    if path.is_dir() or path.suffix == ".mcap":
        if scene_path is not None:
            raise UserError("--scene", "a bag holds its own robot; --scene is for a CSV")
        return from_bag(path)
    if path.suffix == ".csv":
        return from_csv(path, scene_path)
    raise UserError(str(path), f"unknown kind of run {path.suffix or '(no suffix)'!r}: expected "
                               "a CSV from simulate (.csv), a bag directory or an .mcap file")
