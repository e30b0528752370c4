"""`simulator`: the ROS 2 node. shell.py is its ROS side (publishers, subscriptions, services,
`main`); loop.py the stepping state machine, parameters.py the parameters (declare.py declares
them with rclpy), commands.py the command intake, lockstep.py synchronous mode, recording.py its
bags. loop.py, parameters.py and lockstep.py import no ROS."""
from .parameters import PARAMETERS  # noqa: F401  (the one table of the node's parameters)


def main(args=None) -> int:
    """The `simulator` executable (setup.py's entry point)."""
    from .shell import main as run
    return run(args)
