"""Ctrl-C or SIGTERM while the node loads its kernels: the process ends at once, with one line.

On an install never warmed up, loading the kernels compiles them for minutes, in the main
thread, before the node steps, publishes or records anything. rclpy's own handlers only shut its
context down (SIGTERM then waits for the compile to end), and the KeyboardInterrupt of SIGINT,
raised inside numba's compiler, can crash the interpreter (seen: SIGSEGV, SIGABRT). Within
`exit_on_stop` both signals end the process at the next Python bytecode instead: nothing is
recorded yet, and every kernel numba finished is already in its cache (written file by file,
each by an atomic rename). Status 0, as the node's other stops.
"""
from __future__ import annotations

import os
import signal
import sys
from contextlib import contextmanager

import rclpy.signals

from ..runtime import cli

STOPS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def exit_on_stop(say):
    """Within it, SIGINT and SIGTERM say so through ``say`` and end the process; rclpy's
    handlers are back afterwards."""
    options = rclpy.signals.get_current_signal_handlers_options()
    rclpy.signals.uninstall_signal_handlers()

    def stop(signum, frame):
        say(f"stopped by {signal.Signals(signum).name} while loading the engine's kernels "
            f"(nothing was recorded)")
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)

    try:
        with cli.signal_handlers(STOPS, stop):
            yield
    finally:
        rclpy.signals.install_signal_handlers(options)
