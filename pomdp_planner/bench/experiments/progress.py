"""A minimal stderr progress bar for the long experiment runs (no third-party dependency)."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``with Progress("table III", total=35) as p: ... p.advance()``.

    Draws ``label [#####.....] k/n elapsed`` on ``stream`` (stderr by default), redrawn in
    place when the stream is a terminal and at most every ~10 % otherwise (CI logs).
    ``enabled=False`` makes it silent.
    """

    def __init__(self, label: str, total: int, stream: TextIO | None = None, enabled: bool = True,
                 width: int = 30):
        self.label = label
        self.total = max(int(total), 1)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.width = width
        self.done = 0
        self.t0 = time.perf_counter()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_decile = -1

    def __enter__(self) -> Progress:
        self._draw()
        return self

    def __exit__(self, *exc: object) -> None:
        self.done = min(self.done, self.total)
        self._draw(final=True)

    def advance(self, n: int = 1, note: str = "") -> None:
        self.done += n
        self._draw(note=note)

    def _draw(self, note: str = "", final: bool = False) -> None:
        if not self.enabled:
            return
        frac = min(self.done / self.total, 1.0)
        decile = int(frac * 10)
        if not self._tty and not final and decile == self._last_decile:
            return
        self._last_decile = decile
        filled = round(frac * self.width)
        bar = "#" * filled + "." * (self.width - filled)
        elapsed = time.perf_counter() - self.t0
        text = f"{self.label} [{bar}] {self.done}/{self.total} {elapsed:6.1f}s {note}"
        if self._tty:
            self.stream.write("\r" + text.ljust(100)[:100] + ("\n" if final else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
