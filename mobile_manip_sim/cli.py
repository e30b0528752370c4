"""What every executable shares: turning a `UserError` into one line on stderr and status 2."""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Callable

from .errors import EXIT_USER_ERROR, UserError


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line and status 2, like every other user error."""

    def error(self, message):
        raise UserError(self.prog, message)


class Terminated(BaseException):
    """SIGTERM, raised in the main thread like KeyboardInterrupt so that `finally` blocks close
    what is open (a bag, a CSV); the process then exits with 128 + SIGTERM."""


EXIT_TERMINATED = 128 + signal.SIGTERM


def _terminate(signum, frame):
    raise Terminated()


def run(main: Callable[[list[str] | None], int | None], argv: list[str] | None = None, *,
        sigterm: bool = False) -> int:
    """Call ``main(argv)``; a `UserError` becomes ``<prog>: error: <key>: <problem>``, status 2.
    With `sigterm`, SIGTERM raises `Terminated` in the main thread (status 143)."""
    prog = sys.argv[0].rsplit("/", 1)[-1] if sys.argv else "mobile_manip_sim"
    previous = None
    if sigterm and threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        return int(main(argv) or 0)
    except Terminated:
        return EXIT_TERMINATED
    except UserError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130
    except RuntimeError as error:  # SimulationError: the numbers went bad; say when and where
        if "SimulationError" not in {kind.__name__ for kind in type(error).__mro__}:
            raise   # (by name: importing the engine here would load numba for every executable)
        print(f"{prog}: error: {error}", file=sys.stderr)
        # A StepLimitError names the settings that cannot follow the run: a user's choice.
        return EXIT_USER_ERROR if getattr(error, "key", None) else 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
