"""``planner``: anytime branch-and-bound with myopic policy bounds (paper Sec. V) on each new belief.

Topics (relative names, remappable):

* subscribes ``belief`` (``Float64MultiArray``, layout ``[("state", S), ("epoch=<t>", 1)]``), latest
  value only (``qos.LATCHED_QOS``: a backlog of older beliefs is never planned for);
* publishes ``action`` (``Int64MultiArray [epoch, action_priority]``, ``qos.STREAM_QOS``) with
  ``epoch = t + 1``: the action computed from the belief of epoch ``t`` moves the system to epoch
  ``t + 1``; so every action names the belief it was computed from;
* ``plan_info`` (``Float64MultiArray``, one record per decision: see ``messages``);
* ``/diagnostics`` (``DiagnosticArray``) about once a second: depth reached, nodes expanded,
  % pruned, whether the bounds certified the action, time used, deadline misses, the
  assumption-check status of the model, the parameters in force.

Each new belief (epoch greater than the last one planned for; a belief that fails validation is
counted, logged and never planned for) runs ``Planner.plan(belief, max_depth, time_budget,
use_bounds)``; the action is published within ``time_budget`` plus a small overhead (decoding,
the last depth's bookkeeping, publishing: see README for measured latencies). A decision whose
total time exceeds ``time_budget + deadline_slack`` counts as a deadline miss.

Planning runs in its own ``MutuallyExclusiveCallbackGroup``; parameter services and diagnostics
are in the default group, so on the ``MultiThreadedExecutor`` they are answered during a search.
Parameter changes take effect at the next decision (``bound_variant`` re-solves the bounds then).

Structural assumptions: the planner comes from the core's assumption gate
(``core.gate.build_planner``, the same rule as every other entry point). If the model fails
Assumption 1, the node warns once and searches exhaustively (``use_bounds`` ignored); with
``refuse_if_assumptions_fail`` (the gate's ``on_assumption_failure="refuse"``) it publishes
nothing and reports ERROR in diagnostics instead. An infeasible LP (or Shannon bounds covering no
domain) also means exhaustive search. Only guaranteed bounds certify a decision.
"""

from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.bounds import BOUND_VARIANTS
from ..core.gate import PlannerSetup, build_planner
from ..core.io.sensors import load_model_file
from ..core.search import Planner
from .diagnostics import status
from .messages import MessageError, decode_belief, encode_action, encode_plan_info
from .params import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE, declare_model_file, descriptor
from .qos import LATCHED_QOS, STREAM_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for

TUNABLE = ("time_budget", "max_depth", "use_bounds", "bound_variant", "deadline_slack")


