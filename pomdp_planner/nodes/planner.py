"""``planner``: anytime branch-and-bound with myopic policy bounds (paper Sec. V) on each new belief.

Topics (relative names, remappable; layouts: :mod:`.messages`, QoS: :mod:`.qos`):

* subscribes ``belief`` (``Float64MultiArray``, layout ``[("state", S), ("epoch=<t>", 1)]``,
  ``STREAM_QOS``: every sample);
* publishes ``action`` (``Int64MultiArray [t + 1, action_priority]``: the action computed from
  the belief of epoch ``t``, ``STREAM_QOS``), ``plan_info`` (one record per decision) and
  ``/diagnostics`` (``planner: planning``).

The planner comes from the core's assumption gate (``core/gate.py``); which belief is planned,
joining, re-sync, the decision cache, re-sending and what the diagnostics may claim are the
core's :class:`~pomdp_planner.core.loop.PlannerLoop`. Planning runs in its own
``MutuallyExclusiveCallbackGroup``: a second reader of ``belief`` there plans as soon as a
belief comes, while the default group checks and counts every belief and answers the parameter
services and diagnostics during a search. Parameters change at the next decision. Parameters,
topics and diagnostics: docs/ros.md.
"""

from __future__ import annotations

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT
from ..core.gate import MAX_SETUP_SECONDS, SetupStages
from ..core.loop import TUNABLE, PlannerLoop, PlannerOutput, check_params
from ..core.loop.planner_loop import setup_limit
from ..core.options import MAX_DEPTH_RANGE, TIME_BUDGET_RANGE
from .loop_node import ManagedLoopNode, OneShot
from .messages import MessageError, decode_belief, encode_action, encode_plan_info, wire_bounds
from .params import declare_double, descriptor
from .qos import STREAM_QOS
from .runtime import callback, main_for
from .take import subscribe


class PlannerNode(ManagedLoopNode):
    """Planner node, a managed node (see module docstring; its lifecycle: :class:`ManagedLoopNode`)."""

    task = "planning"

    def __init__(self, node_name: str = "planner", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
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
        declare_double(self, "max_setup_seconds", MAX_SETUP_SECONDS, d(
            "Longest set-up accepted at configure (assumption check, bound LP, planner tables), as estimated "
            "before it starts, in seconds; 0: no limit. A set-up expected to take more is refused in one line",
            read_only=True, float_range=(0.0, 1e9)))
        self.declare_parameter("chunk_kib", 1024, d(
            "Memory per search chunk (KiB); the deadline is checked between chunks, so smaller = tighter "
            "deadlines",
            read_only=True, int_range=(16, 1 << 20)))
        self.accept_changes(check_params)
        self.bring_up()

    def configure_loop(self) -> PlannerLoop:
        """The model, the assumption gate, the bound LP and the planner's tables; the topics."""
        value = self.get_parameter
        stages = SetupStages(self.get_logger().info)
        model = self.load_model(stages)
        loop = PlannerLoop(model, {name: value(name).value for name in TUNABLE}, self.live, now=self.now(),
                           refuse=value("refuse_if_assumptions_fail").value,
                           chunk_bytes=1024 * value("chunk_kib").value, progress=self.get_logger().info, active=False,
                           max_setup_seconds=setup_limit(value("max_setup_seconds").value))
        self.action_pub = self.create_lifecycle_publisher(Int64MultiArray, "action", STREAM_QOS)
        self.info_pub = self.create_lifecycle_publisher(Float64MultiArray, "plan_info", STREAM_QOS)
        plan_group = MutuallyExclusiveCallbackGroup()
        # Two readers of ``belief``: in the default group ``_on_belief`` decodes, checks and counts
        # each sample into the loop's mailbox (during a search too); in plan_group
        # ``_on_belief_planning`` plans what the mailbox holds, right when a belief comes. The two
        # readers need not see the same samples (one may match a writer later, or lose a large
        # sample whose writer left during its delivery), so the default group wakes plan_group
        # (the guard condition) whenever the mailbox holds a belief; a wake-up that finds the
        # mailbox taken plans nothing. The guard also serves the join.
        bound = wire_bounds(self.model.S)["belief"]
        self.subscribe_input("belief", Float64MultiArray, "belief", STREAM_QOS, self._on_belief, bound=bound,
                             kind="belief",
                             on_bad=lambda problem: self.call(self.loop.rejected_belief, problem))
        subscribe(self, Float64MultiArray, "belief", self._on_belief_planning, STREAM_QOS, bound.max_bytes,
                  callback_group=plan_group, screen=self._followed_belief)
        self._plan_trigger = self.create_guard_condition(self._plan_next, callback_group=plan_group)
        self._join = OneShot(self, self._plan_trigger.trigger)
        return loop

    @callback
    def _on_belief(self, msg: Float64MultiArray) -> None:
        now = self.now()
        try:
            bel, problem = decode_belief(msg, self.model.S), ""
        except MessageError as exc:
            bel, problem = None, str(exc)
        with self.lock:
            if bel is None:
                out = self.loop.rejected_belief(problem, now)
            else:
                out = self.loop.belief(bel, now, planner_ahead=True)
        self.emit(out)

    def _followed_belief(self, raw: bytes | None, info: dict) -> bool:
        """The planning reader's screen: only a sample of the followed writer wakes the planning side
        (a flood of foreign beliefs costs it nothing; the other reader counts them)."""
        return raw is not None and self.checked.followed("belief", info.get("publisher_gid"))

    @callback
    def _on_belief_planning(self, raw: bytes | None, info: dict) -> None:
        """The planning reader: wakes the planning side as a belief comes (its content is the other
        reader's business)."""
        self._plan_next()

    @callback
    def _plan_next(self) -> None:
        """The planning callback (plan_group): plan the belief in the mailbox, if any."""
        with self.lock:
            loop = self.loop  # None after a cleanup
            job = None if loop is None else loop.take(self.now())
        if job is not None:
            self.call(loop.decided, job, None if job.cached is not None else loop.search(job))

    def emit(self, out: PlannerOutput) -> None:
        for a in out.actions:
            self.action_pub.publish(encode_action(a.epoch, a.priority))
        if out.plan_info is not None:
            self.info_pub.publish(encode_plan_info(**out.plan_info.as_dict()))
        self.log(out.logs)
        self._join.arm(out.join_at, self.now())
        if out.plan_now:
            self._plan_trigger.trigger()


def main(args=None) -> None:
    main_for([PlannerNode])


if __name__ == "__main__":
    main()
