"""Each compiled lane's own impact log and the outcome of a call for a lane, as the C++ core's
`LaneSet` fills them (core/include/mms/lanes.hpp): the impacts of one call (a block of samples)
that Python reads after it; a lane with more pauses, and goes on once they are read."""
from collections import namedtuple

import numpy as np

from ..core import vocabulary
from ..engine.impact_log import LOG_COLUMNS

# a lane's outcome after a call (`code`)
LANE_DONE, LANE_PAUSED, LANE_FAILED = (vocabulary[name] for name in (
    "LANE_DONE", "LANE_PAUSED", "LANE_FAILED"))

LOG_ROWS = 16   # rows of each lane's own log

ImpactLogs = namedtuple("ImpactLogs", "log log_q log_u log_free count")


def impact_logs(lanes: int, nq: int, nu: int) -> ImpactLogs:
    """Each lane's own impact log, indexed by lane (rows as `stops.StopsData`'s)."""
    return ImpactLogs(np.zeros((lanes, LOG_ROWS, LOG_COLUMNS)), np.zeros((lanes, LOG_ROWS, nq)),
                      np.zeros((lanes, LOG_ROWS, 2, nu)),
                      np.zeros((lanes, LOG_ROWS, nu), dtype=np.bool_),
                      np.zeros(lanes, dtype=np.int64))


def lane_log(logs: ImpactLogs, lane: int) -> ImpactLogs:
    """Lane `lane`'s own log, read by `Simulation._collect_impacts` as the stops' log (the same
    field names) and emptied by it."""
    return ImpactLogs(logs.log[lane], logs.log_q[lane], logs.log_u[lane], logs.log_free[lane],
                      logs.count[lane:lane + 1])


def empty_rows(lanes: int, size: int) -> np.ndarray:
    """Rows for calls that write none (`advance_to`): one row per lane, never written."""
    return np.zeros((lanes, 1, size + 1))
