"""``planner``: anytime branch-and-bound with myopic policy bounds (paper Sec. V) on each new belief.

Topics (relative names, remappable):

* subscribes ``belief`` (``Float64MultiArray``, layout ``[("state", S), ("epoch=<t>", 1)]``) with
  ``qos.STREAM_QOS`` (every sample: a stray or repeated belief cannot displace the real one from
  the reader) into a one-slot mailbox that keeps the newest valid, not-yet-planned belief within
  the epoch window; the planning callback takes it from there (a backlog of older beliefs is
  never planned for);
* publishes ``action`` (``Int64MultiArray [epoch, action_priority]``, ``qos.STREAM_QOS``) with
  ``epoch = t + 1``: the action computed from the belief of epoch ``t`` moves the system to epoch
  ``t + 1``; so every action names the belief it was computed from;
* ``plan_info`` (``Float64MultiArray``, one record per decision: see ``messages``);
* ``/diagnostics`` (``DiagnosticArray``) about once a second: depth reached, nodes expanded,
  % pruned, whether the bounds certified the action, time used, deadline misses, the
  assumption-check status of the model, the parameters in force.

Each new belief (epoch greater than the last one planned for and within ``epoch_window`` of it; a
belief that fails validation is counted, logged and never planned for) runs ``Planner.plan(belief,
max_depth, time_budget, use_bounds)``; the action is published within ``time_budget`` plus a small
overhead (decoding, the last depth's bookkeeping, publishing: see README for measured latencies).
A decision whose total time exceeds ``time_budget + deadline_slack`` counts as a deadline miss.

Liveness (``core/liveness.py``; README, "Liveness"): a belief beyond ``epoch_window`` is dropped
and counted (``out_of_window``); a stale or repeated one is counted (``stale_beliefs``); a
planner that for ``stall_warn_after`` seconds has received only stale or out-of-window beliefs (at
least three) re-syncs to the newest of them (a restarted filter on another numbering). A starting
planner plans the newest belief it receives within ``JOIN_DELAY`` of the first. The last
action is re-published every ``resend_period`` while the belief it leads to has not come, from a
cache of recent decisions: an epoch decided once is never re-planned differently (after a
re-sync too). ``belief`` silent or not advancing for ``stall_warn_after`` / ``stall_error_after``
seconds is WARN / ERROR in diagnostics.

Planning runs in its own ``MutuallyExclusiveCallbackGroup``; parameter services and diagnostics
are in the default group, so on the ``MultiThreadedExecutor`` they are answered during a search.
Parameter changes take effect at the next decision (``bound_variant`` and ``bound_constant``
re-solve the bounds then, once per pair: the gate's planners are kept by (variant, constant)).

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
from collections import OrderedDict

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT
from ..core.gate import PlannerSetup, build_planner
from ..core.io.sensors import load_model_file
from ..core.liveness import JOIN_DELAY, EpochLine, InputWatch, Level, Resender
from ..core.options import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE
from ..core.search import Planner
from .diagnostics import LEVELS, Warnings, array, status
from .messages import BeliefMsg, MessageError, bound_fields, decode_belief, encode_action, encode_plan_info
from .params import (
    ParameterNode,
    accept_integers_for_doubles,
    declare_double,
    declare_liveness,
    declare_model_file,
    descriptor,
)
from .qos import STREAM_QOS
from .runtime import NodeConfigError, callback, config_errors, main_for

TUNABLE = ("time_budget", "max_depth", "use_bounds", "bound_variant", "bound_constant", "deadline_slack")
#: Decisions kept (by epoch) to re-send or re-publish an epoch's action without planning it again.
DECISION_CACHE = 64


class PlannerNode(ParameterNode):
    """Planner node (see module docstring)."""

    def __init__(self, node_name: str = "planner", **kwargs):
        super().__init__(node_name, **kwargs)
        accept_integers_for_doubles(self)
        d = descriptor
        model_file = declare_model_file(self)
        declare_double(self, "time_budget", 0.1, d(
            "Planning time per decision in seconds (anytime iterative deepening stops at it)",
            float_range=TIME_BUDGET_RANGE))
        self.declare_parameter("max_depth", 3, d("Maximum search depth (Table II convention)",
                                                 int_range=MAX_DEPTH_RANGE))
        self.declare_parameter("use_bounds", True, d("Prune with the myopic policy bounds (Sec. V)"))
        self.declare_parameter("bound_variant", BOUND_VARIANTS[0], d(
            "Bound vectors g, h to solve for", constraints=f"one of {', '.join(BOUND_VARIANTS)}"))
        self.declare_parameter("bound_constant", DEFAULT_CONSTANT, d(
            "Belief-independent constant of the bound LP: mlr (exact for the MLR monotonicity Corollary 1 needs) "
            "or fosd (the stronger first-order dominance constant C_S)",
            constraints=f"one of {', '.join(BOUND_CONSTANTS)}"))
        self.declare_parameter("refuse_if_assumptions_fail", False, d(
            "If the model fails the structural assumptions: publish nothing (ERROR) instead of exhaustive search",
            read_only=True))
        declare_double(self, "deadline_slack", 0.02, d(
            "Allowed overhead (s) beyond time_budget before a decision counts as a deadline miss",
            float_range=(0.0, 10.0)))
        self.declare_parameter("chunk_kib", 1024, d(
            "Memory per search chunk (KiB); the deadline is checked between chunks, so smaller = tighter "
            "deadlines (32 MiB chunks overshot a 0.2 s budget by up to 0.7 s on S = 8)",
            read_only=True, int_range=(16, 1 << 20)))
        self.live = declare_liveness(self)
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
        self._planner_key: tuple[str, str] | None = None  # (bound_variant, bound_constant) of the planner
        self._bounds_ok = False
        self._bounds_message = ""
        self._ensure_planner(self.params["bound_variant"], self.params["bound_constant"])
        self.report = self.setup.report  # Assumption 1, checked once by the gate (cached per model)
        self.refusing = self.setup.mode == "refuse"
        if self.refusing:
            self.get_logger().error("model fails the structural assumptions; refusing to plan "
                                    f"(refuse_if_assumptions_fail): {self.report.summary()}")
        elif not self.report.holds:
            self.get_logger().warning("model fails the structural assumptions; the bounds are not valid, "
                                      f"falling back to exhaustive search: {self.report.summary()}")
        self.line = EpochLine(self.live.epoch_window)  # position: the last belief epoch planned for
        self.last_epoch = -1  # the same, -1 before the first
        self.planning_epoch: int | None = None
        self._mailbox: tuple[BeliefMsg, float] | None = None  # newest belief to plan, its arrival time
        self._join_first_seen: float | None = None  # first belief seen before the first decision
        self._decisions: OrderedDict[int, int] = OrderedDict()  # action epoch -> priority (recent ones)
        self._last_action = None
        self.resender = Resender(self.live.resend_period)
        self.watch = InputWatch("belief", "belief")
        self.last = None
        self.last_latency = float("nan")
        self.last_params: dict = {}
        self.counts = {"decisions": 0, "deadline_misses": 0, "budget_exhausted": 0, "certified": 0,
                       "bad_beliefs": 0, "stale_beliefs": 0, "out_of_window": 0, "resyncs": 0,
                       "resent_actions": 0, "cached_decisions": 0}
        self.warnings = Warnings(self.get_logger(), self.counts)
        # counts at the previous diagnostics (WARN while they grow)
        self._reported = {"deadline_misses": 0, "bad_beliefs": 0, "out_of_window": 0, "resyncs": 0}

        self.action_pub = self.create_publisher(Int64MultiArray, "action", STREAM_QOS)
        self.info_pub = self.create_publisher(Float64MultiArray, "plan_info", STREAM_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.plan_group = MutuallyExclusiveCallbackGroup()
        # Two readers of ``belief``, each taking every sample: in the default group, ``_on_belief``
        # decodes, checks and counts each one and keeps the newest to plan in the mailbox (it runs
        # during a search too); in plan_group, ``_on_belief_planning`` plans the mailbox's belief.
        # The planning reader runs right when a belief comes, so the usual decision costs no extra
        # hand-over between callbacks; the guard condition wakes the planning group only when the
        # mailbox got a belief after the planning reader had already taken that sample (and for a
        # join or a re-sync).
        self._received = self._planning_received = 0  # samples taken by each reader
        self.create_subscription(Float64MultiArray, "belief", self._on_belief, STREAM_QOS)
        self.create_subscription(Float64MultiArray, "belief", self._on_belief_planning, STREAM_QOS,
                                 callback_group=self.plan_group)
        self._plan_trigger = self.create_guard_condition(self._plan_next, callback_group=self.plan_group)
        self._join_timer = self.create_timer(JOIN_DELAY, self._on_join_timer, autostart=False)
        self.create_timer(self.live.watchdog_period, self._watchdog)
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
        if "bound_constant" in values and values["bound_constant"] not in BOUND_CONSTANTS:
            return f"bound_constant: {values['bound_constant']!r} is not one of {list(BOUND_CONSTANTS)}"
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
    def _ensure_planner(self, variant: str, constant: str) -> None:
        """(Re)build the core planner for ``variant`` and ``constant`` through the assumption gate:
        the bounds are solved when the pair changes (can take a while), Assumption 1 is checked once
        per model."""
        if self._planner_key == (variant, constant):
            return
        setup = build_planner(self.model, variant=variant, constant=constant, on_assumption_failure=self._on_failure,
                              chunk_bytes=self._chunk_bytes)
        bounds = f"{variant}, constant {constant}"
        if setup.pruning:
            self._bounds_message = f"{bounds}: feasible"
        elif setup.report is not None and setup.report.holds:  # the LP, not the model, is the problem
            self._bounds_message = f"{bounds}: {setup.reason}; exhaustive search"
            self.get_logger().warning(f"bounds {self._bounds_message}")
        else:
            self._bounds_message = "not used (assumptions fail)"
        self.setup: PlannerSetup = setup
        self._bounds_ok = setup.pruning
        self._planner = setup.planner
        self._planner_key = (variant, constant)

    @callback
    def _on_belief(self, msg: Float64MultiArray) -> None:
        """Receive a belief: the newest valid, not-yet-planned one within the window goes to the
        mailbox; every other one is counted."""
        arrived = time.perf_counter()
        try:
            bel = decode_belief(msg, self.model.S)
        except MessageError as exc:
            with self._lock:
                self._received += 1
                self.watch.arrived(False)
                self.warnings.warn("bad_beliefs", f"ignored {exc}; no action published")
            return
        with self._lock:
            self._received += 1
            verdict = self.line.classify(bel.epoch)
            new = verdict in ("join", "next", "ahead")
            self.watch.arrived(new, bel.epoch)
            if new:
                self.resender.answered()
                if self._mailbox is None or bel.epoch > self._mailbox[0].epoch:
                    self._mailbox = (bel, arrived)
                if verdict == "join" and self._join_first_seen is None:
                    # joining: the newest of what comes within JOIN_DELAY (a restarted filter's history
                    # starts with its prior at epoch 0; a running filter's history ends at its epoch)
                    self._join_first_seen = time.monotonic()
                    self._join_timer.reset()
            elif verdict == "out_of_window":
                self.line.off_line(bel.epoch, (bel, arrived))
                self.warnings.warn("out_of_window", f"belief of epoch {bel.epoch} is beyond the epoch window "
                                   f"({self.live.epoch_window}) of epoch {self.line.position}: dropped (a restarted "
                                   "filter or a forged message)")
            else:
                self.counts["stale_beliefs"] += 1
                if verdict == "behind":
                    self.line.off_line(bel.epoch, (bel, arrived))
            resynced = self._resync_if_due()
            # the planning reader has taken this sample already (it may run ahead): wake it again
            wake = self._mailbox is not None and (resynced or self._planning_received >= self._received)
        if wake:
            self._plan_trigger.trigger()

    @callback
    def _on_belief_planning(self, msg: Float64MultiArray) -> None:
        """The planning group's reader: plan what the mailbox holds (``_on_belief`` checks the sample)."""
        with self._lock:
            self._planning_received += 1
        self._plan_next()

    def _resync_if_due(self) -> bool:
        """(lock held) The re-sync rule: put the newest off-line belief in the mailbox."""
        due = self.line.resync_due(self.live.stall.warn_after)
        if due is None:
            return False
        self.warnings.warn("resyncs", self.line.resync_reason(due, "beliefs", "filter"))
        self.line.resync(due.epoch - 1)  # so that the belief of due.epoch is the next one
        self._mailbox = due.payload
        return True

    @callback
    def _on_join_timer(self) -> None:
        self._join_timer.cancel()
        self._plan_trigger.trigger()

    @callback
    def _plan_next(self) -> None:
        """The planning callback (plan_group): plan the belief in the mailbox, if any."""
        with self._lock:
            if self.line.position is None and (self._join_first_seen is None
                                               or time.monotonic() - self._join_first_seen < JOIN_DELAY):
                return  # joining: the join timer wakes this callback again
            taken, self._mailbox = self._mailbox, None
            if taken is None:
                return
            bel, t0 = taken
            if self.line.position is None:  # the join: the deliberate JOIN_DELAY is not decision latency
                t0 = time.perf_counter()
            elif bel.epoch <= self.line.position:
                return  # a newer one was planned meanwhile
            self.line.advance(bel.epoch)
            self.last_epoch = bel.epoch
            cached = self._decisions.get(bel.epoch + 1)
        if self.refusing:
            return
        if cached is not None:  # decided before (a re-sync came back to it): the same action again
            self._publish_action(encode_action(bel.epoch + 1, cached))
            with self._lock:
                self.counts["cached_decisions"] += 1
            return
        with self._lock:
            params = dict(self.params)
        self._ensure_planner(params["bound_variant"], params["bound_constant"])
        use_bounds = bool(params["use_bounds"]) and self._bounds_ok
        self.planning_epoch = bel.epoch  # the belief being planned for (None when idle)
        try:
            result = self._planner.plan(bel.belief, max_depth=params["max_depth"],
                                        time_budget=params["time_budget"], use_bounds=use_bounds)
        finally:
            self.planning_epoch = None
        self._publish_action(encode_action(bel.epoch + 1, int(result.priority)))
        with self._lock:
            self._decisions[bel.epoch + 1] = int(result.priority)
            while len(self._decisions) > DECISION_CACHE:
                self._decisions.popitem(last=False)
        latency = time.perf_counter() - t0
        pruned = result.percent_pruned[-1] if result.percent_pruned else 0.0
        missed = latency > params["time_budget"] + params["deadline_slack"]
        self.info_pub.publish(encode_plan_info(
            epoch=bel.epoch + 1, action_priority=result.priority, depth=result.depth,
            nodes_expanded=sum(result.nodes_expanded), pruned_percent=pruned, certified=result.certified,
            time_used=result.time_used, latency=latency, deadline_hit=result.deadline_hit, deadline_miss=missed,
            **bound_fields(result.root_bounds)))
        with self._lock:
            self.last = result
            self.last_latency = latency
            self.last_params = {**params, "use_bounds_effective": use_bounds, "belief_epoch": bel.epoch}
            self.counts["decisions"] += 1
            self.counts["certified"] += bool(result.certified)
            self.counts["budget_exhausted"] += bool(result.deadline_hit)
            if missed:
                self.counts["deadline_misses"] += 1
                self.warnings.last = (f"epoch {bel.epoch + 1}: decision took {latency * 1e3:.1f} ms "
                                      f"(budget {params['time_budget'] * 1e3:.0f} ms)")

    def _publish_action(self, msg) -> None:
        self.action_pub.publish(msg)
        with self._lock:
            self._last_action = msg
            self.resender.published()

    @callback
    def _watchdog(self) -> None:
        """Re-send the last action while the belief it leads to has not come; the time-based re-sync."""
        with self._lock:
            resend = self._last_action if self.resender.due() and self.planning_epoch is None else None
            if resend is not None:
                self.resender.resending()
                self.counts["resent_actions"] += 1
            self._resync_if_due()
            wake = self._mailbox is not None
        if resend is not None:
            self.action_pub.publish(resend)
        if wake:
            self._plan_trigger.trigger()

    # ----------------------------------------------------------- diagnostics
    def diagnostics_values(self) -> tuple[bytes, str, dict]:
        """Level, message and values of the next diagnostics message (WARN: problems since the last one)."""
        with self._lock:
            r, counts, lp, params = self.last, dict(self.counts), dict(self.last_params), dict(self.params)
            latency, warning = self.last_latency, self.warnings.last
            stall, stall_text = self.watch.status(self.live.stall)
            watch_values = self.watch.values()
        values: dict = {"assumptions_hold": self.report.holds, "assumptions": self.report.summary(),
                        "bounds": self._bounds_message, **{f"param.{k}": v for k, v in params.items()},
                        **counts, **watch_values}
        if r is not None:
            values.update({
                "last.belief_epoch": lp.get("belief_epoch"), "last.action_priority": int(r.priority),
                "last.depth": int(r.depth), "last.nodes_expanded": int(sum(r.nodes_expanded)),
                "last.pruned_percent": float(r.percent_pruned[-1]) if r.percent_pruned else 0.0,
                "last.certified": bool(r.certified), "last.time_used": float(r.time_used),
                "last.latency": float(latency), "last.deadline_hit": bool(r.deadline_hit),
                "last.time_budget": lp.get("time_budget"), "last.max_depth": lp.get("max_depth"),
                "last.use_bounds": lp.get("use_bounds_effective"),
                "last.bound_variant": lp.get("bound_variant"), "last.bound_constant": lp.get("bound_constant"),
            })
        recent = {k: counts[k] - n for k, n in self._reported.items()}
        self._reported = {k: counts[k] for k in self._reported}
        if self.refusing:
            return DiagnosticStatus.ERROR, "refusing to plan: model fails the structural assumptions", values
        level, texts = stall, [stall_text] if stall_text else []
        if not self.report.holds:
            level = max(level, Level.WARN)
            texts.insert(0, "assumptions fail: exhaustive search")
        if any(recent.values()):  # WARN while problems keep coming, OK again once they stop
            level = max(level, Level.WARN)
            texts.append(f"since the last report: {recent['deadline_misses']} deadline misses, "
                         f"{recent['bad_beliefs']} bad beliefs, {recent['out_of_window']} beliefs out of the "
                         f"epoch window, {recent['resyncs']} re-syncs; last: {warning}")
        if not texts:
            texts = ["waiting for a belief" if r is None else
                     f"depth {r.depth}, {'certified' if r.certified else 'not certified'}"]
        return LEVELS[level], "; ".join(texts), values

    @callback
    def _publish_diagnostics(self) -> None:
        level, text, values = self.diagnostics_values()
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: planning", self.model.name, level, text, values)))


def main(args=None) -> None:
    main_for([PlannerNode])


if __name__ == "__main__":
    main()
