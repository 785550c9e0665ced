"""What the loop nodes share: the ``model_file`` and liveness parameters, one lock around every
call into the node's loop (``core/loop``), the time those calls get (``time.monotonic``), the
loop's log lines, one-shot timers armed for the times a loop asks to be called back, the watchdog
and the diagnostics (about once a second, ``/diagnostics``), and what every input sample passes
before it is decoded: its size and its writer (:meth:`LoopNode.subscribe_input`; rules "Bounded
samples" and "One writer" of docs/ros.md, "The loop's rules"), with the graph's facts about the
writers of each input. The loop's timers run on the steady clock; ROS time (``use_sim_time``, set
at start-up only: a run-time change is refused) paces only the simulator's steps.

:class:`LoopNode` is a plain node that builds its loop when it is made (the target simulator, the
measurement adapter); :class:`ManagedLoopNode` is a managed (lifecycle) node (the planner and the
belief filter; the states and transitions: docs/ros.md, "Lifecycle"): ``configure`` reads the
parameters, loads the model and builds the loop with its publishers, subscriptions (its inputs,
each checked as above in every state), writer and clock watches and timers, ``activate`` and
``deactivate`` switch its publishing (the rule "Inactive"), ``cleanup`` releases it all, and its
diagnostics publish in every state, saying the state.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.lifecycle.publisher import LifecyclePublisher
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Int64MultiArray

from ..core.gate import SetupStages
from ..core.io.sensors import load_model_file
from ..core.loop import LOOP_STATES, Log, Report, state_report
from ..core.model import POMDP
from .diagnostics import array, log_line, status
from .inputs import CheckedInputs, Input
from .messages import MessageError, WireBound, decode_action, wire_bounds
from .params import (
    CONFIGURE_TIME,
    NodeConfigError,
    ParameterNode,
    accept_integers_for_doubles,
    declare_liveness,
    declare_model_file,
    descriptor,
    liveness,
)
from .runtime import callback, config_errors

#: The parameters a managed node reads as it is made: read-only, refused at once.
START_UP_PARAMETERS = frozenset({"autostart", "strict_parameters"})

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
    each of the loop's outputs in :meth:`emit`. ``task`` names the diagnostics status. A plain
    loop node reads ``model_file`` and the liveness parameters when it is made (``model_file``,
    ``live``)."""

    task = ""
    #: A managed node (:class:`ManagedLoopNode`) reads its parameters at configure instead.
    managed = False

    def __init__(self, node_name: str, **kwargs):
        super().__init__(node_name, **kwargs)
        accept_integers_for_doubles(self)
        declare_model_file(self)
        declare_liveness(self)
        self.lock = threading.Lock()
        self.loop = None
        if not self.managed:
            self.model_file = self.get_parameter("model_file").value
            self.live = liveness(self)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.checked = CheckedInputs(self, self.lock, lambda: None if self.loop is None else self.loop.health,
                                     self.log, self.now)
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
    @property
    def inputs(self) -> dict[str, Input]:
        """The loop's input streams (:class:`~.inputs.CheckedInputs`), by name."""
        return self.checked.streams

    def subscribe_input(self, name: str, msg_type: type, topic: str, qos, on_msg: Callable[[object], None], *,
                        bound: WireBound, on_bad: Callable[[str], None], **kwargs) -> Input:
        """Subscribe to ``topic`` as the loop's input ``name``, its samples checked for size and
        writer before they are decoded (:meth:`.inputs.CheckedInputs.subscribe`)."""
        return self.checked.subscribe(name, msg_type, topic, qos, on_msg, bound=bound, on_bad=on_bad, **kwargs)

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
        """``method(*args, now, **kwargs)`` of the loop with the lock held; its output is emitted.
        A method of a loop that is no longer the node's (released by a cleanup while a search ran)
        is not called."""
        with self.lock:
            if getattr(method, "__self__", self.loop) is not self.loop:
                return
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
            with self.lock:  # a managed node without a loop (unconfigured): the next configure reads them
                logs = [] if self.loop is None else self.loop.set_params({p.name: p.value for p in params})
            self.log(logs)

        self.add_on_set_parameters_callback(validate)
        self.add_post_set_parameters_callback(apply)

    def log(self, logs: Iterable[Log]) -> None:
        logger = self.get_logger()
        for line in logs:
            log_line(logger, line)

    def subscribe_actions(self, qos) -> Input:
        """The ``action`` input of a loop that takes actions (the filter's and the target's)."""
        return self.subscribe_input("action", Int64MultiArray, "action", qos, self._on_action,
                                    bound=wire_bounds(self.model.S)["action"],
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
        self.checked.takeovers()
        self.call(self.loop.watchdog)

    def report(self) -> tuple[str, Report]:
        """``(hardware_id, report)`` for the diagnostics: the loop's report."""
        with self.lock:
            return self.hardware_id(), self.loop.report(self.now())

    def hardware_id(self) -> str:
        """The diagnostics' ``hardware_id``: the model's name."""
        return self.loop.model.name

    def _look_at_graphs_and_clock(self) -> None:
        """Before a report: the graph's writers of every input, and the ROS time (rule "Time")."""
        self.checked.look_at_graphs()
        ros_now = self.get_clock().now().nanoseconds
        with self.lock:
            if self.loop is not None and self.loop.health.clock is not None:
                self.loop.health.clock.tick(ros_now, self.now())

    @callback
    def _publish_diagnostics(self) -> None:
        self._look_at_graphs_and_clock()
        hardware_id, r = self.report()
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: {self.task}", hardware_id,
                                                 r.level, r.message, r.values)))