class PlannerNode(Node):
    """Planner node (see module docstring)."""

    def __init__(self, node_name: str = "planner", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
        model_file = declare_model_file(self)
        self.declare_parameter("time_budget", 0.1, d(
            "Planning time per decision in seconds (anytime iterative deepening stops at it)",
            float_range=TIME_BUDGET_RANGE))
        self.declare_parameter("max_depth", 3, d("Maximum search depth (Table II convention)",
                                                 int_range=MAX_DEPTH_RANGE))
        self.declare_parameter("use_bounds", True, d("Prune with the myopic policy bounds (Sec. V)"))
        self.declare_parameter("bound_variant", BOUND_VARIANTS[0], d(
            "Bound vectors g, h to solve for", constraints=f"one of {', '.join(BOUND_VARIANTS)}"))
        self.declare_parameter("refuse_if_assumptions_fail", False, d(
            "If the model fails the structural assumptions: publish nothing (ERROR) instead of exhaustive search",
            read_only=True))
        self.declare_parameter("deadline_slack", 0.02, d(
            "Allowed overhead (s) beyond time_budget before a decision counts as a deadline miss",
            float_range=(0.0, 10.0)))
        self.declare_parameter("chunk_kib", 1024, d(
            "Memory per search chunk (KiB); the deadline is checked between chunks, so smaller = tighter "
            "deadlines (32 MiB chunks overshot a 0.2 s budget by up to 0.7 s on S = 8)",
            read_only=True, int_range=(16, 1 << 20)))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        with config_errors():
            self.model = load_model_file(model_file)
        self.params = {name: self.get_parameter(name).value for name in TUNABLE}
        bad = self._check_values({k: v for k, v in self.params.items()})
        if bad:
            raise NodeConfigError(bad)
        self._lock = threading.Lock()
        self._chunk_bytes = 1024 * self.get_parameter("chunk_kib").value
        self._on_failure = "refuse" if self.get_parameter("refuse_if_assumptions_fail").value else "exhaustive"
        self._planner: Planner | None = None
        self._planner_variant: str | None = None
        self._bounds_ok = False
        self._bounds_message = ""
        self._ensure_planner(self.params["bound_variant"])
        self.report = self.setup.report  # Assumption 1, checked once by the gate (cached per model)
        self.refusing = self.setup.mode == "refuse"
        if self.refusing:
            self.get_logger().error("model fails the structural assumptions; refusing to plan "
                                    f"(refuse_if_assumptions_fail): {self.report.summary()}")
        elif not self.report.holds:
            self.get_logger().warning("model fails the structural assumptions; the bounds are not valid, "
                                      f"falling back to exhaustive search: {self.report.summary()}")
        self.last_epoch = -1
        self.planning_epoch: int | None = None
        self.last = None
        self.last_latency = float("nan")
        self.last_params: dict = {}
        self.counts = {"decisions": 0, "deadline_misses": 0, "budget_exhausted": 0, "certified": 0,
                       "bad_beliefs": 0, "stale_beliefs": 0}
        self.last_warning = ""
        self._reported = {"deadline_misses": 0, "bad_beliefs": 0}  # counts at the previous diagnostics

        self.action_pub = self.create_publisher(Int64MultiArray, "action", STREAM_QOS)
        self.info_pub = self.create_publisher(Float64MultiArray, "plan_info", STREAM_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.plan_group = MutuallyExclusiveCallbackGroup()
        self.create_subscription(Float64MultiArray, "belief", self._on_belief, LATCHED_QOS,
                                 callback_group=self.plan_group)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f"{self.model.describe()}; assumptions {'hold' if self.report.holds else 'FAIL'}; "
            f"bounds {self._bounds_message}; time_budget {self.params['time_budget']:g} s, "
            f"max_depth {self.params['max_depth']}")

    # ----------------------------------------------------------- parameters
    @staticmethod
    def _check_values(values: dict) -> str:
        if "bound_variant" in values and values["bound_variant"] not in BOUND_VARIANTS:
            return f"bound_variant: {values['bound_variant']!r} is not one of {list(BOUND_VARIANTS)}"
        return ""

    def _validate_parameters(self, params) -> SetParametersResult:
        reason = self._check_values({p.name: p.value for p in params})
        return SetParametersResult(successful=not reason, reason=reason)

    def _apply_parameters(self, params) -> None:
        changed = {p.name: p.value for p in params if p.name in TUNABLE}
        if changed:
            with self._lock:
                self.params = {**self.params, **changed}
            self.get_logger().info(f"parameters changed {changed}; in force from the next decision")

    # ----------------------------------------------------------- planning
    def _ensure_planner(self, variant: str) -> None:
        """(Re)build the core planner for ``variant`` through the assumption gate: the bounds are
        solved once per variant (can take a while), Assumption 1 is checked once per model."""
        if self._planner_variant == variant:
            return
        setup = build_planner(self.model, variant=variant, on_assumption_failure=self._on_failure,
                              chunk_bytes=self._chunk_bytes)
        if setup.pruning:
            self._bounds_message = f"{variant}: feasible"
        elif setup.report is not None and setup.report.holds:  # the LP, not the model, is the problem
            self._bounds_message = f"{variant}: {setup.reason}; exhaustive search"
            self.get_logger().warning(f"bounds {self._bounds_message}")
        else:
            self._bounds_message = "not used (assumptions fail)"
        self.setup: PlannerSetup = setup
        self._bounds_ok = setup.pruning
        self._planner = setup.planner
        self._planner_variant = variant

    @callback
    def _on_belief(self, msg: Float64MultiArray) -> None:
        t0 = time.perf_counter()
        try:
            bel = decode_belief(msg, self.model.S)
        except MessageError as exc:
            with self._lock:
                self.counts["bad_beliefs"] += 1
                self.last_warning = f"ignored {exc}"
            self.get_logger().warning(f"ignored {exc}; no action published")
            return
        if bel.epoch <= self.last_epoch:
            with self._lock:
                self.counts["stale_beliefs"] += 1
            return
        self.last_epoch = bel.epoch
        if self.refusing:
            return
        with self._lock:
            params = dict(self.params)
        self._ensure_planner(params["bound_variant"])
        use_bounds = bool(params["use_bounds"]) and self._bounds_ok
        self.planning_epoch = bel.epoch  # the belief being planned for (None when idle)
        try:
            result = self._planner.plan(bel.belief, max_depth=params["max_depth"],
                                        time_budget=params["time_budget"], use_bounds=use_bounds)
        finally:
            self.planning_epoch = None
        self.action_pub.publish(encode_action(bel.epoch + 1, int(result.priority)))
        latency = time.perf_counter() - t0
        pruned = result.percent_pruned[-1] if result.percent_pruned else 0.0
        missed = latency > params["time_budget"] + params["deadline_slack"]
        self.info_pub.publish(encode_plan_info(
            epoch=bel.epoch + 1, action_priority=result.priority, depth=result.depth,
            nodes_expanded=sum(result.nodes_expanded), pruned_percent=pruned, certified=result.certified,
            time_used=result.time_used, latency=latency, deadline_hit=result.deadline_hit, deadline_miss=missed))
        with self._lock:
            self.last = result
            self.last_latency = latency
            self.last_params = {**params, "use_bounds_effective": use_bounds, "belief_epoch": bel.epoch}
            self.counts["decisions"] += 1
            self.counts["certified"] += bool(result.certified)
            self.counts["budget_exhausted"] += bool(result.deadline_hit)
            if missed:
                self.counts["deadline_misses"] += 1
                self.last_warning = (f"epoch {bel.epoch + 1}: decision took {latency * 1e3:.1f} ms "
                                     f"(budget {params['time_budget'] * 1e3:.0f} ms)")

    # ----------------------------------------------------------- diagnostics
    def diagnostics_values(self) -> tuple[bytes, str, dict]:
        """Level, message and values of the next diagnostics message (WARN: problems since the last one)."""
        with self._lock:
            r, counts, lp, params = self.last, dict(self.counts), dict(self.last_params), dict(self.params)
            latency, warning = self.last_latency, self.last_warning
        values: dict = {"assumptions_hold": self.report.holds, "assumptions": self.report.summary(),
                        "bounds": self._bounds_message, **{f"param.{k}": v for k, v in params.items()},
                        **counts}
        if r is not None:
            values.update({
                "last.belief_epoch": lp.get("belief_epoch"), "last.action_priority": int(r.priority),
                "last.depth": int(r.depth), "last.nodes_expanded": int(sum(r.nodes_expanded)),
                "last.pruned_percent": float(r.percent_pruned[-1]) if r.percent_pruned else 0.0,
                "last.certified": bool(r.certified), "last.time_used": float(r.time_used),
                "last.latency": float(latency), "last.deadline_hit": bool(r.deadline_hit),
                "last.time_budget": lp.get("time_budget"), "last.max_depth": lp.get("max_depth"),
                "last.use_bounds": lp.get("use_bounds_effective"),
            })
        recent = {k: counts[k] - n for k, n in self._reported.items()}
        self._reported = {k: counts[k] for k in self._reported}
        if self.refusing:
            return DiagnosticStatus.ERROR, "refusing to plan: model fails the structural assumptions", values
        if not self.report.holds:
            return DiagnosticStatus.WARN, "assumptions fail: exhaustive search", values
        if any(recent.values()):  # WARN while problems keep coming, OK again once they stop
            return DiagnosticStatus.WARN, (f"since the last report: {recent['deadline_misses']} deadline misses, "
                                           f"{recent['bad_beliefs']} bad beliefs; last: {warning}"), values
        if r is None:
            return DiagnosticStatus.OK, "waiting for a belief", values
        return DiagnosticStatus.OK, f"depth {r.depth}, {'certified' if r.certified else 'not certified'}", values

    @callback
    def _publish_diagnostics(self) -> None:
        level, text, values = self.diagnostics_values()
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status(f"{self.get_name()}: planning", self.model.name, level, text, values)]
        self.diag_pub.publish(msg)


def main(args=None) -> None:
    main_for([PlannerNode])


if __name__ == "__main__":
    main()
