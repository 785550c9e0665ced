"""A loop's health: its counters, the stall watch of each input, the writers of each input stream,
the node's ROS time, throttled warnings, and the report rule every node's diagnostics follow
(docs/ros.md, "The loop's rules": rules "Stall levels", "One writer", "Time" and "Report"), the
console line for each change of a node's level (:class:`HealthChanges`), and the period of an
input (:class:`PeriodWatch`: the rule "Pace").

Times are passed in (``now``, seconds on a monotonic clock); nothing here reads a clock.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Literal

from .clock import ClockWatch
from .writers import WriterWatch

#: Default seconds without progress before an input is WARN / ERROR.
DEFAULT_STALL_WARN = 2.0
DEFAULT_STALL_ERROR = 10.0
#: A recurring warning is logged at most once per this many seconds (per counter).
LOG_INTERVAL = 10.0
#: Counters every loop keeps, all of them problems (the report WARNs while they grow): epochs the
#: loop cannot explain, samples of a second writer, replaced writers, samples larger than the model
#: implies, refused run-time changes of ``use_sim_time``.
COMMON_COUNTERS = ("unexplained_epochs", "foreign_samples", "writer_changes", "oversized_samples",
                   "use_sim_time_refused")


class Level(IntEnum):
    """Diagnostic level of a report (the nodes map it to ``DiagnosticStatus``)."""

    OK = 0
    WARN = 1
    ERROR = 2


@dataclass(frozen=True)
class Log:
    """One line for the node's log."""

    level: Literal["debug", "info", "warning", "error"]
    text: str


@dataclass(frozen=True)
class Report:
    """What a node publishes on ``/diagnostics``: a level, one message, the values (by key)."""

    level: Level
    message: str
    values: dict[str, object]


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
    """Arrivals and progress of one input of a node (rule "Stall levels").

    ``what``: how a new input is called in messages ("action", "reading", "belief").
    ``required=False``: an input the node can do without (the filter's ``action``, only a
    cross-check): it is not reported before it has advanced the node once. ``started``: the
    time the watch starts (silence is counted from it until the first progress). A node that
    was inactive (rule "Inactive") counts silence from its activation
    (:meth:`resume`): while it did not act, its inputs may well have stopped because of it.
    """

    def __init__(self, name: str, what: str, *, started: float, required: bool = True):
        self.name = name
        self.what = what
        self.required = required
        self.started = started
        self.last_progress: float | None = None
        self.last_epoch: int | None = None
        self.received = 0
        self.idle = 0  # inputs received since the last progress that were not progress
        self.resumed: float | None = None  # the node's last activation

    def arrived(self, now: float, progress: bool, epoch: int | None = None) -> None:
        """One input arrived; ``progress``: it advanced the node (a new epoch)."""
        self.received += 1
        if progress:
            self.last_progress = now
            self.idle = 0
            if epoch is not None:
                self.last_epoch = epoch
        else:
            self.idle += 1

    def resume(self, now: float) -> None:
        """The node (re)starts acting at ``now``: silence is counted from here at most."""
        self.resumed = now

    def silent_for(self, now: float) -> float:
        """Seconds since this input last advanced the node (since start if it never did), or
        since the node's last activation if that is later."""
        since = self.started if self.last_progress is None else self.last_progress
        return now - (since if self.resumed is None else max(since, self.resumed))

    def status(self, limits: StallLimits, now: float) -> tuple[Level, str]:
        """Level and message of this input (the message is empty while OK)."""
        if not self.required and self.last_progress is None:
            return Level.OK, ""
        silent = self.silent_for(now)
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

    def values(self, now: float) -> dict[str, object]:
        """Diagnostic values of this input (``input.<name>.*``)."""
        p = f"input.{self.name}"
        return {f"{p}.last_new_epoch": "none" if self.last_epoch is None else self.last_epoch,
                f"{p}.seconds_since_new": round(self.silent_for(now), 3), f"{p}.received": self.received,
                f"{p}.received_since_new": self.idle}


def worst(statuses: Iterable[tuple[Level, str]]) -> tuple[Level, str]:
    """The highest level among ``statuses`` and the messages at that level, joined with ``; ``."""
    statuses = list(statuses)
    level = max((lv for lv, _ in statuses), default=Level.OK)
    return level, "; ".join(text for lv, text in statuses if lv == level and lv > Level.OK and text)


class LogThrottle:
    """At most one log line per ``interval`` seconds for a recurring event; the suppressed
    occurrences are counted and reported with the next line."""

    def __init__(self, interval: float = LOG_INTERVAL):
        self.interval = interval
        self._last: float | None = None
        self._suppressed = 0

    def ready(self, now: float) -> tuple[bool, int]:
        """``(log now?, occurrences suppressed since the previous line)``; counts this one."""
        if self._last is None or now - self._last >= self.interval:
            n, self._suppressed, self._last = self._suppressed, 0, now
            return True, n
        self._suppressed += 1
        return False, 0


