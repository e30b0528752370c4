"""cli.py: SIGINT and SIGTERM stop an executable between writes, never inside one (a bag's
message cut in half is a damaged chunk), with statuses 130 and 143."""
import os
import signal
import time

import pytest

from mobile_manip_sim.runtime import cli
from waiting import wait_for


@pytest.mark.parametrize("signum, status",
                         [(signal.SIGINT, 130), (signal.SIGTERM, cli.EXIT_TERMINATED)])
def test_a_stop_signal_inside_a_critical_block_is_raised_when_the_block_ends(signum, status):
    events = []

    def main(argv):
        with cli.critical():
            os.kill(os.getpid(), signum)
            # the handler runs in here (noted, not raised yet)
            wait_for(lambda: cli._pending == signum, "the handler to note the signal", 30.0)
            events.append("block finished")
        events.append("went on")        # never: the signal is raised as the block ends

    assert cli.run(main, [], sigterm=True) == status
    assert events == ["block finished"]


def test_a_stop_signal_outside_a_critical_block_acts_at_once():
    events = []

    def main(argv):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)               # a signal acting at once interrupts it: nothing after runs
        events.append("slept")
        return 0

    assert cli.run(main, [], sigterm=True) == cli.EXIT_TERMINATED
    assert events == []
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL   # the handlers are put back


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")   # the drop itself
def test_a_stop_signal_dropped_inside_a_finalizer_is_raised_at_the_next_check():
    """Python drops an exception raised in a __del__ (it prints "Exception ignored in"): a
    sweep whose Ctrl-C landed in pyarrow's ParquetWriter.__del__ ran on to its end, status 0.
    Under stop_signals the check between two pieces of work raises it again."""
    events = []
    before = signal.getsignal(signal.SIGINT)

    class Finalized:
        def __del__(self):
            signal.raise_signal(signal.SIGINT)
            wait_for(lambda: cli._raised is not None, "the handler to run inside __del__", 30.0)
            events.append("finalizer ran on")   # never: the handler raised in here

    with pytest.raises(KeyboardInterrupt):
        with cli.stop_signals((signal.SIGINT,)):
            Finalized()                   # collected at once: the interrupt is dropped
            events.append("dropped")
            cli.raise_dropped_stop()
            events.append("went on")      # never
    assert events == ["dropped"]
    cli.raise_dropped_stop()              # raised once: nothing left to raise
    assert signal.getsignal(signal.SIGINT) is before   # the handler is put back


def test_a_stop_signal_that_propagated_is_not_raised_twice():
    with pytest.raises(KeyboardInterrupt):
        with cli.stop_signals((signal.SIGINT,)):
            signal.raise_signal(signal.SIGINT)
            wait_for(lambda: False, "the interrupt", 30.0)
    cli.raise_dropped_stop()              # the interrupt was raised where it landed: no repeat


def test_bench_stops_at_its_next_line_on_a_ctrl_c_that_other_code_swallowed():
    """bench under `cli.run` took a Ctrl-C early in CI and ran on to its end, status 0: some
    code below it had swallowed the KeyboardInterrupt. Each of its progress lines raises a stop
    the handler raised and nothing let through."""
    import io

    from mobile_manip_sim.bench.main import Progress
    events = []

    def main(argv):
        progress = Progress(2, stream=io.StringIO())
        progress.section("first")
        try:   # code that swallows what it calls raise, as a library may
            signal.raise_signal(signal.SIGINT)
            wait_for(lambda: False, "the interrupt", 30.0)
        except BaseException:
            events.append("swallowed")
        progress("a measurement")
        events.append("went on")          # never: the line raised the stop again
        return 0

    assert cli.run(main, [], sigterm=True) == 130
    assert events == ["swallowed"]


def test_held_stderr_keeps_what_c_code_writes_to_descriptor_2(capfd):
    """rcl logs its own line on a failed rclpy.init, straight to descriptor 2: held, it can be
    left out (the node's one line says why) or passed on."""
    with cli.held_stderr() as said:
        os.write(2, b"[ERROR] [rcl]: Failed to parse global arguments\n")
    assert said == [b"[ERROR] [rcl]: Failed to parse global arguments\n"]
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"
