"""What the test modules share: the engine kernels warmed once per session (ros_harness.py holds
the ROS harness itself; waiting.py the one `wait_for`)."""
import pytest


@pytest.fixture(scope="session")
def warm_kernels():
    """The kernels of a node at rk4, dt = 1 ms, compiled or loaded before any node starts."""
    import ros_harness
    ros_harness.warm_kernels(("rk4", 0.001))


@pytest.fixture(scope="session")
def interfaces_prefix():
    """tf2_msgs and control_msgs, built once (cached across sessions by their definitions'
    hash: interfaces_build.py); the install prefix."""
    import interfaces_build
    return interfaces_build.build()