class LoopHealth:
    """Counters, input watches, writers, warnings and the report of one loop (docs/ros.md, "Report").

    ``counters``: every count the loop keeps, in the order diagnostics show them; ``problems``:
    those that make the report WARN when they grew since the previous report (both followed by
    :data:`COMMON_COUNTERS`). A warning is counted, kept as the last warning, and logged at most
    once per ``log_interval`` seconds per counter (the occurrences in between are counted and their
    number given with the next line). Log lines wait in :attr:`logs` until the loop hands them to
    its caller (:meth:`drain_logs`). Every input watch has a :class:`~.writers.WriterWatch` of the
    same name in :attr:`writers`, and so has every name in ``streams`` (inputs without a stall
    watch); ``clock`` watches the node's ROS time once the node has said which it uses
    (:meth:`set_clock`).
    """

    def __init__(self, counters: Sequence[str], problems: Sequence[str], watches: Sequence[InputWatch],
                 stall: StallLimits, *, log_interval: float = LOG_INTERVAL, streams: Sequence[str] = ()):
        unknown = set(problems) - set(counters)
        if unknown:
            raise ValueError(f"problems: not counters: {sorted(unknown)}")
        self.counts: dict[str, int] = dict.fromkeys([*counters, *COMMON_COUNTERS], 0)
        self.problems = (*problems, *COMMON_COUNTERS)
        self.watches = list(watches)
        self.writers = {name: WriterWatch(name, stall.warn_after) for name in [*(w.name for w in watches), *streams]}
        self.clock: ClockWatch | None = None
        self.stall = stall
        self.log_interval = log_interval
        self.last_warning = ""
        self.logs: list[Log] = []
        self._throttles: dict[str, LogThrottle] = {}
        self._reported = dict.fromkeys(self.problems, 0)

    def count(self, counter: str, n: int = 1) -> None:
        self.counts[counter] += n

    def log(self, level: Literal["debug", "info", "warning", "error"], text: str) -> None:
        self.logs.append(Log(level, text))

    def warn(self, counter: str | None, text: str, now: float, *, n: int = 1, log: bool = True) -> None:
        """Count ``n`` occurrences of ``counter`` (``None``: count nothing), keep ``text`` as the last
        warning and log it unless a line of the same counter was logged within ``log_interval``."""
        if counter is not None:
            self.count(counter, n)
        self.last_warning = text
        if not log:
            return
        ready, suppressed = self._throttles.setdefault(counter or "", LogThrottle(self.log_interval)).ready(now)
        if ready:
            self.log("warning", text + (f" (and {suppressed} similar since the last such line)" if suppressed else ""))

    def reject(self, watch: InputWatch | None, counter: str, text: str, now: float) -> None:
        """An input that could not be decoded: received (not progress), counted, warned."""
        if watch is not None:
            watch.arrived(now, False)
        self.warn(counter, text, now)

    def resume(self, now: float) -> None:
        """The node is activated at ``now`` (:meth:`InputWatch.resume` of every watch)."""
        for w in self.watches:
            w.resume(now)

    def watch(self, name: str) -> InputWatch | None:
        """The stall watch of input ``name`` (``None``: a stream without one)."""
        return next((w for w in self.watches if w.name == name), None)

    # ----------------------------------------------------------- what every sample passes first
    def admit(self, name: str, writer: str | None, now: float) -> bool:
        """The rule "One writer" for a sample of ``writer`` on input ``name``: whether the loop may
        act on it (a foreign sample is counted and dropped, its writer's first one logged)."""
        verdict, text = self.writers[name].admit(writer, now)
        if verdict == "foreign":
            watch = self.watch(name)
            if watch is not None:
                watch.arrived(now, False)
            self.count("foreign_samples")
            if text:
                self.last_warning = text
                self.log("warning", text)
            return False
        if verdict == "replaced":
            self.warn("writer_changes", text, now)
        return True

    def oversized(self, name: str, text: str, now: float) -> None:
        """A sample of input ``name`` larger than the model implies, dropped unread (``text``: why)."""
        self.reject(self.watch(name), "oversized_samples", text, now)

    def set_clock(self, sim_time: bool, now: float) -> None:
        """The node's ROS time: ``use_sim_time`` as it started (rule "Time")."""
        self.clock = ClockWatch(sim_time, self.stall.warn_after, now)
        if sim_time:
            self.log("info", "use_sim_time is true: the simulator's steps follow /clock; liveness, re-sends and "
                     "diagnostics run on the steady clock")

    def refuse_sim_time(self, wanted: object, now: float) -> str:
        """A run-time change of ``use_sim_time``, refused (rule "Time"): counted, warned; the reason."""
        reason = (self.clock or ClockWatch(False, self.stall.warn_after, now)).refuse(wanted)
        self.warn("use_sim_time_refused", f"refused a parameter set: {reason}", now)
        return reason

    def drain_logs(self) -> list[Log]:
        logs, self.logs = self.logs, []
        return logs

    def stalled(self, now: float) -> tuple[Level, str]:
        """The worst stall level of the inputs and their messages at that level."""
        return worst(w.status(self.stall, now) for w in self.watches)

    def report(self, now: float, values: Mapping[str, object], *, head: Sequence[str] = (), level: Level = Level.OK,
               stall_note: str = "", idle: str = "", inactive: bool = False) -> Report:
        """The report rule: the level is the highest of ``level``, the inputs' stall level and WARN
        if a problem count grew since the previous report (OK again once they stop); the message
        joins ``head``, the stall messages (followed by ``stall_note``) and the problems since the
        previous report with the last warning, or is ``idle`` if there is nothing to say. The
        values are ``values``, the counts and the watches' values. Each call starts a new "since
        the previous report". ``inactive``: the node is inactive (rule "Inactive"):
        no stall level or message (its inputs may have stopped because of it)."""
        recent = {k: self.counts[k] - n for k, n in self._reported.items() if self.counts[k] > n}
        self._reported = {k: self.counts[k] for k in self.problems}
        stall, stall_text = (Level.OK, "") if inactive else self.stalled(now)
        clock_text = "" if self.clock is None else self.clock.status(now)
        writers = [t for t in (w.status() for w in self.writers.values()) if t]
        texts = [*head, *([clock_text] if clock_text else [])]
        if stall_text:
            texts.append(stall_text + stall_note)
        texts += writers
        if recent:
            items = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in recent.items())
            texts.append(f"since the last report: {items}; last: {self.last_warning}")
        level = max(level, stall, Level.WARN if recent or writers else Level.OK,
                    Level.ERROR if clock_text else Level.OK)
        all_values = {**values, **self.counts}
        for w in self.watches:
            all_values.update(w.values(now))
        for ww in self.writers.values():
            all_values.update(ww.values())
        if self.clock is not None:
            all_values.update(self.clock.values(now))
        return Report(level, "; ".join(texts) or idle, all_values)


