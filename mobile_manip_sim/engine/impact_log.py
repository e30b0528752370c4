"""The end stops' impact log: one row per rod hit (columns LOG_*, the core's: core/include/mms/
run.hpp `LogColumn`), written by the compiled impact into `stops.StopsData.log`, and read from
Python after each compiled call (`collect`) into the `Impact` records that runs and bags report,
with their `ImpactDetail`."""
from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from ..core import vocabulary

# log[i, ...] columns
(LOG_TIME, LOG_LINK, LOG_SIDE, LOG_LD_BEFORE, LOG_LD_AFTER, LOG_LOST, LOG_RESTING,
 LOG_HELD, LOG_HOLD_LOST, LOG_HOLD_BOUND, LOG_COLUMNS) = (vocabulary[name] for name in (
    "LOG_TIME", "LOG_LINK", "LOG_SIDE", "LOG_LD_BEFORE", "LOG_LD_AFTER", "LOG_LOST",
    "LOG_RESTING", "LOG_HELD", "LOG_HOLD_LOST", "LOG_HOLD_BOUND", "LOG_COLUMNS"))

ImpactDetail = namedtuple("ImpactDetail", "q u_before u_after free held")


@dataclass(frozen=True)
class Impact:
    """One end-stop impact, as runs and bags report it."""

    time: float            # s
    link: int              # 1-based
    stop: str              # "lower" or "upper"
    ld_before: float       # l̇_k before (m/s)
    ld_after: float        # l̇_k after (m/s)
    energy_lost: float     # J: what the impact law removed (T⁻ − T⁺ of the law)
    resting: bool          # resting at the stop afterwards
    held: bool = False     # held by the engine (the Zeno guard, or found at its stop not moving
                           # into it) rather than left to the law alone
    hold_energy: float = 0.0   # J: what the hold removed beyond the law (on the impact's first row)

    def as_dict(self) -> dict:
        return dict(self.__dict__)

    @staticmethod
    def from_log(row) -> "Impact":
        # Plain Python numbers (not numpy scalars), so records serialise anywhere (CSV, YAML, bags).
        return Impact(float(row[LOG_TIME]), int(row[LOG_LINK]),
                      "lower" if row[LOG_SIDE] < 0 else "upper", float(row[LOG_LD_BEFORE]),
                      float(row[LOG_LD_AFTER]), float(row[LOG_LOST]), bool(row[LOG_RESTING]),
                      bool(row[LOG_HELD]), float(row[LOG_HOLD_LOST]))


def collect(stops, impacts: list, details: list, warn) -> None:
    """Move the compiled stop log into ``impacts`` (`Impact`) and ``details`` (`ImpactDetail`),
    and empty it; a hold that removed more than the Zeno guard's bound is reported on one line
    (``warn``)."""
    for row in range(int(stops.count[0])):
        log = stops.log[row]
        if log[LOG_HOLD_LOST] > log[LOG_HOLD_BOUND]:
            impact = Impact.from_log(log)
            warn(f"t = {impact.time:.9g} s: rod {impact.link} held at its {impact.stop} stop "
                 f"(arriving at {abs(impact.ld_before):.3g} m/s), removing "
                 f"{impact.hold_energy:.3g} J beyond the impact law (the bound is "
                 f"{log[LOG_HOLD_BOUND]:.3g} J)")
        impacts.append(Impact.from_log(log))
        details.append(ImpactDetail(
            stops.log_q[row].copy(), stops.log_u[row, 0].copy(), stops.log_u[row, 1].copy(),
            [int(i) for i in np.flatnonzero(stops.log_free[row])],
            bool(stops.log[row, LOG_HELD])))
    stops.count[0] = 0
