"""What a bag of an arm-controller run holds, without a node: the trajectories and arrays as
`messages` writes them (through rclpy's serialisation and back: exact, so a re-simulation
gives the engine the very numbers the node gave it) and the controller's settings in the run
metadata (`bag_format`)."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

from mobile_manip_sim.recording.arm_metadata import arm_controller_metadata
from mobile_manip_sim.recording.bag_format import checked_run_metadata
from mobile_manip_sim.ros.messages import arm_command_message, arm_command_values
from mobile_manip_sim.ros.trajectory_goals import HOLD, Trajectory
from mobile_manip_sim.scene.arm_controller import ArmController, ModelError

NAMES = ["arm_revolute_1", "arm_prismatic_1", "arm_revolute_2", "arm_prismatic_2"]
RUN = {"version": "0", "integrator_method": "rk4", "dt": "0.001", "rtol": "1e-06",
       "atol": "1e-09", "source": "node", "publish_rate": "100.0"}


def through_a_bag(message, kind):
    return deserialize_message(serialize_message(message), kind)


@pytest.mark.parametrize("with_rates", [False, True])
def test_a_trajectory_comes_back_from_its_message_bit_for_bit(with_rates):
    rng = np.random.default_rng(7)
    times = np.array([1, 333_333_333, 10 ** 9 + 7, 12 * 10 ** 9], dtype=np.int64)
    rows = [rng.normal(size=(4, 4)) / 3.0 for _ in range(3)]
    trajectory = Trajectory(times, rows[0], rows[1] if with_rates else None,
                            rows[2] if with_rates else None)
    message = arm_command_message("joint_trajectory", trajectory, NAMES, 5 * 10 ** 7)
    assert list(message.joint_names) == NAMES
    assert (message.header.stamp.sec, message.header.stamp.nanosec) == (0, 5 * 10 ** 7)
    back = arm_command_values("joint_trajectory", through_a_bag(message, JointTrajectory))
    assert back.times.dtype == np.int64 and np.array_equal(back.times, times)
    assert np.array_equal(back.positions, trajectory.positions)
    for field in ("velocities", "accelerations"):
        given, got = getattr(trajectory, field), getattr(back, field)
        assert (got is None) if given is None else np.array_equal(got, given)
    # The engine gets times / 1e9 s from both: the same floats.
    assert np.array_equal(back.times / 1e9, times / 1e9)


def test_a_hold_is_a_trajectory_without_points():
    message = arm_command_message("joint_trajectory", HOLD, NAMES, 0)
    assert len(message.points) == 0
    back = arm_command_values("joint_trajectory", through_a_bag(message, JointTrajectory))
    assert len(back.times) == 0


def test_set_points_are_float64_arrays():
    values = [0.1, 1 / 3, -2.5, 0.6]
    message = arm_command_message("position", values, NAMES, 0)
    assert arm_command_values("position", through_a_bag(message, Float64MultiArray)) == values


def test_the_controller_settings_round_trip_through_the_run_metadata():
    control = ArmController("joint_trajectory", (170.0, 800.0, 34.0, 1 / 3), (17.0,) * 4,
                            (0.1, 0.2, 0.3, 0.4), "computed_torque")
    entries = arm_controller_metadata(control)
    assert entries["arm_kp"] == "170.0 800.0 34.0 0.3333333333333333"
    assert not any(key.startswith("arm_model_error") for key in entries)   # exact model
    assert checked_run_metadata({**RUN, **entries})["arm_controller"] == control
    # A model error is recorded exactly, and only the parts that differ from the plant's.
    wrong = ArmController("position", (1.0,) * 4, (0.0,) * 4, (1.0,) * 4, "computed_torque",
                          ModelError(mass=0.2, payload=1 / 3))
    entries = arm_controller_metadata(wrong)
    assert entries["arm_model_error_mass"] == "0.2" and "arm_model_error_inertia" not in entries
    assert checked_run_metadata({**RUN, **entries})["arm_controller"] == wrong
    # Effort mode writes nothing: such a bag is what it was before arm controllers existed.
    assert arm_controller_metadata(ArmController()) == {}
    assert checked_run_metadata(dict(RUN))["arm_controller"] == ArmController()
