"""What the three loop nodes share: the ``model_file`` and liveness parameters, one lock around
every call into the node's loop (``core/loop``), the time those calls get (``time.monotonic``),
the loop's log lines, one-shot timers armed for the times a loop asks to be called back, the
watchdog and the diagnostics (about once a second, ``/diagnostics``), and what every input sample
passes before it is decoded: its size and its writer (:meth:`LoopNode.subscribe_input`; rules
"Bounded samples" and "One writer" of docs/ros.md, "The loop's rules"), with the graph's
facts about the writers of each input. The loop's timers run on the steady clock; ROS time
(``use_sim_time``, set at start-up only: a run-time change is refused) paces only the simulator's
steps."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from std_msgs.msg import Int64MultiArray

from ..core.loop import Log
from .diagnostics import array, status
from .messages import MessageError, decode_action, oversized, wire_limits
from .params import ParameterNode, accept_integers_for_doubles, declare_liveness, declare_model_file
from .runtime import callback
from .take import subscribe

#: Writers per input for which the node looked at the graph on their first sample (the oldest forgotten).
GRAPH_ASKED = 64


@dataclass
class Input:
    """An input stream of a loop node (:meth:`LoopNode.subscribe_input`)."""

    name: str
    msg_type: type
    max_bytes: int
    layout: str
    on_msg: Callable[[object], None]
    on_bad: Callable[[str], None]
    topic: str = ""
    sub: object = None                      # the subscription
    held: tuple[bytes, dict] | None = None  # the newest foreign sample: handed in again at a takeover
    asked: dict[str, None] = field(default_factory=dict)  # writers the graph was looked at for


class OneShot:
    """A timer of ``node`` (on the steady clock) that calls ``fire`` once at the time it was last
    armed for.

    Disarming does not cancel the timer (cancelling it from another callback races with the
    executor taking it as ready: rclpy then raises "timer is canceled"); a disarmed timer fires
    once more and does nothing. Only its own callback cancels it."""

    def __init__(self, node: Node, fire: Callable[[], None]):
        self.context = node.context  # for @callback
        self._fire = fire
        self._at: float | None = None
        self._timer = node.create_timer(1.0, self._on_timer, autostart=False,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def arm(self, at: float | None, now: float) -> None:
        """Fire at ``at`` (``time.monotonic`` time; ``None``: not at all)."""
        if at == self._at:
            return
        self._at = at
        if at is not None:
            self._timer.timer_period_ns = int(max(at - now, 0.001) * 1e9)
            self._timer.reset()

    @callback
    def _on_timer(self) -> None:
        self._timer.cancel()
        armed, self._at = self._at, None
        if armed is not None:
            self._fire()


class LoopNode(ParameterNode):
    """Base of the loop nodes; a subclass builds its loop, then calls :meth:`run`, and publishes
    each of the loop's outputs in :meth:`emit`. ``task`` names the diagnostics status."""

    task = ""

    def __init__(self, node_name: str, **kwargs):
        super().__init__(node_name, **kwargs)
        accept_integers_for_doubles(self)
        self.model_file = declare_model_file(self)
        self.live = declare_liveness(self)
        self.lock = threading.Lock()
        self.loop = None
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.inputs: dict[str, Input] = {}
        self.add_on_set_parameters_callback(self._refuse_sim_time)

    @staticmethod
    def now() -> float:
        return time.monotonic()

    def run(self, loop) -> None:
        """Start ``loop``: diagnostics, the watchdog of its re-send, re-sync and stall rules, its
        first output (``loop.start``)."""
        self.loop = loop
        loop.health.set_clock(bool(self.get_parameter("use_sim_time").value), self.now())
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(self.live.watchdog_period, self._watchdog, clock=self.steady)
        self.create_timer(1.0, self._publish_diagnostics, clock=self.steady)
        self.call(loop.start)

    # ----------------------------------------------------------- inputs
    def subscribe_input(self, name: str, msg_type: type, topic: str, qos, on_msg: Callable[[object], None], *,
                        max_bytes: int, layout: str, on_bad: Callable[[str], None],
                        **kwargs) -> Input:
        """Subscribe to ``topic`` as the loop's input ``name``: a sample larger than ``max_bytes``
        (``layout``: what it should hold) is dropped unread, one of a writer other than the one the
        loop follows is dropped before it is decoded (``loop.health.admit``), the rest is
        deserialized and handed to ``on_msg`` (one that does not deserialize to ``on_bad``)."""
        spec = Input(name, msg_type, max_bytes, layout, on_msg, on_bad)
        sub = subscribe(self, msg_type, topic, lambda raw, info: self._on_sample(spec, raw, info), qos, max_bytes,
                        **kwargs)
        spec.topic, spec.sub = sub.topic_name, sub
        self.inputs[name] = spec
        return spec

    @callback
    def _on_sample(self, spec: Input, raw: bytes | None, info: dict) -> None:
        now = self.now()
        size = info.get("size", 0 if raw is None else len(raw))
        if raw is None or size > spec.max_bytes:
            self._tell(self.loop.health.oversized, spec.name, oversized(spec.name, size, spec.max_bytes, spec.layout))
            return
        writer = info.get("publisher_gid")
        if writer is not None and writer not in spec.asked and not self.loop.health.writers[spec.name].known(writer):
            spec.asked[writer] = None  # its first sample: who is it? (once per writer)
            while len(spec.asked) > GRAPH_ASKED:
                del spec.asked[next(iter(spec.asked))]
            self._look_at_graph(spec)
        with self.lock:
            admitted = self.loop.health.admit(spec.name, writer, now)
            if not admitted:
                spec.held = (raw, info)
            logs = self.loop.health.drain_logs()
        self.log(logs)
        if not admitted:
            return
        try:
            msg = deserialize_message(raw, spec.msg_type)
        except Exception as exc:  # not a sample of the topic's type (a raw publisher's bytes)
            spec.on_bad(f"{spec.name}: not a {spec.msg_type.__name__} ({type(exc).__name__})")
            return
        spec.on_msg(msg)

    def _tell(self, method: Callable, *args) -> None:
        """``method(*args, now)`` of the loop's health with the lock held; its log lines logged."""
        with self.lock:
            method(*args, self.now())
            logs = self.loop.health.drain_logs()
        self.log(logs)

    def _look_at_graph(self, spec: Input) -> None:
        """The graph's facts about the writers of ``spec``'s topic: ``{GID (hex): node name}``."""
        writers = {bytes(i.endpoint_gid).hex(): (i.node_namespace.rstrip("/") + "/" + i.node_name)
                   for i in self.get_publishers_info_by_topic(spec.topic)}
        with self.lock:
            self.loop.health.writers[spec.name].graph(writers)

    def _takeovers(self) -> None:
        """Hand in again the waiting sample of a writer whose predecessor is gone (rule "One writer")."""
        now = self.now()
        for spec in self.inputs.values():
            with self.lock:
                held = spec.held if self.loop.health.writers[spec.name].takeover_due(now) else None
                if held is not None:
                    spec.held = None
            if held is not None:
                self._on_sample(spec, *held)

    # ----------------------------------------------------------- time
    def _refuse_sim_time(self, params: list[Parameter]) -> SetParametersResult:
        """``use_sim_time`` is set at start-up only (rule "Time"): a run-time change is refused."""
        for p in params:
            if p.name == "use_sim_time" and p.value != self.get_parameter("use_sim_time").value:
                with self.lock:
                    if self.loop is None:
                        return SetParametersResult(successful=False, reason="use_sim_time: set at start-up only")
                    reason = self.loop.health.refuse_sim_time(p.value, self.now())
                    logs = self.loop.health.drain_logs()
                self.log(logs)
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def call(self, method: Callable, *args, **kwargs) -> None:
        """``method(*args, now, **kwargs)`` of the loop with the lock held; its output is emitted."""
        with self.lock:
            out = method(*args, self.now(), **kwargs)
        self.emit(out)

    def emit(self, out) -> None:
        raise NotImplementedError

    def accept_changes(self, check: Callable[[Mapping[str, Any]], str]) -> None:
        """Run-time parameter changes: refused with the reason the core's ``check`` gives (after the
        descriptors' ranges, which rclpy enforces first), else handed to the loop's ``set_params``
        with the lock held, its lines logged."""
        def validate(params: list[Parameter]) -> SetParametersResult:
            reason = check({p.name: p.value for p in params})
            return SetParametersResult(successful=not reason, reason=reason)

        def apply(params: list[Parameter]) -> None:
            with self.lock:
                logs = self.loop.set_params({p.name: p.value for p in params})
            self.log(logs)

        self.add_on_set_parameters_callback(validate)
        self.add_post_set_parameters_callback(apply)

    def log(self, logs: Iterable[Log]) -> None:
        logger = self.get_logger()
        for line in logs:  # one call site per severity: rclpy refuses two severities at one site
            if line.level == "debug":
                logger.debug(line.text)
            elif line.level == "info":
                logger.info(line.text)
            elif line.level == "warning":
                logger.warning(line.text)
            else:
                logger.error(line.text)

    def subscribe_actions(self, qos) -> Input:
        """The ``action`` input of a loop that takes actions (the filter's and the target's)."""
        return self.subscribe_input("action", Int64MultiArray, "action", qos, self._on_action,
                                    max_bytes=wire_limits(self.model.S)["action"], layout="[epoch, action_priority]",
                                    on_bad=lambda problem: self.call(self.loop.rejected_action, problem))

    @callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        try:
            act = decode_action(msg, self.loop.model.A)
        except MessageError as exc:
            self.call(self.loop.rejected_action, str(exc))
            return
        self.call(self.loop.action, act)

    @callback
    def _watchdog(self) -> None:
        self._takeovers()
        self.call(self.loop.watchdog)

    @callback
    def _publish_diagnostics(self) -> None:
        for spec in self.inputs.values():
            self._look_at_graph(spec)
        ros_now = self.get_clock().now().nanoseconds
        with self.lock:
            now = self.now()
            self.loop.health.clock.tick(ros_now, now)
            r = self.loop.report(now)
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: {self.task}", self.hardware_id(),
                                                 r.level, r.message, r.values)))

    def hardware_id(self) -> str:
        """The diagnostics' ``hardware_id``: the model's name."""
        return self.loop.model.name
