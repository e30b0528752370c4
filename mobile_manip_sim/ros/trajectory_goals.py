"""Trajectory goals as joint_trajectory_controller (ros2_controllers, Jazzy) handles them, without
ROS: the node's action server and `joint_trajectory` topic turn messages into `Goal`s and hand
them here; the engine does the interpolation (`Simulation.set_arm_trajectory`).

- Joints are matched by name, in any order; a goal must name every arm joint once and no other
  (INVALID_JOINTS). Points: strictly increasing finite times, one finite value per joint, velocities
  and accelerations given for every point or for none, the last point at rest (INVALID_GOAL).
- Start: a header stamp of zero, or one in the past, is now; a future stamp delays the start (the
  current state stays the point at τ = 0); a non-zero stamp whose trajectory ENDS in the past is
  OLD_HEADER_TIMESTAMP. "Now" is simulated time at a segment start: goals, like every command,
  apply at segment starts (timeline.py), so a run stays a pure function of its commands.
- Limits: the engine refuses a point outside a joint's stroke or effort limits with a UserError
  naming the joint; that line is the INVALID_GOAL's text.
- Tolerances (jtc's `get_segment_tolerances`): a goal's value > 0 replaces the default, 0 keeps
  it, -1 erases it (unchecked), another negative value or an unknown joint keeps all the
  defaults. The defaults are jtc's: no path or goal position tolerance, a stopped-velocity goal
  tolerance of 0.01, goal_time 0 (no time limit). Checked at every segment start against the
  state there: before the last point's time the path tolerance (PATH_TOLERANCE_VIOLATED, then the
  arm holds where it is); from then on, within the goal tolerance is SUCCESSFUL, and outside it
  for more than goal_time (when non-zero) GOAL_TOLERANCE_VIOLATED (then it holds).
- A new goal preempts the active one (CANCELED with INVALID_GOAL, "preempted", as jtc); a cancel
  holds the arm where it is and ends the goal as canceled; a reset aborts it (INVALID_GOAL).

Result codes are not written here: `Codes.of` reads them from control_msgs' Result type.
Errors are desired − actual, as jtc's, the position error of a revolute joint (continuous in the
URDF) the shortest angle (`errors`): tolerances, feedback and the controller state read it.
"""
from __future__ import annotations

import math
import threading
from typing import Callable, NamedTuple

import numpy as np

from ..engine.arm_reference import position_errors
from ..runtime.timeline import NS, format_ns
from ..scene.errors import UserError

ERASE = -1.0                     # a goal's tolerance value that switches the check off
STOPPED_VELOCITY_TOLERANCE = 0.01   # jtc's default goal velocity tolerance (rad/s or m/s)
AT_REST = 1.1920928955078125e-07    # float epsilon: jtc's "zero" final velocity


class Codes(NamedTuple):
    """FollowJointTrajectory's result codes, read from control_msgs (`Codes.of`)."""
    successful: int
    invalid_goal: int
    invalid_joints: int
    old_header_timestamp: int
    path_tolerance_violated: int
    goal_tolerance_violated: int

    @classmethod
    def of(cls, result) -> Codes:
        """The codes of ``result`` (control_msgs.action.FollowJointTrajectory.Result, or anything
        with the same constants)."""
        return cls(*(int(getattr(result, name.upper())) for name in cls._fields))


class Point(NamedTuple):
    time_ns: int                 # time_from_start, integer ns (as a Duration holds it)
    positions: tuple
    velocities: tuple = ()
    accelerations: tuple = ()
    effort: tuple = ()           # refused: the arm follows positions (jtc without an effort
                                 # command interface refuses them too)


class JointTolerance(NamedTuple):
    name: str
    position: float = 0.0
    velocity: float = 0.0
    acceleration: float = 0.0


class Goal(NamedTuple):
    """A JointTrajectory (and, from the action, its tolerances) in plain numbers."""
    joint_names: tuple
    points: tuple
    start_ns: int = 0            # header stamp, ns of simulated time; 0 = now
    path_tolerance: tuple = ()   # JointTolerance records
    goal_tolerance: tuple = ()
    goal_time: float = 0.0       # goal_time_tolerance, s (0 = the default)


