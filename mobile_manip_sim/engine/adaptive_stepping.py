"""An adaptive run's solve as the compiled core takes it (core/include/mms/adaptive_stepping.hpp:
rk45 and dop853 with error control and dense output, and the steps SciPy's radau and bdf hand in,
`scipy_steps.py`): its tolerances and its progress count (`step_watch.py`).

One solve runs from its start until a discontinuity (an impact, a release, a command change:
`Simulation._restart`); the step is never cut at a target or a sample. The last accepted step
stays *in hand* inside the core: targets and samples inside it are read from its dense output,
and an event found in it ends the solve there.
"""
from collections import namedtuple

import numpy as np

from .step_watch import clear, make_watch

Solve = namedtuple("Solve", [
    "tolerance",  # (2,) rtol, atol (per component of s, in its own units)
    "watch",      # (3,) the run's progress count (`step_watch`)
])


def make_solve(rtol: float, atol: float) -> Solve:
    return Solve(np.array([rtol, atol]), make_watch())


def new_solve(solve: Solve) -> None:
    """A fresh solve (after a reset): the progress count starts again."""
    clear(solve.watch)
