"""``target_simulator``: the hidden state of a model, stepped by the planner's actions.

Topics (relative names, remappable; layouts: :mod:`.messages`, QoS: :mod:`.qos`):

* subscribes ``action`` (``Int64MultiArray [epoch, action_priority]``, ``STREAM_QOS``) and,
  timer-driven, ``belief`` (``LATCHED_QOS``, only to learn the loop's epoch when it joins);
* publishes, per sensor of ``observation_topics``, ``Int64MultiArray [epoch, action_priority,
  observation]`` carrying the priority actually applied, ``true_state`` (``[epoch, state]``,
  0-based; epoch 0 = the initial state) for evaluation, and ``/diagnostics``
  (``target_simulator: simulation``).

``step_period`` 0 steps once per new action; > 0 steps every period with the latest action (the
simulator is the clock). ``min_subscribers`` holds the first step until every observation topic
has that many subscribers. Stepping, joining a running loop, re-sync and re-send are the core's
:class:`~pomdp_planner.core.loop.TargetLoop`. Parameters, topics and diagnostics: docs/ros.md.
"""

from __future__ import annotations

from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.io.sensors import initial_distribution, load_model_file, load_observation_models
from ..core.loop import DEFAULT_JOIN_TIMEOUT, TargetLoop, TargetOutput
from .loop_node import LoopNode, OneShot
from .messages import MessageError, decode_belief, encode_observation, encode_true_state, wire_bounds
from .params import declare_double, declare_optional_array, descriptor, optional_array
from .qos import LATCHED_QOS, STREAM_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for


class TargetSimulator(LoopNode):
    """Simulated target: hidden Markov state, sampled observations (see module docstring)."""

    task = "simulation"

    def __init__(self, node_name: str = "target_simulator", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
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

        value = self.get_parameter
        topics = optional_array(self, "observation_topics") or []  # an empty list ([]) arrives unset
        if not topics:
            raise NodeConfigError("observation_topics: at least one topic is needed")
        s0, period = value("initial_state").value, value("step_period").value
        self.min_subscribers = value("min_subscribers").value
        with config_errors():
            self.model = load_model_file(self.model_file)
            sensors = load_observation_models(self.model, optional_array(self, "observation_model_files"), len(topics))
            initial = initial_distribution(self.model, optional_array(self, "initial_distribution")) if s0 < 0 else None
            loop = TargetLoop(self.model, sensors, topics, self.live, now=self.now(), seed=value("seed").value,
                              initial_state=s0, initial=initial, step_period=period,
                              default_priority=value("default_priority").value,
                              join_timeout=value("join_timeout").value, outputs_ready=self.min_subscribers == 0)
        self.obs_pubs = [self.create_publisher(Int64MultiArray, t, STREAM_QOS) for t in topics]
        self.state_pub = self.create_publisher(Int64MultiArray, "true_state", STREAM_QOS)
        self.subscribe_actions(STREAM_QOS)
        if loop.timer_mode:
            self.subscribe_input("belief", Float64MultiArray, "belief", LATCHED_QOS, self._on_belief, kind="belief",
                                 bound=wire_bounds(self.model.S)["belief"],
                                 on_bad=lambda problem: None)  # the planner counts bad beliefs
            self.create_timer(period, self._on_tick)  # on ROS time: /clock, with use_sim_time
        if self.min_subscribers > 0:
            self._wait_timer = self.create_timer(0.01, self._check_subscribers, clock=self.steady)
        self._join = OneShot(self, self._on_join)
        self.run(loop)

    @callback
    def _on_belief(self, msg: Float64MultiArray) -> None:
        if self.loop.joined:
            return
        try:
            bel = decode_belief(msg, self.model.S)
        except MessageError:
            return  # not this node's business: the planner counts bad beliefs
        self.call(self.loop.belief_epoch, bel.epoch)

    @callback
    def _check_subscribers(self) -> None:
        if all(p.get_subscription_count() >= self.min_subscribers for p in self.obs_pubs):
            self._wait_timer.cancel()
            self.call(self.loop.outputs_matched)

    @callback
    def _on_join(self) -> None:
        self.call(self.loop.join_due)

    @callback
    def _on_tick(self) -> None:
        self.call(self.loop.tick)

    def emit(self, out: TargetOutput) -> None:
        for r in out.readings:
            for pub, z in zip(self.obs_pubs, r.observations, strict=True):
                pub.publish(encode_observation(r.epoch, r.priority, z))
        for epoch, state in out.true_states:
            self.state_pub.publish(encode_true_state(epoch, state))
        self.log(out.logs)
        self._join.arm(out.join_at, self.now())


def main(args=None) -> None:
    main_for([TargetSimulator])


if __name__ == "__main__":
    main()