class Outcome(NamedTuple):
    code: int | None             # None: canceled
    text: str
    # Ends as CANCELED with ``code`` (a preempted goal: joint_trajectory_controller cancels it
    # with INVALID_GOAL), rather than ABORTED.
    canceled: bool = False


class Tolerances(NamedTuple):
    path: np.ndarray             # (n, 3): position, velocity, acceleration; 0 = unchecked
    goal: np.ndarray
    goal_time: float             # s; 0 = no limit


class Trajectory(NamedTuple):
    """A trajectory in the node's joint order, times in integer ns after the segment start it
    applies at: what goes to `Simulation.set_arm_trajectory` (as ``times / NS`` s, by
    `timeline.apply_arm_command`) and into a bag (as Durations: exact)."""
    times: np.ndarray            # (m,) int64 ns
    positions: np.ndarray        # (m, n)
    velocities: np.ndarray | None
    accelerations: np.ndarray | None


def errors(desired, actual) -> tuple:
    """(position, velocity) errors, desired − actual, of the arm's (q, q̇) pairs: jtc's
    ``compute_error_for_joint``, the shortest angle on the continuous joints."""
    return position_errors(desired[0], actual[0]), np.asarray(desired[1]) - np.asarray(actual[1])


def default_tolerances(n: int) -> Tolerances:
    goal = np.zeros((n, 3))
    goal[:, 1] = STOPPED_VELOCITY_TOLERANCE
    return Tolerances(np.zeros((n, 3)), goal, 0.0)


def _resolved(default: float, value: float) -> float:
    """jtc's `resolve_tolerance_source`; ValueError for an illegal value."""
    if not math.isfinite(value):
        raise ValueError(value)
    if value > 0.0:
        return value
    if abs(value - ERASE) < AT_REST:
        return 0.0
    if value < 0.0:
        raise ValueError(value)
    return default


def tolerances(goal: Goal, names, defaults: Tolerances) -> tuple[Tolerances, str | None]:
    """The goal's tolerances over ``defaults``, and why the defaults were kept (or None)."""
    index = {name: i for i, name in enumerate(names)}
    resolved = {"path": defaults.path.copy(), "goal": defaults.goal.copy()}
    try:
        goal_time = _resolved(defaults.goal_time, goal.goal_time)
    except ValueError:
        return defaults, f"goal_time_tolerance {goal.goal_time:g} is illegal: default tolerances"
    for kind, given in (("path", goal.path_tolerance), ("goal", goal.goal_tolerance)):
        for tolerance in given:
            if tolerance.name not in index:
                return defaults, (f"{kind}_tolerance names joint {tolerance.name!r}, which the "
                                  f"arm does not have: default tolerances")
            row = resolved[kind][index[tolerance.name]]
            for j, field in enumerate(("position", "velocity", "acceleration")):
                try:
                    row[j] = _resolved(row[j], getattr(tolerance, field))
                except ValueError:
                    return defaults, (f"{kind}_tolerance of {tolerance.name}: illegal {field} "
                                      f"{getattr(tolerance, field)}: default tolerances")
    return Tolerances(resolved["path"], resolved["goal"], goal_time), None


def arrange(goal: Goal, names, codes: Codes) -> Trajectory | Outcome:
    """The goal's trajectory in the order ``names`` (the arm's joints), or why not."""
    given = list(goal.joint_names)
    if sorted(given) != sorted(names) or len(set(given)) != len(given):
        return Outcome(codes.invalid_joints, f"joints {given} do not match the arm's {list(names)} "
                                             f"(each once, any order)")
    if not goal.points:
        return Outcome(codes.invalid_goal, "empty trajectory: no points")
    n, order = len(names), [given.index(name) for name in names]
    times = [int(point.time_ns) for point in goal.points]
    for i, t in enumerate(times):
        if t < 0 or (i and t <= times[i - 1]):
            return Outcome(codes.invalid_goal, f"point {i}: time_from_start {format_ns(t)} s is "
                                               f"not after the previous point's (times must be "
                                               f"≥ 0 and strictly increasing)")
    for i, point in enumerate(goal.points):
        if len(point.effort):
            return Outcome(codes.invalid_goal, f"point {i}: efforts given; the arm's trajectory "
                                               f"controller follows positions, not efforts")
    fields = {}
    for field in ("positions", "velocities", "accelerations"):
        rows = [list(getattr(point, field)) for point in goal.points]
        if field != "positions" and all(not row for row in rows):
            fields[field] = None
            continue
        for i, row in enumerate(rows):
            if len(row) != n:
                every = "" if field == "positions" else ", at every point or at none"
                return Outcome(codes.invalid_goal, f"point {i}: {len(row)} {field}, expected {n} "
                                                   f"(one per joint{every})")
            bad = [given[j] for j, v in enumerate(row) if not math.isfinite(v)]
            if bad:
                return Outcome(codes.invalid_goal, f"point {i}: {field} of {bad[0]} is not finite")
        fields[field] = np.array(rows, dtype=float)[:, order]
    last = fields["velocities"]
    if last is not None and np.any(np.abs(last[-1]) > AT_REST):
        j = int(np.argmax(np.abs(last[-1]) > AT_REST))
        return Outcome(codes.invalid_goal, f"the last point's velocity of {names[j]} is "
                                           f"{last[-1][j]:g}, not zero")
    return Trajectory(np.array(times, dtype=np.int64), fields["positions"], fields["velocities"],
                      fields["accelerations"])


