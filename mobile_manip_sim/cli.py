"""What every executable shares: turning a `UserError` into one line on stderr and status 2."""
from __future__ import annotations

import argparse
import sys
from typing import Callable

from .errors import EXIT_USER_ERROR, UserError


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line and status 2, like every other user error."""

    def error(self, message):
        raise UserError(self.prog, message)


def run(main: Callable[[list[str] | None], int | None], argv: list[str] | None = None) -> int:
    """Call ``main(argv)``; a `UserError` becomes ``<prog>: error: <key>: <problem>``, status 2."""
    prog = sys.argv[0].rsplit("/", 1)[-1] if sys.argv else "mobile_manip_sim"
    try:
        return int(main(argv) or 0)
    except UserError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130
    except RuntimeError as error:  # SimulationError: the numbers went bad; say when and where
        if type(error).__name__ != "SimulationError":
            raise
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 1
