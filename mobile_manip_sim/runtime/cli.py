"""What every executable shares: turning a `UserError` into one line on stderr and status 2."""
from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import threading
from contextlib import contextmanager
from typing import Callable, NoReturn

from ..scene.errors import EXIT_USER_ERROR, SimulationError, StepLimitError, UserError


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line and status 2, like every other user error."""

    def error(self, message):
        raise UserError(self.prog, message)


def path(text: str) -> str:
    """An argparse ``type`` for file and directory arguments: an empty path is refused (``--record
    ''`` silently recorded nothing, ``--out ''`` wrote into the working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"an empty path ({text!r})")
    return text


class Terminated(BaseException):
    """SIGTERM, raised in the main thread like KeyboardInterrupt so that `finally` blocks close
    what is open (a bag, a CSV); the process then exits with 128 + SIGTERM."""


EXIT_TERMINATED = 128 + signal.SIGTERM
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_critical_depth = 0      # `critical` blocks entered and not left
_pending = None          # a stop signal that arrived inside one, raised when it ends
_raised = None           # the stop signal last raised by the handler (`raise_dropped_stop`)


def _raise(signum):
    if signum == signal.SIGTERM:
        raise Terminated()
    raise KeyboardInterrupt


def _on_stop_signal(signum, frame):
    global _pending, _raised
    if _critical_depth:
        _pending = signum
        return
    _raised = signum
    _raise(signum)


@contextmanager
def stop_signals(signums=STOP_SIGNALS):
    """Within the block, these signals (SIGINT raises KeyboardInterrupt, SIGTERM `Terminated`)
    wait for the end of a `critical` block, and one raised where Python drops exceptions — inside
    a finalizer (a ``__del__`` such as pyarrow's ParquetWriter's, a weakref callback), which only
    notes it on stderr — is raised again by `raise_dropped_stop`. Only in the main thread (signal
    handlers can be set nowhere else); the handlers before it are put back."""
    global _raised
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _raised = None
    try:
        with signal_handlers(signums, _on_stop_signal):
            yield
    finally:
        _raised = None


@contextmanager
def signal_handlers(signums, handler):
    """Within the block, ``handler`` takes these signals (main thread only); the handlers
    before it are put back."""
    previous = {signum: signal.signal(signum, handler) for signum in signums}
    try:
        yield
    finally:
        for signum, before in previous.items():
            signal.signal(signum, before)


def raise_dropped_stop() -> None:
    """Raise again a stop signal that the handler raised and Python dropped (a loop calls this
    between its pieces of work; a sweep interrupted inside a finalizer ran on to its end, status
    0). One that propagated is never followed by this call: the caller stopped."""
    global _raised
    if _raised is not None:
        signum, _raised = _raised, None
        _raise(signum)


@contextmanager
def critical():
    """A write that must not be cut in half (one sample's CSV row and bag messages): a SIGINT or
    SIGTERM arriving inside is raised when the block ends — raised in the middle, it left a
    message record cut short inside the bag's last chunk, which readers then choke on."""
    global _critical_depth, _pending
    _critical_depth += 1
    try:
        yield
    finally:
        _critical_depth -= 1
    if not _critical_depth and _pending is not None:
        signum, _pending = _pending, None
        _raise(signum)


def run(main: Callable[[list[str] | None], int | None], argv: list[str] | None = None, *,
        sigterm: bool = False) -> int:
    """Call ``main(argv)``; a `UserError` becomes ``<prog>: error: <key>: <problem>``, status 2.
    With `sigterm`, SIGTERM raises `Terminated` in the main thread (status 143), and both it and
    SIGINT wait for the end of a `critical` block."""
    prog = sys.argv[0].rsplit("/", 1)[-1] if sys.argv else "mobile_manip_sim"
    try:
        with stop_signals(STOP_SIGNALS if sigterm else ()):
            return int(main(argv) or 0)
    except Terminated:
        return EXIT_TERMINATED
    except UserError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130
    except SimulationError as error:  # the numbers went bad; say when and where
        print(f"{prog}: error: {error}", file=sys.stderr)
        # A StepLimitError names the settings that cannot follow the run: a user's choice.
        return EXIT_USER_ERROR if isinstance(error, StepLimitError) else 1


def exit_at_once(status: int) -> NoReturn:
    """End the process now with `status`, stdout and stderr flushed, without the interpreter's
    teardown: for a program that has closed everything it opened and only has to go. That
    teardown (freeing every object of numba, LLVM, pyarrow and Dask, a full collection among
    them) took 0.6–1.5 s of a stopped sweep's 0.8–1.9 s on a loaded 2-core machine, the
    sweep's own stop about 0.2 s."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe or stream: nothing more can be said
            pass
    os._exit(status)


@contextmanager
def held_stderr():
    """What the process writes to file descriptor 2 within the block (a C library logging, as
    rcl does), kept in a file instead: the bytes are the yielded list's one item afterwards."""
    said = [b""]
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as held:
            os.dup2(held.fileno(), 2)
            try:
                yield said
            finally:
                os.dup2(saved, 2)
                held.seek(0)
                said[0] = held.read()
    finally:
        os.close(saved)
