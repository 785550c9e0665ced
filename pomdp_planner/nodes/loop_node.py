"""What the three loop nodes share: the ``model_file`` and liveness parameters, one lock around
every call into the node's loop (``core/loop``), the time those calls get (``time.monotonic``),
the loop's log lines, one-shot timers armed for the times a loop asks to be called back, the
watchdog and the diagnostics (about once a second, ``/diagnostics``)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Int64MultiArray

from ..core.loop import Log
from .diagnostics import array, status
from .messages import MessageError, decode_action
from .params import ParameterNode, accept_integers_for_doubles, declare_liveness, declare_model_file
from .runtime import callback


class OneShot:
    """A timer of ``node`` that calls ``fire`` once at the time it was last armed for.

    Disarming does not cancel the timer (cancelling it from another callback races with the
    executor taking it as ready: rclpy then raises "timer is canceled"); a disarmed timer fires
    once more and does nothing. Only its own callback cancels it."""

    def __init__(self, node: Node, fire: Callable[[], None]):
        self.context = node.context  # for @callback
        self._fire = fire
        self._at: float | None = None
        self._timer = node.create_timer(1.0, self._on_timer, autostart=False)

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

    @staticmethod
    def now() -> float:
        return time.monotonic()

    def run(self, loop) -> None:
        """Start ``loop``: diagnostics, the watchdog of its re-send, re-sync and stall rules, its
        first output (``loop.start``)."""
        self.loop = loop
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(self.live.watchdog_period, self._watchdog)
        self.create_timer(1.0, self._publish_diagnostics)
        self.call(loop.start)

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

    @callback
    def _on_action(self, msg: Int64MultiArray) -> None:
        """An ``action`` sample for a loop that takes actions (the filter's and the target's)."""
        try:
            act = decode_action(msg, self.loop.model.A)
        except MessageError as exc:
            self.call(self.loop.rejected_action, str(exc))
            return
        self.call(self.loop.action, act)

    @callback
    def _watchdog(self) -> None:
        self.call(self.loop.watchdog)

    @callback
    def _publish_diagnostics(self) -> None:
        with self.lock:
            r = self.loop.report(self.now())
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: {self.task}", self.loop.model.name,
                                                 r.level, r.message, r.values)))
