"""The run's clock and step scratch: the arrays the compiled stepper (core/include/mms/
stepping.hpp for the fixed-step methods, adaptive_stepping.hpp for the adaptive ones) advances in
place, so that everything a run is stays where Python reads it between calls.

The time line of the fixed-step methods: t = t0 + k·dt with an integer step count k (so that long
runs land exactly on k·dt); a target off that grid ends in one shorter step, after which the grid
restarts there. The adaptive methods keep their time in CLOCK_T0 (CLOCK_K stays 0). Python is
entered once per call — and, so that signals, `~/pause` and `~/reset` act promptly, whenever a
call has used its step budget (`status.BUDGET`).
"""
from collections import namedtuple

import numpy as np

from ..core import vocabulary
from ..scene.coordinates import arm_size
from .events import N_SAMPLES

# clock[...] entries (core/include/mms/run.hpp `ClockEntry`): CLOCK_LOST the energy the impact
# law removed (J), CLOCK_HELD the energy holds removed beyond it (J), CLOCK_HOLDS how many impacts
# were held, CLOCK_UPDATES how many updates the sampled controllers took (the next is due at
# CLOCK_UPDATES · period)
(CLOCK_T0, CLOCK_DT, CLOCK_K, CLOCK_STEPS, CLOCK_LOST, CLOCK_HELD, CLOCK_HOLDS, CLOCK_UPDATES,
 CLOCK_SIZE) = (vocabulary[name] for name in (
    "CLOCK_T0", "CLOCK_DT", "CLOCK_K", "CLOCK_STEPS", "CLOCK_LOST", "CLOCK_HELD", "CLOCK_HOLDS",
    "CLOCK_UPDATES", "CLOCK_ENTRIES"))

StepScratch = namedtuple("StepScratch", [
    "out",      # (size,) the step's end state
    "trial",    # (size,) trial steps of the event functions
    "stages",   # (4, size) Runge–Kutta stages
    "forces",   # (size,) holding forces (first n_u entries)
    "samples",  # (N_SAMPLES + 2n,) instants bracketing a crossing
    "crossed",  # (n,) int64: the stop (−1, +1) each rod is past at the bracket's end, or 0
])


def make_scratch(size: int, n_links: int) -> StepScratch:
    return StepScratch(np.zeros(size), np.zeros(size), np.zeros((4, size)),
                       np.zeros(size), np.zeros(N_SAMPLES + arm_size(n_links)),
                       np.zeros(max(n_links, 1), dtype=np.int64))
