"""The one exception type for user mistakes (bad scene, bad flag, bad bag, bad path).

Adapters (CLI, node, replay) catch it, print its one-line message and exit with status 2.
"""


class UserError(Exception):
    """A mistake in what the user gave us; ``key`` names where (``robot.arm.links[1].length``)."""

    def __init__(self, key: str, problem: str):
        super().__init__(f"{key}: {problem}" if key else problem)
        self.key = key
        self.problem = problem


EXIT_USER_ERROR = 2
