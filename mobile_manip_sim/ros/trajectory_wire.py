"""A trajectory_msgs/JointTrajectory read straight from its CDR bytes into arrays.

rclpy's deserialisation of a 100,000-point trajectory builds some 500,000 Python objects in one
C call that holds the interpreter lock for seconds (no other thread of the node runs meanwhile)
and leaves the memory of those objects with the process. Here the node's subscription takes the
bytes (``raw=True``) and this reads them with a loop over offsets only — the interpreter lock is
handed on as in any Python loop, so services answer meanwhile — and numpy gathers the values:
the work is proportional to the message's size and what stays is the arrays.

`read_trajectory` returns a `WireTrajectory`; `arrays` checks it as `trajectory_goals.arrange`
checks a goal (same rules, same texts) and returns its `Trajectory` in the node's joint order.
A message that is not a well-formed JointTrajectory is a ValueError with one line.
"""
from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

from ..runtime.timeline import NS, format_ns
from ..scene.limits import TRAJECTORY_POINTS
from .trajectory_goals import AT_REST, Codes, Outcome, Trajectory

MAX_JOINTS = 1024      # joint names in one message (the arm has 2 per link, 64 links at most)
MAX_NAME = 1024        # bytes of one name


class WireTrajectory(NamedTuple):
    joint_names: tuple
    start_ns: int                # header stamp (ns); 0 = now
    times: np.ndarray            # (m,) int64 ns: time_from_start
    fields: dict                 # "positions", "velocities", "accelerations", "effort" →
    #                              (counts, offsets): (m,) int64 each, offsets into `words`' bytes
    words: np.ndarray            # the message's payload as float64 words (values are aligned)


class _Reader:
    def __init__(self, data: bytes):
        if len(data) < 4 or data[1] not in (0, 1):
            raise ValueError("not a CDR message (no encapsulation header)")
        self.data, self.little = memoryview(data)[4:], data[1] == 1
        self.end = len(self.data)
        self.at = 0
        self.prefix = "<" if self.little else ">"

    def align(self, size: int) -> None:
        self.at += -self.at % size

    def take(self, fmt: str, size: int):
        self.align(size)
        if self.at + size > self.end:
            raise ValueError(f"truncated at byte {self.at}")
        value = struct.unpack_from(self.prefix + fmt, self.data, self.at)[0]
        self.at += size
        return value

    def string(self) -> str:
        n = self.take("I", 4)
        if n > MAX_NAME or self.at + n > self.end:
            raise ValueError(f"a string of {n} bytes")
        text = bytes(self.data[self.at:self.at + n]).rstrip(b"\0")
        self.at += n
        return text.decode("utf-8", "replace")


def read_trajectory(data: bytes) -> WireTrajectory:
    """The JointTrajectory in ``data`` (its CDR bytes, encapsulation header first)."""
    r = _Reader(data)
    sec, nanosec = r.take("i", 4), r.take("I", 4)
    r.string()   # frame_id
    names = r.take("I", 4)
    if names > MAX_JOINTS:
        raise ValueError(f"{names} joint names")
    joint_names = tuple(r.string() for _ in range(names))
    m = r.take("I", 4)
    if m > TRAJECTORY_POINTS:
        raise ValueError(f"{m} points, beyond the {TRAJECTORY_POINTS} a trajectory may have")
    if m * 24 > r.end - r.at:
        raise ValueError(f"{m} points do not fit in {len(data)} bytes")
    kinds = ("positions", "velocities", "accelerations", "effort")
    counts = {kind: np.zeros(m, dtype=np.int64) for kind in kinds}
    offsets = {kind: np.zeros(m, dtype=np.int64) for kind in kinds}
    seconds = np.zeros(m, dtype=np.int64)
    nanos = np.zeros(m, dtype=np.int64)
    take, end = r.take, r.end
    for i in range(m):
        for kind in kinds:
            n = take("I", 4)
            if n:
                r.align(8)
                if n > MAX_JOINTS or r.at + 8 * n > end:
                    raise ValueError(f"point {i}: {n} {kind}")
                counts[kind][i], offsets[kind][i] = n, r.at
                r.at += 8 * n
        seconds[i], nanos[i] = take("i", 4), take("I", 4)
    words = np.frombuffer(r.data[:end - end % 8], dtype=np.dtype("<f8" if r.little else ">f8"))
    fields = {kind: (counts[kind], offsets[kind]) for kind in kinds}
    return WireTrajectory(joint_names, int(sec) * NS + int(nanosec), seconds * NS + nanos, fields,
                          words)


def _gather(wire: WireTrajectory, offsets: np.ndarray, n: int) -> np.ndarray:
    """(m, n) values from each row's offset (rows whose count is not n hold anything: the
    caller refuses them by their count). At most m × n values: a message cannot make it
    allocate more than the goal it would be."""
    if wire.words.size == 0:
        return np.zeros((offsets.size, n))
    index = np.minimum(offsets[:, None] // 8 + np.arange(n), wire.words.size - 1)
    return wire.words[index].astype(float)


def arrays(wire: WireTrajectory, names, codes: Codes) -> Trajectory | Outcome:
    """``wire`` as the trajectory in the order ``names`` (the arm's joints), or why not — the
    rules and texts of `trajectory_goals.arrange`, on arrays."""
    given = list(wire.joint_names)
    if sorted(given) != sorted(names) or len(set(given)) != len(given):
        return Outcome(codes.invalid_joints, f"joints {given} do not match the arm's {list(names)} "
                                             f"(each once, any order)")
    times = wire.times
    if times.size == 0:
        return Outcome(codes.invalid_goal, "empty trajectory: no points")
    bad = np.flatnonzero((times < 0) | np.concatenate([[False], np.diff(times) <= 0]))
    if bad.size:
        i = int(bad[0])
        return Outcome(codes.invalid_goal, f"point {i}: time_from_start {format_ns(int(times[i]))}"
                                           f" s is not after the previous point's (times must "
                                           f"be ≥ 0 and strictly increasing)")
    counts, _ = wire.fields["effort"]
    if counts.any():
        i = int(np.flatnonzero(counts)[0])
        return Outcome(codes.invalid_goal, f"point {i}: efforts given; the arm's trajectory "
                                           f"controller follows positions, not efforts")
    n, order = len(names), [given.index(name) for name in names]
    out = {}
    for field in ("positions", "velocities", "accelerations"):
        counts, offsets = wire.fields[field]
        if field != "positions" and not counts.any():
            out[field] = None
            continue
        values = _gather(wire, offsets, n)
        wrong = counts != n
        finite = np.isfinite(values)
        bad = np.flatnonzero(wrong | ~finite.all(axis=1))
        if bad.size:
            i = int(bad[0])
            if wrong[i]:
                every = "" if field == "positions" else ", at every point or at none"
                return Outcome(codes.invalid_goal, f"point {i}: {int(counts[i])} {field}, "
                                                   f"expected {n} (one per joint{every})")
            j = int(np.flatnonzero(~finite[i])[0])
            return Outcome(codes.invalid_goal, f"point {i}: {field} of {given[j]} is not finite")
        out[field] = np.ascontiguousarray(values[:, order])
    last = out["velocities"]
    if last is not None and np.any(np.abs(last[-1]) > AT_REST):
        j = int(np.argmax(np.abs(last[-1]) > AT_REST))
        return Outcome(codes.invalid_goal, f"the last point's velocity of {names[j]} is "
                                           f"{last[-1][j]:g}, not zero")
    return Trajectory(times.astype(np.int64), out["positions"], out["velocities"],
                      out["accelerations"])
