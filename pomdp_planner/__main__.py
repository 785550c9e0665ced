"""The ``pomdp-planner`` console script and ``python -m pomdp_planner``: the command line.

Importing the command line (numpy, scipy, the solvers) takes most of a second. Ctrl-C in that
time would print Python's ``KeyboardInterrupt`` traceback from somewhere inside an import, so
:func:`main` first installs a SIGINT handler that ends the process at once with exit code 130
and one line, then imports :mod:`pomdp_planner.cli` and puts Python's handler back: from then
on :func:`pomdp_planner.cli.main` turns an interrupt into the same line and code. This module
imports nothing heavy. (A SIGINT before this module runs, while the interpreter itself starts,
is Python's.)
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Sequence

from . import _interrupted_while_starting

#: Exit code of an interrupted command (128 + SIGINT, the shell's convention).
EXIT_INTERRUPTED = 130
INTERRUPTED = "pomdp-planner: interrupted"


def _exit_interrupted(signum: int, frame: object) -> None:
    """SIGINT during start-up: one line, exit 130, no clean-up (nothing has been done yet)."""
    os.write(2, (INTERRUPTED + "\n").encode())
    os._exit(EXIT_INTERRUPTED)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    # Only when SIGINT has Python's default handler in the main thread (or the package's start-up
    # one, pomdp_planner/__init__.py): an ignored SIGINT (a background job) stays ignored, and an
    # embedding program's handler is left alone.
    guard = (threading.current_thread() is threading.main_thread()
             and signal.getsignal(signal.SIGINT) in (signal.default_int_handler, _interrupted_while_starting))
    if guard:
        signal.signal(signal.SIGINT, _exit_interrupted)
    try:
        from .cli import main as run
    finally:
        if guard:
            signal.signal(signal.SIGINT, signal.default_int_handler)
    return run(argv)


if __name__ == "__main__":
    sys.exit(main())
