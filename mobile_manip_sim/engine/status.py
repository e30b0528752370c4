"""Why a compiled core's call returned: one vocabulary for the fixed-step core (`stepping.py`)
and the adaptive one (`adaptive_stepping.py`), read by `Simulation` after every call.

Plain integers, so the compiled code returns them as is.
"""

DONE = 0         # reached the requested time (or the sample asked for)
BUDGET = 1       # the call's step budget is spent: call again
LOG_FULL = 2     # the impact log is full: collect it and call again
NOT_FINITE = 3   # the state became NaN or infinite (a SimulationError)
CHATTER = 4      # impacts without end within one step: the log's room ran out (last resort)
STALLED = 5      # adaptive: the step fell below 10 spacings of t, or a stage overflowed
CRAWLING = 6     # adaptive: the steps crawl (`step_watch`: which limit, and where)
CONTACT_FAILED = 7   # an impact's or a release's contact solve found no answer