def started(trajectory: Trajectory, start_ns: int, now_ns: int,
            codes: Codes) -> Trajectory | Outcome:
    """The trajectory as applied at ``now_ns``: delayed by a future start, or refused when its
    start stamp is non-zero and it ends before now."""
    if start_ns == 0 or start_ns <= now_ns:
        if start_ns and start_ns + int(trajectory.times[-1]) < now_ns:
            return Outcome(codes.old_header_timestamp,
                           f"the trajectory starts at {format_ns(start_ns)} s and ends before "
                           f"now ({format_ns(now_ns)} s of simulated time)")
        return trajectory
    return trajectory._replace(times=trajectory.times + (start_ns - now_ns))


class Request:
    """One goal from submission to its outcome. ``handle`` is the caller's (the node's goal
    handle, None for the topic); ``finished`` is set once ``outcome`` is known."""

    def __init__(self, goal: Goal, handle=None):
        self.goal, self.handle = goal, handle
        self.trajectory: Trajectory | None = None
        self.tolerances: Tolerances | None = None
        self.note: str | None = None         # why the goal's tolerances were not taken
        self.applied_ns: int | None = None   # the segment start it applied at
        self.cancel_requested = False
        self.outcome: Outcome | None = None
        self.finished = threading.Event()

    def finish(self, outcome: Outcome) -> None:
        if self.outcome is None:
            self.outcome = outcome
            self.finished.set()


class Step(NamedTuple):
    """What happened at a segment start."""
    command: Trajectory | None   # applied (a trajectory, or HOLD); None: nothing new
    feedback: tuple | None       # (request, desired, actual, error) of the active goal
    finished: list               # requests that ended here


HOLD = Trajectory(np.zeros(0, dtype=np.int64), np.zeros((0, 0)), None, None)   # hold where it is


