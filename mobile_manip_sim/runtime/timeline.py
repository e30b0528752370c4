"""The run's time line: the one owner of WHEN things happen in a run, for every adapter (the
node, `simulate` and its recorder, `replay --resimulate`, `plot`). No ROS, no I/O.

Grid. A run is a sequence of points k = 0, 1, … at t_k = k / rate seconds of simulated time
(the node's publications, `simulate`'s samples); a headless run of `duration` s ends with one
more point at `duration` when that is off the grid. Point k's stamp is t_k in integer
nanoseconds (exactly k·10⁹/rate when that is an integer, otherwise rounded to the nearest ns
without accumulating), so stamps never drift, skip or repeat. Segment k runs from point k to
point k + 1: the engine advances to `Grid.time(k + 1)`, the float k + 1 / rate itself.

Commands. Efforts and velocity commands change only at segment starts (zero-order hold): the
command in effect over segment k is chosen at its start t_k and held to t_{k+1}.
- The node takes the latest valid command received up to the segment start (`CommandSlot`); a
  command older than `command_timeout` (simulated time) falls to zero once, until the next one.
- A bag records each command as applied, stamped with the segment start from which it was held,
  and only when it changed (`RunRecorder.commands`): the command over the segment starting at s
  is the latest record with stamp ≤ s (`CommandHistory`). Re-simulation and plots read it so.
- `apply_commands` is how a segment's commands enter the engine (node and re-simulation alike),
  `apply_arm_command` an arm controller's (position, velocity, trajectory: applied when given);
  `start_node_time_line` is the node's t = 0: the scene's initial state with ZERO efforts (a
  robot should not move before someone commands it), where `simulate` holds the scene's efforts.
"""
from __future__ import annotations

import math
from bisect import bisect_right
from fractions import Fraction
from typing import Iterator

import numpy as np

from ..scene.arm_controller import MODES
from ..scene.coordinates import arm_width

NS = 10 ** 9
OFF_GRID_TOLERANCE = 1e-12   # relative: a duration this close to a grid point is on it


def stamp_ns(k: int, rate: Fraction) -> int:
    """k / rate in integer nanoseconds, rounded half up: exact, and never drifting with k."""
    numerator = k * NS * rate.denominator
    return (2 * numerator + rate.numerator) // (2 * rate.numerator)


def seconds_ns(seconds: float) -> int:
    """A time in seconds (a float, taken exactly) in integer nanoseconds, rounded half up."""
    value = Fraction(seconds) * NS
    return math.floor(value + Fraction(1, 2))


def format_ns(ns: int) -> str:
    """Integer nanoseconds as exact decimal seconds (``12.340000000``)."""
    return f"{'-' if ns < 0 else ''}{abs(ns) // NS}.{abs(ns) % NS:09d}"


class Grid:
    """The points of a run at ``rate`` Hz of simulated time (see the module docstring); endless
    (the node) or ending at ``duration`` s (a headless run). Nothing is materialised: a run of
    10⁹ points costs no memory."""

    def __init__(self, rate: float, duration: float | None = None):
        self.hz = float(rate)
        self.rate = Fraction(self.hz)
        self.duration = duration
        self.on_grid = None       # points k / rate ≤ duration
        self.count = None         # all points, None = endless
        if duration is not None:
            self.on_grid = int(duration * self.hz + 1e-9) + 1
            last = (self.on_grid - 1) / self.hz
            off = duration - last > OFF_GRID_TOLERANCE * max(1.0, duration)
            self.count = self.on_grid + off

    def _off_grid(self, k: int) -> bool:
        return self.on_grid is not None and k >= self.on_grid

    def time(self, k: int) -> float:
        """t_k in seconds: what the engine advances to for point k."""
        return self.duration if self._off_grid(k) else k / self.hz

    def stamp(self, k: int) -> int:
        """t_k in integer nanoseconds: the stamp of point k's messages."""
        return seconds_ns(self.duration) if self._off_grid(k) else stamp_ns(k, self.rate)

    def times(self) -> Iterator[float]:
        """t_0, t_1, … generated one at a time (a long run never holds them all)."""
        k = 0
        while self.count is None or k < self.count:
            yield self.time(k)
            k += 1

    def index(self, stamp: int) -> int | None:
        """k of the point stamped ``stamp`` ns, or None when no point has that stamp."""
        k = round(Fraction(stamp) * self.rate / NS)
        if 0 <= k and (self.count is None or k < self.on_grid) and self.stamp(k) == stamp:
            return k
        last = None if self.count is None else self.count - 1
        return last if last is not None and self.stamp(last) == stamp else None

    def segments(self, start: int, end: int) -> Iterator[tuple[int, float]]:
        """(segment start stamp, time the engine advances to) for every segment from the point
        stamped ``start`` to the one stamped ``end``, generated one at a time; ValueError (at
        once) when one is not a point."""
        first, last = self.index(start), self.index(end)
        for stamp, k in ((start, first), (end, last)):
            if k is None:
                raise ValueError(f"stamp {stamp} ns is not a point of the {self.hz:g} Hz grid"
                                 + ("" if self.duration is None else
                                    f" of a {self.duration:g} s run"))
        return ((self.stamp(k), self.time(k + 1)) for k in range(first, last))


