"""``target_simulator``: the hidden state of a model, stepped by the planner's actions.

Topics (relative names, remappable):

* subscribes ``action`` (``Int64MultiArray [epoch, action_priority]``; every action: ``STREAM_QOS``)
  and, timer-driven, ``belief`` (latest only, to learn the loop's epoch when it joins);
* publishes, per configured sensor, ``observation`` (default; parameter ``observation_topics``)
  as ``Int64MultiArray [epoch, action_priority, observation]`` and ``true_state``
  (``[epoch, state]``, 0-based; epoch 0 = the initial state) for evaluation;
* ``/diagnostics`` about once a second.

Each action of a *new* epoch ``t`` (``t`` > the last simulated epoch, within ``epoch_window``;
older or repeated ones are dropped and counted) moves the state ``s ~ P[a, s, :]`` and draws one
observation per sensor ``z_k ~ O_k[a, s, :]``; the observation carries the epoch and the action
actually applied, so the belief filter pairs them without relying on timing. A jump in epochs
(an action was lost) is simulated as one step and counted as a gap.

**Joining** (``core/liveness.py``, "Join"). A (re)started simulator takes no step before it knows
the loop's epoch: it continues from the newest action it receives within ``JOIN_DELAY`` (0.2 s)
of the first one (the planner's transient-local history arrives as one burst), simulating that
action's epoch; timer-driven, from the newest of that and the latched belief's epoch, or, if
nothing comes within ``join_timeout``, from epoch 0 on its own. Its state is drawn as at any start
(``initial_state`` / ``initial_distribution`` / the model's ``start``): a restarted simulator is a
target that jumped, which the filter's recovery rule handles. Said in its log and in diagnostics
(``joined_at``).

``min_subscribers`` (default 0): no step, in either mode, until every observation topic has at
least that many matched subscriptions (e.g. 2: the belief filter and a recorder), so that they
all get every epoch from the first.

Timer mode (``step_period > 0``): the simulator is the clock. Every period it steps once with the
most recent action (``default_priority`` before any arrives), numbering epochs itself; the
observations again carry the action that was applied, so pairing stays exact.

Liveness: stepping on actions, the last observations are re-published every ``resend_period``
while no new action comes; an action beyond ``epoch_window`` is dropped and counted, and a
simulator that for ``stall_warn_after`` seconds has received only such (or stale) actions, at
least three, re-syncs to the newest (``core/liveness.py``). ``action`` silent or not
advancing for ``stall_warn_after`` / ``stall_error_after`` seconds is WARN / ERROR.
"""

from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.io.sensors import initial_distribution, load_model_file, load_observation_models
from ..core.liveness import DEFAULT_JOIN_TIMEOUT, JOIN_DELAY, EpochLine, InputWatch, Level, Resender
from ..core.model import action_of_priority
from .diagnostics import Warnings, array, status
from .messages import ActionMsg, MessageError, decode_action, decode_belief, encode_observation, encode_true_state
from .params import (
    ParameterNode,
    accept_integers_for_doubles,
    declare_double,
    declare_liveness,
    declare_model_file,
    declare_optional_array,
    descriptor,
    optional_array,
)
from .qos import LATCHED_QOS, STREAM_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for

#: Counts that make the diagnostics WARN when they grew since the previous report.
PROBLEMS = ("malformed_actions", "out_of_window", "resyncs")


