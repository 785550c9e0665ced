"""Which epochs from the wire a loop acts on: the epoch window, the verdicts, the re-sync, jump and
join evidence, and at-least-once delivery of a loop's last output (rules: docs/ros.md, "The loop's
rules").

Every rule here is a function of epochs, counts and the time the caller passes in (``now``,
seconds on any monotonic clock); nothing reads a clock of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from .health import BeliefPace, LoopHealth, StallLimits

#: Default epoch window: the farthest jump a node acts on (a gap up to it is walked, as one
#: prediction per epoch, and logged as one line).
DEFAULT_EPOCH_WINDOW = 1000
#: Off-line inputs (and, on a counting line, consecutive epochs) that a stalled node needs to re-sync.
RESYNC_MIN_INPUTS = 3
#: Consecutive off-line readings on which a fresh counting line (a filter with no reading applied) joins.
JOIN_MIN_INPUTS = 2
#: Default re-send period (s).
DEFAULT_RESEND_PERIOD = 1.0
#: Seconds a (re)starting node keeps collecting evidence of the loop's epoch after the first before
#: it joins at the newest: a transient-local history arrives as one burst, within milliseconds.
JOIN_DELAY = 0.2
#: Default seconds a timer-driven simulator waits for the loop's epoch before numbering on its own.
DEFAULT_JOIN_TIMEOUT = 5.0

Verdict = Literal["join", "next", "ahead", "repeat", "behind", "out_of_window"]


@dataclass(frozen=True)
class Liveness:
    """The liveness settings of a loop (the nodes' parameters ``epoch_window``, ``resend_period``,
    ``stall_warn_after``, ``stall_error_after``)."""

    epoch_window: int = DEFAULT_EPOCH_WINDOW
    resend_period: float = DEFAULT_RESEND_PERIOD
    stall: StallLimits = field(default_factory=StallLimits)

    def __post_init__(self):
        if self.epoch_window < 1:
            raise ValueError(f"epoch_window: must be at least 1, got {self.epoch_window}")

    @property
    def watchdog_period(self) -> float:
        """How often a node checks its re-send, re-sync and stall rules: a quarter of the shortest
        of their times, within 0.05..1 s (0.25 s by default)."""
        shortest = min(self.resend_period if self.resend_period > 0 else self.stall.warn_after,
                       self.stall.warn_after)
        return min(1.0, max(0.05, shortest / 4))


def classify(epoch: int, position: int | None, window: int) -> Verdict:
    """Where ``epoch`` stands relative to a node at ``position`` (rule "Verdicts").

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
    stricter evidence of a line whose source counts (rule "Re-sync"). A line is
    *fresh* until it first advances. ``now``: the time the line is made.
    """

    def __init__(self, window: int = DEFAULT_EPOCH_WINDOW, *, now: float, position: int | None = None,
                 counting: bool = False):
        if window < 1:
            raise ValueError(f"window: must be at least 1, got {window}")
        self.window = window
        self.position = position
        self.counting = counting
        self.fresh = True
        self.last_advance = now
        self.resyncs = 0
        self._reset_evidence()

    def _reset_evidence(self) -> None:
        self.off_line_inputs = 0          # since the last advance
        self._first_off_line: float | None = None
        self._run = 0                     # consecutive epochs of the current run (counting lines)
        self._newest: OffLine | None = None

    def classify(self, epoch: int) -> Verdict:
        return classify(epoch, self.position, self.window)

    def advance(self, epoch: int, now: float) -> None:
        """The node acted on ``epoch`` (its new position); clears the re-sync evidence."""
        self.position = epoch
        self.fresh = False
        self.last_advance = now
        self._reset_evidence()

    def off_line(self, epoch: int, payload: Any, now: float) -> None:
        """Record an input the node did not act on (``behind`` or ``out_of_window``)."""
        prev = self._newest
        self.off_line_inputs += 1
        if self._first_off_line is None:
            self._first_off_line = now
        if prev is None or not 0 <= epoch - prev.epoch <= 1:
            self._run = 1
        elif epoch == prev.epoch + 1:
            self._run += 1
        self._newest = OffLine(epoch, payload)

    def stalled_for(self, now: float) -> float:
        """Seconds since the node last advanced (or since the line was made)."""
        return now - self.last_advance

    def clear_evidence(self) -> None:
        """The node accepted an input it can explain (it is not stalled): the evidence starts again."""
        self._reset_evidence()

    def jump(self, due: OffLine) -> bool:
        """Whether re-syncing to ``due`` is a jump ahead within the window (rule "Explained epochs")."""
        return self.position is not None and 0 < due.epoch - self.position <= self.window

    def resync_due(self, stall_after: float, now: float, *, jump_after: float | None = None) -> OffLine | None:
        """The off-line input to re-sync to now, or ``None`` (rules "Re-sync" and "Explained epochs").

        ``jump_after``: the node follows a jump ahead within the window as soon as two consecutive
        epochs beyond what it can explain came with nothing acted on in between, once it has not
        advanced for ``jump_after`` seconds (``None``: never, only the re-sync rule)."""
        new = self._newest
        if new is None or new.epoch == self.position:
            return None
        if self.counting and self.fresh:
            return new if self._run >= JOIN_MIN_INPUTS else None
        if (jump_after is not None and self._run >= JOIN_MIN_INPUTS and self.jump(new)
                and now - self.last_advance >= jump_after):
            return new
        if now - self._first_off_line < stall_after:
            return None
        if self.counting:
            return new if self._run >= RESYNC_MIN_INPUTS else None
        return new if self.off_line_inputs >= RESYNC_MIN_INPUTS else None

    def resync_reason(self, due: OffLine, what: str, peer: str, now: float) -> str:
        """The log line of a re-sync to ``due`` (before :meth:`resync`): ``what`` the inputs are
        called, ``peer`` the node that presumably restarted."""
        return (f"re-synced from epoch {self.position} to epoch {due.epoch}: nothing new for "
                f"{self.stalled_for(now):.1f} s while {self.off_line_inputs} {what} came from another numbering "
                f"(a restarted {peer}?)")

    def resync(self, epoch: int, now: float) -> None:
        """Adopt ``epoch`` (the node acted on the off-line input): counted in ``resyncs``."""
        self.resyncs += 1
        self.advance(epoch, now)


class JoinWait:
    """The join rule of a (re)started node (rule "Join"): it collects evidence of the
    loop's epoch for :data:`JOIN_DELAY` after the first and then joins at the newest."""

    def __init__(self, delay: float = JOIN_DELAY):
        self.delay = delay
        self.first_seen: float | None = None
        self.newest: int | None = None

    def note(self, epoch: int, now: float) -> None:
        """Evidence that the loop is at ``epoch``; the newest wins."""
        if self.newest is None or epoch > self.newest:
            self.newest = epoch
        if self.first_seen is None:
            self.first_seen = now

    def settled(self, now: float) -> bool:
        """Whether the evidence has been collected for the whole delay."""
        return self.first_seen is not None and now - self.first_seen >= self.delay

    def wake_at(self, now: float) -> float | None:
        """When the evidence will have settled, if that is still to come (else ``None``)."""
        if self.first_seen is None or self.settled(now):
            return None
        return self.first_seen + self.delay


