"""The simulated target's loop: the hidden state of a model, stepped by the planner's actions
(rules: docs/ros.md, "The loop's rules"; node: ``nodes/target_simulator.py``).

Each step of epoch ``t`` under priority ``p`` (action ``a = p - 1``) moves the state
``s ~ P[a, s, :]`` and draws one reading per sensor ``z_k ~ O_k[a, s, :]``; the readings carry the
epoch and the priority actually applied, so the filter pairs them without relying on timing.
Stepping on actions, the target steps the action of the epoch it steps next, and no other: an
action further ahead is one no planner of this loop can have sent (rule "Explained epochs");
timer-driven, the node calls :meth:`TargetLoop.tick` every period and an action of an epoch up to
the next one only sets the priority of the next ticks. A (re)started target joins the loop's
numbering first (rule "Join"; rules: docs/ros.md, "The loop's rules").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..checks import check_int
from ..model import POMDP, action_of_priority
from ..sparse import sample_choice
from .epochs import DEFAULT_JOIN_TIMEOUT, EpochLine, JoinWait, Liveness, Resender
from .health import InputWatch, Log, LoopHealth, Report
from .samples import ActionSample

COUNTERS = ("steps", "stale_actions", "malformed_actions", "out_of_window", "resyncs", "resent_observations")
#: Counts that make the report WARN when they grew since the previous one.
PROBLEMS = ("malformed_actions", "out_of_window", "resyncs")


@dataclass(frozen=True)
class Readings:
    """The readings of one epoch, one per sensor, taken under ``priority``."""

    epoch: int
    priority: int
    observations: tuple[int, ...]


@dataclass
class TargetOutput:
    """What one call of the loop asks the node to do: publish ``readings`` (each on every sensor's
    topic) and ``true_states`` (``(epoch, state)``), log ``logs``, and call
    :meth:`TargetLoop.join_due` at ``join_at`` (``None``: no join pending)."""

    readings: list[Readings] = field(default_factory=list)
    true_states: list[tuple[int, int]] = field(default_factory=list)
    logs: list[Log] = field(default_factory=list)
    join_at: float | None = None


class TargetLoop:
    """The target of ``model`` with one observation array per sensor (``sensors``, named ``topics``).

    ``initial_state``: 0-based, or ``-1`` to draw it from ``initial`` (a distribution over the
    states; uniform if not given) with the seeded generator, before any step. ``step_period > 0``:
    timer-driven, the node calls :meth:`tick` every ``step_period`` seconds (``default_priority``
    until an action comes). ``outputs_ready=False``: no step until :meth:`outputs_matched` (the
    node's ``min_subscribers``).
    """

    def __init__(self, model: POMDP, sensors: Sequence[np.ndarray], topics: Sequence[str], live: Liveness, *,
                 now: float, seed: int = 0,
                 initial_state: int = -1, initial: np.ndarray | None = None, step_period: float = 0.0,
                 default_priority: int = 1, join_timeout: float = DEFAULT_JOIN_TIMEOUT, outputs_ready: bool = True):
        self.model = model
        self.sensors = list(sensors)
        self.topics = list(topics)
        self.live = live
        self.rng = np.random.default_rng(seed)
        initial_state = check_int(initial_state, "initial_state", -1, model.S - 1)
        self.last_priority = check_int(default_priority, "default_priority", 1, model.A)
        if initial_state < 0:
            p = np.full(model.S, 1.0 / model.S) if initial is None else initial
            initial_state = int(self.rng.choice(model.S, p=p))
        self.state = initial_state
        self.epoch = 0
        self.step_period = step_period
        self.timer_mode = step_period > 0
        self.outputs_ready = outputs_ready
        self.joined = False
        self.joined_at = "not yet"
        self._started = now
        self._join_timeout = join_timeout
        self._join = JoinWait()
        self.held: ActionSample | None = None  # newest action seen before joining
        self._newest_action = -1
        self.line = EpochLine(live.epoch_window, now=now)
        self.watch = InputWatch("action", "action", started=now)
        self.health = LoopHealth(COUNTERS, PROBLEMS, [self.watch], live.stall,
                                 streams=("belief",) if self.timer_mode else ())
        self.resender = Resender(0.0 if self.timer_mode else live.resend_period)
        self._last: Readings | None = None
        self._out = TargetOutput()

    # ----------------------------------------------------------- inputs
    def start(self, now: float) -> TargetOutput:
        """The initial state, published as epoch 0."""
        self._out.true_states.append((0, self.state))
        mode = f"timer mode, step every {self.step_period:g} s" if self.timer_mode else "stepping on each new action"
        self.health.log("info", f"{self.model.describe()}; initial state {self.state}; sensors {self.topics}; {mode}")
        return self._result(now)

    def action(self, act: ActionSample, now: float) -> TargetOutput:
        """One decoded action (rules "Join" and "Epoch window")."""
        if not self.joined:
            if self.held is None or act.epoch > self.held.epoch:
                self.held = act
                self.last_priority = act.priority
            self._join.note(act.epoch - 1, now)
            return self.join_due(now)
        verdict = self.line.classify(act.epoch)
        if self.timer_mode:  # the target is the clock: an action only sets the priority of the next ticks
            if verdict == "out_of_window":
                self.watch.arrived(now, False)
                self._out_of_window(act.epoch, now)
            elif act.epoch > self.epoch + 1:
                self.watch.arrived(now, False)
                self._unexplained(act.epoch, now)
            else:
                new = act.epoch > self._newest_action
                self.watch.arrived(now, new, act.epoch)
                if new:
                    self._newest_action = act.epoch
                    self.last_priority = act.priority
            return self._result(now)
        if verdict == "next":
            self.watch.arrived(now, True, act.epoch)
            self.resender.answered()
            self._step(act.epoch, act.priority, now)
            return self._result(now)
        self.watch.arrived(now, False)
        if verdict == "out_of_window":
            self._out_of_window(act.epoch, now)
        elif verdict == "ahead":
            self._unexplained(act.epoch, now)
        else:
            self.health.count("stale_actions")
            self.health.log("debug", f"ignored action of epoch {act.epoch} (already at epoch {self.epoch})")
        if verdict != "repeat":
            self.line.off_line(act.epoch, act, now)
            self._resync_if_due(now)
        return self._result(now)

    def rejected_action(self, problem: str, now: float) -> TargetOutput:
        self.health.reject(self.watch, "malformed_actions", f"ignored action: {problem}", now)
        return self._result(now)

    def belief_epoch(self, epoch: int, now: float) -> TargetOutput:
        """The loop's epoch seen on ``belief`` (timer-driven: evidence for the join)."""
        if not self.joined:
            self._join.note(epoch, now)
        return self._result(now)

    def outputs_matched(self, now: float) -> TargetOutput:
        """The node's outputs have their subscribers: stepping may start."""
        self.outputs_ready = True
        self.health.log("info", "observation subscribers matched; stepping")
        return self.join_due(now)

    def join_due(self, now: float) -> TargetOutput:
        """Join once the evidence has settled and the outputs are ready (rule "Join")."""
        self._try_join(now)
        return self._result(now)

    def tick(self, now: float) -> TargetOutput:
        """Timer-driven: one step with the latest priority (once joined)."""
        self._try_join(now)
        if self.joined:
            self._step(self.epoch + 1, self.last_priority, now)
        return self._result(now)

    def watchdog(self, now: float) -> TargetOutput:
        """Stepping on actions: re-send the last readings while no new action comes; re-sync."""
        if not self.joined:
            return self.join_due(now)
        if self.resender.due(now) and self._last is not None:
            self._out.readings.append(self._last)
            self.resender.resending(now)
            self.health.count("resent_observations")
        if not self.timer_mode:
            self._resync_if_due(now)
        return self._result(now)

    def report(self, now: float) -> Report:
        note = f"; stepping with priority {self.last_priority}" if self.timer_mode else ""
        return self.health.report(now, {"epoch": self.epoch, "true_state": self.state, "joined_at": self.joined_at},
                                  head=[f"epoch {self.epoch}" + ("" if self.joined else " (not joined yet)")],
                                  stall_note=note)

    # ----------------------------------------------------------- rules
    def _try_join(self, now: float) -> None:
        if self.joined or not self.outputs_ready:
            return
        if self._join.settled(now):
            position, how = self._join.newest, "the newest epoch of the loop it received"
        elif self.timer_mode and now - self._started >= self._join_timeout:
            position, how = 0, f"nothing received within join_timeout ({self._join_timeout:g} s): numbering on its own"
        else:
            return
        if not self.timer_mode and self.held is None:
            return  # stepping on actions: the join is the newest action
        self.joined = True
        self.epoch = position
        self.line.advance(position, now)
        self.joined_at = f"epoch {position}"
        if position > 0:
            self._out.true_states.append((position, self.state))
        self.health.log("info", f"joined the loop at epoch {position} ({how}); next step: epoch {position + 1}")
        held, self.held = self.held, None
        if held is not None and self.timer_mode:
            self._newest_action = held.epoch
        if held is not None and not self.timer_mode and held.epoch == position + 1:
            self.watch.arrived(now, True, held.epoch)
            self._step(held.epoch, held.priority, now)

    def _unexplained(self, epoch: int, now: float) -> None:
        """An action beyond the epoch the target steps next: no planner of this loop can have sent it
        (its actions answer beliefs of epochs the target has stepped)."""
        self.health.warn("unexplained_epochs", f"action of epoch {epoch} is beyond epoch {self.epoch + 1}, the one "
                         "the simulator steps next: dropped (a stray, forged or replayed message?)", now)

    def _out_of_window(self, epoch: int, now: float) -> None:
        self.health.warn("out_of_window", f"action of epoch {epoch} is beyond the epoch window "
                         f"({self.live.epoch_window}) of epoch {self.epoch}: dropped (a restarted planner or a "
                         "forged message)", now)

    def _resync_if_due(self, now: float) -> None:
        """Stepping on actions: the re-sync rule (:class:`~.epochs.EpochLine`) steps the newest off-line action."""
        due = self.line.resync_due(self.live.stall.warn_after, now)
        if due is None:
            return
        self.health.warn("resyncs", self.line.resync_reason(due, "actions", "planner", now), now)
        self.line.resync(due.epoch - 1, now)
        self.epoch = due.epoch - 1
        self._step(due.epoch, due.payload.priority, now)

    def _step(self, epoch: int, priority: int, now: float) -> None:
        """Simulate epoch ``epoch`` under ``priority``: transition, one reading per sensor."""
        a = action_of_priority(priority, self.model.A)
        m = self.model
        self.state = sample_choice(self.rng, m.P_csr if m.sparse else m.P, a, self.state)
        self.epoch = epoch
        self.last_priority = priority
        self.line.advance(epoch, now)
        self.health.count("steps")
        self._last = Readings(epoch, priority, tuple(sample_choice(self.rng, O, a, self.state)
                                                     for O in self.sensors))
        self._out.readings.append(self._last)
        self._out.true_states.append((epoch, self.state))
        self.resender.published(now)

    def _result(self, now: float) -> TargetOutput:
        out, self._out = self._out, TargetOutput()
        out.logs = self.health.drain_logs()
        out.join_at = None if self.joined else self._join.wake_at(now)
        return out
