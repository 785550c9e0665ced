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
  told us, otherwise held; an epoch missing some sensors is applied with the readings it has
  after ``epoch_timeout``;
* a belief that fails the core's simplex check is never published (defensive; cannot arise
  from valid readings), the previous one is kept.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray

from ..core.belief import BeliefError
from ..core.epoch_buffer import EpochBuffer, EpochReadings
from ..core.filter import EpochFilter
from ..core.io.sensors import initial_distribution, load_model_file, load_observation_models
from ..core.model import action_of_priority, priority_of
from ..core.uncertainty import SHANNON
from .diagnostics import status
from .messages import MessageError, OutOfRangeError, decode_action, decode_observation, encode_belief
from .params import declare_model_file, declare_optional_array, descriptor, optional_array
from .qos import LATCHED_QOS, STREAM_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for


class BeliefFilter(Node):
    """Belief filter node (see module docstring)."""

    def __init__(self, node_name: str = "belief_filter", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
        model_file = declare_model_file(self)
        self.declare_parameter("observation_topics", ["observation"], d(
            "Observation topics, one per sensor, each [epoch, action_priority, observation]", read_only=True))
        declare_optional_array(self, "observation_model_files", "string",
                               "Per-sensor model file whose O is used ('' = the model's own)")
        declare_optional_array(self, "initial_distribution", "double",
                               "Prior belief (S probabilities); unset = model start or uniform")
        self.declare_parameter("epoch_timeout", 0.5, d(
            "Seconds to wait for missing sensor readings (or a lost epoch) before going on",
            float_range=(0.001, 60.0)))
        self.declare_parameter("max_pending_epochs", 10, d(
            "Later epochs buffered before a missing one is given up", int_range=(1, 10000)))
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
        self.buffer = EpochBuffer(len(self.topics), next_epoch=1,
                                  timeout=self.get_parameter("epoch_timeout").value,
                                  max_pending=self.get_parameter("max_pending_epochs").value)
        self.counts = {k: 0 for k in (
            "readings", "impossible_observations", "contradicting_observations", "out_of_range_observations",
            "malformed_messages", "duplicates", "conflicts", "gaps", "incomplete_epochs", "action_mismatches",
            "bad_beliefs")}
        self.last_warning = ""
        self._reported_problems = 0

        self.belief_pub = self.create_publisher(Float64MultiArray, "belief", STREAM_QOS)
        self.entropy_pub = self.create_publisher(Float64, "belief_entropy", LATCHED_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        for k, topic in enumerate(self.topics):
            self.create_subscription(Int64MultiArray, topic, lambda msg, k=k: self._on_observation(k, msg),
                                     STREAM_QOS)
        self.create_subscription(Int64MultiArray, "action", self._on_action, STREAM_QOS)
        self.create_timer(0.02, self._release)
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
        self.counts[counter] += 1
        self.last_warning = text
        self.get_logger().warning(text)

    @callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        try:
            act = decode_action(msg, self.model.A)
        except MessageError as exc:
            self._warn("malformed_messages", f"ignored action: {exc}")
            return
        self.buffer.command(act.epoch, action_of_priority(act.priority, self.model.A))

    @callback
    def _on_observation(self, sensor: int, msg: Int64MultiArray) -> None:
        Z = self.filter.num_observations(sensor)
        try:
            obs = decode_observation(msg, self.model.A, Z)
        except MessageError as exc:
            counter = "out_of_range_observations" if isinstance(exc, OutOfRangeError) else "malformed_messages"
            self._warn(counter, f"{self.topics[sensor]}: ignored {exc}")
            return
        self.counts["readings"] += 1
        result = self.buffer.add(sensor, obs.epoch, action_of_priority(obs.priority, self.model.A),
                                 obs.observation)
        if result == "duplicate":
            self.counts["duplicates"] += 1
        elif result == "conflict":
            self._warn("conflicts", f"{self.topics[sensor]}: reading of epoch {obs.epoch} conflicts with an "
                                    "earlier one (different action or observation); dropped")
        self._release()

    # ----------------------------------------------------------- filtering
    @callback
    def _release(self) -> None:
        for entry in self.buffer.pop_ready():
            self._apply_epoch(entry)

    def _apply_epoch(self, entry: EpochReadings) -> None:
        action = entry.action_to_apply
        if entry.gap:
            self._warn("gaps", f"epoch {entry.epoch} lost (no reading); " + (
                "action unknown, belief held" if action is None else
                f"predicting with the commanded priority {priority_of(action)}"))
        else:
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
        try:
            step = self.filter.step(self.belief, action, entry.readings)
        except BeliefError as exc:
            self._warn("bad_beliefs", f"epoch {entry.epoch}: {exc}; not published")
            self.epoch = entry.epoch
            return
        for k in step.restarted:
            self._warn("impossible_observations",
                       f"epoch {entry.epoch}: {self.topics[k]} observation {entry.readings[k]} impossible under "
                       "the belief; filter restarted from the uniform prior with this epoch's readings")
        for k in step.dropped:
            self._warn("contradicting_observations",
                       f"epoch {entry.epoch}: {self.topics[k]} observation {entry.readings[k]} impossible from "
                       f"every state under priority {priority_of(action)}: contradicts the model; reading dropped")
        self.belief = step.belief
        self.epoch = entry.epoch
        self._publish()

    def _publish(self) -> None:
        self.belief_pub.publish(encode_belief(self.epoch, self.belief))
        self.entropy_pub.publish(Float64(data=float(SHANNON.value(self.belief))))

    @callback
    def _publish_diagnostics(self) -> None:
        problems = sum(v for k, v in self.counts.items() if k not in ("readings", "duplicates", "action_mismatches"))
        recent, self._reported_problems = problems - self._reported_problems, problems
        # WARN while problems keep coming (since the previous report), OK again once they stop
        level = DiagnosticStatus.WARN if recent else DiagnosticStatus.OK
        text = f"epoch {self.epoch}" + (f"; {recent} problem(s) since the last report, last: {self.last_warning}"
                                        if recent else "")
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status(
            f"{self.get_name()}: belief", self.model.name, level, text,
            {"epoch": self.epoch, "entropy": float(SHANNON.value(self.belief)),
             "pending_epochs": self.buffer.pending_epochs, **self.counts})]
        self.diag_pub.publish(msg)


def main(args=None) -> None:
    main_for([BeliefFilter])


if __name__ == "__main__":
    main()
