"""The project's error types, matched by type wherever they are caught: `UserError` for user
mistakes (bad scene, bad flag, bad bag, bad path) — adapters (CLI, node, replay) catch it, print
its one-line message and exit with status 2 —; `SimulationError` (with `StepLimitError`) for a
run whose numbers went bad; `CdrLayoutError` for a message buffer of the wrong layout (a bug).
Plain Python, no imports: any layer may catch them.
"""


class UserError(Exception):
    """A mistake in what the user gave us; ``key`` names where (``robot.arm.links[1].length``)."""

    def __init__(self, key: str, problem: str):
        super().__init__(f"{key}: {problem}" if key else problem)
        self.key = key
        self.problem = problem



class SimulationError(RuntimeError):
    """The numbers went bad (NaN/Inf): says when and which quantity."""


class StepLimitError(SimulationError):
    """An adaptive method cannot follow the solution (`step_watch`): the settings named by `key`
    and the efforts are to blame, so adapters treat it like a user error (status 2)."""

    def __init__(self, key: str, problem: str):
        super().__init__(f"{key}: {problem}")
        self.key, self.problem = key, problem


class CdrLayoutError(RuntimeError):
    """The buffer does not have the layout of its message type (a bug, not a user error)."""


EXIT_USER_ERROR = 2
