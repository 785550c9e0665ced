"""The belief filter's loop: readings in, beliefs out (rules: docs/ros.md, "The loop's rules";
node: ``nodes/belief_filter.py``).

A reading is classified against the filter's epoch (:mod:`.epochs`), buffered in epoch order
(:class:`~.epoch_buffer.EpochBuffer`), and each released epoch goes to the core's epoch filter
(:class:`~pomdp_planner.core.filter.EpochFilter`, the one ``simulate`` uses): prediction once with
the action the readings carry (paper Eq. 1), one update per reading (Eq. 2), the recovery rule.
Soft-evidence topics (``likelihood_topics``: a likelihood per state instead of an observation
index, :class:`~.samples.LikelihoodSample`) are sensors like the others, after the observation
topics: the same buffer and rules, and the update ``b'(s) ∝ l(s) b^a(s)``.
The belief of epoch ``t`` is published after epoch ``t`` is applied; the prior is epoch 0. A run
of lost epochs is one log line and one belief (its last epoch's); epochs are declared lost only
when the readings after them count on (never on the word of one reading ahead). A fresh filter
joins a running loop on two consecutive readings beyond its reach; a running one follows a jump
of the readings far ahead only on two consecutive epochs with nothing applied for
``epoch_timeout``; a stalled one re-syncs to readings counting on another numbering (a restarted
simulator); the last belief is re-sent while no reading of the next epoch comes (rules:
docs/ros.md, "The loop's rules").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..belief import BeliefError
from ..filter import EpochFilter
from ..model import POMDP, action_of_priority, priority_of
from ..uncertainty import SHANNON
from .epoch_buffer import EpochBuffer, EpochReadings
from .epochs import EpochLine, Liveness, Resender
from .health import InputWatch, Log, LoopHealth, Report
from .samples import ActionSample, LikelihoodSample, ObservationSample

COUNTERS = ("readings", "impossible_observations", "contradicting_observations", "out_of_range_observations",
            "malformed_messages", "duplicates", "conflicts", "gaps", "incomplete_epochs", "action_mismatches",
            "bad_beliefs", "out_of_window", "resyncs", "resent_beliefs")
#: Counts that make the report WARN when they grew since the previous one.
PROBLEMS = ("impossible_observations", "contradicting_observations", "out_of_range_observations",
            "malformed_messages", "conflicts", "gaps", "incomplete_epochs", "bad_beliefs", "out_of_window",
            "resyncs")


@dataclass(frozen=True, eq=False)
class BeliefOut:
    """A belief to publish: its epoch, the probabilities and their Shannon entropy (nats)."""

    epoch: int
    belief: np.ndarray
    entropy: float


@dataclass
class FilterOutput:
    """What one call of the loop asks the node to do: publish ``beliefs`` in order, log ``logs``,
    and call :meth:`FilterLoop.release` at ``release_at`` (``None``: nothing waits for a time-out)."""

    beliefs: list[BeliefOut] = field(default_factory=list)
    logs: list[Log] = field(default_factory=list)
    release_at: float | None = None


class FilterLoop:
    """The filter's loop for ``model`` with one observation array per sensor (``sensors``, named
    ``topics`` in messages) and one soft-evidence sensor per ``likelihood_topics`` (sensor indices
    after the observation topics), starting from ``prior`` at epoch 0 at time ``now``."""

    def __init__(self, model: POMDP, sensors: Sequence[np.ndarray], prior: np.ndarray, topics: Sequence[str],
                 live: Liveness, *, now: float, epoch_timeout: float = 0.5, max_pending: int = 10,
                 likelihood_topics: Sequence[str] = ()):
        self.model = model
        self.topics = [*topics, *likelihood_topics]
        self.filter = EpochFilter(model, sensors, likelihoods=len(likelihood_topics))
        if self.filter.num_sensors != len(self.topics):
            raise ValueError(f"topics: {len(self.topics)} names for {self.filter.num_sensors} sensors")
        self.live = live
        self.belief = np.asarray(prior, dtype=float)
        self.epoch = 0
        self.started_from = "prior at epoch 0"
        self.line = EpochLine(live.epoch_window, now=now, position=0, counting=True)
        self.buffer = EpochBuffer(len(self.topics), next_epoch=1, timeout=epoch_timeout, max_pending=max_pending,
                                  window=live.epoch_window)
        self.action_watch = InputWatch("action", "action", started=now, required=False)
        self.watches = [InputWatch(t, "reading", started=now) for t in self.topics]
        self.health = LoopHealth(COUNTERS, PROBLEMS, [*self.watches, self.action_watch], live.stall)
        self.resender = Resender(live.resend_period)
        self._newest_command = -1
        self._last: BeliefOut | None = None
        self._out: list[BeliefOut] = []

    # ----------------------------------------------------------- inputs
    def start(self, now: float) -> FilterOutput:
        """The prior, published as epoch 0."""
        self._publish(now)
        self.health.log("info", f"{self.model.describe()}; sensors {self.topics}; prior published as epoch 0")
        return self._result()

    def observation(self, sensor: int, obs: ObservationSample | LikelihoodSample, now: float) -> FilterOutput:
        """One decoded reading of sensor ``sensor`` (a likelihood for a soft-evidence sensor):
        buffered if it is within the filter's reach ahead, else counted (and kept as evidence for
        the join, jump and re-sync rules); ready epochs applied."""
        soft = isinstance(obs, LikelihoodSample)
        if soft != self.filter.soft(sensor):
            raise ValueError(f"sensor {sensor} ({self.topics[sensor]}) does not take a {type(obs).__name__}")
        reading = tuple(obs.likelihood) if soft else obs.observation
        self.health.count("readings")
        action = action_of_priority(obs.priority, self.model.A)
        verdict = self.line.classify(obs.epoch)
        watch, topic = self.watches[sensor], self.topics[sensor]
        if verdict in ("next", "ahead"):
            result = self.buffer.add(sensor, obs.epoch, action, reading, now)
            if result != "far":
                watch.arrived(now, result in ("buffered", "replaced"), obs.epoch)
            if result in ("buffered", "replaced"):
                self.resender.answered()
            if result == "duplicate":
                self.health.count("duplicates")
            elif result == "conflict":
                self.health.warn("conflicts", f"{topic}: reading of epoch {obs.epoch} conflicts with an earlier one "
                                 "(different action or observation); dropped", now)
            elif result == "replaced":
                self.health.warn("conflicts", f"{topic}: reading of epoch {obs.epoch} conflicts with one that came "
                                 "ahead of the loop; the one that came in order replaced it", now)
            if result != "far":
                return self._release(now)
            verdict = "far"
        watch.arrived(now, False)
        if verdict in ("repeat", "behind"):  # an epoch already applied: a re-send, or stale
            self.health.count("duplicates")
        elif verdict == "far":
            self.line.off_line(obs.epoch, (sensor, action, reading), now)
            due = self.line.resync_due(self.live.stall.warn_after, now, jump_after=self.buffer.timeout)
            # before joining, the running loop's readings are expected to be far ahead; one that
            # completes a jump (below) is acted on
            if not self.line.fresh and (due is None or not self.line.jump(due)):
                self.health.warn("unexplained_epochs", f"{topic}: reading of epoch {obs.epoch} is more than "
                                 f"{self.buffer.reach} epochs ahead of epoch {self.epoch}: not buffered, no epoch "
                                 "declared lost on its word (a stray, forged or replayed message?)", now)
        else:
            self._out_of_window(topic, obs.epoch, now)
        if verdict not in ("repeat", "far"):
            self.line.off_line(obs.epoch, (sensor, action, reading), now)
        if verdict != "repeat":
            self._resync_if_due(now)
        return self._release(now)

    def rejected_observation(self, sensor: int, problem: str, now: float, *, out_of_range: bool = False
                             ) -> FilterOutput:
        """A message on sensor ``sensor``'s topic that could not be decoded (``problem``)."""
        counter = "out_of_range_observations" if out_of_range else "malformed_messages"
        self.health.reject(self.watches[sensor], counter, f"{self.topics[sensor]}: ignored {problem}", now)
        return self._result()

    def action(self, act: ActionSample, now: float) -> FilterOutput:
        """A commanded action: remembered to predict through a lost epoch and to cross-check (up
        to the next epoch: no planner of the loop commands further ahead)."""
        new = act.epoch > self._newest_command
        if self.buffer.command(act.epoch, action_of_priority(act.priority, self.model.A)):
            self._newest_command = max(self._newest_command, act.epoch)
            self.action_watch.arrived(now, new, act.epoch)
        else:
            self.action_watch.arrived(now, False)
            if self.line.fresh:
                pass  # before joining, the planner's history is expected to be out of the window
            elif act.epoch > self.buffer.next_epoch and act.epoch - self.epoch <= self.live.epoch_window:
                self.health.warn("unexplained_epochs", f"action of epoch {act.epoch} is beyond epoch "
                                 f"{self.buffer.next_epoch}, the one the filter applies next: ignored (a stray, "
                                 "forged or replayed message?)", now)
            elif act.epoch > self.buffer.next_epoch:
                self._out_of_window("action", act.epoch, now)
        return self._result()

    def rejected_action(self, problem: str, now: float) -> FilterOutput:
        self.health.reject(self.action_watch, "malformed_messages", f"ignored action: {problem}", now)
        return self._result()

    def release(self, now: float) -> FilterOutput:
        """Apply the epochs whose time-out has come (the node calls it at ``release_at``)."""
        return self._release(now)

    def watchdog(self, now: float) -> FilterOutput:
        """Re-send the last belief while no new reading answers it; the time-based re-sync rule."""
        if self.resender.due(now) and self._last is not None:
            self._out.append(self._last)
            self.resender.resending(now)
            self.health.count("resent_beliefs")
        if self._resync_if_due(now):
            return self._release(now)
        return self._result()

    def report(self, now: float) -> Report:
        return self.health.report(now, {"epoch": self.epoch, "entropy": float(SHANNON.value(self.belief)),
                                        "pending_epochs": self.buffer.pending_epochs,
                                        "started_from": self.started_from}, head=[f"epoch {self.epoch}"])

    # ----------------------------------------------------------- rules
    def _out_of_window(self, topic: str, epoch: int, now: float) -> None:
        self.health.warn("out_of_window", f"{topic}: epoch {epoch} is beyond the epoch window "
                         f"({self.live.epoch_window}) of epoch {self.epoch}: dropped (a restarted peer or a forged "
                         "message)", now)

    def _resync_if_due(self, now: float) -> bool:
        """The join, jump and re-sync rules (:class:`~.epochs.EpochLine`): act on the reading that
        completed the evidence as the next epoch; the belief is kept (joining: it is still the prior)."""
        due = self.line.resync_due(self.live.stall.warn_after, now, jump_after=self.buffer.timeout)
        if due is None:
            return False
        sensor, action, z = due.payload
        old, fresh, jump, stalled = self.epoch, self.line.fresh, self.line.jump(due), self.line.stalled_for(now)
        if fresh:
            self.line.resync(due.epoch - 1, now)
            self.started_from = f"prior at epoch {due.epoch - 1} (joined a running loop)"
            self.health.warn(None, f"joined a running loop at epoch {due.epoch}: its readings are beyond the epoch "
                             f"window of epoch {old}; the belief before epoch {due.epoch} is the prior", now)
        elif jump:
            self.line.advance(due.epoch - 1, now)
            lost = due.epoch - 1 - old
            self.health.warn("gaps", f"epochs {old + 1}..{due.epoch - 1} lost ({lost}, no reading applied for "
                             f"{stalled:.1f} s while the readings went on from epoch {due.epoch - 1}): belief held",
                             now, n=lost)
        else:
            self.line.resync(due.epoch - 1, now)
            self.health.warn("resyncs", f"re-synced from epoch {old} to epoch {due.epoch}: nothing applied for "
                             f"{stalled:.1f} s while readings counted up to epoch {due.epoch} on another numbering "
                             "(a restarted simulator?); belief kept", now)
        self.epoch = due.epoch - 1
        self.buffer.reset(due.epoch)
        self.buffer.add(sensor, due.epoch, action, z, now)
        return True

    def _release(self, now: float) -> FilterOutput:
        gaps: list[EpochReadings] = []
        for entry in self.buffer.pop_ready(now):
            if entry.gap:
                gaps.append(entry)
                self._apply(entry, now)
                continue
            if gaps:
                self._report_gaps(gaps, now)
                gaps = []
            if self._apply(entry, now):
                self._publish(now)
        if gaps:
            self._report_gaps(gaps, now)
        return self._result()

    def _report_gaps(self, gaps: list[EpochReadings], now: float) -> None:
        """A run of lost epochs: one log line, one belief (its last epoch's)."""
        first, last = gaps[0], gaps[-1]
        predicted = sum(e.action_to_apply is not None for e in gaps)
        if len(gaps) == 1:
            action = first.action_to_apply
            text = f"epoch {first.epoch} lost (no reading); " + (
                "action unknown, belief held" if action is None else
                f"predicting with the commanded priority {priority_of(action)}")
        else:
            text = (f"epochs {first.epoch}..{last.epoch} lost ({len(gaps)}, no reading): predicted with the "
                    f"commanded action for {predicted}, held for {len(gaps) - predicted}")
        self.health.warn("gaps", text, now, n=len(gaps))
        self._publish(now)

    def _apply(self, entry: EpochReadings, now: float) -> bool:
        """Apply one released epoch with the core filter; False if the result was not a belief."""
        action = entry.action_to_apply
        if not entry.gap:
            if entry.mismatch:
                # informational: expected in the simulator's timer mode, which numbers epochs itself
                self.health.count("action_mismatches")
                self.health.log("debug", f"epoch {entry.epoch}: observations taken under priority "
                                f"{priority_of(entry.action)}, commanded {priority_of(entry.commanded)}; "
                                f"using {priority_of(entry.action)}")
            if not entry.complete:
                missing = [t for k, t in enumerate(self.topics) if k not in entry.readings]
                self.health.warn("incomplete_epochs", f"epoch {entry.epoch}: no reading from {missing}; "
                                 "applying the others", now)
        self.epoch = entry.epoch
        self.line.advance(entry.epoch, now)
        try:
            step = self.filter.step(self.belief, action, entry.readings)
        except BeliefError as exc:
            self.health.warn("bad_beliefs", f"epoch {entry.epoch}: {exc}; not published", now)
            return False
        for k in step.restarted:
            self.health.warn("impossible_observations", f"epoch {entry.epoch}: {self._reading(k, entry)} impossible "
                             "under the belief; filter restarted from the uniform prior with this epoch's readings",
                             now)
        for k in step.dropped:
            self.health.warn("contradicting_observations", f"epoch {entry.epoch}: {self._reading(k, entry)} "
                             f"impossible from every state under priority {priority_of(action)}: contradicts the "
                             "model; reading dropped", now)
        self.belief = step.belief
        return True

    def _reading(self, sensor: int, entry: EpochReadings) -> str:
        """A reading as a log line names it: ``<topic> observation <z>`` or ``<topic> likelihood``."""
        topic = self.topics[sensor]
        return f"{topic} likelihood" if self.filter.soft(sensor) else f"{topic} observation {entry.readings[sensor]}"

    def _publish(self, now: float) -> None:
        self._last = BeliefOut(self.epoch, self.belief, float(SHANNON.value(self.belief)))
        self._out.append(self._last)
        self.resender.published(now)

    def _result(self) -> FilterOutput:
        out, self._out = self._out, []
        return FilterOutput(out, self.health.drain_logs(), self.buffer.next_deadline())
