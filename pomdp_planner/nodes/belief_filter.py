"""``belief_filter``: the Bayes filter of the paper (Eqs. 1-2) fed by observation topics.

Topics (relative names, remappable; layouts: :mod:`.messages`, QoS: :mod:`.qos`):

* subscribes each topic of ``observation_topics`` (``Int64MultiArray [epoch, action_priority,
  observation]``), each of ``likelihood_topics`` (soft evidence, ``Float64MultiArray`` with the
  epoch and priority in its layout, as the measurement adapter publishes it) and ``action``
  (``[epoch, action_priority]``: to predict through a lost epoch and to cross-check), all
  ``STREAM_QOS``;
* publishes ``belief`` (``Float64MultiArray``, layout ``[("state", S), ("epoch=<t>", 1)]``,
  ``STREAM_QOS``; epoch 0 is the prior), ``belief_entropy`` (``Float64``, Shannon entropy in nats
  of the same belief; ``LATCHED_QOS``) and ``/diagnostics`` (``belief_filter: belief``).

Each observation applies with the action it carries, epochs in order, one prediction and one
update per sensor reading (``b'(s) ∝ l(s) b^a(s)`` for soft evidence); the rules (epoch buffer,
gaps, recovery, joining, re-sync, re-send, stall levels) are the core's
:class:`~pomdp_planner.core.loop.FilterLoop`. Parameters, topics and diagnostics: docs/ros.md.
"""

from __future__ import annotations

from rclpy.parameter import Parameter
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray

from ..core.gate import SetupStages
from ..core.io.sensors import initial_distribution, load_observation_models
from ..core.loop import FilterLoop, FilterOutput
from .loop_node import ManagedLoopNode, OneShot
from .messages import MessageError, OutOfRangeError, decode_likelihood, decode_observation, encode_belief, wire_bounds
from .params import declare_double, declare_optional_array, descriptor, optional_array
from .qos import LATCHED_QOS, STREAM_QOS
from .runtime import NodeConfigError, callback, main_for


class BeliefFilter(ManagedLoopNode):
    """Belief filter node, a managed node (see module docstring; its lifecycle: :class:`ManagedLoopNode`)."""

    task = "belief"

    def __init__(self, node_name: str = "belief_filter", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
        self.declare_parameter("observation_topics", ["observation"], d(
            "Observation topics, one per sensor, each [epoch, action_priority, observation]", read_only=True))
        declare_optional_array(self, "likelihood_topics", "string",
                               "Soft-evidence topics, one per sensor: a likelihood per state (measurement_adapter)")
        declare_optional_array(self, "observation_model_files", "string",
                               "Per-sensor model file whose O is used ('' = the model's own)")
        declare_optional_array(self, "initial_distribution", "double",
                               "Prior belief (S probabilities); unset = model start or uniform")
        declare_double(self, "epoch_timeout", 0.5, d(
            "Seconds to wait for missing sensor readings (or a lost epoch) before going on",
            float_range=(0.001, 60.0)))
        self.declare_parameter("max_pending_epochs", 10, d(
            "Later epochs buffered before a missing one is given up", int_range=(1, 10000)))
        # ranges and types: the descriptors (nothing else to validate); side effects after a set
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.bring_up()

    def configure_loop(self) -> FilterLoop:
        """The model, the sensors' observation models and the prior; the topics."""
        self.topics = optional_array(self, "observation_topics") or []  # an empty list ([]) arrives unset
        soft_topics = optional_array(self, "likelihood_topics") or []
        every = self.topics + soft_topics
        if not every or len(set(every)) != len(every):
            raise NodeConfigError(f"observation_topics, likelihood_topics: need distinct topics, at least one, got "
                                  f"{self.topics} and {soft_topics}")
        model = self.load_model(SetupStages(self.get_logger().info))
        sensors = load_observation_models(model, optional_array(self, "observation_model_files"), len(self.topics))
        prior = initial_distribution(model, optional_array(self, "initial_distribution"))
        loop = FilterLoop(model, sensors, prior, self.topics, self.live, now=self.now(),
                          epoch_timeout=self.get_parameter("epoch_timeout").value,
                          max_pending=self.get_parameter("max_pending_epochs").value, likelihood_topics=soft_topics,
                          active=False)
        self.belief_pub = self.create_lifecycle_publisher(Float64MultiArray, "belief", STREAM_QOS)
        self.entropy_pub = self.create_lifecycle_publisher(Float64, "belief_entropy", LATCHED_QOS)
        bounds = wire_bounds(model.S)
        for k, topic in enumerate(self.topics):
            self.subscribe_input(topic, Int64MultiArray, topic, STREAM_QOS,
                                 lambda msg, k=k: self._on_observation(k, msg), bound=bounds["observation"],
                                 kind="observation",
                                 on_bad=lambda problem, k=k: self.call(self.loop.rejected_observation, k, problem))
        for k, topic in enumerate(soft_topics, start=len(self.topics)):
            self.subscribe_input(topic, Float64MultiArray, topic, STREAM_QOS,
                                 lambda msg, k=k: self._on_likelihood(k, msg), bound=bounds["likelihood"],
                                 kind="likelihood",
                                 on_bad=lambda problem, k=k: self.call(self.loop.rejected_observation, k, problem))
        self.subscribe_actions(STREAM_QOS)
        self._release = OneShot(self, self._on_release)  # armed only while an epoch waits for its time-out
        return loop

    def _apply_parameters(self, params: list[Parameter]) -> None:
        with self.lock:
            if self.loop is None:  # unconfigured: the next configure reads them
                return
            for p in params:
                if p.name == "epoch_timeout":
                    self.loop.buffer.timeout = p.value
                elif p.name == "max_pending_epochs":
                    self.loop.buffer.max_pending = p.value

    @callback
    def _on_observation(self, sensor: int, msg: Int64MultiArray) -> None:
        try:
            obs = decode_observation(msg, self.model.A, self.loop.filter.num_observations(sensor))
        except MessageError as exc:
            self.call(self.loop.rejected_observation, sensor, str(exc), out_of_range=isinstance(exc, OutOfRangeError))
            return
        self.call(self.loop.observation, sensor, obs)

    @callback
    def _on_likelihood(self, sensor: int, msg: Float64MultiArray) -> None:
        try:
            evidence = decode_likelihood(msg, self.model.A, self.model.S)
        except MessageError as exc:
            self.call(self.loop.rejected_observation, sensor, str(exc), out_of_range=isinstance(exc, OutOfRangeError))
            return
        self.call(self.loop.observation, sensor, evidence)

    @callback
    def _on_release(self) -> None:
        self.call(self.loop.release)

    def emit(self, out: FilterOutput) -> None:
        for b in out.beliefs:
            self.belief_pub.publish(encode_belief(b.epoch, b.belief))
            self.entropy_pub.publish(Float64(data=b.entropy))
        self.log(out.logs)
        self._release.arm(out.release_at, self.now())


def main(args=None) -> None:
    main_for([BeliefFilter])


if __name__ == "__main__":
    main()
