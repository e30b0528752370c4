"""trajectory_goals without ROS: joint matching, start times, tolerances, preemption, cancel, as
joint_trajectory_controller does them. The result codes are read from the FollowJointTrajectory
definition the project carries (tools/interfaces/), not written here. ``apply`` is the list the
segment starts' commands go to; `Stroke` refuses positions as the engine does (a UserError
naming the joint)."""
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mobile_manip_sim.ros.trajectory_goals import (
    HOLD,
    Codes,
    Goal,
    JointTolerance,
    Outcome,
    Point,
    TrajectoryGoals,
    arrange,
    errors,
    started,
    tolerances,
)
from mobile_manip_sim.scene.errors import UserError

ACTION = (Path(__file__).resolve().parents[2] / "tools" / "interfaces" / "control_msgs" /
          "action" / "FollowJointTrajectory.action")
NAMES = ["arm_revolute_1", "arm_prismatic_1", "arm_revolute_2", "arm_prismatic_2"]
MS = 10 ** 6
S = 10 ** 9


def result_constants():
    """The Result section's constants of the carried action definition."""
    result = ACTION.read_text().split("---")[1]
    return SimpleNamespace(**{name: int(value) for name, value in
                              re.findall(r"^int32 (\w+) = (-?\d+)$", result, re.M)})


CODES = Codes.of(result_constants())


class Stroke:
    """Takes trajectories like the engine: a prismatic position outside [0.05, 0.6] m is a
    UserError naming the joint. Keeps what it applied."""

    def __init__(self):
        self.applied = []

    def __call__(self, trajectory):
        for row in trajectory.positions:
            for name, value in zip(NAMES, row, strict=True):
                if "prismatic" in name and not 0.05 <= value <= 0.6:
                    raise UserError(name, f"{value:g} m is outside the stroke [0.05, 0.6]")
        self.applied.append(trajectory)


def goal(names=NAMES, times=(1.0, 2.0, 3.0), start_ns=0, **kwargs):
    points = tuple(Point(round(t * S), tuple(0.1 * (i + 1) + 0.01 * j for j in range(len(names))))
                   for i, t in enumerate(times))
    return Goal(tuple(names), points, start_ns, **kwargs)


def state(q, qd=None):
    q = np.asarray(q, dtype=float)
    return q, np.zeros_like(q) if qd is None else np.asarray(qd, dtype=float)


def test_the_codes_are_control_msgs_ones():
    assert CODES == Codes(0, -1, -2, -3, -4, -5)


def test_joints_are_matched_by_name_in_any_order():
    shuffled = [NAMES[i] for i in (2, 0, 3, 1)]
    given = goal(shuffled)
    trajectory = arrange(given, NAMES, CODES)
    # Column j of the goal is joint shuffled[j]: rearranged to the arm's order.
    for point, row in zip(given.points, trajectory.positions, strict=True):
        assert row.tolist() == [point.positions[shuffled.index(name)] for name in NAMES]
    assert trajectory.positions[0].tolist() != list(given.points[0].positions)
    assert trajectory.velocities is None and trajectory.accelerations is None


@pytest.mark.parametrize("names", [NAMES[:3], NAMES + ["gripper"], NAMES[:3] + ["elbow"],
                                   NAMES[:3] + NAMES[:1], []])
def test_unknown_missing_or_repeated_joints_are_invalid_joints(names):
    outcome = arrange(goal(names), NAMES, CODES)
    assert outcome.code == CODES.invalid_joints and "do not match the arm's" in outcome.text


@pytest.mark.parametrize("points, says", [
    ((), "empty trajectory"),
    ((Point(S, (0,) * 4), Point(S, (0,) * 4)), "point 1: time_from_start 1.000000000 s is not "),
    ((Point(-1, (0,) * 4),), "point 0: time_from_start -0.000000001 s is not"),
    ((Point(S, (0,) * 3),), "point 0: 3 positions, expected 4"),
    ((Point(S, (0, 0, float("inf"), 0)),), "point 0: positions of arm_revolute_2 is not fini"),
    ((Point(S, (0,) * 4, (0,) * 4), Point(2 * S, (0,) * 4)), "point 1: 0 velocities, expected 4"),
    ((Point(S, (0,) * 4, (), (), (1.0,) * 4),), "point 0: efforts given"),
    ((Point(S, (0,) * 4, (0, 0.5, 0, 0)),),
     "the last point's velocity of arm_prismatic_1 is 0.5"),
])
def test_malformed_trajectories_are_invalid_goals_in_one_line(points, says):
    outcome = arrange(Goal(tuple(NAMES), points), NAMES, CODES)
    assert outcome.code == CODES.invalid_goal and outcome.text.startswith(says)
    assert "\n" not in outcome.text


