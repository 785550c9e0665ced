"""``sensor_manager``: one sensing budget shared by K targets (docs/multitarget.md): every epoch a
priority for every target, the actions in force never costing more than ``effort_budget``.

Topics (relative names, remappable; layouts: :mod:`.messages`, QoS: :mod:`.qos`), for every
namespace ``<ns>`` of ``targets``:

* subscribes ``<ns>/belief`` (``Float64MultiArray``, the target's belief filter, ``STREAM_QOS``;
  every sample checked for its size and its writer before it is decoded, as every loop node's);
* publishes ``<ns>/action`` (``Int64MultiArray [t + 1, action_priority]``: computed from that
  target's belief of epoch ``t``, ``STREAM_QOS``), and once per decision ``allocation`` (every
  target's action in force, one record) and ``/diagnostics`` (``sensor_manager: allocation``:
  the price, the dual bound and the gap, labelled guaranteed or not as the planner says, the
  budget in force and every target's input).

The rules (pairing, the actions in force and the budget, when to decide, silent targets; and per
target the planner's: window, join, mailbox, re-sync, re-send, stall levels) are the core's
:class:`~pomdp_planner.core.loop.ManagerLoop`; the joint decision is the core's
:class:`~pomdp_planner.core.multitarget.planner.MultiTargetPlanner`. Decisions run in their own
``MutuallyExclusiveCallbackGroup``, so beliefs are counted and parameters answered during a
search. A managed (lifecycle) node, as the planner: ``configure`` reads the parameters, loads the
models and runs every target's gate, ``activate`` / ``deactivate`` start and stop deciding
(``autostart``, default true, walks both at start-up). Parameters, topics and diagnostics:
docs/ros.md, "Sensor manager".
"""

from __future__ import annotations

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from ..core.bounds import BOUND_CONSTANTS, BOUND_VARIANTS, DEFAULT_CONSTANT
from ..core.io.sensors import load_model_file
from ..core.loop import ManagerLoop, ManagerOutput
from ..core.loop.manager_params import RANGES, TUNABLE, check_params, check_targets, manager_problem
from ..core.multitarget.planner import DEFAULT_EVALUATIONS, MAX_EVALUATIONS_RANGE, SEARCH_MODES
from ..core.multitarget.problem import MAX_CAPACITY_UNITS
from .loop_node import ManagedLoopNode, OneShot
from .messages import MessageError, decode_belief, encode_action, encode_allocation, wire_bounds
from .params import declare_double, declare_optional_array, descriptor, optional_array
from .qos import STREAM_QOS
from .runtime import callback, main_for


