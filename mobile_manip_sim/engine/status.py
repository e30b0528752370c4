"""Why a call of the compiled stepper returned, read by `Simulation` after every call. The
values are the core's (core/include/mms/run.hpp `Status`, `core.vocabulary`)."""
from ..core import vocabulary

DONE = vocabulary["DONE"]                # reached the requested time (or the sample asked for)
BUDGET = vocabulary["BUDGET"]            # the call's step budget is spent: call again
LOG_FULL = vocabulary["LOG_FULL"]        # the impact log is full: collect it and call again
NOT_FINITE = vocabulary["NOT_FINITE"]    # the state became NaN or infinite (a SimulationError)
CHATTER = vocabulary["CHATTER"]          # impacts without end within one step: the log's room ran
                                         # out (last resort)
STALLED = vocabulary["STALLED"]          # adaptive: the step fell below 10 spacings of t, or a
                                         # stage overflowed
CRAWLING = vocabulary["CRAWLING"]        # adaptive: the steps crawl (`step_watch`: which limit)
CONTACT_FAILED = vocabulary["CONTACT_FAILED"]   # an impact's or a release's contact solve found
                                                # no answer
