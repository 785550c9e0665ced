"""The planner's loop: beliefs in, actions out (rules: docs/ros.md, "The loop's rules"; node: ``nodes/planner.py``).

Each new belief of epoch ``t`` that follows the beliefs so far (``t`` at most one beyond the
newest accepted; a jump of the filter is followed on two consecutive beliefs) goes to a one-slot
*mailbox* that keeps the newest valid, not-yet-planned belief; the planning side takes it
(:meth:`PlannerLoop.take`), runs the anytime branch-and-bound with the myopic policy bounds
(paper Sec. V; :meth:`~pomdp_planner.core.search.Planner.plan`) and answers with the action of
epoch ``t + 1``. Decisions are cached by epoch: an epoch decided once is answered with the same
action again, never re-planned. The planner comes from the assumption gate
(:func:`~pomdp_planner.core.gate.build_planner`); a certificate is reported only where the gate
guarantees the bounds (:meth:`PlannerLoop.report`).

The search runs outside the loop's other calls (the node's planning thread), so :meth:`search`
touches only the planner; every other method is called with the node's lock held.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..bounds import check_constant, check_variant
from ..errors import OptionError
from ..gate import MAX_SETUP_SECONDS, PlannerSetup, build_planner
from ..model import POMDP, format_bytes, priority_of
from ..search import DEFAULT_CHUNK_BYTES, SearchResult
from .epochs import EpochLine, JoinWait, Liveness, Resender, belief_verdict, off_stream_belief
from .health import BeliefPace, InputWatch, Level, Log, LoopHealth, PeriodWatch, Report
from .samples import ActionSample, BeliefSample

#: Parameters that may change while the loop runs (in force from the next decision).
TUNABLE = ("time_budget", "max_depth", "use_bounds", "bound_variant", "bound_constant", "deadline_slack")
#: Decisions kept (by epoch) to re-send or answer an epoch again without planning it again.
DECISION_CACHE = 64
COUNTERS = ("decisions", "deadline_misses", "budget_exhausted", "certified", "bad_beliefs", "stale_beliefs",
            "out_of_window", "resyncs", "resent_actions", "cached_decisions")
#: Counts that make the report WARN when they grew since the previous one.
PROBLEMS = ("deadline_misses", "bad_beliefs", "out_of_window", "resyncs")


@dataclass(frozen=True)
class PlanInfo:
    """The record of one decision (the node's ``plan_info`` topic). ``certified`` is true only when
    the root bounds agree and the gate guarantees them; ``latency`` is belief-in to action-out (s)."""

    epoch: int
    action_priority: int
    depth: int
    nodes_expanded: int
    pruned_percent: float
    certified: bool
    time_used: float
    latency: float
    deadline_hit: bool
    deadline_miss: bool
    #: The myopic policy bounds at the belief (Theorem 2) as priorities: the optimal priority lies in
    #: ``[bound_lower, bound_upper]``; ``nan`` when the decision used no guaranteed bounds.
    bound_lower: float = math.nan
    bound_upper: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _bound_fields(r: SearchResult, guaranteed: bool) -> dict[str, float]:
    """``bound_lower``, ``bound_upper`` of a decision's :class:`PlanInfo`: its root bounds as
    priorities, shown only when they are guaranteed."""
    if r.root_bounds is None or not guaranteed:
        return {}
    return {"bound_lower": float(priority_of(r.root_bounds[0])), "bound_upper": float(priority_of(r.root_bounds[1]))}


@dataclass(frozen=True, eq=False)
class PlanJob:
    """A belief taken from the mailbox: plan it with ``params``, or answer with ``cached``."""

    epoch: int
    belief: np.ndarray
    arrived: float
    params: Mapping[str, Any]
    cached: int | None = None


@dataclass(frozen=True, eq=False)
class Searched:
    """What :meth:`PlannerLoop.search` found: the result, whether the bounds pruned, and whether
    the gate guarantees them (only then may the decision be reported as certified)."""

    result: SearchResult
    use_bounds: bool
    guaranteed: bool
    logs: tuple[Log, ...] = ()


@dataclass
class PlannerOutput:
    """What one call of the loop asks the node to do: publish ``actions`` and ``plan_info``, log
    ``logs``, wake the planning side (:meth:`PlannerLoop.take`) now if ``plan_now``, and at
    ``join_at`` (``None``: no join pending)."""

    actions: list[ActionSample] = field(default_factory=list)
    plan_info: PlanInfo | None = None
    logs: list[Log] = field(default_factory=list)
    plan_now: bool = False
    join_at: float | None = None


def checked_params(params: Mapping[str, Any], tunable: Sequence[str],
                   check: Callable[[Mapping[str, Any]], str]) -> dict[str, Any]:
    """The ``tunable`` parameters of ``params``, every one given (else ``ValueError``: a caller's
    bug) and accepted by ``check`` (else its reason as an :class:`~..errors.OptionError`)."""
    missing = [k for k in tunable if k not in params]
    if missing:
        raise ValueError(f"params: missing {missing}")
    bad = check(params)
    if bad:
        raise OptionError(bad)
    return {k: params[k] for k in tunable}


def apply_changes(params: Mapping[str, Any], changed: Mapping[str, Any],
                  tunable: Sequence[str]) -> tuple[dict[str, Any], list[Log]]:
    """``params`` with the ``tunable`` ones of ``changed`` (already checked) in force from the next
    decision, and the line that says so (none if nothing tunable changed)."""
    changed = {k: v for k, v in changed.items() if k in tunable}
    if not changed:
        return dict(params), []
    return {**params, **changed}, [Log("info", f"parameters changed {changed}; in force from the next decision")]


def check_params(values: Mapping[str, Any]) -> str:
    """Why ``values`` (some of :data:`TUNABLE`) cannot be used, or ``""``: the bound variant and
    constant must be the core's (:func:`~pomdp_planner.core.bounds.check_variant`,
    :func:`~pomdp_planner.core.bounds.check_constant`; ranges and types are the adapters' descriptors)."""
    try:
        if "bound_variant" in values:
            check_variant(values["bound_variant"], "bound_variant")
        if "bound_constant" in values:
            check_constant(values["bound_constant"], "bound_constant")
    except OptionError as exc:
        return str(exc)
    return ""


#: How a node's user lifts the set-up time limit (the end of the gate's refusal).
SETUP_HINT = "the parameter max_setup_seconds raises the limit (0: no limit)"


def setup_limit(value: float) -> float | None:
    """The node parameter ``max_setup_seconds`` as the gate's limit: ``None`` (no limit) for 0."""
    return None if value == 0 else float(value)


class PlannerLoop:
    """The planner's loop for ``model`` with the :data:`TUNABLE` parameters ``params``.

    ``refuse``: if the model fails the structural assumptions, plan nothing (the gate's
    ``on_assumption_failure="refuse"``) instead of searching exhaustively. ``chunk_bytes``: the
    search's chunk size (the deadline is checked between chunks). ``progress``: where the gate
    announces a set-up that will take a while, as it starts, and each stage over a second as it
    ends (log lines; the loop's other lines come with its outputs). ``active=False``: the loop
    starts inactive (rule "Inactive"; :meth:`activate`). ``max_setup_seconds``: the longest set-up
    the gate accepts, as estimated before it starts (``None``: no limit; the node's parameter of
    that name, 0 meaning no limit, :func:`setup_limit`).
    """

    def __init__(self, model: POMDP, params: Mapping[str, Any], live: Liveness, *, now: float,
                 refuse: bool = False, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 progress: Callable[[str], None] | None = None, active: bool = True,
                 max_setup_seconds: float | None = MAX_SETUP_SECONDS):
        self.params = checked_params(params, TUNABLE, check_params)
        self.model = model
        self.live = live
        self._on_failure = "refuse" if refuse else "exhaustive"
        self._chunk_bytes = chunk_bytes
        self._max_setup_seconds = max_setup_seconds
        self._progress = progress
        self._planner_key: tuple[str, str] | None = None
        self._refused_setups: set[tuple[str, str]] = set()  # run-time choices the gate refused
        self.health = LoopHealth(COUNTERS, PROBLEMS, [InputWatch("belief", "belief", started=now)], live.stall)
        self.pace = PeriodWatch("mean")  # the period of new beliefs (rule "Pace"; a burst does not shorten it)
        self._pace_warned: float | None = None  # the time_budget warned about
        bounds_warning = self._ensure_planner(self.params["bound_variant"], self.params["bound_constant"])
        self.assumptions = self.setup.report  # Assumption 1, checked once by the gate (cached per model)
        self.refusing = self.setup.mode == "refuse"
        if self.setup.planner is not None:
            self.setup.planner.check_memory(1, "max_depth")  # refused (one line) if not even depth 1 fits
        self._depth_caps: dict[int, int] = {}  # max_depth asked -> the deepest within the memory budget
        if bounds_warning is not None:
            self.health.logs.append(bounds_warning)
        if self.refusing:
            self.health.log("error", "model fails the structural assumptions; refusing to plan "
                            f"(refuse_if_assumptions_fail): {self.assumptions.summary()}")
        elif not self.assumptions.holds:
            self.health.log("warning", "model fails the structural assumptions; the bounds are not valid, "
                            f"falling back to exhaustive search: {self.assumptions.summary()}")
        self.health.log("info", f"{model.describe()}; assumptions {'hold' if self.assumptions.holds else 'FAIL'}; "
                        f"bounds {self.bounds_message}; time_budget {self.params['time_budget']:g} s, "
                        f"max_depth {self.params['max_depth']}")
        self.line = EpochLine(live.epoch_window, now=now)  # position: the last belief epoch planned for
        self._stream = -1  # the newest belief epoch accepted (the beliefs so far lead up to it)
        self.planning: int | None = None  # the belief epoch being searched for (None when idle)
        self._mailbox: tuple[BeliefSample, float] | None = None  # newest belief to plan, its arrival time
        self._join = JoinWait()
        self._decisions: OrderedDict[int, int] = OrderedDict()  # action epoch -> priority (recent ones)
        self._last_action: ActionSample | None = None
        self.resender = Resender(live.resend_period)
        self.last: SearchResult | None = None
        self.last_params: dict[str, Any] = {}
        self.active = active
        self._pace = BeliefPace()  # when beliefs come (a filter resuming after a pause)
        self.health.forget["belief"] = self._join_afresh

    def _join_afresh(self, now: float) -> None:
        """The expected writer replaced a stray that was followed (rule "One writer"): what the
        stray's beliefs left (their epochs, the mailbox, the decisions and the last action answering
        them) is dropped, and the planner joins the new writer's stream as a fresh planner does."""
        self.line = EpochLine(self.live.epoch_window, now=now)
        self._stream = -1
        self._mailbox = None
        self._join = JoinWait()
        self._decisions.clear()
        self._last_action = None
        self.resender = Resender(self.live.resend_period)
        self.health.log("info", "belief: the stray's epochs are dropped; joining the expected writer's beliefs")

    @property
    def mailbox(self) -> BeliefSample | None:
        """The belief waiting to be planned, if any."""
        return None if self._mailbox is None else self._mailbox[0]

    @property
    def last_action(self) -> ActionSample | None:
        """The newest action decided (kept unpublished while inactive; :meth:`activate` sends it if
        no belief has answered it)."""
        return self._last_action

    # ----------------------------------------------------------- parameters
    def set_params(self, changed: Mapping[str, Any]) -> list[Log]:
        """Parameters changed at run time (checked with :func:`check_params`); in force from the next decision."""
        self.params, logs = apply_changes(self.params, changed, TUNABLE)
        return logs

    def _ensure_planner(self, variant: str, constant: str) -> Log | None:
        """(Re)build the core planner for ``variant`` and ``constant`` through the assumption gate:
        the bounds are solved when the pair changes (can take a while), Assumption 1 is checked once
        per model. A pair whose set-up the gate refuses at run time (its cost) is said once, as the
        warning, and the planner in force stays. Returns the warning to log, if any."""
        if self._planner_key == (variant, constant) or (variant, constant) in self._refused_setups:
            return None
        bounds, warning = f"{variant}, constant {constant}", None
        try:
            setup = build_planner(self.model, variant=variant, constant=constant,
                                  on_assumption_failure=self._on_failure, chunk_bytes=self._chunk_bytes,
                                  progress=self._progress, max_setup_seconds=self._max_setup_seconds,
                                  setup_hint=SETUP_HINT)
        except OptionError as exc:  # a set-up the gate refuses (its cost): at start-up, the node's error
            if self._planner_key is None:
                raise
            self._refused_setups.add((variant, constant))  # said once; the planner in force stays
            old_variant, old_constant = self._planner_key
            return Log("warning", f"bounds {bounds} refused: {exc}; planning on with bounds {old_variant}, "
                       f"constant {old_constant}")
        if setup.pruning:
            message = f"{bounds}: feasible"
        elif setup.report is not None and setup.report.holds:  # the LP, not the model, is the problem
            message = f"{bounds}: {setup.reason}; exhaustive search"
            warning = Log("warning", f"bounds {message}")
        else:
            message = "not used (assumptions fail)"
        self.setup: PlannerSetup = setup
        self.bounds_message = message
        self._planner_key = (variant, constant)
        return warning

    # ----------------------------------------------------------- lifecycle
    def activate(self, now: float) -> PlannerOutput:
        """Start planning and publishing (rule "Inactive"): the input watch counts
        silence from now, the last action is sent again at once if no belief has answered it (it
        may have been decided while inactive), and the belief in the mailbox is planned."""
        if self.active:
            return self._result(now)
        self.active = True
        self.health.resume(now)
        actions = []
        if self.resender.waiting and self.planning is None and self._last_action is not None:
            actions.append(self._last_action)
            self.resender.resending(now)
            self.health.count("resent_actions")
        waiting = self._mailbox
        self.health.log("info", "activated: planning " + (
            f"the belief of epoch {waiting[0].epoch}" if waiting is not None else "the next belief"))
        return self._result(now, actions=actions, plan_now=waiting is not None)

    def deactivate(self, now: float) -> PlannerOutput:
        """Stop planning and publishing; the bounds, the decision cache and the newest belief stay
        (rule "Inactive"). A search already running finishes; its action is kept
        and sent at activation if still unanswered."""
        if self.active:
            self.active = False
            self.health.log("info", "deactivated: not planning or publishing; the newest belief is kept for "
                            "the activation")
        return self._result(now)

    # ----------------------------------------------------------- beliefs
    def start(self, now: float) -> PlannerOutput:
        """The start-up lines (the model, the assumptions, the bounds in force)."""
        return self._result(now)

    def belief(self, bel: BeliefSample, now: float, *, planner_ahead: bool = False) -> PlannerOutput:
        """A decoded belief: the newest valid, not-yet-planned one within the window goes to the
        mailbox; every other one is counted (and kept as evidence for the re-sync rule).

        ``planner_ahead``: the planning side has already looked at the mailbox for this sample (a
        node whose planning side reads the topic too), so it is woken if the mailbox got a belief
        since; it is woken anyway after a re-sync."""
        verdict = belief_verdict(self.line, self._stream, self._pace, self.health, bel.epoch, now)
        new = verdict in ("join", "next", "ahead")
        self.health.watches[0].arrived(now, new, bel.epoch)
        if new:
            self.resender.answered()
            if verdict != "join":
                self.pace.arrived(now)
            if self._mailbox is None or bel.epoch > self._mailbox[0].epoch:
                if self._mailbox is not None and self.active and verdict != "join":
                    self._check_pace(self._mailbox[0].epoch)  # an unplanned belief is skipped
                self._mailbox = (bel, now)
            if verdict == "join":
                # the newest of what comes within JOIN_DELAY (a restarted filter's history starts with
                # its prior at epoch 0; a running filter's history ends at its epoch)
                self._join.note(bel.epoch, now)
            else:
                self._stream = max(self._stream, bel.epoch)
                self.line.clear_evidence()
                if not self.active:  # the epochs skipped while inactive are never planned for ("Inactive")
                    self.line.advance(self._mailbox[0].epoch - 1, now)
        else:
            off_stream_belief(self.line, self.health, verdict, bel.epoch, (bel, now), stream=self._stream,
                              window=self.live.epoch_window, stall_warn=self.live.stall.warn_after, now=now)
        resynced = self._resync_if_due(now)
        return self._result(now, plan_now=self.active and self._mailbox is not None and (resynced or planner_ahead))

    def _check_pace(self, skipped: int) -> None:
        """Rule "Pace": a belief skipped (replaced in the mailbox before it was planned) while
        ``time_budget`` exceeds the period of the beliefs is one warning per ``time_budget``."""
        period, budget = self.pace.period(), self.params["time_budget"]
        if period is None or budget <= period or self._pace_warned == budget:
            return
        self._pace_warned = budget
        self.health.log("warning", f"time_budget {budget:g} s exceeds the period of the beliefs ({period:.3g} s, the "
                        f"mean of the last {self.pace.intervals} intervals): beliefs come faster than decisions and "
                        f"are skipped (epoch {skipped} was); keep time_budget below the sensor period")

    def rejected_belief(self, problem: str, now: float) -> PlannerOutput:
        self.health.reject(self.health.watches[0], "bad_beliefs", f"ignored {problem}; no action published", now)
        return self._result(now)

    def _resync_if_due(self, now: float) -> bool:
        """The jump and re-sync rules (:class:`~.epochs.EpochLine`): put the newest off-line belief in
        the mailbox."""
        due = self.line.resync_due(self.live.stall.warn_after, now, jump_after=0.0)
        if due is None:
            return False
        if self.line.jump(due):
            self.health.warn(None, f"followed the beliefs from epoch {self._stream} to epoch {due.epoch}: two "
                             "consecutive beliefs beyond the newest (a jump of the filter)", now)
        else:
            self.health.warn("resyncs", self.line.resync_reason(due, "beliefs", "filter", now), now)
        self.line.resync(due.epoch - 1, now)  # so that the belief of due.epoch is the next one
        self._stream = due.epoch
        self._mailbox = due.payload
        return True

    # ----------------------------------------------------------- planning
    def take(self, now: float) -> PlanJob | None:
        """The belief to plan now, if any (``None`` while inactive, joining, refusing or with nothing new)."""
        if not self.active:
            return None
        if self.line.position is None and not self._join.settled(now):
            return None  # joining: the node calls again at join_at
        taken, self._mailbox = self._mailbox, None
        if taken is None:
            return None
        bel, arrived = taken
        if self.line.position is None:  # the join: the deliberate JOIN_DELAY is not decision latency
            arrived = now
        elif bel.epoch <= self.line.position:
            return None  # a newer one was planned meanwhile
        self.line.advance(bel.epoch, now)
        self._stream = max(self._stream, bel.epoch)
        if self.refusing:
            return None
        cached = self._decisions.get(bel.epoch + 1)
        if cached is None:
            self.planning = bel.epoch
        return PlanJob(bel.epoch, bel.belief, arrived, dict(self.params), cached)

    def _use_bounds(self, params: Mapping[str, Any]) -> bool:
        return bool(params["use_bounds"]) and self.setup.pruning

    def search(self, job: PlanJob) -> Searched:
        """Plan ``job`` (not under the node's lock: only the planning side calls it). ``max_depth``
        is capped at the deepest depth within the planner's memory budget (a warning the first
        time a value is capped), as for every anytime search (``core/policies.py``)."""
        p = job.params
        logs = [w for w in (self._ensure_planner(p["bound_variant"], p["bound_constant"]),) if w is not None]
        use_bounds = self._use_bounds(p)
        planner = self.setup.planner
        depth = p["max_depth"]
        fits = self._depth_caps.get(depth)
        if fits is None:
            fits = self._depth_caps[depth] = planner.deepest_depth_within_budget(depth)
            if fits < depth:
                logs.append(Log("warning", f"max_depth capped at {fits} (asked {depth}): a deeper search needs more "
                                f"than the planner's memory budget of {format_bytes(planner.memory_budget)}"))
        result = planner.plan(job.belief, max_depth=fits, time_budget=p["time_budget"], use_bounds=use_bounds)
        return Searched(result, use_bounds, use_bounds and self.setup.guaranteed, tuple(logs))

    def decided(self, job: PlanJob, searched: Searched | None, now: float) -> PlannerOutput:
        """The answer to ``job``: its cached action (``searched is None``) or the new decision."""
        if searched is None:
            self.health.count("cached_decisions")
            return self._send(ActionSample(job.epoch + 1, job.cached), now)
        self.planning = None
        self.health.logs.extend(searched.logs)
        r, p = searched.result, job.params
        action = ActionSample(job.epoch + 1, int(r.priority))
        self._decisions[action.epoch] = action.priority
        while len(self._decisions) > DECISION_CACHE:
            self._decisions.popitem(last=False)
        latency = now - job.arrived
        certified = bool(r.certified) and searched.guaranteed
        missed = latency > p["time_budget"] + p["deadline_slack"]
        self.last = r
        self.last_params = {**p, "use_bounds_effective": searched.use_bounds, "belief_epoch": job.epoch,
                            "latency": latency, "certified": certified, "guaranteed": searched.guaranteed}
        self.health.count("decisions")
        self.health.count("certified", certified)
        self.health.count("budget_exhausted", bool(r.deadline_hit))
        if missed:
            self.health.warn("deadline_misses", f"epoch {action.epoch}: decision took {latency * 1e3:.1f} ms "
                             f"(budget {p['time_budget'] * 1e3:.0f} ms)", now, log=False)
        out = self._send(action, now)
        if not self.active:
            return out
        out.plan_info = PlanInfo(
            epoch=action.epoch, action_priority=action.priority, depth=int(r.depth),
            nodes_expanded=int(sum(r.nodes_expanded)), pruned_percent=float(r.percent_pruned[-1]) if r.percent_pruned
            else 0.0, certified=certified, time_used=float(r.time_used), latency=latency,
            deadline_hit=bool(r.deadline_hit), deadline_miss=missed, **_bound_fields(r, searched.guaranteed))
        return out

    def _send(self, action: ActionSample, now: float) -> PlannerOutput:
        """Publish ``action`` (kept, unpublished, while inactive: :meth:`activate` sends it)."""
        self._last_action = action
        self.resender.published(now)
        return self._result(now, actions=[action] if self.active else [])

    def watchdog(self, now: float) -> PlannerOutput:
        """Re-send the last action while the belief it leads to has not come; the time-based re-sync."""
        actions = []
        if self.active and self.resender.due(now) and self.planning is None and self._last_action is not None:
            actions.append(self._last_action)
            self.resender.resending(now)
            self.health.count("resent_actions")
        self._resync_if_due(now)
        return self._result(now, actions=actions, plan_now=self.active and self._mailbox is not None)

    def _result(self, now: float, **kw) -> PlannerOutput:
        join_at = self._join.wake_at(now) if self.line.position is None else None
        return PlannerOutput(logs=self.health.drain_logs(), join_at=join_at, **kw)

    # ----------------------------------------------------------- diagnostics
    def report(self, now: float) -> Report:
        """The diagnostics (rule "Report"). A certificate is claimed only where the
        gate guarantees the bounds: ``certified`` (the count) only while the planner in force has
        guaranteed bounds, ``last.certified`` only for a decision pruned with guaranteed bounds;
        ``guaranteed`` and ``guarantee`` say what the gate decided and why."""
        setup, r, lp = self.setup, self.last, self.last_params
        values: dict[str, object] = {
            "assumptions_hold": self.assumptions.holds, "assumptions": self.assumptions.summary(),
            "bounds": self.bounds_message, "guaranteed": setup.guaranteed, "guarantee": setup.describe(),
            **{f"param.{k}": v for k, v in self.params.items()}}
        if r is None:
            idle = "waiting for a belief"
        elif lp["guaranteed"]:
            idle = f"depth {r.depth}, {'certified' if lp['certified'] else 'not certified'}"
        else:
            idle = f"depth {r.depth}, exhaustive search"
        head = [] if self.assumptions.holds else ["assumptions fail: exhaustive search"]
        if not self.active:
            head.insert(0, "inactive: not planning or publishing" + (
                f" (newest belief: epoch {self._mailbox[0].epoch})" if self._mailbox is not None else ""))
        report = self.health.report(now, values, head=head, idle=idle, inactive=not self.active,
                                    level=Level.OK if self.assumptions.holds else Level.WARN)
        values = report.values
        if not setup.guaranteed:
            values.pop("certified")
        if r is not None:
            values.update({
                "last.belief_epoch": lp["belief_epoch"], "last.action_priority": int(r.priority),
                "last.depth": int(r.depth), "last.nodes_expanded": int(sum(r.nodes_expanded)),
                "last.pruned_percent": float(r.percent_pruned[-1]) if r.percent_pruned else 0.0,
                **({"last.certified": lp["certified"]} if lp["guaranteed"] else {}),
                "last.time_used": float(r.time_used), "last.latency": float(lp["latency"]),
                "last.deadline_hit": bool(r.deadline_hit), "last.partial": bool(r.partial),
                "last.time_budget": lp["time_budget"],
                "last.max_depth": lp["max_depth"], "last.use_bounds": lp["use_bounds_effective"],
                "last.bound_variant": lp["bound_variant"], "last.bound_constant": lp["bound_constant"],
            })
        if self.refusing:
            return Report(Level.ERROR, "refusing to plan: model fails the structural assumptions", values)
        return report
