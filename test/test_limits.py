"""One limits module (`mobile_manip_sim.scene.limits`): every entry point checks against it, so a
value one of them takes is not refused by another — what the node may record, a re-run accepts."""
import pytest

from mobile_manip_sim.recording.bag_format import checked_run_metadata
from mobile_manip_sim.scene import limits
from mobile_manip_sim.scene.errors import UserError

NODE_RANGES = {"publish_rate": limits.PUBLISH_RATE, "real_time_factor": limits.REAL_TIME_FACTOR,
               "command_timeout": limits.COMMAND_TIMEOUT, "sync_timeout": limits.SYNC_TIMEOUT,
               "wheel_speed.kp": limits.WHEEL_SPEED_GAIN, "wheel_speed.ki": limits.WHEEL_SPEED_GAIN,
               "integrator.dt": limits.INTEGRATOR_OVERRIDE,
               "integrator.rtol": limits.INTEGRATOR_OVERRIDE,
               "integrator.atol": limits.INTEGRATOR_OVERRIDE, "foxglove_port": limits.PORT,
               "imu.noise.seed": limits.IMU_SEED,
               "arm_model_error.mass": limits.MODEL_ERROR,
               "arm_model_error.inertia": limits.MODEL_ERROR,
               "arm_model_error.payload": (-1.0, limits.MASS[1])}   # negative: the scene's


def test_the_node_declares_the_ranges_of_the_limits_module():
    from mobile_manip_sim.node import PARAMETERS
    declared = {name: parameter.range for name, parameter in PARAMETERS.items()
                if parameter.range}
    assert declared == NODE_RANGES


NODE_RUN = {"version": "0", "integrator_method": "rk4", "dt": "0.001", "rtol": "1e-09",
            "atol": "1e-12", "source": "node", "base_command": "velocity"}


@pytest.mark.parametrize("end", [0, 1])
def test_a_bag_of_the_node_at_the_ends_of_its_ranges_is_accepted_for_a_re_run(end):
    gain = repr(limits.WHEEL_SPEED_GAIN[end])
    metadata = checked_run_metadata({**NODE_RUN, "publish_rate": repr(limits.PUBLISH_RATE[end]),
                                     "wheel_speed_kp": gain, "wheel_speed_ki": gain})
    assert metadata["publish_rate"] == limits.PUBLISH_RATE[end]


def test_a_rate_past_the_sample_rate_bound_is_refused_naming_the_key():
    with pytest.raises(UserError) as caught:
        checked_run_metadata({**NODE_RUN, "publish_rate": repr(limits.SAMPLE_RATE[1] * 10),
                              "wheel_speed_kp": "0.5", "wheel_speed_ki": "5.0"})
    assert caught.value.key == "mobile_manip_sim.publish_rate"
