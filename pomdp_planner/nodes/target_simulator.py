"""``target_simulator``: the hidden state of a model, stepped by the planner's actions.

Topics (relative names, remappable):

* subscribes ``action`` (``Int64MultiArray [epoch, action_priority]``; every action: ``STREAM_QOS``);
* publishes, per configured sensor, ``observation`` (default; parameter ``observation_topics``)
  as ``Int64MultiArray [epoch, action_priority, observation]`` and ``true_state``
  (``[epoch, state]``, 0-based; epoch 0 = the initial state) for evaluation;
* ``/diagnostics`` about once a second.

Each action of a *new* epoch ``t`` (``t`` > the last simulated epoch; older or repeated ones are
dropped and counted) moves the state ``s ~ P[a, s, :]`` and draws one observation per sensor
``z_k ~ O_k[a, s, :]``; the observation carries the epoch and the action actually applied, so the
belief filter pairs them without relying on timing. A jump in epochs (an action was lost) is
simulated as one step and counted as a gap.

``min_subscribers`` (default 0): no step, in either mode, until every observation topic has at
least that many matched subscriptions (e.g. 2: the belief filter and a recorder), so that they
all get every epoch from the first; actions that arrive before are kept (the newest one) and
applied once the subscribers are there.

Timer mode (``step_period > 0``): the simulator is the clock. Every period it steps once with the
most recent action (``default_priority`` before any arrives), numbering epochs itself; the
observations again carry the action that was applied, so pairing stays exact.
"""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Int64MultiArray

from ..core.io.sensors import initial_distribution, load_model_file, load_observation_models
from ..core.model import action_of_priority
from .diagnostics import status
from .messages import ActionMsg, MessageError, decode_action, encode_observation, encode_true_state
from .params import declare_model_file, declare_optional_array, descriptor, optional_array
from .qos import STREAM_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for


class TargetSimulator(Node):
    """Simulated target: hidden Markov state, sampled observations (see module docstring)."""

    def __init__(self, node_name: str = "target_simulator", **kwargs):
        super().__init__(node_name, **kwargs)
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
        self.declare_parameter("step_period", 0.0, d(
            "0 = step on each new action; > 0 = step every period (s) with the latest action",
            read_only=True, float_range=(0.0, 3600.0)))
        self.declare_parameter("min_subscribers", 0, d(
            "Do not step until every observation topic has this many matched subscribers (0 = no wait)",
            read_only=True, int_range=(0, 1000)))
        self.declare_parameter("default_priority", 1, d(
            "Action used in timer mode before the first action arrives", read_only=True, int_range=(1, 1000)))

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
        self.counts = {"steps": 0, "stale_actions": 0, "malformed_actions": 0, "epoch_gaps": 0}

        self.obs_pubs = [self.create_publisher(Int64MultiArray, t, STREAM_QOS) for t in topics]
        self.state_pub = self.create_publisher(Int64MultiArray, "true_state", STREAM_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Int64MultiArray, "action", self._on_action, STREAM_QOS)
        self.min_subscribers = self.get_parameter("min_subscribers").value
        self._held_action: ActionMsg | None = None  # arrived before the subscribers (min_subscribers)
        if self.min_subscribers > 0:
            self._wait_timer = self.create_timer(0.01, self._check_subscribers)
        period = self.get_parameter("step_period").value
        self.timer_mode = period > 0.0
        if self.timer_mode:
            self.create_timer(period, self._on_tick)
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
        self.counts["steps"] += 1
        for O, pub in zip(self.sensor_O, self.obs_pubs, strict=True):
            z = int(self.rng.choice(O.shape[2], p=O[a, self.state]))
            pub.publish(encode_observation(epoch, priority, z))
        self.state_pub.publish(encode_true_state(epoch, self.state))

    @callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        try:
            act = decode_action(msg, self.model.A)
        except MessageError as exc:
            self.counts["malformed_actions"] += 1
            self.get_logger().warning(f"ignored action: {exc}")
            return
        self.last_priority = act.priority
        if self.timer_mode:
            return
        if not self.subscribers_ready():
            if self._held_action is None or act.epoch > self._held_action.epoch:
                self._held_action = act
            return
        self._release_held()
        self._apply_action(act)

    def _apply_action(self, act: ActionMsg) -> None:
        if act.epoch <= self.epoch:
            self.counts["stale_actions"] += 1
            self.get_logger().debug(f"ignored action of epoch {act.epoch} (already at epoch {self.epoch})")
            return
        if act.epoch > self.epoch + 1:
            self.counts["epoch_gaps"] += 1
            self.get_logger().warning(f"action jumps from epoch {self.epoch} to {act.epoch} (actions lost?)")
        self.step(act.epoch, act.priority)

    def subscribers_ready(self) -> bool:
        """Whether every observation topic has ``min_subscribers`` matched subscriptions (latched)."""
        if self.min_subscribers > 0:
            if any(p.get_subscription_count() < self.min_subscribers for p in self.obs_pubs):
                return False
            self.min_subscribers = 0
            self.get_logger().info("observation subscribers matched; stepping")
        return True

    def _release_held(self) -> None:
        held, self._held_action = self._held_action, None
        if held is not None and not self.timer_mode:
            self._apply_action(held)

    @callback
    def _check_subscribers(self) -> None:
        if self.subscribers_ready():
            self._wait_timer.cancel()
            self._release_held()

    @callback
    def _on_tick(self) -> None:
        if self.subscribers_ready():
            self.step(self.epoch + 1, self.last_priority)

    @callback
    def _publish_diagnostics(self) -> None:
        level = DiagnosticStatus.WARN if self.counts["malformed_actions"] else DiagnosticStatus.OK
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status(
            f"{self.get_name()}: simulation", self.model.name, level,
            f"epoch {self.epoch}", {"epoch": self.epoch, "true_state": self.state, **self.counts})]
        self.diag_pub.publish(msg)


def main(args=None) -> None:
    main_for([TargetSimulator])


if __name__ == "__main__":
    main()
