"""The one `wait_for` of the tests and benchmarks that wait on other processes, and `no_hang`,
the net under work that must end by itself."""
import signal
import time
from contextlib import contextmanager

POLL = 0.005   # s between looks
HANG = 120.0   # s of wall time after which `no_hang` calls a block hung: a net, not a figure


class TimedOut(AssertionError):
    """A condition did not come about in time (a test failure; bench scripts exit with it)."""


def found(value) -> bool:
    """What a predicate's value means: None, False and an empty sequence are "not yet";
    anything else is found, 0 included (an index)."""
    return not (value is None or value is False
                or (isinstance(value, (list, tuple, dict, set, str)) and not value))


def wait_for(predicate, what: str, timeout: float):
    """Poll `predicate` until its value is `found` (returned); TimedOut naming `what`."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if found(value):
            return value
        time.sleep(POLL)
    raise TimedOut(f"timed out after {timeout} s waiting for {what}")


@contextmanager
def no_hang(what: str, seconds: float = HANG):
    """Fail (TimedOut naming `what`) if the block has not ended after `seconds` of wall time: a
    net under work that must end by itself (a hostile input refused, a solver that gives up),
    so a regression that loops fails instead of hanging the run. Not a timing assert: the bound
    is far beyond any loaded machine's time for the work. Main thread only (SIGALRM)."""
    def expired(signum, frame):
        raise TimedOut(f"{what} did not end within {seconds} s (a hang or a loop)")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