class HealthChanges:
    """The console side of the rule "Report": a node logs each change of its diagnostics' level
    once, as its report changes it (OK -> WARN or ERROR, WARN <-> ERROR, and back to OK with how
    long it was not), not on every report at the same level. Starts at OK."""

    def __init__(self):
        self.level = Level.OK
        self.since: float | None = None  # when the level last left OK

    def update(self, level: Level, message: str, now: float) -> Log | None:
        """The line for a report at ``level`` with ``message`` at ``now``, or ``None`` if the level
        did not change."""
        if level == self.level:
            return None
        before, self.level = self.level, level
        if level == Level.OK:
            took = "" if self.since is None else f" after {now - self.since:.1f} s"
            self.since = None
            return Log("info", f"health OK again{took} (was {before.name})")
        if before == Level.OK:
            self.since = now
        text = f"health {level.name}: {message}" if message else f"health {level.name}"
        return Log("error" if level == Level.ERROR else "warning", text)


#: Intervals a :class:`PeriodWatch` keeps, and how many it needs before it says a period.
PERIOD_WINDOW = 20
PERIOD_MIN_INTERVALS = 10


class PeriodWatch:
    """The period of an input (rule "Pace") over its last :data:`PERIOD_WINDOW` intervals between
    arrivals (``None`` until :data:`PERIOD_MIN_INTERVALS` are known): ``how="mean"`` (the window's
    span over its intervals: a rate, which a burst of samples does not move, a pause lengthens) or
    ``"median"`` (which one pause does not move, a burst shortens). Each caller takes the one whose
    error cannot raise a false warning."""

    def __init__(self, how: str = "mean", window: int = PERIOD_WINDOW, min_intervals: int = PERIOD_MIN_INTERVALS):
        if how not in ("mean", "median"):
            raise ValueError(f"how: mean or median, got {how!r}")
        self.how = how
        self.min_intervals = min_intervals
        self._last: float | None = None
        self._intervals: deque[float] = deque(maxlen=window)

    def arrived(self, now: float) -> None:
        if self._last is not None:
            self._intervals.append(now - self._last)
        self._last = now

    @property
    def intervals(self) -> int:
        """How many intervals the period is the median of."""
        return len(self._intervals)

    def period(self) -> float | None:
        if len(self._intervals) < self.min_intervals:
            return None
        if self.how == "mean":
            return sum(self._intervals) / len(self._intervals)
        ordered = sorted(self._intervals)
        n = len(ordered)
        return ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2
