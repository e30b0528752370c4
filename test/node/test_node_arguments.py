"""The node's command line before rcl sees it (node/arguments.py) and its parameter rules
(node/parameters.py), without ROS; test_node.py runs a few of the same through the executable."""
import pytest

from mobile_manip_sim.node import arguments, parameters
from mobile_manip_sim.node.parameters import MIN_REAL_TIME_FACTOR, PARAMETERS
from mobile_manip_sim.scene.errors import UserError

BOOLS = [name for name, spec in PARAMETERS.items() if isinstance(spec.default, bool)]


@pytest.mark.parametrize("name", [*PARAMETERS, "not_ours"])
def test_a_blank_value_is_refused_naming_the_parameter(name):
    for rule in (f"{name}:=", f"{name}:=  ", f"mobile_manip_sim:{name}:="):
        with pytest.raises(UserError) as error:
            arguments.check(["--ros-args", "-p", rule])
        assert error.value.key == name and "no value" in error.value.problem


@pytest.mark.parametrize("name", BOOLS)
def test_a_bool_is_true_or_false_only(name):
    for text in ("yes", "no", "on", "off", "1", "y"):
        with pytest.raises(UserError, match="expected true or false"):
            arguments.check(["--ros-args", "--param", f"{name}:={text}"])
    for text in ("true", "false", "True", "FALSE"):
        arguments.check(["--ros-args", "-p", f"{name}:={text}"])


def test_other_rules_are_left_to_rcl():
    """An unknown name, a remap and quoted or ordinary values pass this check untouched (rcl and
    the node's declarations judge them); only the rules above raise."""
    assert arguments.check(["--ros-args", "-p", "scene:=''", "-p", "unknown_thing:=yes", "-r",
                            "odom:=ground_truth", "-p", "publish_rate:=50.0"]) is None


@pytest.mark.parametrize("content, problem", [
    ("/**:\n  ros__parameters:\n    publish_clock: yes\n", "publish_clock: expected true or false"),
    ("/mobile_manip_sim:\n  ros__parameters:\n    synchronous: 'true'\n",
     "synchronous: expected true or false"),
    ("/**:\n  ros__parameters:\n    integrator:\n      dt:\n", "integrator.dt: no value"),
])
def test_a_params_file_is_held_to_the_same_rules(tmp_path, content, problem):
    path = tmp_path / "params.yaml"
    path.write_text(content)
    with pytest.raises(UserError) as error:
        arguments.check(["--ros-args", "--params-file", str(path)])
    assert error.value.key == "--params-file" and problem in error.value.problem


def test_help_is_asked_before_ros_args_and_names_every_parameter():
    assert arguments.wants_help(["--help"]) and arguments.wants_help(["-h", "--ros-args"])
    assert not arguments.wants_help(["--ros-args", "-p", "scene:=--help"])
    text = arguments.help_text()
    for name, spec in PARAMETERS.items():
        assert f"  {name}{' *' if spec.dynamic else ''} = " in text
        assert spec.description in text
    for policy in ("history", "depth", "reliability"):   # rclpy's standard QoS overrides
        assert f"  qos_overrides.<topic>.publisher.{policy} = " in text


@pytest.mark.parametrize("value, problem", [
    (0.0, None), (MIN_REAL_TIME_FACTOR, None), (1.0, None),
    (1e-12, "must be 0 (as fast as possible) or at least 0.001, got 1e-12"),
    (1e-300, "got 1e-300"), (float("inf"), "must be finite"), (float("nan"), "must be finite"),
])
def test_the_real_time_factor_is_0_or_at_least_the_minimum(value, problem):
    found = parameters.value_problem("real_time_factor", value)
    assert (found is None) if problem is None else (problem in found)
