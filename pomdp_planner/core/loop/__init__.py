"""The rules of the node loop, without ROS: simulator -> observation -> filter -> belief -> planner
-> action -> simulator.

Each loop (:class:`TargetLoop`, :class:`FilterLoop`, :class:`PlannerLoop`, :class:`AdapterLoop`
between a real sensor and the filter, and :class:`ManagerLoop`, the planner of K targets under one
effort budget) takes decoded inputs
(:mod:`.samples`) and the current time (``now``, seconds on a monotonic clock, passed in by the
caller) and returns what to publish, what to log and, on request, what to report (small result
dataclasses). No loop imports rclpy, starts a thread or reads a clock: the nodes (``nodes/``)
decode, call the loop, encode and run the timers, and tests drive the loops by hand
(``test/test_loop_*.py``). Modules: :mod:`.epochs` (window, verdicts, re-sync, jump and join
evidence, re-send), :mod:`.health` (counters, stall watch, throttled warnings, the report rule),
:mod:`.writers` (one writer per stream), :mod:`.clock` (ROS time), :mod:`.epoch_buffer` (readings
in epoch order), :mod:`.managed` (what a managed node reports without a loop), one module per loop
(:mod:`.adapter_loop` adds its own rules for a sensor's readings: values, limits, staleness,
ordering, binning, numbering; :mod:`.manager_loop` its own for the joint decision: pairing, the
actions in force, the budget, when to decide, silent targets).

The rules themselves (the epoch window, explained epochs, gaps, jumps, re-sync, joining, one
writer per stream, bounded samples, time, the mailbox, the decision cache, the epoch buffer,
re-send, stall levels, inactive, the report) are stated once, in one table: docs/ros.md, "The loop's rules";
every module here cites its rules by the names of that table, and ``test/test_docs.py`` checks
that each cited name is a row of it.
"""

from .adapter_loop import INPUT_TYPES, POINT_FIELDS, AdapterLoop, AdapterOutput, ObservationBins, point_value
from .epoch_buffer import EpochBuffer, EpochReadings
from .epochs import DEFAULT_JOIN_TIMEOUT, JOIN_DELAY, EpochLine, JoinWait, Liveness, Resender, classify
from .filter_loop import BeliefOut, FilterLoop, FilterOutput
from .health import Level, Log, LoopHealth, Report, StallLimits
from .managed import LOOP_STATES, state_report, transition_request
from .manager_loop import Allocation, JointJob, ManagerLoop, ManagerOutput
from .planner_loop import TUNABLE, PlanInfo, PlanJob, PlannerLoop, PlannerOutput, check_params
from .samples import ActionSample, BeliefSample, LikelihoodSample, ObservationSample
from .target_loop import Readings, TargetLoop, TargetOutput

__all__ = [
    "DEFAULT_JOIN_TIMEOUT",
    "INPUT_TYPES",
    "JOIN_DELAY",
    "LOOP_STATES",
    "POINT_FIELDS",
    "TUNABLE",
    "ActionSample",
    "AdapterLoop",
    "AdapterOutput",
    "Allocation",
    "BeliefOut",
    "BeliefSample",
    "EpochBuffer",
    "EpochLine",
    "EpochReadings",
    "FilterLoop",
    "FilterOutput",
    "JoinWait",
    "JointJob",
    "Level",
    "LikelihoodSample",
    "Liveness",
    "Log",
    "LoopHealth",
    "ManagerLoop",
    "ManagerOutput",
    "ObservationBins",
    "ObservationSample",
    "PlanInfo",
    "PlanJob",
    "PlannerLoop",
    "PlannerOutput",
    "Readings",
    "Report",
    "Resender",
    "StallLimits",
    "TargetLoop",
    "TargetOutput",
    "check_params",
    "classify",
    "point_value",
    "state_report",
    "transition_request",
]
