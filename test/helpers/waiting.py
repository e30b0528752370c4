"""The one `wait_for` of the tests and benchmarks that wait on other processes."""
import time

POLL = 0.005   # s between looks


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
