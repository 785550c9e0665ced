"""The run recorder's rule, without ROS: the loop's topics paired by epoch into run-record rows
(:mod:`~pomdp_planner.core.io.run_record`), in epoch order and in bounded memory (node:
``nodes/run_recorder.py``; the demo's table uses the same loop).

**Which row holds what.** Row ``t`` is the decision made from the belief of epoch ``t``, as
``simulate --record`` writes step ``t`` (``b_t``, ``s_t``, ``a_t``):

==============  =================================================================================
column          comes from
==============  =================================================================================
``epoch``       ``t``
``b0..bS-1``    the ``belief`` labelled ``epoch=t`` (after the readings of epoch ``t``; ``0``: the prior)
``true_state``  ``true_state`` ``[t, s]``: the hidden state that belief estimates (empty without one)
``action``      ``action`` ``[t + 1, p]``: the priority the planner chose from that belief
``lower``,      ``plan_info`` of epoch ``t + 1`` (the same decision): ``bound_lower``, ``bound_upper``
``upper``       where the planner published them (finite: guaranteed bounds), else empty
``depth``,      ``depth``, ``latency`` (belief in to action out, seconds) of that ``plan_info``;
``latency``     empty without one
``certified``   ``1`` when that ``plan_info`` says certified and its bounds agree, else ``0``
==============  =================================================================================

**Parts.** A row *needs* its belief and its action; its ``plan_info`` and its true state are
*awaited* (the true state only when expected: ``expect_true_state``, or once any ``true_state``
has arrived, i.e. a simulated run). The rows are written strictly in increasing epoch, the oldest
pending row first; it blocks the later ones until it is written or dropped:

* a row is written as soon as it is complete;
* a row with what it needs is written without an awaited part once that part is *given up*: its
  topic has delivered a later epoch (each topic has one writer, reliable, in order: the missing
  sample is lost), or ``row_timeout`` seconds have passed since the row had what it needs (a
  topic that stopped, e.g. ``expect_true_state`` without a simulator);
* a row without what it needs is dropped (``dropped_rows``: e.g. the epochs of a filter's gap,
  which have no belief, or beliefs the planner skipped, which have no action) once the missing
  part is given up the same way; no time-out here, so a planner that takes long loses no row;
* at most ``max_pending_rows`` rows wait; one more forces the oldest out (written with what it
  has, or dropped; ``forced_rows``): a late or missing message never grows anything without bound.

A sample of an epoch already written or dropped is *late* (``late_samples``), one more than
``epoch_window`` beyond the last row written or dropped is *out of window* (``out_of_window``: a
forged epoch cannot take the record over); both are dropped. When for :data:`RESYNC_AFTER`
seconds no row has been written or dropped while at least three such samples came (the loop
restarted on another numbering; re-sent samples of the last row do not count), the recorder
re-syncs (``resyncs``, one log line): the waiting rows are dropped and recording goes on from the
newest of those samples (the re-sync rule of the other nodes, ``core/loop/epochs.py``). A second,
different action or belief for an epoch (a restarted planner deciding again) is a ``conflict``:
the first is kept. A ``plan_info`` is checked before it is used: its epoch an integer,
its priority the row's action, ``depth`` an integer >= 0, ``latency`` finite and >= 0, the bounds
both ``NaN`` or integers with ``1 <= lower <= upper <= A``, ``certified`` only with agreeing
bounds; a ``plan_info`` that fails is dropped (``bad_plan_info``) and the row has none. So the
record shows root bounds only where the planner published guaranteed ones and claims no
certificate the planner did not. Each topic follows one writer (``health.writers``, the rule "One
writer" of the other nodes): the node drops a second writer's samples before they reach the loop.

Times are passed in (``now``, seconds on a monotonic clock); nothing here reads a clock or a file.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .epochs import DEFAULT_EPOCH_WINDOW, EpochLine, OffLine
from .health import DEFAULT_STALL_WARN, Log, LoopHealth, Report, StallLimits
from .planner_loop import PlanInfo
from .samples import ActionSample, BeliefSample

#: Seconds a row with what it needs waits for an awaited part before it is written without it,
#: when the part's topic has not moved past it.
DEFAULT_ROW_TIMEOUT = 5.0
#: Rows that may wait at once.
DEFAULT_MAX_PENDING_ROWS = 1000
#: Seconds of only late or out-of-window samples before the recorder re-syncs (the other nodes'
#: default ``stall_warn_after``).
RESYNC_AFTER = DEFAULT_STALL_WARN
#: The recorder's inputs; the counts of :class:`RecorderLoop`.
TOPICS = ("belief", "action", "plan_info", "true_state")
COUNTERS = ("rows_written", "dropped_rows", "forced_rows", "rows_without_plan_info", "rows_without_true_state",
            "late_samples", "out_of_window", "resyncs", "conflicts", "bad_plan_info", "malformed_messages")
#: Counts that make the report WARN when they grew since the previous one.
PROBLEMS = ("forced_rows", "out_of_window", "resyncs", "conflicts", "bad_plan_info", "malformed_messages")


@dataclass(frozen=True, eq=False)
class RecordRow:
    """One row of the record (module docstring): the decision made from ``belief`` (epoch
    ``epoch``), ``priority`` ``1..A`` chosen from it, ``true_state`` (0-based) and ``info`` (the
    checked ``plan_info`` of epoch ``epoch + 1``) where known."""

    epoch: int
    belief: np.ndarray
    priority: int
    true_state: int | None = None
    info: PlanInfo | None = None

    @property
    def bounds(self) -> tuple[int, int] | None:
        """The root bound interval ``(lower, upper)`` as priorities, where the planner published it."""
        if self.info is None or math.isnan(self.info.bound_lower):
            return None
        return int(self.info.bound_lower), int(self.info.bound_upper)

    def record_fields(self) -> dict[str, Any]:
        """The keyword arguments of :meth:`~pomdp_planner.core.io.run_record.RunRecordWriter.write`
        after ``epoch``, ``belief`` and ``priority``."""
        info = self.info
        return {"true_state": self.true_state, "bounds": self.bounds,
                "guaranteed": self.bounds is not None,  # the planner publishes only guaranteed bounds
                "depth": None if info is None else info.depth,
                "certified": info is not None and info.certified,
                "latency": None if info is None else info.latency}


@dataclass
class RecorderOutput:
    """What one call of the loop asks its caller to do: write ``rows`` (in this order), log
    ``logs``, and call :meth:`RecorderLoop.poll` at ``due`` (``None``: nothing is waiting on time)."""

    rows: list[RecordRow] = field(default_factory=list)
    logs: list[Log] = field(default_factory=list)
    due: float | None = None


def check_plan_info(values: Mapping[str, float], num_actions: int) -> PlanInfo:
    """The ``plan_info`` record ``values`` (the decoded message: field -> float) as a
    :class:`PlanInfo`, checked (module docstring); ``ValueError`` naming the field otherwise."""

    def integer(name: str, lo: int, hi: float = math.inf) -> int:
        v = float(values[name])
        if not (math.isfinite(v) and v.is_integer() and lo <= v <= hi):
            raise ValueError(f"plan_info: {name} must be an integer in {lo}..{hi:g}, got {v!r}")
        return int(v)

    def flag(name: str) -> bool:
        return bool(integer(name, 0, 1))

    epoch = integer("epoch", 1, 1e18)
    priority = integer("action_priority", 1, num_actions)
    latency, time_used = float(values["latency"]), float(values["time_used"])
    for name, v in (("latency", latency), ("time_used", time_used)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"plan_info: {name} must be a finite number >= 0 seconds, got {v!r}")
    lo, up = float(values["bound_lower"]), float(values["bound_upper"])
    if math.isnan(lo) and math.isnan(up):
        bounds = (math.nan, math.nan)
    else:
        bounds = (integer("bound_lower", 1, num_actions), integer("bound_upper", 1, num_actions))
        if bounds[0] > bounds[1]:
            raise ValueError(f"plan_info: bound_lower {bounds[0]} above bound_upper {bounds[1]}")
        if not bounds[0] <= priority <= bounds[1]:
            raise ValueError(f"plan_info: action_priority {priority} outside the bounds [{bounds[0]}, {bounds[1]}]")
    certified = flag("certified")
    if certified and (math.isnan(bounds[0]) or bounds[0] != bounds[1]):
        raise ValueError("plan_info: certified without agreeing bounds")
    return PlanInfo(epoch=epoch, action_priority=priority, depth=integer("depth", 0),
                    nodes_expanded=integer("nodes_expanded", 0), pruned_percent=float(values["pruned_percent"]),
                    certified=certified, time_used=time_used, latency=latency, deadline_hit=flag("deadline_hit"),
                    deadline_miss=flag("deadline_miss"), bound_lower=float(bounds[0]), bound_upper=float(bounds[1]))


@dataclass
class _Pending:
    """The parts of one row received so far."""

    belief: np.ndarray | None = None
    priority: int | None = None
    true_state: int | None = None
    info: PlanInfo | None = None
    needs_met_at: float | None = None  # when belief and action were both there


class RecorderLoop:
    """The pairing rule of the module docstring for a model with ``S`` states and ``A`` actions;
    ``now``: the time the recorder starts."""

    def __init__(self, S: int, A: int, *, now: float, row_timeout: float = DEFAULT_ROW_TIMEOUT,
                 max_pending_rows: int = DEFAULT_MAX_PENDING_ROWS, epoch_window: int = DEFAULT_EPOCH_WINDOW,
                 expect_true_state: bool = False):
        if not row_timeout > 0:
            raise ValueError(f"row_timeout: must be > 0 seconds, got {row_timeout!r}")
        if max_pending_rows < 1 or epoch_window < 1:
            raise ValueError("max_pending_rows, epoch_window: must be >= 1")
        self.S, self.A = int(S), int(A)
        self.row_timeout = float(row_timeout)
        self.max_pending_rows = int(max_pending_rows)
        self.epoch_window = int(epoch_window)
        self.expect_true_state = bool(expect_true_state)
        self.pending: dict[int, _Pending] = {}
        self._order: list[int] = []  # heap of the pending epochs
        #: The newest row epoch each topic has delivered (the give-up rule).
        self.newest: dict[str, int] = {}
        #: Rows up to this epoch are written or dropped (``None``: none yet).
        self.done_upto: int | None = None
        self.last_written: int | None = None
        #: The window and the re-sync evidence, positioned at ``done_upto``.
        self.line = EpochLine(self.epoch_window, now=now)
        # no stall watches (it only observes); one writer per topic, as for every loop input
        self.health = LoopHealth(COUNTERS, PROBLEMS, [], StallLimits(), streams=TOPICS)

    # ----------------------------------------------------------- inputs
    def belief(self, sample: BeliefSample, now: float) -> RecorderOutput:
        """The belief of epoch ``sample.epoch`` (decoded, on the simplex): row ``sample.epoch``."""
        row = self._row("belief", sample.epoch, now)
        if row is not None:
            if row.belief is None:
                row.belief = np.asarray(sample.belief, dtype=float)
                self._needs_met(row, now)
            elif not np.array_equal(row.belief, sample.belief):
                self._conflict(f"belief of epoch {sample.epoch} differs from the first one received", now)
        return self._advance(now)

    def action(self, sample: ActionSample, now: float) -> RecorderOutput:
        """The action ``[t + 1, p]``, chosen from the belief of epoch ``t``: row ``t``."""
        row = self._row("action", sample.epoch - 1, now)
        if row is not None:
            if row.priority is None:
                if row.info is not None and row.info.action_priority != sample.priority:
                    self._bad_info(f"plan_info of epoch {sample.epoch} names priority {row.info.action_priority}, "
                                   f"the action {sample.priority}", now)
                    row.info = None
                row.priority = int(sample.priority)
                self._needs_met(row, now)
            elif row.priority != sample.priority:
                self._conflict(f"action of epoch {sample.epoch}: priority {sample.priority} after {row.priority}; "
                               "the first is kept", now)
        return self._advance(now)

    def plan_info(self, values: Mapping[str, float], now: float) -> RecorderOutput:
        """A decoded ``plan_info`` record (field -> float), checked by :func:`check_plan_info`:
        the decision of row ``epoch - 1``."""
        try:
            info = check_plan_info(values, self.A)
        except ValueError as exc:
            self._bad_info(str(exc), now)
            return self._advance(now)
        row = self._row("plan_info", info.epoch - 1, now)
        if row is not None and row.info is None:
            if row.priority is not None and row.priority != info.action_priority:
                self._bad_info(f"plan_info of epoch {info.epoch} names priority {info.action_priority}, the action "
                               f"{row.priority}", now)
            else:
                row.info = info
        return self._advance(now)

    def true_state(self, epoch: int, state: int, now: float) -> RecorderOutput:
        """``true_state`` ``[epoch, state]`` (0-based): row ``epoch``; from now on true states are awaited."""
        if not 0 <= state < self.S:
            return self.rejected("true_state", f"true_state: state {state} out of range 0..{self.S - 1}", now)
        self.expect_true_state = True
        row = self._row("true_state", epoch, now)
        if row is not None and row.true_state is None:
            row.true_state = int(state)
        return self._advance(now)

    def rejected(self, topic: str, text: str, now: float) -> RecorderOutput:
        """A message on ``topic`` that could not be decoded (``text`` says why): counted, dropped."""
        self.health.warn("malformed_messages", text, now)
        return self._advance(now)

    def poll(self, now: float) -> RecorderOutput:
        """Called at the ``due`` time of an output: the time-outs."""
        return self._advance(now)

    def close(self, now: float) -> RecorderOutput:
        """The end of the run: every waiting row with what it needs is written, in order, the others
        dropped; nothing waits any more."""
        out = RecorderOutput()
        while self.pending:
            self._resolve(self._pop(), out, now)
        out.logs = self.health.drain_logs()
        return out

    def report(self, now: float) -> Report:
        """Diagnostics: the last row written, the rows waiting, the counts (WARN while problems grow)."""
        last = "none" if self.last_written is None else self.last_written
        return self.health.report(now, {"last_row_epoch": last, "pending_rows": len(self.pending)},
                                  head=[f"{self.health.counts['rows_written']} rows written (last: epoch {last})"])

    # ----------------------------------------------------------- rules
    def _row(self, topic: str, epoch: int, now: float) -> _Pending | None:
        """The pending row ``epoch`` for a sample of ``topic``, created if needed; ``None`` if the
        sample is late or out of window (counted, and evidence for a re-sync)."""
        if epoch < 0:
            self.health.count("late_samples")  # an action of epoch 0 answers no belief
            return None
        verdict = self.line.classify(epoch)
        if verdict == "repeat":  # a re-send of the last row's samples: no evidence of another numbering
            self.health.count("late_samples")
            return None
        if verdict == "behind" or (verdict == "out_of_window" and epoch < self.done_upto):
            self.health.count("late_samples")
            self.line.off_line(epoch, None, now)
            return None
        if verdict == "out_of_window":
            self.health.warn("out_of_window", f"{topic}: epoch {epoch} is more than epoch_window ({self.epoch_window}) "
                             f"beyond the last row written or dropped ({self.done_upto}); dropped", now)
            self.line.off_line(epoch, None, now)
            return None
        self.newest[topic] = max(self.newest.get(topic, epoch), epoch)
        row = self.pending.get(epoch)
        if row is None:
            row = self.pending[epoch] = _Pending()
            heapq.heappush(self._order, epoch)
        return row

    def _pop(self) -> tuple[int, _Pending]:
        """The oldest pending row, removed."""
        epoch = heapq.heappop(self._order)
        return epoch, self.pending.pop(epoch)

    @staticmethod
    def _needs_met(row: _Pending, now: float) -> None:
        if row.belief is not None and row.priority is not None and row.needs_met_at is None:
            row.needs_met_at = now

    def _conflict(self, text: str, now: float) -> None:
        self.health.warn("conflicts", text, now)

    def _bad_info(self, text: str, now: float) -> None:
        self.health.warn("bad_plan_info", text + "; the row is written without it", now)

    def _missing(self, epoch: int, row: _Pending) -> list[str]:
        """The topics row ``epoch`` still lacks, needed ones first."""
        missing = [t for t, have in (("belief", row.belief), ("action", row.priority)) if have is None]
        if row.info is None:
            missing.append("plan_info")
        if self.expect_true_state and row.true_state is None:
            missing.append("true_state")
        return missing

    def _given_up(self, epoch: int, topic: str) -> bool:
        """The row's part from ``topic`` will not come: its topic has delivered a later row's sample."""
        return self.newest.get(topic, -1) > epoch

    def _settled(self, epoch: int, row: _Pending, now: float) -> bool:
        """Whether the oldest row ``epoch`` can be written or dropped now (module docstring)."""
        missing = self._missing(epoch, row)
        if row.needs_met_at is None:  # lacks its belief or its action: dropped once one is given up
            return any(self._given_up(epoch, t) for t in missing if t in ("belief", "action"))
        return (not missing or now - row.needs_met_at >= self.row_timeout
                or all(self._given_up(epoch, t) for t in missing))

    def _resolve(self, item: tuple[int, _Pending], out: RecorderOutput, now: float) -> None:
        """Write the row ``item`` (epoch, parts) with what it has, or drop it if it lacks what it needs."""
        epoch, row = item
        self.done_upto = epoch
        self.line.advance(epoch, now)
        if row.belief is None or row.priority is None:
            self.health.count("dropped_rows")
            return
        self.health.count("rows_written")
        self.health.count("rows_without_plan_info", row.info is None)
        self.health.count("rows_without_true_state", row.true_state is None)
        self.last_written = epoch
        out.rows.append(RecordRow(epoch, row.belief, row.priority, row.true_state, row.info))

    def _advance(self, now: float) -> RecorderOutput:
        out = RecorderOutput()
        while len(self.pending) > self.max_pending_rows:
            self.health.warn("forced_rows", f"more than max_pending_rows ({self.max_pending_rows}) rows waiting: "
                             f"row {self._order[0]} forced out with what it has", now)
            self._resolve(self._pop(), out, now)
        while self.pending:
            epoch = self._order[0]
            row = self.pending[epoch]
            if not self._settled(epoch, row, now):
                if row.needs_met_at is not None:
                    out.due = row.needs_met_at + self.row_timeout
                break
            self._resolve(self._pop(), out, now)
        due = self.line.resync_due(RESYNC_AFTER, now)
        if due is not None:
            self._resync(due, now)
        out.logs = self.health.drain_logs()
        return out

    def _resync(self, due: OffLine, now: float) -> None:
        """Go on from row ``due.epoch`` (module docstring): the waiting rows are dropped, the topics'
        newest epochs forgotten."""
        epoch = due.epoch
        reason = self.line.resync_reason(due, "samples", "loop", now)
        self.health.warn("resyncs", f"{reason}; {len(self.pending)} waiting rows dropped", now)
        self.health.count("dropped_rows", len(self.pending))
        self.pending.clear()
        self._order.clear()
        self.newest.clear()
        self.done_upto = epoch - 1
        self.line.resync(epoch - 1, now)
