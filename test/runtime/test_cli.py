"""cli.py: SIGINT and SIGTERM stop an executable between writes, never inside one (a bag's
message cut in half is a damaged chunk), with statuses 130 and 143."""
import os
import signal
import time

import pytest

from mobile_manip_sim.runtime import cli


@pytest.mark.parametrize("signum, status",
                         [(signal.SIGINT, 130), (signal.SIGTERM, cli.EXIT_TERMINATED)])
def test_a_stop_signal_inside_a_critical_block_is_raised_when_the_block_ends(signum, status):
    events = []

    def main(argv):
        with cli.critical():
            os.kill(os.getpid(), signum)
            time.sleep(0.05)            # the handler runs in here: it must not raise yet
            events.append("block finished")
        events.append("went on")        # never: the signal is raised as the block ends

    assert cli.run(main, [], sigterm=True) == status
    assert events == ["block finished"]


def test_a_stop_signal_outside_a_critical_block_acts_at_once():
    def main(argv):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
        return 0

    start = time.monotonic()
    assert cli.run(main, [], sigterm=True) == cli.EXIT_TERMINATED
    assert time.monotonic() - start < 1.0
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL   # the handlers are put back
