"""``belief_filter``: the Bayes filter of the paper (Eqs. 1-2) fed by observation topics.

Topics (relative names, remappable):

* subscribes each topic of ``observation_topics`` (``Int64MultiArray [epoch, action_priority,
  observation]``) and ``action`` (``[epoch, action_priority]``, only to cross-check), all with
  ``STREAM_QOS`` (every sample);
* publishes ``belief`` (``Float64MultiArray``, layout ``[("state", S), ("epoch=<t>", 1)]``;
  ``STREAM_QOS``: transient-local, so a late planner still gets the newest belief and a
  recorder every one), ``belief_entropy`` (``Float64``, Shannon entropy in nats of the same
  belief; latched, depth 1) and ``/diagnostics`` about once a second.

Pairing by design: an observation is applied with the action *it carries* (the action the
simulator or sensor was under), never with "the last action seen", and epochs are applied in
order (``core.epoch_buffer.EpochBuffer``: out-of-order readings wait, duplicates are dropped,
gaps are reported). Each released epoch goes to the core's epoch filter
(``core.filter.EpochFilter``, the one ``simulate`` uses): prediction once with the carried
action (Eq. 1), then one update (Eq. 2) per sensor reading of that epoch with that sensor's
observation model, its recovery rule and its gap rule. The belief of epoch ``t`` is published
after epoch ``t`` is applied; the prior is epoch 0. This node only decodes, calls the core,
encodes, and counts.

Recovery and bad input (each logged and counted in diagnostics; the node keeps running):

* impossible reading (``eta = 0`` under the belief): the filter restarts from the uniform prior
  pushed through the epoch's transition and applies the reading (``impossible_observations``);
  a reading impossible even then contradicts the model and is dropped
  (``contradicting_observations``); the rule and its reasons: ``core/filter.py``;
* out-of-range observation or action, wrong length or label: message dropped;
* a lost epoch (gap): predicted with the commanded action of that epoch if the ``action`` topic
  told us, otherwise held; a run of lost epochs is one log line and one published belief (that
  of its last epoch); an epoch missing some sensors is applied with the readings it has after
  ``epoch_timeout`` (released by a one-shot timer armed for the buffer's next deadline, not by
  polling);
* a belief that fails the core's simplex check is never published (defensive; cannot arise
  from valid readings), the previous one is kept.

Liveness (``core/liveness.py``; README, "Liveness"): readings beyond ``epoch_window`` of the
filter's epoch are dropped and counted (``out_of_window``), never walked; a filter that has
applied no reading yet *joins* a running loop on two consecutive such readings (the belief
before the epoch it joins at is the prior: said in its log and in the diagnostics'
``started_from``); a stalled filter re-syncs to a simulator that counts on a numbering of its
own (a restarted one). The belief of the filter's epoch is re-published every
``resend_period`` while no new reading comes. Each observation topic (and ``action``, once
it has delivered) is watched: no new reading for ``stall_warn_after`` / ``stall_error_after``
seconds is WARN / ERROR, saying which topic and since when.
"""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray

from ..core.belief import BeliefError
from ..core.epoch_buffer import EpochBuffer, EpochReadings
from ..core.filter import EpochFilter
from ..core.io.sensors import initial_distribution, load_model_file, load_observation_models
from ..core.liveness import EpochLine, InputWatch, Level, Resender, worst
from ..core.model import action_of_priority, priority_of
from ..core.uncertainty import SHANNON
from .diagnostics import Warnings, array, status
from .messages import MessageError, OutOfRangeError, decode_action, decode_observation, encode_belief
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
PROBLEMS = ("impossible_observations", "contradicting_observations", "out_of_range_observations",
            "malformed_messages", "conflicts", "gaps", "incomplete_epochs", "bad_beliefs", "out_of_window",
            "resyncs")