class ManagedLoopNode(LifecycleNodeMixin, LoopNode):
    """Base of the managed loop nodes (module docstring). A subclass declares its parameters, then
    calls :meth:`bring_up`; :meth:`configure_loop` (at configure) reads them and returns its loop,
    made inactive, creating the publishers (lifecycle publishers: they publish only while active),
    subscriptions and timers it needs; the base creates the watchdog and releases all of them at
    cleanup. Every parameter declared read-only is read at configure: it may be set while the node
    is unconfigured (in force at the next configure) and is refused in every other state.

    ``autostart`` (default true) walks configure and activate in :meth:`bring_up`, so the node
    starts as a plain one does, and a configure that fails raises :class:`NodeConfigError` (the
    process's one ``[FATAL]`` line). Without it the node waits, unconfigured, for the
    ``change_state`` service; a configure that fails leaves it unconfigured, its reason in the log
    (one line) and in the diagnostics (ERROR) until a configure succeeds. A value refused as a
    parameter is declared (:class:`~.params.ParameterNode`'s one line) is such a reason: the
    parameter takes its default and configure fails with that line until the parameter is set
    (``autostart`` and ``strict_parameters``, read as the node is made, are refused at once).
    Built by ``runtime.run_nodes``, the node waits with its autostart until the process has
    checked the parameters given to its nodes (:meth:`start`): an undeclared parameter is
    reported before a long configure, and ``strict_parameters`` refuses it before one.
    """

    managed = True

    def __init__(self, node_name: str, **kwargs):
        self._configure_time: set[str] = set()
        self._refused: dict[str, str] = {}  # parameter -> its refusal (params.refusal), until it is set
        LoopNode.__init__(self, node_name, **kwargs)
        self.declare_parameter("autostart", True, descriptor(
            "Configure and activate at start-up (false: wait, unconfigured, for the lifecycle services)",
            read_only=True))
        LifecycleNodeMixin.__init__(self)  # the lifecycle services, in the default callback group
        self.model: POMDP | None = None
        self.configure_error = ""
        self.configure_seconds: float | None = None
        self._configuring_since: float | None = None
        self._autostarting = False
        self._failure: Exception | None = None  # an unexpected error in a transition (a bug)
        self._configured: list = []  # what configure created (released at cleanup)
        self.add_on_set_parameters_callback(self._refuse_configure_time_parameters)
        self.add_post_set_parameters_callback(self._forget_refusals)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # its own group: diagnostics go on during a long configure (the default group's transition)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=MutuallyExclusiveCallbackGroup(),
                          clock=self.steady)

    def declare_parameter(self, name, value=None, descriptor=None, ignore_override=False):
        """``Node.declare_parameter``; a read-only parameter becomes a configure-time one (class docstring)."""
        if descriptor is not None and descriptor.read_only and name not in START_UP_PARAMETERS:
            descriptor.read_only = False
            descriptor.additional_constraints = "; ".join(filter(None, (descriptor.additional_constraints,
                                                                        CONFIGURE_TIME)))
            self._configure_time.add(name)
        return super().declare_parameter(name, value, descriptor, ignore_override)

    def declare_parameters(self, namespace, parameters, ignore_override=False):
        """:class:`~.params.ParameterNode`'s, with a refused value kept for configure (class
        docstring): the parameter is declared with its default."""
        declared = []
        for entry in parameters:
            try:
                declared += super().declare_parameters(namespace, [entry], ignore_override)
            except NodeConfigError as exc:
                name = f"{namespace}.{entry[0]}" if namespace else entry[0]
                if name in START_UP_PARAMETERS:
                    raise
                declared += super().declare_parameters(namespace, [entry], ignore_override=True)
                self._refused[name] = str(exc)  # after the declaration: its set forgets refusals
        return declared

    def _forget_refusals(self, params: list[Parameter]) -> None:
        for p in params:
            self._refused.pop(p.name, None)

    @property
    def lifecycle_state(self) -> str:
        """The label of the current lifecycle state (``unconfigured``, ``inactive``, ``active``, ...)."""
        return self._state_machine.current_state[1]

    def _refuse_configure_time_parameters(self, params: list[Parameter]) -> SetParametersResult:
        late = [p.name for p in params if p.name in self._configure_time]
        state = self.lifecycle_state
        if late and state != "unconfigured":
            return SetParametersResult(successful=False, reason=(
                f"{', '.join(late)}: read-only while the node is {state} ({CONFIGURE_TIME}; "
                f"'ros2 lifecycle set {self.get_fully_qualified_name()} cleanup' first)"))
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------- bring-up
    def bring_up(self) -> None:
        """The end of a subclass's ``__init__``: :meth:`start`, unless ``runtime.run_nodes`` builds
        the node (it calls :meth:`start` once it has checked the given parameters)."""
        if not self.start_deferred:
            self.start()

    def start(self) -> None:
        """With ``autostart``: configure, then activate (class docstring); else wait unconfigured."""
        if not self.get_parameter("autostart").value:
            self.get_logger().info(f"unconfigured (autostart false): waiting for configure "
                                   f"('ros2 lifecycle set {self.get_fully_qualified_name()} configure')")
            return
        self._autostarting = True
        try:
            ok = self.trigger_configure() == TransitionCallbackReturn.SUCCESS
        finally:
            self._autostarting = False
        if not ok:
            if self._failure is not None:
                raise self._failure
            raise NodeConfigError(self.configure_error, node=self.get_name())
        if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:  # a bug: rclpy has swallowed it
            raise RuntimeError(f"{self.get_name()}: activate failed (see the log)")

    def configure_loop(self):
        """Read the parameters, build and return the loop (inactive) and its entities (class docstring)."""
        raise NotImplementedError

    def load_model(self, stages: SetupStages) -> POMDP:
        """Load ``model_file`` (a stage of the configure: reported when it takes over a second)."""
        with stages.stage("model file"):
            self.model = load_model_file(self.model_file)
        return self.model

    # ------------------------------------------------------------- transitions
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Parameters, model, loop (the planner's: the assumption gate and the bound LP), entities."""
        t0 = self._configuring_since = self.now()
        self._failure = None
        before = self._entities()
        try:
            if self._refused:
                raise NodeConfigError(next(iter(self._refused.values())))
            with config_errors():
                self.model_file = self.get_parameter("model_file").value
                self.live = liveness(self)
                loop = self.configure_loop()
            self.create_timer(self.live.watchdog_period, self._watchdog, clock=self.steady)
        except NodeConfigError as exc:
            return self._configure_failed(before, str(exc))
        except Exception as exc:  # a bug, not bad input: the traceback is logged (and raised by autostart)
            self._failure = exc
            self.get_logger().error(f"configure failed: {traceback.format_exc()}")
            return self._configure_failed(before, f"internal error: {exc!r}", logged=True)
        finally:
            self._configuring_since = None
        self._configured = [e for e in self._entities() if id(e) not in {id(b) for b in before}]
        self.configure_error = ""
        self.configure_seconds = self.now() - t0
        loop.health.set_clock(bool(self.get_parameter("use_sim_time").value), self.now())
        with self.lock:
            self.loop = loop
        self.call(loop.start)
        self.get_logger().info(f"configured in {self.configure_seconds:.2f} s")
        return super().on_configure(state)

    def _configure_failed(self, before: list, reason: str, logged: bool = False) -> TransitionCallbackReturn:
        self._configured = [e for e in self._entities() if id(e) not in {id(b) for b in before}]
        self._release_loop()
        self.configure_error = reason
        if not (self._autostarting or logged):  # autostart: the [FATAL] line says it
            self.get_logger().error(f"configure failed, still unconfigured: {reason}")
        return TransitionCallbackReturn.FAILURE

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Start publishing (the lifecycle publishers first), then the loop's activation."""
        ret = super().on_activate(state)
        try:
            self.call(self.loop.activate)
        except Exception:  # a bug: rclpy would swallow it without a word
            self.get_logger().error(f"activate failed: {traceback.format_exc()}")
            raise
        return ret

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The loop's deactivation (it keeps its state), then the lifecycle publishers."""
        self.call(self.loop.deactivate)
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Release the loop, the model and everything configure created."""
        self._release_loop()
        self.get_logger().info("cleaned up: model and loop released")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release_loop()
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """After an unexpected error in a transition: release everything (back to unconfigured)."""
        self._release_loop()
        return super().on_error(state)

    def _entities(self) -> list:
        return [*self.publishers, *self.subscriptions, *self.timers, *self.guards]

    def _release_loop(self) -> None:
        with self.lock:
            self.loop = None
            self.model = None
            self.checked.clear()
        for e in self._configured:
            if isinstance(e, LifecyclePublisher):
                self.destroy_lifecycle_publisher(e)
            elif e in self._publishers:
                self.destroy_publisher(e)
            elif e in self._subscriptions:
                self.destroy_subscription(e)
            elif e in self._timers:
                self.destroy_timer(e)
            elif e in self._guards:
                self.destroy_guard_condition(e)
        self._configured = []

    # ------------------------------------------------------------- diagnostics
    def report(self) -> tuple[str, Report]:
        """The loop's report in the states with a loop, else the state's (``core.loop.state_report``);
        ``lifecycle_state`` and ``configure_seconds`` among the values."""
        state = self.lifecycle_state
        with self.lock:
            loop = self.loop
            r = loop.report(self.now()) if loop is not None and state in LOOP_STATES else None
        since = self._configuring_since
        if r is None:
            r = state_report(state, configure_error=self.configure_error,
                             busy_for=None if since is None else self.now() - since)
        values = {"lifecycle_state": state, **r.values}
        if self.configure_seconds is not None:
            values["configure_seconds"] = round(self.configure_seconds, 3)
        hardware_id = loop.model.name if loop is not None else str(self.get_parameter("model_file").value)
        return hardware_id, Report(r.level, r.message, values)
