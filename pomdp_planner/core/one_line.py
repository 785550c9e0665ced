"""One line for every error a command line prints (Lesson 3: a one-line error for every bad input).

:func:`one_line` shows a text on one line; :class:`Parser` is an ``ArgumentParser`` whose errors
are that one line naming the option and exit code 2, never the usage text. Every command line of
the package uses it: ``pomdp-planner`` (``cli/``), the demo (``nodes/demo.py``) and the
benchmarks' own (``python -m pomdp_planner.bench...``).
"""

from __future__ import annotations

import argparse
from typing import NoReturn


def one_line(text: str) -> str:
    """``text`` on one line: every character that is not printable (line breaks of any kind, including
    the separators ``str.splitlines`` honours, and other control characters) is shown escaped, as in
    ``repr``. Every error is one line of stderr, whatever a user typed."""
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line naming the option (module docstring)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see '{self.prog} --help')\n")
