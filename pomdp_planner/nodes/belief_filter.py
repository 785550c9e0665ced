"""``belief_filter``: the Bayes filter of the paper (Eqs. 1-2) fed by observation topics.

Topics (relative names, remappable):

* subscribes each topic of ``observation_topics`` (``Int64MultiArray [epoch, action_priority,
  observation]``) and ``action`` (``[epoch, action_priority]``, only to cross-check), all with
  ``common.STREAM_QOS`` (every sample);
* publishes ``belief`` (``Float64MultiArray``, layout ``[("state", S), ("epoch=<t>", 1)]``;
  ``common.STREAM_QOS``: transient-local, so a late planner still gets the newest belief and a
  recorder every one), ``belief_entropy`` (``Float64``, Shannon entropy in nats of the same
  belief; latched, depth 1) and ``/diagnostics`` about once a second.

Pairing by design: an observation is applied with the action *it carries* (the action the
simulator or sensor was under), never with "the last action seen", and epochs are applied in
order (``epoch_buffer.EpochBuffer``: out-of-order readings wait, duplicates are dropped, gaps
are reported). One epoch = prediction once with the carried action (Eq. 1), then one update
(Eq. 2) per sensor reading of that epoch with that sensor's observation model. The belief of
epoch ``t`` is published after epoch ``t`` is applied; the prior is epoch 0.

Recovery and bad input (each logged and counted in diagnostics; the node keeps running):

* impossible reading (``eta = 0``, core raises ``ImpossibleObservation``): the reading is
  discarded, the belief stays the prediction of that epoch (updated with the epoch's other,
  possible readings; for the first reading that is the predicted belief carried by the
  exception);
* out-of-range observation or action, wrong length or label: message dropped;
* a lost epoch (gap): predicted with the commanded action of that epoch if the ``action`` topic
  told us, otherwise not predicted at all; an epoch missing some sensors is applied with the
  readings it has after ``epoch_timeout``;
* a non-finite or off-simplex belief is never published (defensive; cannot arise from valid
  readings), the previous one is kept.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray

from ..core.belief import ImpossibleObservation, predict, update
from ..core.model import POMDP, action_of_priority
from . import common
from .epoch_buffer import EpochBuffer, EpochReadings
from .messages import MessageError, OutOfRangeError, decode_action, decode_observation, encode_belief

#: How many commanded actions (by epoch) are remembered for gap handling and cross-checks.
ACTION_MEMORY = 256


def sensor_model(model: POMDP, O: np.ndarray) -> POMDP:
    """A model with identity transitions and sensor ``O``: the core's Eq. 2 without prediction."""
    eye = np.broadcast_to(np.eye(model.S), (model.A, model.S, model.S))
    return POMDP(P=eye, O=O, r=np.zeros((model.S, model.A)), gamma=0.0, name=f"{model.name}/sensor")