class BeliefFilter(ParameterNode):
    """Belief filter node (see module docstring)."""

    def __init__(self, node_name: str = "belief_filter", **kwargs):
        super().__init__(node_name, **kwargs)
        accept_integers_for_doubles(self)
        d = descriptor
        model_file = declare_model_file(self)
        self.declare_parameter("observation_topics", ["observation"], d(
            "Observation topics, one per sensor, each [epoch, action_priority, observation]", read_only=True))
        declare_optional_array(self, "observation_model_files", "string",
                               "Per-sensor model file whose O is used ('' = the model's own)")
        declare_optional_array(self, "initial_distribution", "double",
                               "Prior belief (S probabilities); unset = model start or uniform")
        declare_double(self, "epoch_timeout", 0.5, d(
            "Seconds to wait for missing sensor readings (or a lost epoch) before going on",
            float_range=(0.001, 60.0)))
        self.declare_parameter("max_pending_epochs", 10, d(
            "Later epochs buffered before a missing one is given up", int_range=(1, 10000)))
        self.live = declare_liveness(self)
        # ranges and types: the descriptors (nothing else to validate); side effects after a set
        self.add_post_set_parameters_callback(self._apply_parameters)

        self.topics = list(self.get_parameter("observation_topics").value)
        if not self.topics or len(set(self.topics)) != len(self.topics):
            raise NodeConfigError(f"observation_topics: need distinct topics, got {self.topics}")
        with config_errors():
            self.model = load_model_file(model_file)
            sensors = load_observation_models(self.model, optional_array(self, "observation_model_files"),
                                              len(self.topics))
            self.filter = EpochFilter(self.model, sensors)
            self.belief = initial_distribution(self.model, optional_array(self, "initial_distribution"))
        self.epoch = 0
        window = self.live.epoch_window
        self.line = EpochLine(window, position=0, counting=True)
        self.buffer = EpochBuffer(len(self.topics), next_epoch=1,
                                  timeout=self.get_parameter("epoch_timeout").value,
                                  max_pending=self.get_parameter("max_pending_epochs").value, window=window)
        self.started_from = "prior at epoch 0"
        self.counts = {k: 0 for k in (
            "readings", "impossible_observations", "contradicting_observations", "out_of_range_observations",
            "malformed_messages", "duplicates", "conflicts", "gaps", "incomplete_epochs", "action_mismatches",
            "bad_beliefs", "out_of_window", "resyncs", "resent_beliefs")}
        self.warnings = Warnings(self.get_logger(), self.counts)
        self._reported_problems = 0
        self.watches = [InputWatch(t, "reading") for t in self.topics]
        self.action_watch = InputWatch("action", "action", required=False)
        self._newest_command = -1
        self.resender = Resender(self.live.resend_period)
        self._last_msg: Float64MultiArray | None = None

        self.belief_pub = self.create_publisher(Float64MultiArray, "belief", STREAM_QOS)
        self.entropy_pub = self.create_publisher(Float64, "belief_entropy", LATCHED_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        for k, topic in enumerate(self.topics):
            self.create_subscription(Int64MultiArray, topic, lambda msg, k=k: self._on_observation(k, msg),
                                     STREAM_QOS)
        self.create_subscription(Int64MultiArray, "action", self._on_action, STREAM_QOS)
        # one-shot: armed for the buffer's next time-out deadline only while an epoch waits for one
        self._release_timer = self.create_timer(1.0, self._on_release_timer, autostart=False)
        self.create_timer(self.live.watchdog_period, self._watchdog)
        self.create_timer(1.0, self._publish_diagnostics)
        self._publish()
        self.get_logger().info(f"{self.model.describe()}; sensors {self.topics}; prior published as epoch 0")

    # ----------------------------------------------------------- parameters
    def _apply_parameters(self, params) -> None:
        for p in params:
            if p.name == "epoch_timeout":
                self.buffer.timeout = p.value
            elif p.name == "max_pending_epochs":
                self.buffer.max_pending = p.value

    # ----------------------------------------------------------- input
    def _warn(self, counter: str, text: str) -> None:
        """Count, keep for diagnostics, log (at most one line per kind every 10 s)."""
        self.warnings.warn(counter, text)

    @property
    def last_warning(self) -> str:
        return self.warnings.last

    @callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        try:
            act = decode_action(msg, self.model.A)
        except MessageError as exc:
            self.action_watch.arrived(False)
            self._warn("malformed_messages", f"ignored action: {exc}")
            return
        new = act.epoch > self._newest_command
        if self.buffer.command(act.epoch, action_of_priority(act.priority, self.model.A)):
            self._newest_command = max(self._newest_command, act.epoch)
            self.action_watch.arrived(new, act.epoch)
            return
        self.action_watch.arrived(False)
        if not self.line.fresh:  # before joining, the planner's history is expected to be out of the window
            self._out_of_window("action", act.epoch)

    @callback
    def _on_observation(self, sensor: int, msg: Int64MultiArray) -> None:
        Z = self.filter.num_observations(sensor)
        try:
            obs = decode_observation(msg, self.model.A, Z)
        except MessageError as exc:
            self.watches[sensor].arrived(False)
            counter = "out_of_range_observations" if isinstance(exc, OutOfRangeError) else "malformed_messages"
            self._warn(counter, f"{self.topics[sensor]}: ignored {exc}")
            return
        self.counts["readings"] += 1
        self._take(sensor, obs.epoch, action_of_priority(obs.priority, self.model.A), obs.observation)
        self._release()

    def _take(self, sensor: int, epoch: int, action: int, z: int) -> None:
        """One decoded reading: buffer it if it is within the window ahead, else count it (and keep it
        as evidence for the join / re-sync rule)."""
        verdict = self.line.classify(epoch)
        watch = self.watches[sensor]
        if verdict in ("next", "ahead"):
            result = self.buffer.add(sensor, epoch, action, z)
            watch.arrived(result == "buffered", epoch)
            if result == "buffered":
                self.resender.answered()
            elif result == "duplicate":
                self.counts["duplicates"] += 1
            elif result == "conflict":
                self._warn("conflicts", f"{self.topics[sensor]}: reading of epoch {epoch} conflicts with an "
                                        "earlier one (different action or observation); dropped")
            return
        watch.arrived(False)
        if verdict in ("repeat", "behind"):  # an epoch already applied: a re-send, or stale
            self.counts["duplicates"] += 1
        else:
            self._out_of_window(self.topics[sensor], epoch)
        if verdict != "repeat":
            self.line.off_line(epoch, (sensor, action, z))
            self._resync_if_due()  # _on_observation releases what it buffered

    def _out_of_window(self, topic: str, epoch: int) -> None:
        self._warn("out_of_window", f"{topic}: epoch {epoch} is beyond the epoch window ({self.live.epoch_window}) "
                                    f"of epoch {self.epoch}: dropped (a restarted peer or a forged message)")

    def _resync_if_due(self) -> bool:
        """The join / re-sync rule (``core.liveness.EpochLine``): act on the reading that completed
        the evidence as the next epoch; the belief is kept (joining: it is still the prior)."""
        due = self.line.resync_due(self.live.stall.warn_after)
        if due is None:
            return False
        sensor, action, z = due.payload
        old, fresh, stalled = self.epoch, self.line.fresh, self.line.stalled_for()
        self.line.resync(due.epoch - 1)
        self.epoch = due.epoch - 1
        self.buffer.reset(due.epoch)
        if fresh:
            self.started_from = f"prior at epoch {due.epoch - 1} (joined a running loop)"
            self.warnings.warn(None, f"joined a running loop at epoch {due.epoch}: its readings are beyond the "
                                     f"epoch window of epoch {old}; the belief before epoch {due.epoch} is the prior")
        else:
            self._warn("resyncs", f"re-synced from epoch {old} to epoch {due.epoch}: nothing applied for "
                                  f"{stalled:.1f} s while readings counted up to epoch {due.epoch} on another "
                                  "numbering (a restarted simulator?); belief kept")
        self.buffer.add(sensor, due.epoch, action, z)
        return True

    # ----------------------------------------------------------- filtering
    def _release(self) -> None:
        gaps: list[EpochReadings] = []
        for entry in self.buffer.pop_ready():
            if entry.gap:
                gaps.append(entry)
                self._apply_epoch(entry)
                continue
            if gaps:
                self._report_gaps(gaps)
                gaps = []
            if self._apply_epoch(entry):
                self._publish()
        if gaps:
            self._report_gaps(gaps)
        self._arm_release_timer()

    def _arm_release_timer(self) -> None:
        deadline = self.buffer.next_deadline()
        if deadline is None:
            self._release_timer.cancel()
            return
        self._release_timer.timer_period_ns = int(max(deadline - time.monotonic(), 0.001) * 1e9)
        self._release_timer.reset()

    @callback
    def _on_release_timer(self) -> None:
        self._release_timer.cancel()
        self._release()

    def _report_gaps(self, gaps: list[EpochReadings]) -> None:
        """A run of lost epochs: one log line, one belief (its last epoch's)."""
        first, last = gaps[0], gaps[-1]
        predicted = sum(e.action_to_apply is not None for e in gaps)
        self.counts["gaps"] += len(gaps) - 1  # _warn counts the last one
        if len(gaps) == 1:
            action = first.action_to_apply
            text = f"epoch {first.epoch} lost (no reading); " + (
                "action unknown, belief held" if action is None else
                f"predicting with the commanded priority {priority_of(action)}")
        else:
            text = (f"epochs {first.epoch}..{last.epoch} lost ({len(gaps)}, no reading): predicted with the "
                    f"commanded action for {predicted}, held for {len(gaps) - predicted}")
        self._warn("gaps", text)
        self._publish()

    def _apply_epoch(self, entry: EpochReadings) -> bool:
        """Apply one released epoch with the core filter; False if the result was not a belief."""
        action = entry.action_to_apply
        if not entry.gap:
            if entry.mismatch:
                # informational: expected in the simulator's timer mode, which numbers epochs itself
                self.counts["action_mismatches"] += 1
                self.get_logger().debug(f"epoch {entry.epoch}: observations taken under priority "
                                        f"{priority_of(entry.action)}, commanded {priority_of(entry.commanded)}; "
                                        f"using {priority_of(entry.action)}")
            if not entry.complete:
                missing = [self.topics[k] for k in range(len(self.topics)) if k not in entry.readings]
                self._warn("incomplete_epochs", f"epoch {entry.epoch}: no reading from {missing}; "
                                                "applying the others")
        self.epoch = entry.epoch
        self.line.advance(entry.epoch)
        try:
            step = self.filter.step(self.belief, action, entry.readings)
        except BeliefError as exc:
            self._warn("bad_beliefs", f"epoch {entry.epoch}: {exc}; not published")
            return False
        for k in step.restarted:
            self._warn("impossible_observations",
                       f"epoch {entry.epoch}: {self.topics[k]} observation {entry.readings[k]} impossible under "
                       "the belief; filter restarted from the uniform prior with this epoch's readings")
        for k in step.dropped:
            self._warn("contradicting_observations",
                       f"epoch {entry.epoch}: {self.topics[k]} observation {entry.readings[k]} impossible from "
                       f"every state under priority {priority_of(action)}: contradicts the model; reading dropped")
        self.belief = step.belief
        return True

    def _publish(self) -> None:
        self._last_msg = encode_belief(self.epoch, self.belief)
        self.belief_pub.publish(self._last_msg)
        self.entropy_pub.publish(Float64(data=float(SHANNON.value(self.belief))))
        self.resender.published()

    # ----------------------------------------------------------- liveness
    @callback
    def _watchdog(self) -> None:
        """Re-send the last belief while no new reading answers it; the time-based re-sync rule."""
        if self.resender.due() and self._last_msg is not None:
            self.belief_pub.publish(self._last_msg)
            self.resender.resending()
            self.counts["resent_beliefs"] += 1
        if self._resync_if_due():
            self._release()

    def liveness(self) -> tuple[Level, str]:
        return worst([w.status(self.live.stall) for w in [*self.watches, self.action_watch]])

    @callback
    def _publish_diagnostics(self) -> None:
        problems = sum(self.counts[k] for k in PROBLEMS)
        recent, self._reported_problems = problems - self._reported_problems, problems
        # WARN while problems keep coming (since the previous report), OK again once they stop
        level, stall_text = self.liveness()
        texts = [f"epoch {self.epoch}"]
        if stall_text:
            texts.append(stall_text)
        if recent:
            level = max(level, Level.WARN)
            texts.append(f"{recent} problem(s) since the last report, last: {self.last_warning}")
        values = {"epoch": self.epoch, "entropy": float(SHANNON.value(self.belief)),
                  "pending_epochs": self.buffer.pending_epochs, "started_from": self.started_from, **self.counts}
        for w in [*self.watches, self.action_watch]:
            values.update(w.values())
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: belief", self.model.name, level,
                                                 "; ".join(texts), values)))


def main(args=None) -> None:
    main_for([BeliefFilter])


if __name__ == "__main__":
    main()
