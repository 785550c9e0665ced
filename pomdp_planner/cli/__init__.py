"""The ``pomdp-planner`` command line (also ``python -m pomdp_planner``).

Each subcommand is a module ``pomdp_planner.cli.<name>`` (listed in :data:`SUBCOMMANDS`)
exposing ``register(subparsers)``, which adds its parser and sets ``func`` (called with the
parsed arguments, returning an exit code). Pure core only: nothing here imports rclpy.

Exit codes: 0 success, 1 a negative answer (``check``: Assumption 1 fails; ``bounds``: the bounds
are not guaranteed or the LP is infeasible), 2 bad input: a bad argument, file or option value, or a request the guards
refuse (too deep, too large). Every error is one line on stderr naming the option or field;
:func:`main` returns the code instead of raising ``SystemExit``, so it can be called in-process.
An interrupt (Ctrl-C), also while the command is still starting (``pomdp_planner.__main__``), ends
with code 130 and one line; a closed output pipe (``| head``) ends quietly with code 0. A warning
(e.g. a model file accepted with a change, which the loader says) is one line on stderr:
``pomdp-planner: warning: ...``.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Sequence

from ..__main__ import EXIT_INTERRUPTED, INTERRUPTED
from ..core.errors import InputError, InputWarning
from . import bench, bounds, check, export, plan, plot, replay, simulate
from ._common import Parser, one_line

#: Subcommand modules, in the order ``--help`` lists them.
SUBCOMMANDS = (check, bounds, export, simulate, plan, plot, replay, bench)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="pomdp-planner",
        description="Information-acquisition POMDPs with myopic policy bounds (Lauri et al.). "
        "Actions are shown as tracking priorities 1..A (1 = greatest priority).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in SUBCOMMANDS:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad argument (2, one line already printed)
        return exc.code if isinstance(exc.code, int) else 2
    except KeyboardInterrupt:
        return _interrupted()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", InputWarning)
            warnings.showwarning = _one_line_warning
            return int(args.func(args) or 0)
    except InputError as exc:  # bad input: the message names the field
        print(f"pomdp-planner: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (| head): stop quietly
        _silence_stdout()
        return 0
    except UnicodeEncodeError as exc:  # e.g. a file name that is not UTF-8, printed to a strict stdout
        print(f"pomdp-planner: error: cannot print the output: {exc.reason} ({exc.encoding})", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return _interrupted()


def _interrupted() -> int:
    print(INTERRUPTED, file=sys.stderr)
    return EXIT_INTERRUPTED


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Show a warning as one line on stderr (``pomdp-planner: warning: ...``), without Python's
    location and source line: e.g. a model file accepted with a change (``InputWarning``)."""
    print(f"pomdp-planner: warning: {one_line(str(message))}", file=sys.stderr)


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's final flush of a closed pipe does not
    print "Exception ignored ... BrokenPipeError" (Python's documented recipe)."""
    try:
        sys.stdout.flush()
    except (BrokenPipeError, ValueError):
        pass
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a real file (a test's capture): nothing to flush at exit
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