class BeliefFilter(Node):
    """Belief filter node (see module docstring)."""

    def __init__(self, node_name: str = "belief_filter", **kwargs):
        super().__init__(node_name, **kwargs)
        d = common.descriptor
        self.declare_parameter("model_file", common.DEFAULT_MODEL, d(
            "Model YAML file (absolute, or relative to the package share dir / source tree)", read_only=True))
        self.declare_parameter("observation_topics", ["observation"], d(
            "Observation topics, one per sensor, each [epoch, action_priority, observation]", read_only=True))
        common.declare_optional_array(self, "observation_model_files", "string",
                                      "Per-sensor model file whose O is used ('' = the model's own)")
        common.declare_optional_array(self, "initial_distribution", "double",
                                      "Prior belief (S probabilities); unset = model start or uniform")
        self.declare_parameter("epoch_timeout", 0.5, d(
            "Seconds to wait for missing sensor readings (or a lost epoch) before going on",
            float_range=(0.001, 60.0)))
        self.declare_parameter("max_pending_epochs", 10, d(
            "Later epochs buffered before a missing one is given up", int_range=(1, 10000)))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self.model = common.load_node_model(self.get_parameter("model_file").value)
        self.topics = list(self.get_parameter("observation_topics").value)
        if not self.topics or len(set(self.topics)) != len(self.topics):
            raise common.NodeConfigError(f"observation_topics: need distinct topics, got {self.topics}")
        self.sensor_O = common.load_observation_models(
            self.model, common.optional_array(self, "observation_model_files"), len(self.topics))
        self.sensor_models = [sensor_model(self.model, O) for O in self.sensor_O]
        self.belief = common.initial_distribution(self.model, common.optional_array(self, "initial_distribution"))
        self.epoch = 0
        self.buffer = EpochBuffer(len(self.topics), next_epoch=1,
                                  timeout=self.get_parameter("epoch_timeout").value,
                                  max_pending=self.get_parameter("max_pending_epochs").value)
        self.commanded: OrderedDict[int, int] = OrderedDict()
        self.counts = {k: 0 for k in (
            "readings", "impossible_observations", "out_of_range_observations", "malformed_messages",
            "duplicates", "conflicts", "gaps", "incomplete_epochs", "action_mismatches", "bad_beliefs")}
        self.last_warning = ""
        self._reported_problems = 0

        self.belief_pub = self.create_publisher(Float64MultiArray, "belief", common.STREAM_QOS)
        self.entropy_pub = self.create_publisher(Float64, "belief_entropy", common.LATCHED_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        for k, topic in enumerate(self.topics):
            self.create_subscription(Int64MultiArray, topic, lambda msg, k=k: self._on_observation(k, msg),
                                     common.STREAM_QOS)
        self.create_subscription(Int64MultiArray, "action", self._on_action, common.STREAM_QOS)
        self.create_timer(0.02, self._release)
        self.create_timer(1.0, self._publish_diagnostics)
        self._publish()
        self.get_logger().info(f"{self.model.describe()}; sensors {self.topics}; prior published as epoch 0")

    # ----------------------------------------------------------- parameters
    def _validate_parameters(self, params) -> SetParametersResult:
        # Ranges and types are enforced by the descriptors; nothing else to check here.
        return SetParametersResult(successful=True)

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

    @common.callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        try:
            act = decode_action(msg, self.model.A)
        except MessageError as exc:
            self._warn("malformed_messages", f"ignored action: {exc}")
            return
        self.commanded[act.epoch] = act.priority
        while len(self.commanded) > ACTION_MEMORY:
            self.commanded.popitem(last=False)

    @common.callback
    def _on_observation(self, sensor: int, msg: Int64MultiArray) -> None:
        Z = self.sensor_O[sensor].shape[2]
        try:
            obs = decode_observation(msg, self.model.A, Z)
        except MessageError as exc:
            counter = "out_of_range_observations" if isinstance(exc, OutOfRangeError) else "malformed_messages"
            self._warn(counter, f"{self.topics[sensor]}: ignored {exc}")
            return
        self.counts["readings"] += 1
        result = self.buffer.add(sensor, obs.epoch, obs.priority, obs.observation)
        if result == "duplicate":
            self.counts["duplicates"] += 1
        elif result == "conflict":
            self._warn("conflicts", f"{self.topics[sensor]}: reading of epoch {obs.epoch} conflicts with an "
                                    "earlier one (different action or observation); dropped")
        self._release()

    # ----------------------------------------------------------- filtering
    @common.callback
    def _release(self) -> None:
        for entry in self.buffer.pop_ready():
            self._apply_epoch(entry)

    def _apply_epoch(self, entry: EpochReadings) -> None:
        m = self.model
        priority = entry.priority
        if priority is None:
            priority = self.commanded.get(entry.epoch)
            self._warn("gaps", f"epoch {entry.epoch} lost (no reading); " + (
                f"predicting with the commanded priority {priority}" if priority else
                "action unknown, belief not predicted"))
        else:
            commanded = self.commanded.get(entry.epoch)
            if commanded is not None and commanded != priority:
                # informational: expected in the simulator's timer mode, which numbers epochs itself
                self.counts["action_mismatches"] += 1
                self.get_logger().debug(f"epoch {entry.epoch}: observations taken under priority {priority}, "
                                        f"commanded {commanded}; using {priority}")
            if not entry.complete:
                missing = [self.topics[k] for k in range(len(self.topics)) if k not in entry.readings]
                self._warn("incomplete_epochs", f"epoch {entry.epoch}: no reading from {missing}; "
                                                "applying the others")
        b = self.belief
        if priority is not None:
            a = action_of_priority(priority, m.A)
            b = predict(m, b, a)
            for k in sorted(entry.readings):
                z = entry.readings[k]
                try:
                    b = update(self.sensor_models[k], b, a, z)
                except ImpossibleObservation as exc:
                    b = exc.predicted
                    self._warn("impossible_observations",
                               f"epoch {entry.epoch}: {self.topics[k]} observation {z} impossible under the "
                               f"belief (eta = {exc.eta:.3g}); reading discarded, keeping the prediction")
        if not (np.all(np.isfinite(b)) and abs(b.sum() - 1.0) < 1e-6 and np.all(b >= 0.0)):
            self._warn("bad_beliefs", f"epoch {entry.epoch}: belief left the simplex ({b}); not published")
            self.epoch = entry.epoch
            return
        self.belief = b / b.sum()
        self.epoch = entry.epoch
        self._publish()

    def _publish(self) -> None:
        self.belief_pub.publish(encode_belief(self.epoch, self.belief))
        self.entropy_pub.publish(Float64(data=common.shannon_entropy(self.belief)))

    @common.callback
    def _publish_diagnostics(self) -> None:
        problems = sum(v for k, v in self.counts.items() if k not in ("readings", "duplicates", "action_mismatches"))
        recent, self._reported_problems = problems - self._reported_problems, problems
        # WARN while problems keep coming (since the previous report), OK again once they stop
        level = DiagnosticStatus.WARN if recent else DiagnosticStatus.OK
        text = f"epoch {self.epoch}" + (f"; {recent} problem(s) since the last report, last: {self.last_warning}"
                                        if recent else "")
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [common.status(
            f"{self.get_name()}: belief", self.model.name, level, text,
            {"epoch": self.epoch, "entropy": common.shannon_entropy(self.belief),
             "pending_epochs": self.buffer.pending_epochs, **self.counts})]
        self.diag_pub.publish(msg)


def main(args=None) -> None:
    common.main_for([BeliefFilter])


if __name__ == "__main__":
    main()
