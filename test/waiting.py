"""Polling with a deadline, for tests that wait on other processes."""
import time

import pytest


def wait_for(predicate, what: str, timeout: float):
    """Poll `predicate` until it returns something truthy (returned); fail naming `what`."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.005)
    pytest.fail(f"timed out after {timeout} s waiting for {what}")
