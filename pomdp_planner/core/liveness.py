"""Liveness rules of the node loop: which epochs from the wire a node acts on, how a (re)started
node joins the loop, when it re-syncs to a restarted peer, when it re-sends its last output, and
how long an input may stay silent before the node reports it.

Every rule here is a pure function of epochs, counts and times; the nodes (``nodes/``) feed in what
arrives and publish what the rules decide. Time comes from ``clock`` (default ``time.monotonic``),
so tests drive it by hand. The numbers are parameters of the nodes (docs/ros.md, "Parameters"); the
defaults are the module constants below.

**Epoch window.** Epochs come from other processes and are not trusted: a node that is at epoch
``p`` (its *position*: the last epoch it acted on) acts only on epochs within ``p +- window``
(:func:`classify`). An epoch beyond the window is never walked epoch by epoch: the input is
dropped and counted (``out_of_window``), and logged once per episode (:class:`LogThrottle`). It
is either an attack (a forged message) or a peer that restarted with a numbering of its own; the
re-sync rule below tells the two apart by persistence.

**Verdicts** (:func:`classify`): ``next`` (``p + 1``), ``ahead`` (``p + 2 .. p + window``),
``repeat`` (``p``: a re-send or a duplicate; harmless), ``behind`` (``p - window .. p - 1``: stale)
and ``out_of_window``. ``behind`` and ``out_of_window`` inputs are *off-line*: the node does not
act on them, but they are the evidence of the re-sync rule.

**Re-sync** (:class:`EpochLine`). A node re-syncs to the newest off-line input (acts on it as if
it were the next one, adopting its epoch; counted ``resyncs``, one log line) when

* for ``stall_after`` seconds it has received off-line inputs and nothing it could act on (the
  first off-line input since it last advanced is ``stall_after`` old), and
* at least :data:`RESYNC_MIN_INPUTS` off-line inputs arrived since it last advanced; for a
  *counting* line (the belief filter, whose source, the simulator, numbers epochs by stepping)
  they must moreover span :data:`RESYNC_MIN_INPUTS` consecutive epochs (``e, e + 1, e + 2``;
  repeats of an epoch neither break nor extend the run): a restarted simulator counting from 1
  qualifies, a stray repeating one stale reading does not.

So a single forged message never moves a node (it is one input, and the loop keeps advancing),
and a peer that restarted on another numbering is followed once it is clear that the loop cannot
advance otherwise. The time is counted from the first off-line input, not from the last advance:
a node that waited while a peer was dead must not re-sync to the burst of old epochs that the
restarted peer replays from its inputs' histories (it catches up within a fraction of a second).

A *fresh* counting line (a filter that has applied no reading yet: it may have been started into
a running loop) joins at once, without the stall, on :data:`JOIN_MIN_INPUTS` off-line inputs
forming such a run (two readings, e.g. the oldest two of the simulator's transient-local history).

**Join** (the simulator; ``nodes/target_simulator.py``). A (re)started simulator takes no step
before it knows the loop's epoch: it continues the numbering of the newest action (and, timer-driven,
of the newest belief) it receives within :data:`JOIN_DELAY` of the first one. Timer-driven, with
nothing received within ``join_timeout``, it numbers on its own from epoch 0 (a loop without planner
and filter, or one that they will join).

**Re-send** (:class:`Resender`, at-least-once delivery). A node that published its output for
epoch ``t`` and has not had the input it expects next (the input that answers it) within
``period`` seconds publishes the same message again, every ``period`` until answered. Receivers
are idempotent (a repeat is dropped as ``repeat``), so a duplicate is harmless by design and a
lost sample (a history replaced before a reader took it, a transport loss, a reader that
restarted) costs one period, not the loop.

**Stall levels** (:class:`InputWatch`). Each input of a node records when it last *advanced* the
node (a new epoch; repeats, stale and out-of-window inputs are not progress). An input that has
not advanced for ``warn_after`` seconds is WARN, for ``error_after`` seconds ERROR, with a message
that names the input, since when (seconds and the last epoch) and what arrived meanwhile.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal

#: Default epoch window: the farthest jump a node acts on (a gap up to it is walked, as one
#: prediction per epoch, and logged as one line).
DEFAULT_EPOCH_WINDOW = 1000
#: Off-line inputs (and, on a counting line, consecutive epochs) that a stalled node needs to re-sync.
RESYNC_MIN_INPUTS = 3
#: Consecutive off-line readings on which a fresh counting line (a filter with no reading applied) joins.
JOIN_MIN_INPUTS = 2
#: Default seconds without progress before an input is WARN / ERROR, and the re-send period.
DEFAULT_STALL_WARN = 2.0
DEFAULT_STALL_ERROR = 10.0
DEFAULT_RESEND_PERIOD = 1.0
#: Seconds a (re)starting simulator keeps collecting actions (and beliefs) after the first one before
#: it joins at the newest: a transient-local history arrives as one burst, within milliseconds.
JOIN_DELAY = 0.2
#: Default seconds a timer-driven simulator waits for the loop's epoch before numbering on its own.
DEFAULT_JOIN_TIMEOUT = 5.0

Verdict = Literal["join", "next", "ahead", "repeat", "behind", "out_of_window"]


class Level(IntEnum):
    """Diagnostic level of a liveness check (the nodes map it to ``DiagnosticStatus``)."""

    OK = 0
    WARN = 1
    ERROR = 2


def classify(epoch: int, position: int | None, window: int) -> Verdict:
    """Where ``epoch`` stands relative to a node at ``position`` (module docstring, "Verdicts").

    ``position is None``: the node has not joined the loop yet (``"join"``)."""
    if window < 1:
        raise ValueError(f"window: must be at least 1, got {window}")
    if position is None:
        return "join"
    d = epoch - position
    if d > window or d < -window:
        return "out_of_window"
    if d == 0:
        return "repeat"
    if d < 0:
        return "behind"
    return "next" if d == 1 else "ahead"


@dataclass(frozen=True)
class OffLine:
    """The newest off-line input: its epoch and what the node needs to act on it (``payload``)."""

    epoch: int
    payload: Any = None


class EpochLine:
    """A node's position on the loop's epoch line and the evidence for re-syncing it.

    ``position``: the last epoch the node acted on (``None``: not joined). ``counting``: the
    stricter evidence of a line whose source counts (module docstring). A line is *fresh* until
    it first advances.
    """

    def __init__(self, window: int = DEFAULT_EPOCH_WINDOW, *, position: int | None = None,
                 counting: bool = False, clock: Callable[[], float] = time.monotonic):
        if window < 1:
            raise ValueError(f"window: must be at least 1, got {window}")
        self.window = window
        self.position = position
        self.counting = counting
        self.fresh = True
        self._clock = clock
        self.last_advance = clock()
        self.resyncs = 0
        self._reset_evidence()

    def _reset_evidence(self) -> None:
        self.off_line_inputs = 0          # since the last advance
        self._first_off_line: float | None = None
        self._run = 0                     # consecutive epochs of the current run (counting lines)
        self._newest: OffLine | None = None

    def classify(self, epoch: int) -> Verdict:
        return classify(epoch, self.position, self.window)

    def advance(self, epoch: int) -> None:
        """The node acted on ``epoch`` (its new position); clears the re-sync evidence."""
        self.position = epoch
        self.fresh = False
        self.last_advance = self._clock()
        self._reset_evidence()

    def off_line(self, epoch: int, payload: Any = None) -> None:
        """Record an input the node did not act on (``behind`` or ``out_of_window``)."""
        prev = self._newest
        self.off_line_inputs += 1
        if self._first_off_line is None:
            self._first_off_line = self._clock()
        if prev is None or not 0 <= epoch - prev.epoch <= 1:
            self._run = 1
        elif epoch == prev.epoch + 1:
            self._run += 1
        self._newest = OffLine(epoch, payload)

    def stalled_for(self) -> float:
        """Seconds since the node last advanced (or since the line was made)."""
        return self._clock() - self.last_advance

    def resync_due(self, stall_after: float) -> OffLine | None:
        """The off-line input to re-sync to now, or ``None`` (module docstring, "Re-sync")."""
        new = self._newest
        if new is None or new.epoch == self.position:
            return None
        if self.counting and self.fresh:
            return new if self._run >= JOIN_MIN_INPUTS else None
        if self._clock() - self._first_off_line < stall_after:
            return None
        if self.counting:
            return new if self._run >= RESYNC_MIN_INPUTS else None
        return new if self.off_line_inputs >= RESYNC_MIN_INPUTS else None

    def resync_reason(self, due: OffLine, what: str, peer: str) -> str:
        """The log line of a re-sync to ``due`` (before :meth:`resync`): ``what`` the inputs are
        called, ``peer`` the node that presumably restarted."""
        return (f"re-synced from epoch {self.position} to epoch {due.epoch}: nothing new for "
                f"{self.stalled_for():.1f} s while {self.off_line_inputs} {what} came from another numbering "
                f"(a restarted {peer}?)")

    def resync(self, epoch: int) -> None:
        """Adopt ``epoch`` (the node acted on the off-line input): counted in ``resyncs``."""
        self.resyncs += 1
        self.advance(epoch)


class Resender:
    """At-least-once delivery of a node's last output (module docstring, "Re-send").

    ``period <= 0`` disables re-sending. The node calls :meth:`published` when it publishes a
    new output, :meth:`answered` when the input it expects next arrives, and asks :meth:`due`
    (e.g. from a timer); after re-sending it calls :meth:`published` again.
    """

    def __init__(self, period: float = DEFAULT_RESEND_PERIOD, clock: Callable[[], float] = time.monotonic):
        self.period = period
        self._clock = clock
        self._sent_at: float | None = None
        self.resent = 0

    def published(self) -> None:
        self._sent_at = self._clock()

    def answered(self) -> None:
        self._sent_at = None

    @property
    def waiting(self) -> bool:
        return self._sent_at is not None

    def due(self) -> bool:
        """Whether the last output has waited ``period`` seconds for its answer."""
        return self.period > 0 and self._sent_at is not None and self._clock() - self._sent_at >= self.period

    def resending(self) -> None:
        """The node re-sends now (counted in ``resent``; the period starts again)."""
        self.resent += 1
        self.published()


@dataclass(frozen=True)
class StallLimits:
    """Seconds without progress on an input before it is WARN, then ERROR."""

    warn_after: float = DEFAULT_STALL_WARN
    error_after: float = DEFAULT_STALL_ERROR

    def __post_init__(self):
        if not 0 < self.warn_after <= self.error_after:
            raise ValueError(f"stall limits: need 0 < warn_after ({self.warn_after}) <= error_after "
                             f"({self.error_after})")


class InputWatch:
    """Arrivals and progress of one input of a node (module docstring, "Stall levels").

    ``what``: how a new input is called in messages ("action", "reading", "belief").
    ``required=False``: an input the node can do without (the filter's ``action``, only a
    cross-check): it is not reported before it has advanced the node once.
    """

    def __init__(self, name: str, what: str, clock: Callable[[], float] = time.monotonic, *,
                 required: bool = True):
        self.name = name
        self.what = what
        self.required = required
        self._clock = clock
        self.started = clock()
        self.last_progress: float | None = None
        self.last_epoch: int | None = None
        self.received = 0
        self.idle = 0  # inputs received since the last progress that were not progress

    def arrived(self, progress: bool, epoch: int | None = None) -> None:
        """One input arrived; ``progress``: it advanced the node (a new epoch)."""
        self.received += 1
        if progress:
            self.last_progress = self._clock()
            self.idle = 0
            if epoch is not None:
                self.last_epoch = epoch
        else:
            self.idle += 1

    def silent_for(self) -> float:
        """Seconds since this input last advanced the node (since start if it never did)."""
        return self._clock() - (self.started if self.last_progress is None else self.last_progress)

    def status(self, limits: StallLimits) -> tuple[Level, str]:
        """Level and message of this input (the message is empty while OK)."""
        if not self.required and self.last_progress is None:
            return Level.OK, ""
        silent = self.silent_for()
        if silent >= limits.error_after:
            level = Level.ERROR
        elif silent >= limits.warn_after:
            level = Level.WARN
        else:
            return Level.OK, ""
        if self.last_progress is None:
            text = f"{self.name}: no {self.what} since start ({silent:.1f} s)"
        else:
            text = f"{self.name}: no new {self.what} for {silent:.1f} s (last: epoch {self.last_epoch})"
        if self.idle:
            text += f"; {self.idle} received meanwhile, none new (repeats, stale or out of window)"
        return level, text

    def values(self) -> dict[str, object]:
        """Diagnostic values of this input (``input.<name>.*``)."""
        p = f"input.{self.name}"
        return {f"{p}.last_new_epoch": "none" if self.last_epoch is None else self.last_epoch,
                f"{p}.seconds_since_new": round(self.silent_for(), 3), f"{p}.received": self.received,
                f"{p}.received_since_new": self.idle}


def worst(statuses: list[tuple[Level, str]]) -> tuple[Level, str]:
    """The highest level among ``statuses`` and the messages at that level, joined with ``; ``."""
    level = max((lv for lv, _ in statuses), default=Level.OK)
    return level, "; ".join(text for lv, text in statuses if lv == level and lv > Level.OK and text)


class LogThrottle:
    """At most one log line per ``interval`` seconds for a recurring event; the suppressed
    occurrences are counted and reported with the next line."""

    def __init__(self, interval: float = 10.0, clock: Callable[[], float] = time.monotonic):
        self.interval = interval
        self._clock = clock
        self._last: float | None = None
        self._suppressed = 0

    def ready(self) -> tuple[bool, int]:
        """``(log now?, occurrences suppressed since the previous line)``; counts this one."""
        now = self._clock()
        if self._last is None or now - self._last >= self.interval:
            n, self._suppressed, self._last = self._suppressed, 0, now
            return True, n
        self._suppressed += 1
        return False, 0