def sample_times(duration: float, sample_rate: float) -> Iterator[float]:
    """A headless run's sample times: k / rate for every k with k / rate ≤ duration, then
    duration itself if it is off the rate's grid."""
    return Grid(sample_rate, duration).times()


# --- commands ---------------------------------------------------------------------------------

class CommandSlot:
    """The node's latest valid command of one group (wheels, arm or cmd_vel) and the simulated
    time (ns) of the segment start at which it was first taken."""

    def __init__(self, size: int):
        self.size = size
        self.seq = 0             # valid commands received, ever (synchronous mode counts them)
        self.seq_published = 0   # seq when the latest state went out
        self.clear()

    def clear(self) -> None:
        self.values = np.zeros(self.size)
        self.received_ns: int | None = None
        self.timed_out = False

    def receive(self, values, now_ns: int) -> None:
        self.values = np.array(values, dtype=float)
        self.received_ns = now_ns
        self.timed_out = False
        self.seq += 1

    def held(self, segment_start_ns: int, timeout_ns: int) -> tuple[np.ndarray, bool]:
        """The values to hold from ``segment_start_ns`` on, and whether they have just timed
        out (then they are zero until the next command; ``timeout_ns`` 0 disables)."""
        stale = (timeout_ns > 0 and self.received_ns is not None and not self.timed_out
                 and segment_start_ns - self.received_ns >= timeout_ns)
        if stale:
            self.values = np.zeros(self.size)
            self.timed_out = True
        return self.values.copy(), stale


class CommandHistory:
    """One group's recorded commands, (stamp ns, values) in time order: the values held over
    the segment that starts at a stamp, or None before the first record."""

    def __init__(self, records=()):
        self.stamps: list[int] = []
        self.values: list[np.ndarray] = []
        for stamp, values in records:
            self.add(stamp, values)

    def add(self, stamp: int, values) -> None:
        if self.stamps and stamp < self.stamps[-1]:
            raise ValueError(f"command at {stamp} ns recorded after one at {self.stamps[-1]} ns")
        self.stamps.append(int(stamp))
        self.values.append(np.asarray(values, dtype=float))

    def __bool__(self) -> bool:
        return bool(self.stamps)

    def at(self, stamp: int) -> np.ndarray | None:
        i = bisect_right(self.stamps, stamp) - 1
        return self.values[i] if i >= 0 else None


def start_node_time_line(sim) -> None:
    """The node's t = 0 (at start and after ~/reset): initial state, zero efforts (an arm
    controller holds the initial pose: `Simulation.reset`)."""
    sim.reset()
    sim.set_efforts(np.zeros(2),
                    None if sim.arm_controller.active else np.zeros(arm_width(sim.nu)))


def apply_commands(sim, base, joints, velocity: bool) -> tuple[np.ndarray, np.ndarray]:
    """Hold a segment's commands in the engine: ``base`` the wheel torques (τ_R, τ_L), or in
    velocity mode the base twist (v, ω) for the wheel-speed loop; ``joints`` the arm efforts.
    None leaves a group as it is. Returns (base, joints) as applied (after effort limits):
    what a bag records (base None: velocity mode, no twist given)."""
    if velocity:
        if base is not None:
            sim.set_base_velocity(*base)
        sim.set_efforts(joints=joints)
        applied_base = None if base is None else np.array(base, dtype=float)
    else:
        sim.set_efforts(base, joints)
        applied_base = sim.wheel_efforts
    return applied_base, sim.joint_efforts


def apply_arm_command(sim, mode: str, command) -> None:
    """An arm controller's command as it enters the engine at a segment start (node and
    re-simulation alike), through the engine setter of the ``mode``'s row
    (`scene.arm_controller.MODES`): in an array mode (position, velocity) the n_arm values; in
    joint_trajectory a `trajectory_goals.Trajectory` (times in integer ns; no points: hold where
    it is). A command the engine refuses is its UserError."""
    row = MODES[mode]
    if row.array:
        getattr(sim, row.setter)(command)
    elif len(command.times) == 0:
        sim.hold_arm()
    else:
        getattr(sim, row.setter)(command.times / NS, command.positions, command.velocities,
                                 command.accelerations)
