"""The rules of the node loop, without ROS: simulator -> observation -> filter -> belief -> planner
-> action -> simulator.

Each loop (:class:`TargetLoop`, :class:`FilterLoop`, :class:`PlannerLoop`, :class:`AdapterLoop`
between a real sensor and the filter, and :class:`ManagerLoop`, the planner of K targets under one
effort budget) takes decoded inputs
(:mod:`.samples`) and the current time (``now``, seconds on a monotonic clock, passed in by the
caller) and returns what to publish, what to log and, on request, what to report (small result
dataclasses). No loop imports rclpy, starts a thread or reads a clock: the nodes (``nodes/``)
decode, call the loop, encode and run the timers, and tests drive the loops by hand
(``test/test_loop_*.py``). Modules: :mod:`.epochs` (window, verdicts, re-sync and join evidence,
re-send), :mod:`.health` (counters, stall watch, throttled warnings, the report rule),
:mod:`.epoch_buffer` (readings in epoch order), one module per loop (:mod:`.adapter_loop` has
its own table: values, limits, staleness, ordering, binning, numbering; :mod:`.manager_loop` its
own for the joint decision: pairing, the actions in force, the budget, when to decide, silent
targets).

=====================  ====================================================================
rule                   what it says
=====================  ====================================================================
Epoch window           Epochs come from other processes and are not trusted. A node at epoch
                       ``p`` (its *position*: the last epoch it acted on) acts only on epochs
                       within ``p +- epoch_window``. Beyond it an input is dropped and counted
                       (``out_of_window``), logged at most once per 10 s, never walked epoch
                       by epoch (a forged message or a peer restarted on a numbering of its own;
                       the re-sync rule tells them apart by persistence).
Verdicts               ``next`` (``p + 1``), ``ahead`` (``p + 2 .. p + window``), ``repeat``
                       (``p``: a re-send or a duplicate; harmless), ``behind`` (stale),
                       ``out_of_window``; ``join`` before the node has a position. ``behind`` and
                       ``out_of_window`` inputs are *off-line*: not acted on, but the evidence
                       of the re-sync rule.
Re-sync                A node re-syncs to the newest off-line input (acts on it as the next one,
                       adopting its epoch; ``resyncs``, one log line) when for
                       ``stall_warn_after`` seconds it has received off-line inputs and nothing it
                       could act on (counted from the *first* off-line input, so a burst of old
                       epochs replayed by a restarted peer is no evidence), and at least
                       :data:`~.epochs.RESYNC_MIN_INPUTS` off-line inputs came; on a *counting*
                       line (the filter, whose source numbers epochs by stepping) they must span
                       that many consecutive epochs. One forged message never moves a node.
Join (filter)          A filter that has applied no reading yet joins a running loop at once on
                       :data:`~.epochs.JOIN_MIN_INPUTS` consecutive off-line readings; the belief
                       before the epoch it joins at is the prior (``started_from``).
Join (planner, sim.)   A (re)started planner or simulator acts on nothing before it knows the
                       loop's epoch: it continues from the newest belief (the planner) or action
                       (the simulator; timer-driven also the newest belief) received within
                       :data:`~.epochs.JOIN_DELAY` of the first. A timer-driven simulator with
                       nothing received within ``join_timeout`` numbers on its own from epoch 0.
Mailbox                The planner keeps the newest valid, not-yet-planned belief within the
                       window in a one-slot mailbox; a backlog of older beliefs is never planned
                       for, and a stale or repeated belief (``stale_beliefs``) cannot take the
                       real one's place.
Decision cache         An epoch decided once is answered with the same action again (the last
                       :data:`~.planner_loop.DECISION_CACHE` epochs), never re-planned.
Epoch buffer           The filter applies epochs in order: later readings wait, a repeat is a
                       duplicate, a contradicting one a conflict (both dropped); an epoch is
                       applied when every sensor has reported, or after ``epoch_timeout`` /
                       ``max_pending_epochs`` with what it has (``incomplete_epochs``).
Gaps                   An epoch without any reading is predicted with its commanded action if
                       known, else held; a run of lost epochs is one log line and one belief.
                       The simulator steps a jump in action epochs once (``epoch_gaps``).
Re-send                A node whose output has not been answered by the input it expects next
                       within ``resend_period`` publishes it again, every period (at-least-once
                       delivery; receivers are idempotent).
Stall levels           An input that has not advanced its node (a new epoch) for
                       ``stall_warn_after`` / ``stall_error_after`` seconds is WARN / ERROR,
                       named with since when and what arrived meanwhile.
Report                 A node's diagnostics are WARN while a problem count grew since the
                       previous report (OK again once they stop), with the last warning; the
                       level is the highest of that, the stall levels and the loop's own.
=====================  ====================================================================
"""

from .adapter_loop import INPUT_TYPES, POINT_FIELDS, AdapterLoop, AdapterOutput, ObservationBins, point_value
from .epoch_buffer import EpochBuffer, EpochReadings
from .epochs import DEFAULT_JOIN_TIMEOUT, JOIN_DELAY, EpochLine, JoinWait, Liveness, Resender, classify
from .filter_loop import BeliefOut, FilterLoop, FilterOutput
from .health import Level, Log, LoopHealth, Report, StallLimits
from .manager_loop import Allocation, JointJob, ManagerLoop, ManagerOutput
from .planner_loop import TUNABLE, PlanInfo, PlanJob, PlannerLoop, PlannerOutput, check_params
from .samples import ActionSample, BeliefSample, LikelihoodSample, ObservationSample
from .target_loop import Readings, TargetLoop, TargetOutput

__all__ = [
    "DEFAULT_JOIN_TIMEOUT", "INPUT_TYPES", "JOIN_DELAY", "POINT_FIELDS", "TUNABLE", "ActionSample", "AdapterLoop",
    "AdapterOutput", "BeliefOut", "BeliefSample", "EpochBuffer", "EpochLine", "EpochReadings", "FilterLoop",
    "FilterOutput", "JoinWait", "Level", "LikelihoodSample", "Liveness", "Log", "LoopHealth", "ObservationBins",
    "ObservationSample", "PlanInfo", "PlanJob", "PlannerLoop", "PlannerOutput", "Readings", "Report", "Resender",
    "StallLimits", "TargetLoop", "TargetOutput", "check_params", "classify", "point_value",
]
__all__ += ["Allocation", "JointJob", "ManagerLoop", "ManagerOutput"]