class TrajectoryGoals:
    """The goals of the arm (joints ``names``): `submit` and `cancel` from any thread;
    `segment_start` from the stepping thread."""

    def __init__(self, names, codes: Codes):
        self.names, self.codes = list(names), codes
        self.defaults = default_tolerances(len(self.names))
        self._lock = threading.Lock()
        self._pending: Request | None = None
        self.active: Request | None = None

    def submit(self, goal: Goal, handle=None, arranged=None) -> Request:
        """A new goal: refused at once (finished) or waiting for the next segment start, where
        it preempts the active one. A goal still waiting is preempted by this one. ``arranged``:
        the goal's `arrange` done already (from arrays: its points are then left empty)."""
        request = Request(goal, handle)
        if arranged is None:
            arranged = arrange(goal, self.names, self.codes)
        if isinstance(arranged, Outcome):
            request.finish(arranged)
            return request
        request.trajectory = arranged
        request.tolerances, request.note = tolerances(goal, self.names, self.defaults)
        with self._lock:
            if self._pending is not None:
                self._pending.finish(self._preempted())
            self._pending = request
        return request

    def cancel(self, request: Request) -> None:
        """Cancel ``request``: one waiting ends now; the active one at the next segment start,
        where the arm holds where it is."""
        with self._lock:
            if request is self._pending:
                self._pending = None
                request.finish(Outcome(None, "canceled before it started"))
            else:
                request.cancel_requested = True

    def forget(self, text: str) -> None:
        """A reset: every goal ends (INVALID_GOAL, ``text``)."""
        with self._lock:
            for request in (self._pending, self.active):
                if request is not None:
                    request.finish(Outcome(self.codes.invalid_goal, text))
            self._pending = self.active = None

    def _preempted(self) -> Outcome:
        return Outcome(self.codes.invalid_goal, "preempted by a new goal", canceled=True)

    def segment_start(self, now_ns: int, desired, actual,
                      apply: Callable[[Trajectory], None]) -> Step:
        """At the segment start ``now_ns`` (simulated time), with the arm's reference
        ``desired`` = (q, q̇, q̈) and state ``actual`` = (q, q̇) there: check the active goal,
        act on a cancel, start a waiting goal. ``apply(trajectory)`` puts a trajectory (or HOLD)
        into the engine; a UserError from it refuses the goal (INVALID_GOAL, its line)."""
        with self._lock:
            pending, self._pending = self._pending, None
        finished, feedback, hold = [], None, False
        active = self.active
        if active is not None:
            error = errors(desired, actual)
            feedback = (active, desired, actual, error)
            outcome = Outcome(None, "canceled") if active.cancel_requested else \
                self._check(active, now_ns, error)
            if outcome is not None:
                hold = outcome.code != self.codes.successful
                active.finish(outcome)
                finished.append(active)
                self.active = None
        command = None
        if pending is not None and not pending.finished.is_set():
            command = self._start(pending, now_ns, apply)
            if command is not None and self.active is not None:
                self.active.finish(self._preempted())
                finished.append(self.active)
            if command is not None:
                self.active = pending
            else:
                finished.append(pending)
        if command is None and hold:
            apply(HOLD)
            command = HOLD
        return Step(command, feedback, finished)

    def _start(self, request: Request, now_ns: int, apply) -> Trajectory | None:
        trajectory = started(request.trajectory, request.goal.start_ns, now_ns, self.codes)
        if isinstance(trajectory, Outcome):
            request.finish(trajectory)
            return None
        try:
            apply(trajectory)
        except UserError as error:
            request.finish(Outcome(self.codes.invalid_goal, str(error)))
            return None
        request.trajectory, request.applied_ns = trajectory, now_ns
        return trajectory

    def _check(self, request: Request, now_ns: int, error) -> Outcome | None:
        """jtc's tolerance checks of the active goal at ``now_ns``; None while it goes on."""
        tau = (now_ns - request.applied_ns) / NS
        end = int(request.trajectory.times[-1]) / NS
        errors = np.stack([error[0], error[1], np.zeros_like(error[0])], axis=1)
        limits = request.tolerances
        if tau < end or now_ns == request.applied_ns:
            joint = _violation(errors, limits.path)
            if joint is not None:
                return Outcome(self.codes.path_tolerance_violated,
                               f"path tolerance violated at t = {format_ns(now_ns)} s: "
                               f"{self._describe(joint, errors, limits.path)}")
            if tau < end:
                return None
        joint = _violation(errors, limits.goal)
        if joint is None:
            return Outcome(self.codes.successful, "goal reached")
        late = tau - end
        if limits.goal_time > 0.0 and late > limits.goal_time:
            return Outcome(self.codes.goal_tolerance_violated,
                           f"goal tolerance not reached {late:g} s after the trajectory's end "
                           f"(goal_time {limits.goal_time:g} s): "
                           f"{self._describe(joint, errors, limits.goal)}")
        return None

    def _describe(self, joint: int, errors: np.ndarray, limits: np.ndarray) -> str:
        fields = [f"{name} error {errors[joint, j]:.6g} beyond {limits[joint, j]:g}"
                  for j, name in enumerate(("position", "velocity", "acceleration"))
                  if 0.0 < limits[joint, j] < abs(errors[joint, j])]
        return f"{self.names[joint]} {', '.join(fields)}"


def _violation(errors: np.ndarray, limits: np.ndarray) -> int | None:
    """The first joint whose errors exceed a checked (> 0) tolerance, or None."""
    outside = (limits > 0.0) & (np.abs(errors) > limits)
    rows = np.flatnonzero(outside.any(axis=1))
    return int(rows[0]) if rows.size else None