class TargetSimulator(ParameterNode):
    """Simulated target: hidden Markov state, sampled observations (see module docstring)."""

    def __init__(self, node_name: str = "target_simulator", **kwargs):
        super().__init__(node_name, **kwargs)
        accept_integers_for_doubles(self)
        d = descriptor
        model_file = declare_model_file(self)
        self.declare_parameter("seed", 0, d("Random seed of the simulated target", read_only=True,
                                            int_range=(0, 2**31 - 1)))
        self.declare_parameter("initial_state", -1, d(
            "Initial 0-based state; -1 = sample from initial_distribution (or the model's start, or uniform)",
            read_only=True, int_range=(-1, 1_000_000)))
        declare_optional_array(self, "initial_distribution", "double",
                               "Initial state distribution (S probabilities); unset = model start or uniform")
        self.declare_parameter("observation_topics", ["observation"], d(
            "One topic per sensor; each publishes [epoch, action_priority, observation]", read_only=True))
        declare_optional_array(self, "observation_model_files", "string",
                               "Per-sensor model file whose observation matrix O is used ('' = the model's own)")
        declare_double(self, "step_period", 0.0, d(
            "0 = step on each new action; > 0 = step every period (s) with the latest action",
            read_only=True, float_range=(0.0, 3600.0)))
        self.declare_parameter("min_subscribers", 0, d(
            "Do not step until every observation topic has this many matched subscribers (0 = no wait)",
            read_only=True, int_range=(0, 1000)))
        self.declare_parameter("default_priority", 1, d(
            "Action used in timer mode before the first action arrives", read_only=True, int_range=(1, 1000)))
        declare_double(self, "join_timeout", DEFAULT_JOIN_TIMEOUT, d(
            "Timer mode: seconds to wait for the loop's epoch (an action or a belief) before numbering epochs "
            "from 0 on its own", read_only=True, float_range=(0.0, 3600.0)))
        self.live = declare_liveness(self)

        topics = list(self.get_parameter("observation_topics").value)
        if not topics:
            raise NodeConfigError("observation_topics: at least one topic is needed")
        with config_errors():
            self.model = m = load_model_file(model_file)
            self.sensor_O = load_observation_models(m, optional_array(self, "observation_model_files"), len(topics))
        self.rng = np.random.default_rng(self.get_parameter("seed").value)
        s0 = self.get_parameter("initial_state").value
        if s0 >= m.S:
            raise NodeConfigError(f"initial_state: {s0} out of range -1..{m.S - 1}")
        if s0 < 0:
            with config_errors():
                b0 = initial_distribution(m, optional_array(self, "initial_distribution"))
            s0 = int(self.rng.choice(m.S, p=b0))
        self.state = s0
        self.epoch = 0
        default_priority = self.get_parameter("default_priority").value
        if default_priority > m.A:
            raise NodeConfigError(f"default_priority: {default_priority} out of range 1..{m.A}")
        self.last_priority = default_priority
        self.counts = {"steps": 0, "stale_actions": 0, "malformed_actions": 0, "epoch_gaps": 0,
                       "out_of_window": 0, "resyncs": 0, "resent_observations": 0}
        self._reported_problems = 0
        self.warnings = Warnings(self.get_logger(), self.counts)

        period = self.get_parameter("step_period").value
        self.timer_mode = period > 0.0
        self.joined = False
        self.joined_at = "not yet"
        self._started = time.monotonic()
        self._join_timeout = self.get_parameter("join_timeout").value
        self._join_epoch: int | None = None       # newest epoch seen before joining (its last step)
        self._join_first_seen: float | None = None
        self._held_action: ActionMsg | None = None  # newest action seen before joining
        self._newest_action = -1
        self.line = EpochLine(self.live.epoch_window)
        self.watch = InputWatch("action", "action")
        self.resender = Resender(self.live.resend_period if not self.timer_mode else 0.0)
        self._last_observations: list[Int64MultiArray] = []

        self.obs_pubs = [self.create_publisher(Int64MultiArray, t, STREAM_QOS) for t in topics]
        self.state_pub = self.create_publisher(Int64MultiArray, "true_state", STREAM_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Int64MultiArray, "action", self._on_action, STREAM_QOS)
        if self.timer_mode:  # the loop's epoch, to join a running loop before the first tick
            self.create_subscription(Float64MultiArray, "belief", self._on_belief, LATCHED_QOS)
        self.min_subscribers = self.get_parameter("min_subscribers").value
        if self.min_subscribers > 0:
            self._wait_timer = self.create_timer(0.01, self._check_subscribers)
        self._join_timer = self.create_timer(JOIN_DELAY, self._on_join_timer, autostart=False)
        if self.timer_mode:
            self.create_timer(period, self._on_tick)
        self.create_timer(self.live.watchdog_period, self._watchdog)
        self.create_timer(1.0, self._publish_diagnostics)
        self.state_pub.publish(encode_true_state(0, self.state))
        self.get_logger().info(
            f"{m.describe()}; initial state {self.state}; sensors {topics}; "
            + (f"timer mode, step every {period:g} s" if self.timer_mode else "stepping on each new action")
        )

    def step(self, epoch: int, priority: int) -> None:
        """Simulate epoch ``epoch`` under ``priority``: transition, one reading per sensor, publish."""
        a = action_of_priority(priority, self.model.A)
        self.state = int(self.rng.choice(self.model.S, p=self.model.P[a, self.state]))
        self.epoch = epoch
        self.line.advance(epoch)
        self.counts["steps"] += 1
        self._last_observations = []
        for O, pub in zip(self.sensor_O, self.obs_pubs, strict=True):
            z = int(self.rng.choice(O.shape[2], p=O[a, self.state]))
            msg = encode_observation(epoch, priority, z)
            pub.publish(msg)
            self._last_observations.append(msg)
        self.state_pub.publish(encode_true_state(epoch, self.state))
        self.resender.published()

    # ----------------------------------------------------------- joining the loop
    def _note_join(self, epoch: int) -> None:
        """Evidence of the loop's epoch before joining: the newest wins."""
        if self._join_epoch is None or epoch > self._join_epoch:
            self._join_epoch = epoch
        if self._join_first_seen is None:
            self._join_first_seen = time.monotonic()
            self._join_timer.reset()

    def _try_join(self) -> None:
        """Join once the evidence has settled (JOIN_DELAY after the first) and the subscribers are there."""
        if self.joined or not self.subscribers_ready():
            return
        now = time.monotonic()
        if self._join_first_seen is not None and now - self._join_first_seen >= JOIN_DELAY:
            position, how = self._join_epoch, "the newest epoch of the loop it received"
        elif self.timer_mode and now - self._started >= self._join_timeout:
            position, how = 0, f"nothing received within join_timeout ({self._join_timeout:g} s): numbering on its own"
        else:
            return
        if not self.timer_mode and self._held_action is None:
            return  # stepping on actions: the join is the newest action
        self.joined = True
        self._join_timer.cancel()
        self.epoch = position
        self.line.advance(position)
        self.joined_at = f"epoch {position}"
        if position > 0:
            self.state_pub.publish(encode_true_state(position, self.state))
        self.get_logger().info(f"joined the loop at epoch {position} ({how}); next step: epoch {position + 1}")
        held, self._held_action = self._held_action, None
        if held is not None and self.timer_mode:
            self._newest_action = held.epoch
        if held is not None and not self.timer_mode and held.epoch == position + 1:
            self.watch.arrived(True, held.epoch)
            self.step(held.epoch, held.priority)

    @callback
    def _on_join_timer(self) -> None:
        self._join_timer.cancel()
        self._try_join()

    @callback
    def _on_belief(self, msg: Float64MultiArray) -> None:
        if self.joined:
            return
        try:
            bel = decode_belief(msg, self.model.S)
        except MessageError:
            return  # not this node's business: the planner counts bad beliefs
        self._note_join(bel.epoch)

    # ----------------------------------------------------------- actions
    @callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        try:
            act = decode_action(msg, self.model.A)
        except MessageError as exc:
            self.watch.arrived(False)
            self.warnings.warn("malformed_actions", f"ignored action: {exc}")
            return
        if not self.joined:
            if self._held_action is None or act.epoch > self._held_action.epoch:
                self._held_action = act
                self.last_priority = act.priority
            self._note_join(act.epoch - 1)
            self._try_join()
            return
        verdict = self.line.classify(act.epoch)
        if self.timer_mode:  # the simulator is the clock: an action only sets the priority of the next ticks
            if verdict == "out_of_window":
                self.watch.arrived(False)
                self._out_of_window(act.epoch)
                return
            new = act.epoch > self._newest_action
            self.watch.arrived(new, act.epoch)
            if new:
                self._newest_action = act.epoch
                self.last_priority = act.priority
            return
        if verdict in ("next", "ahead"):
            self.watch.arrived(True, act.epoch)
            self.resender.answered()
            self._step_action(act)
            return
        self.watch.arrived(False)
        if verdict == "out_of_window":
            self._out_of_window(act.epoch)
        else:
            self.counts["stale_actions"] += 1
            self.get_logger().debug(f"ignored action of epoch {act.epoch} (already at epoch {self.epoch})")
        if verdict != "repeat":
            self.line.off_line(act.epoch, act)
            self._resync_if_due()

    def _step_action(self, act: ActionMsg) -> None:
        if act.epoch > self.epoch + 1:
            self.warnings.warn("epoch_gaps", f"action jumps from epoch {self.epoch} to {act.epoch} (actions lost?)")
        self.last_priority = act.priority
        self.step(act.epoch, act.priority)

    def _out_of_window(self, epoch: int) -> None:
        self.warnings.warn("out_of_window", f"action of epoch {epoch} is beyond the epoch window "
                           f"({self.live.epoch_window}) of epoch {self.epoch}: dropped (a restarted planner or a "
                           "forged message)")

    def _resync_if_due(self) -> None:
        """Stepping on actions: the re-sync rule (core.liveness.EpochLine) steps the newest off-line action."""
        due = self.line.resync_due(self.live.stall.warn_after)
        if due is None:
            return
        self.warnings.warn("resyncs", self.line.resync_reason(due, "actions", "planner"))
        self.line.resync(due.epoch - 1)
        self.epoch = due.epoch - 1
        self.step(due.epoch, due.payload.priority)

    def subscribers_ready(self) -> bool:
        """Whether every observation topic has ``min_subscribers`` matched subscriptions (latched)."""
        if self.min_subscribers > 0:
            if any(p.get_subscription_count() < self.min_subscribers for p in self.obs_pubs):
                return False
            self.min_subscribers = 0
            self.get_logger().info("observation subscribers matched; stepping")
        return True

    @callback
    def _check_subscribers(self) -> None:
        if self.subscribers_ready():
            self._wait_timer.cancel()
            self._try_join()

    @callback
    def _on_tick(self) -> None:
        if not self.joined:
            self._try_join()
            if not self.joined:
                return
        self.step(self.epoch + 1, self.last_priority)

    # ----------------------------------------------------------- liveness
    @callback
    def _watchdog(self) -> None:
        """Stepping on actions: re-send the last observations while no new action comes; re-sync."""
        if not self.joined:
            self._try_join()
            return
        if self.resender.due() and self._last_observations:
            for pub, msg in zip(self.obs_pubs, self._last_observations, strict=True):
                pub.publish(msg)
            self.resender.resending()
            self.counts["resent_observations"] += 1
        if not self.timer_mode:
            self._resync_if_due()

    @callback
    def _publish_diagnostics(self) -> None:
        problems = sum(self.counts[k] for k in PROBLEMS)
        recent, self._reported_problems = problems - self._reported_problems, problems
        level, stall_text = self.watch.status(self.live.stall)
        texts = [f"epoch {self.epoch}" + ("" if self.joined else " (not joined yet)")]
        if stall_text:
            texts.append(stall_text + (f"; stepping with priority {self.last_priority}" if self.timer_mode else ""))
        if recent:
            level = max(level, Level.WARN)
            texts.append(f"{recent} problem(s) since the last report, last: {self.warnings.last}")
        values = {"epoch": self.epoch, "true_state": self.state, "joined_at": self.joined_at, **self.counts,
                  **self.watch.values()}
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: simulation", self.model.name, level,
                                                 "; ".join(texts), values)))


def main(args=None) -> None:
    main_for([TargetSimulator])


if __name__ == "__main__":
    main()