def test_start_zero_or_past_is_now_future_delays_ended_is_old_header():
    trajectory = arrange(goal(), NAMES, CODES)
    now = 10 * 10 ** 9
    assert started(trajectory, 0, now, CODES) is trajectory
    assert started(trajectory, now - 2 * 10 ** 9, now, CODES) is trajectory   # ends at now + 1 s
    later = started(trajectory, now + 500 * MS, now, CODES)
    assert later.times.tolist() == [1500 * MS, 2500 * MS, 3500 * MS]
    old = started(trajectory, now - 3 * 10 ** 9 - 1, now, CODES)
    assert old.code == CODES.old_header_timestamp and "ends before now" in old.text


def test_goal_tolerances_follow_jtc_resolution():
    defaults = TrajectoryGoals(NAMES, CODES).defaults
    assert defaults.goal[:, 1].tolist() == [0.01] * 4 and not defaults.path.any()
    given = goal(path_tolerance=(JointTolerance("arm_prismatic_2", 0.02),),
                 goal_tolerance=(JointTolerance("arm_revolute_1", 0.001, -1.0),), goal_time=0.5)
    resolved, note = tolerances(given, NAMES, defaults)
    assert note is None and resolved.goal_time == 0.5
    assert resolved.path[3].tolist() == [0.02, 0.0, 0.0]
    assert resolved.goal[0].tolist() == [0.001, 0.0, 0.0]   # -1 erased the velocity check
    for bad, says in ((JointTolerance("gripper", 0.1), "which the arm does not have"),
                      (JointTolerance("arm_revolute_1", -0.5), "illegal position -0.5")):
        kept, note = tolerances(goal(path_tolerance=(bad,)), NAMES, defaults)
        assert kept is defaults and says in note


def run_to(goals, apply, stamps_ms, q, qd=None, desired=None):
    """Segment starts at ``stamps_ms`` with the arm at (q, q̇) and reference ``desired`` (default:
    on the spot): the steps."""
    actual = state(q, qd)
    desired = desired or (actual[0], np.zeros(4), np.zeros(4))
    return [goals.segment_start(ms * MS, desired, actual, apply) for ms in stamps_ms]


def test_a_goal_applies_at_the_next_segment_start_and_succeeds_within_its_goal_tolerance():
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    request = goals.submit(goal(goal_tolerance=tuple(JointTolerance(n, 0.01) for n in NAMES)))
    assert not request.finished.is_set() and not apply.applied
    final = arrange(goal(), NAMES, CODES).positions[-1]
    first = run_to(goals, apply, [1000], np.zeros(4))[0]
    assert first.command is apply.applied[0] and request.applied_ns == 1000 * MS
    # Before the end: feedback, no outcome (path tolerance unchecked by default).
    step = run_to(goals, apply, [2000, 3990], np.zeros(4))[-1]
    assert step.feedback[0] is request and not step.finished and request.outcome is None
    assert np.array_equal(step.feedback[3][0], np.zeros(4))
    # At the end, 0.02 off in one joint: outside; goal_time 0 waits. Then within: SUCCESSFUL.
    end = (final, 0 * final, 0 * final)
    step = run_to(goals, apply, [4000], final + [0, 0.02, 0, 0], desired=end)[0]
    assert request.outcome is None
    step = run_to(goals, apply, [4010], final + 0.005, desired=end)[0]
    assert request.outcome == Outcome(CODES.successful, "goal reached")
    assert step.finished == [request] and step.command is None   # the engine holds the end
    assert goals.active is None and len(apply.applied) == 1


def test_path_and_goal_time_violations_abort_and_hold():
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    path = goals.submit(goal(path_tolerance=(JointTolerance("arm_revolute_2", 0.05),)))
    run_to(goals, apply, [0], np.zeros(4))
    step = run_to(goals, apply, [100], [0, 0, 0.06, 0], desired=state(np.zeros(4)) + (None,))[0]
    assert path.outcome.code == CODES.path_tolerance_violated
    assert "arm_revolute_2 position error -0.06 beyond 0.05" in path.outcome.text
    assert step.command is HOLD and apply.applied[-1] is HOLD
    late = goals.submit(goal(times=(1.0,), goal_time=0.25,
                             goal_tolerance=(JointTolerance("arm_prismatic_1", 0.001),)))
    run_to(goals, apply, [200], np.zeros(4))
    end = (np.full(4, 0.3), np.zeros(4), np.zeros(4))
    run_to(goals, apply, [1200, 1450], np.full(4, 0.3) + 0.01, desired=end)
    assert late.outcome is None   # 0.25 s late is not beyond goal_time yet
    step = run_to(goals, apply, [1460], np.full(4, 0.3) + 0.01, desired=end)[0]
    assert late.outcome.code == CODES.goal_tolerance_violated and step.command is HOLD
    assert "0.26 s after the trajectory's end (goal_time 0.25 s): arm_prismatic_1" in \
        late.outcome.text