class SensorManager(ManagedLoopNode):
    """Sensor manager node, a managed node (see module docstring; its lifecycle: :class:`ManagedLoopNode`)."""

    task = "allocation"

    def __init__(self, node_name: str = "sensor_manager", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
        declare_optional_array(self, "targets", "string",
                               "Namespaces of the targets, e.g. [target1, target2, target3]: reads <ns>/belief, "
                               "publishes <ns>/action")
        declare_optional_array(self, "model_files", "string",
                               "One model file per target (aligned with targets); unset: model_file for every target")
        declare_double(self, "effort_budget", 1.0, d(
            "Effort budget B: the actions in force of all targets never cost more together",
            read_only=True, float_range=(0.0, float(MAX_CAPACITY_UNITS))))
        declare_optional_array(self, "efforts", "double",
                               "Effort of each priority 1..A: A values for every target, or every target's A "
                               "values one target after the other; unset: A - p for priority p")
        declare_double(self, "discount", -1.0, d(
            "The joint discount, replacing every model's (0..1); -1: the models' common discount",
            read_only=True, float_range=(-1.0, 1.0)))
        self.declare_parameter("search", SEARCH_MODES[0], d(
            "Per-target search: bnb (myopic bounds where the gate allows) or exhaustive (the dual bound is then "
            "guaranteed)", read_only=True, constraints=f"one of {', '.join(SEARCH_MODES)}"))
        declare_double(self, "time_budget", 0.1, d(
            "Seconds per joint decision, all targets and prices (anytime iterative deepening)",
            float_range=RANGES["time_budget"]))
        self.declare_parameter("max_depth", 3, d("Deepest search depth (Table II convention)",
                                                 int_range=RANGES["max_depth"]))
        self.declare_parameter("max_evaluations", DEFAULT_EVALUATIONS, d(
            "Evaluations of the dual bound (each one search per target) per depth, in the search for the price",
            read_only=True, int_range=MAX_EVALUATIONS_RANGE))
        declare_double(self, "gather_timeout", 0.1, d(
            "Seconds a decision waits, after the first target's new belief, for the other targets' before it "
            "decides without them", float_range=RANGES["gather_timeout"]))
        declare_double(self, "deadline_slack", 0.02, d(
            "Allowed overhead (s) beyond time_budget before a decision counts as a deadline miss",
            float_range=RANGES["deadline_slack"]))
        self.declare_parameter("bound_variant", BOUND_VARIANTS[0], d(
            "Bound vectors g, h of every target", read_only=True, constraints=f"one of {', '.join(BOUND_VARIANTS)}"))
        self.declare_parameter("bound_constant", DEFAULT_CONSTANT, d(
            "Constant of the bound LP (mlr or fosd)", read_only=True,
            constraints=f"one of {', '.join(BOUND_CONSTANTS)}"))
        self.accept_changes(check_params)
        self.bring_up()

    def configure_loop(self) -> ManagerLoop:
        """The targets, their models and the joint problem, the gate of every target; the topics."""
        value = self.get_parameter
        targets = check_targets(optional_array(self, "targets") or [])
        files = optional_array(self, "model_files")
        if files is None:
            models = [load_model_file(self.model_file)] * len(targets)
        else:
            loaded = {}  # one model object per file: targets of one file are searched as one batch
            for k, f in enumerate(files):
                if f not in loaded:
                    loaded[f] = load_model_file(f, f"model_files[{k}]")
            models = [loaded[f] for f in files]
        discount = value("discount").value
        problem = manager_problem(targets, models, value("effort_budget").value, optional_array(self, "efforts"),
                                  None if discount == -1.0 else discount)
        loop = ManagerLoop(problem, {name: value(name).value for name in TUNABLE}, self.live, now=self.now(),
                           search=value("search").value, variant=value("bound_variant").value,
                           constant=value("bound_constant").value,
                           max_evaluations=value("max_evaluations").value, active=False)
        self.action_pubs = [self.create_lifecycle_publisher(Int64MultiArray, f"{t}/action", STREAM_QOS)
                            for t in targets]
        self.allocation_pub = self.create_lifecycle_publisher(Int64MultiArray, "allocation", STREAM_QOS)
        for k, (t, m) in enumerate(zip(targets, models, strict=True)):
            self.subscribe_input(f"{t}/belief", Float64MultiArray, f"{t}/belief", STREAM_QOS,
                                 lambda msg, k=k: self._on_belief(k, msg), bound=wire_bounds(m.S)["belief"],
                                 kind="belief",
                                 on_bad=lambda problem, k=k: self.call(self.loop.rejected_belief, k, problem))
        # decisions in their own group: beliefs are counted, parameters and diagnostics answered meanwhile
        group = MutuallyExclusiveCallbackGroup()
        self._decide_trigger = self.create_guard_condition(self._decide, callback_group=group)
        self._wake = OneShot(self, self._decide_trigger.trigger)
        return loop

    @callback
    def _on_belief(self, k: int, msg: Float64MultiArray) -> None:
        loop = self.loop  # None after a cleanup
        if loop is None:
            return
        try:
            bel = decode_belief(msg, loop.problem.models[k].S)
        except MessageError as exc:
            self.call(loop.rejected_belief, k, str(exc))
            return
        self.call(loop.belief, k, bel)

    @callback
    def _decide(self) -> None:
        """The decision callback (its own group): decide what is due, if anything."""
        with self.lock:
            loop = self.loop  # None after a cleanup
            job = None if loop is None else loop.take(self.now())
        if job is not None:
            self.call(loop.decided, job, loop.search(job))

    def emit(self, out: ManagerOutput) -> None:
        for k, a in out.actions:
            self.action_pubs[k].publish(encode_action(a.epoch, a.priority))
        if out.allocation is not None:
            self.allocation_pub.publish(encode_allocation(out.allocation.decision, out.allocation.actions,
                                                          self.loop.names))
        self.log(out.logs)
        self._wake.arm(out.wake_at, self.now())
        if out.decide_now:
            self._decide_trigger.trigger()

    def hardware_id(self, loop: ManagerLoop) -> str:
        """The targets' models joined by ``+``."""
        return loop.hardware_id


def main(args=None) -> None:
    main_for([SensorManager])


if __name__ == "__main__":
    main()
