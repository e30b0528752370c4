"""Many runs of one robot in one compiled call: `Batch` (runs.py) over the compiled lanes
(the C++ core's `LaneSet`). Sweeps run their chunks through it."""
from .runs import Batch, LaneStatus, TimeLimit, error_line, overlapped

__all__ = ["Batch", "LaneStatus", "TimeLimit", "error_line", "overlapped"]