def test_out_of_stroke_is_the_engines_line_as_invalid_goal():
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    points = (Point(S, (0.0, 0.3, 0.0, 0.3)), Point(2 * S, (0.0, 0.9, 0.0, 0.3)))
    request = goals.submit(Goal(tuple(NAMES), points))
    step = run_to(goals, apply, [0], np.zeros(4))[0]
    assert request.outcome == Outcome(CODES.invalid_goal, "arm_prismatic_1: 0.9 m is outside "
                                                          "the stroke [0.05, 0.6]")
    assert step.finished == [request] and step.command is None and not apply.applied


def test_a_new_goal_preempts_the_active_one_and_a_waiting_one():
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    first = goals.submit(goal())
    run_to(goals, apply, [0], np.zeros(4))
    waiting = goals.submit(goal(times=(2.0,)))
    second = goals.submit(goal(times=(5.0,)))
    assert waiting.outcome == Outcome(CODES.invalid_goal, "preempted by a new goal", canceled=True)
    step = run_to(goals, apply, [10], np.zeros(4))[0]
    assert first.outcome == Outcome(CODES.invalid_goal, "preempted by a new goal", canceled=True)
    assert step.finished == [first] and goals.active is second
    assert step.command.times.tolist() == [5 * S] and second.applied_ns == 10 * MS


def test_cancel_holds_where_it_is():
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    request = goals.submit(goal())
    run_to(goals, apply, [0], np.zeros(4))
    goals.cancel(request)
    assert request.outcome is None   # at the next segment start
    step = run_to(goals, apply, [30], np.full(4, 0.02))[0]
    assert request.outcome == Outcome(None, "canceled") and step.command is HOLD
    waiting = goals.submit(goal())
    goals.cancel(waiting)
    assert waiting.outcome.code is None and run_to(goals, apply, [40], np.zeros(4))[0].command \
        is None


def test_a_reset_aborts_every_goal():
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    active = goals.submit(goal())
    run_to(goals, apply, [0], np.zeros(4))
    waiting = goals.submit(goal())
    goals.forget("the simulation was reset")
    assert active.outcome == waiting.outcome == Outcome(CODES.invalid_goal,
                                                        "the simulation was reset")
    assert goals.active is None and run_to(goals, apply, [10], np.zeros(4))[0] == (None, None, [])


TURN = 2.0 * np.pi


def test_errors_are_the_shortest_angle_on_the_revolute_joints_only():
    """jtc's compute_error_for_joint: continuous joints (the arm's revolute ones, as the URDF
    declares them) take angles::shortest_angular_distance, the others desired − actual."""
    desired = (np.array([-3.0, 6.5, 3.0 + 2 * TURN, 0.2]), np.array([0.1, 0.2, 0.3, 0.4]))
    actual = (np.array([3.0, 0.5, 3.1, 0.3]), np.zeros(4))
    position, velocity = errors(desired, actual)
    assert position.tolist() == pytest.approx([TURN - 6.0, 6.0, -0.1, -0.1], abs=1e-12)
    assert velocity.tolist() == [0.1, 0.2, 0.3, 0.4]


def test_tolerances_read_the_shortest_angle():
    """A revolute joint at 3.2 rad whose reference is −3.0 (= 3.283 − 2π) is 0.083 rad off,
    not 6.2: inside a 0.1 path tolerance; at the end inside a 0.1 goal tolerance (SUCCESSFUL);
    the feedback's error says 0.083 too. A 0.05 tolerance is violated, naming 0.083."""
    goals, apply = TrajectoryGoals(NAMES, CODES), Stroke()
    tolerance = (JointTolerance("arm_revolute_1", 0.1),)
    request = goals.submit(goal(times=(1.0,), path_tolerance=tolerance, goal_tolerance=tolerance))
    q = np.array([3.2, 0.3, 0.0, 0.3])
    desired = (np.array([-3.0, 0.3, 0.0, 0.3]), np.zeros(4), np.zeros(4))
    run_to(goals, apply, [0], q, desired=desired)
    step = run_to(goals, apply, [500], q, desired=desired)[0]
    assert request.outcome is None
    assert step.feedback[3][0][0] == pytest.approx(TURN - 6.2, abs=1e-12)
    run_to(goals, apply, [1000], q, desired=desired)
    assert request.outcome == Outcome(CODES.successful, "goal reached")
    strict = goals.submit(goal(times=(1.0,),
                               path_tolerance=(JointTolerance("arm_revolute_1", 0.05),)))
    run_to(goals, apply, [1100, 1200], q, desired=desired)
    assert strict.outcome.code == CODES.path_tolerance_violated
    assert "arm_revolute_1 position error 0.0831853 beyond 0.05" in strict.outcome.text