class Resender:
    """At-least-once delivery of a node's last output (rule "Re-send").

    ``period <= 0`` disables re-sending. The node calls :meth:`published` when it publishes a
    new output, :meth:`answered` when the input it expects next arrives, and asks :meth:`due`
    (e.g. from a timer); after re-sending it calls :meth:`resending`.
    """

    def __init__(self, period: float = DEFAULT_RESEND_PERIOD):
        self.period = period
        self._sent_at: float | None = None
        self.resent = 0

    def published(self, now: float) -> None:
        self._sent_at = now

    def answered(self) -> None:
        self._sent_at = None

    @property
    def waiting(self) -> bool:
        return self._sent_at is not None

    def due(self, now: float) -> bool:
        """Whether the last output has waited ``period`` seconds for its answer."""
        return self.period > 0 and self._sent_at is not None and now - self._sent_at >= self.period

    def resending(self, now: float) -> None:
        """The node re-sends now (counted in ``resent``; the period starts again)."""
        self.resent += 1
        self.published(now)


def belief_verdict(line: EpochLine, stream: int, pace: BeliefPace, health: LoopHealth, epoch: int, now: float, *,
                   who: str = "", acted: str = "planned") -> str:
    """The verdict on a belief of ``epoch`` of the stream followed (``stream``: its newest epoch
    accepted; ``pace``: when its samples came, updated here): :meth:`EpochLine.classify`, and
    ``"unexplained"`` for one beyond ``stream + 1`` (rule "Explained epochs") unless its filter
    resumed after a pause (:class:`~.health.BeliefPace`: explained, one info line). ``who``
    prefixes the line (the sensor manager's target); ``acted``: what is done to the belief."""
    verdict = line.classify(epoch)
    if verdict in ("next", "ahead") and epoch > max(stream, line.position) + 1:
        if pace.resumed(now):
            health.log("info", f"{who}belief of epoch {epoch} after {now - pace.last:.2f} s without a belief "
                       f"(newest: epoch {stream}): the filter resumed (activated again?); {acted}")
        else:
            verdict = "unexplained"  # the beliefs so far do not lead to it (rule "Explained epochs")
    pace.heard(now)
    return verdict


def off_stream_belief(line: EpochLine, health: LoopHealth, verdict: Verdict, epoch: int, item: Any, *,
                      stream: int, window: int, stall_warn: float, now: float, who: str = "",
                      acted: str = "planned") -> None:
    """A belief the planner side does not act on (docs/ros.md, "The loop's rules": explained
    epochs, epoch window, stale): an ``unexplained`` one is off-line evidence and, unless it
    completes a jump of the filter (two consecutive beliefs), warned about; one ``out_of_window``
    is dropped and warned about; a ``behind`` or ``repeat`` one is counted as stale (``behind``
    also as off-line evidence). ``stream``: the newest epoch of the stream followed; ``who``: a
    prefix naming the input (the sensor manager's target); ``acted``: what is not done to it."""
    if verdict == "unexplained":
        line.off_line(epoch, item, now)
        due = line.resync_due(stall_warn, now, jump_after=0.0)
        if due is None or not line.jump(due):  # else it completes a jump: the caller acts on it
            health.warn("unexplained_epochs", f"{who}belief of epoch {epoch} does not follow the beliefs so far "
                        f"(newest: epoch {stream}): not {acted} unless the next belief follows it (a jump of the "
                        "filter); a stray, forged or replayed message?", now)
    elif verdict == "out_of_window":
        line.off_line(epoch, item, now)
        health.warn("out_of_window", f"{who}belief of epoch {epoch} is beyond the epoch window ({window}) of epoch "
                    f"{line.position}: dropped (a restarted filter or a forged message)", now)
    else:
        health.count("stale_beliefs")
        if verdict == "behind":
            line.off_line(epoch, item, now)
