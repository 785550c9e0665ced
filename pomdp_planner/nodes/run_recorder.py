"""``run_recorder``: the loop's topics, paired by epoch, streamed to a run-record CSV.

Topics (relative names, remappable; layouts: :mod:`.messages`):

* subscribes ``belief``, ``action``, ``plan_info`` and ``true_state`` (``RECORDER_QOS``: reliable,
  transient-local like the writers, so it matches them and gets their history when it starts late),
  each sample checked for its size and its writer before it is decoded, as the loop nodes' inputs;
* publishes ``/diagnostics`` (``run_recorder: recording``).

Row ``t`` of the record is the decision made from the belief of epoch ``t``: that belief, the true
state of epoch ``t`` where a simulator publishes it, the action ``[t + 1, p]`` and the
``plan_info`` of epoch ``t + 1``. The pairing rule (when a row is written, what it waits for,
bounded memory) is the core's :class:`~pomdp_planner.core.loop.recorder_loop.RecorderLoop`; the
format is :mod:`~pomdp_planner.core.io.run_record` (``pomdp-planner plot FILE`` draws it). Each
row is flushed as it is written, whole or not at all; at exit the rows still waiting are written
with what they have. A write that fails (a full disk) is one ERROR line and diagnostics at ERROR;
the file ends on its last whole row and the node goes on without recording.
:class:`RunInputs` (the subscriptions and the loop's timer) is also the demo's monitor's.
Parameters: docs/ros.md ("Run recorder").
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.errors import InputError
from ..core.io.outputs import check_output_file
from ..core.io.run_bag import is_bag, open_run_output, write_row
from ..core.io.sensors import load_model_file
from ..core.loop import Level
from ..core.loop.epochs import DEFAULT_EPOCH_WINDOW
from ..core.loop.recorder_loop import DEFAULT_MAX_PENDING_ROWS, DEFAULT_ROW_TIMEOUT, RecorderLoop, RecorderOutput
from ..core.options import TIME_BUDGET_RANGE
from .diagnostics import array, status
from .inputs import CheckedInputs
from .loop_node import OneShot
from .messages import (
    MessageError,
    decode_action,
    decode_belief,
    decode_observation,
    decode_plan_info,
    decode_true_state,
    wire_bounds,
)
from .params import ParameterNode, declare_double, declare_model_file, descriptor
from .qos import RECORDER_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for


class RunInputs:
    """``node``'s subscriptions to ``belief``, ``action``, ``plan_info`` and ``true_state`` feeding
    ``loop``: each sample checked for size and writer before it is decoded (:class:`~.inputs.CheckedInputs`:
    the rules "Bounded samples" and "One writer", counted in the loop's health), then decoded and
    passed with ``time.monotonic()``; the one-shot timer of the loop's time-outs, and once a second
    the graph's writers and the takeovers. Every output of the loop goes to ``emit``, under one lock."""

    def __init__(self, node: Node, loop: RecorderLoop, emit: Callable[[RecorderOutput], None]):
        self.context = node.context  # for @callback
        self.loop, self.emit = loop, emit
        self.lock = threading.Lock()
        S, A = loop.S, loop.A
        bounds = wire_bounds(S)
        inputs = {"belief": (Float64MultiArray, lambda m: decode_belief(m, S), loop.belief),
                  "action": (Int64MultiArray, lambda m: decode_action(m, A), loop.action),
                  "plan_info": (Float64MultiArray, decode_plan_info, loop.plan_info),
                  "true_state": (Int64MultiArray, decode_true_state, lambda s, now: loop.true_state(*s, now))}
        self.checked = CheckedInputs(node, self.lock, lambda: loop.health, lambda logs: emit(RecorderOutput(logs=logs)))
        self.subscriptions = {
            topic: self.checked.subscribe(topic, kind, topic, RECORDER_QOS,
                                          functools.partial(self._on_message, topic, decode, apply),
                                          bound=bounds[topic],
                                          on_bad=functools.partial(self.call, loop.rejected, topic)).sub
            for topic, (kind, decode, apply) in inputs.items()}
        self._timer = OneShot(node, lambda: self.call(loop.poll))
        node.create_timer(1.0, self._writers, clock=Clock(clock_type=ClockType.STEADY_TIME))

    @callback
    def _on_message(self, topic: str, decode: Callable, apply: Callable, msg) -> None:
        try:
            sample = decode(msg)
        except MessageError as exc:
            self.call(self.loop.rejected, topic, str(exc))
            return
        self.call(apply, sample)

    @callback
    def _writers(self) -> None:
        self.checked.look_at_graphs()
        self.checked.takeovers()

    def call(self, method: Callable, *args) -> RecorderOutput:
        """``method(*args, now)`` of the loop with the lock held; its output emitted, its timer armed."""
        with self.lock:
            now = time.monotonic()
            out = method(*args, now)
            self.emit(out)
            self._timer.arm(out.due, now)
        return out


class RunRecorderNode(ParameterNode):
    """Records the loop as a run-record CSV (module docstring)."""

    def __init__(self, node_name: str = "run_recorder", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
        self.model_file = declare_model_file(self)
        self.declare_parameter("file", "", d("The run-record CSV to write (created or overwritten; relative to the "
                                             "working directory)", read_only=True))
        declare_double(self, "time_budget", 0.0, d(
            "The planner's time_budget (s), written into the record for the plot's budget line; 0 = none",
            read_only=True, float_range=(0.0, TIME_BUDGET_RANGE[1])))
        declare_double(self, "row_timeout", DEFAULT_ROW_TIMEOUT, d(
            "Seconds a row with its belief and action waits for its plan_info (and true state) when their topic "
            "has not moved past it", read_only=True, float_range=(0.01, 3600.0)))
        self.declare_parameter("max_pending_rows", DEFAULT_MAX_PENDING_ROWS, d(
            "Rows that may wait at once; one more forces the oldest out", read_only=True, int_range=(1, 1_000_000)))
        self.declare_parameter("epoch_window", DEFAULT_EPOCH_WINDOW, d(
            "A sample more than this many epochs beyond the last row written is dropped", read_only=True,
            int_range=(1, 1_000_000)))
        self.declare_parameter("expect_true_state", False, d(
            "Wait (up to row_timeout) for each row's true state from the start (a simulated run); without it, "
            "true states are awaited once the first one has arrived", read_only=True))
        value = self.get_parameter
        path = value("file").value
        if not path.strip():
            raise NodeConfigError("file: must name the CSV file to write, e.g. -p file:=run.csv")
        budget = value("time_budget").value
        with config_errors():
            self.model = load_model_file(self.model_file)
            check_output_file(path, "file", stdout=False)
            self.writer = open_run_output(path, "file", self.model.name, self.model.S, self.model.A,
                                          budget if budget > 0 else None, namespace=self.get_namespace())
        self.path = path
        self.write_error = ""
        self.last_row: int | None = None
        self.loop = RecorderLoop(self.model.S, self.model.A, now=time.monotonic(),
                                 row_timeout=value("row_timeout").value,
                                 max_pending_rows=value("max_pending_rows").value,
                                 epoch_window=value("epoch_window").value,
                                 expect_true_state=value("expect_true_state").value)
        self.inputs = RunInputs(self, self.loop, self._emit)
        if is_bag(path):  # a bag also keeps the loop's readings, as they come (for replay)
            self.create_subscription(Int64MultiArray, "observation", self._on_observation, RECORDER_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f"recording {self.model.name} (S={self.model.S}, A={self.model.A}) to {path}")

    def _emit(self, out: RecorderOutput) -> None:
        for line in out.logs:
            (self.get_logger().warning if line.level == "warning" else self.get_logger().info)(line.text)
        if self.writer is None:
            return
        try:
            for row in out.rows:
                write_row(self.writer, row.epoch, row.belief, row.priority, info=row.info, **row.record_fields())
                self.last_row = row.epoch
        except InputError as exc:  # a full disk (the rows are valid: the loop checked their parts)
            ends = "no row" if self.last_row is None else f"the row of epoch {self.last_row}"
            self.write_error = f"{exc}; recording stopped (the file ends on {ends})"
            self.get_logger().error(self.write_error)
            self._close_file()

    @callback
    def _on_observation(self, msg: Int64MultiArray) -> None:
        """A reading of the loop, written into the bag as it comes (only recorded: a malformed one is
        left out; the rows' rules do not use it)."""
        try:
            obs = decode_observation(msg, self.model.A, self.model.Z)
        except MessageError:
            return
        with self.inputs.lock:
            if self.writer is None:
                return
            try:
                self.writer.observation(obs.epoch, obs.priority, obs.observation)
            except InputError as exc:
                self.write_error = f"{exc}; recording stopped"
                self.get_logger().error(self.write_error)
                self._close_file()

    def _close_file(self) -> None:
        writer, self.writer = self.writer, None
        if writer is not None:
            try:
                writer.close()
            except OSError:
                pass

    @callback
    def _publish_diagnostics(self) -> None:
        with self.inputs.lock:
            r = self.loop.report(time.monotonic())
        level, message = (Level.ERROR, f"{self.write_error}; {r.message}") if self.write_error else (r.level,
                                                                                                     r.message)
        values = {"file": self.path, **r.values}
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: recording", self.model.name, level, message,
                                                 values)))

    def destroy_node(self) -> None:
        """Write the rows still waiting (with what they have), close the file, then destroy the node."""
        if getattr(self, "inputs", None) is not None:
            self.inputs.call(self.loop.close)
        self._close_file()
        super().destroy_node()


def main(args=None) -> None:
    main_for([RunRecorderNode])


if __name__ == "__main__":
    main()
