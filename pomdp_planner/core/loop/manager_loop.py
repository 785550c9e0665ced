"""The sensor manager's loop: the beliefs of K targets in, one priority per target out, every set of
actions in force within one effort budget (node: ``nodes/sensor_manager.py``; docs/ros.md,
"Sensor manager"; the planner: :class:`~pomdp_planner.core.multitarget.planner.MultiTargetPlanner`,
docs/multitarget.md).

Each target is a loop of its own (its simulator or sensor and its belief filter, in its namespace)
that numbers its own epochs. Per target the manager keeps what the planner keeps for its one
target (:class:`TargetInbox`; rules of docs/ros.md, "The loop's rules": the epoch window and
verdicts, explained epochs and the jump, the join, a one-slot mailbox of the newest valid,
not-yet-decided belief, re-sync, the re-send of the last action, the stall watch, the decision
cache; the node checks every belief sample's size and writer first, rules "Bounded samples" and
"One writer"). On top of those, the rules of the joint
decision:

=====================  ====================================================================
rule                   what it says
=====================  ====================================================================
Pairing                A decision takes each decided target's belief from its mailbox (epoch
                       ``t_k`` of that target's numbering) and answers with ``[t_k + 1, p_k]``
                       on that target's ``action``: every action names the belief it was
                       computed from, whatever the other targets' epochs are.
In force               Every target has one action in force: the last one published for it
                       (a timer-driven simulator keeps applying it, and a sensor acts on it
                       until the next). Before its first action a target has none and counts
                       its least effort (a timer-driven simulator's ``default_priority``
                       should be that priority).
Budget                 The actions in force never cost more than ``B`` together. A decision
                       decides the targets that have a new belief (the *decided* ones) within
                       what the others' actions in force leave, ``B - sum e_k(in force)``, by
                       the planner's exact knapsack (a sub-problem of the decided targets with
                       that budget), and the whole set in force is checked again, exactly,
                       before anything is published (``refused_decisions``: never expected).
When to decide         A decision is due once some target has a new belief and either every
                       target the manager waits for has one too, or ``gather_timeout`` seconds
                       have passed since the first of them. It waits for a target while that
                       target's belief input is not stalled (a new belief within
                       ``stall_warn_after``, or since start); one decision at a time.
Silent target          A target without a new belief is *held*: not decided, its action in
                       force kept and its effort reserved (its simulator or sensor goes on
                       applying it), the others decided over the rest of the budget. Once its
                       input has stalled the others no longer wait for it; it rejoins the
                       decisions with its next new belief.
Decision cache         An action epoch decided once for a target is answered with the same
                       action again (re-published, counted as held: ``cached_decisions``).
Joint record           Every decision is also published as one record, the actions in force
                       of all targets (``allocation``): what a single sensor applies at once.
=====================  ====================================================================

The manager is a managed node: while inactive (rule "Inactive", as the planner's) it decides and
publishes nothing; each target's newest belief waits in its mailbox and its position follows it
(the epochs skipped are never decided); a decision that ends while inactive publishes nothing and
gives its beliefs back to the mailboxes. Activated, it sends again the actions in force that no
belief has answered and decides what the mailboxes hold.

The bounds of a decision are the planner's, for the sub-problem it decided (the decided targets,
the budget left to them); ``bound_guaranteed`` exactly as the planner says it (every target
searched exhaustively). The search runs outside the loop's other calls (the node's planning
thread): :meth:`ManagerLoop.search` touches only the planners; every other method is called with
the node's lock held.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

from ..bounds import DEFAULT_CONSTANT, check_constant, check_variant
from ..checks import check_choice
from ..errors import InputError
from ..model import POMDP
from ..multitarget.planner import DEFAULT_EVALUATIONS, SEARCH_MODES, JointDecision, MultiTargetPlanner
from ..multitarget.problem import MultiTargetProblem, format_effort, make_problem
from .epochs import EpochLine, JoinWait, Liveness, Resender, belief_verdict, off_stream_belief
from .health import BeliefPace, InputWatch, Log, LoopHealth, Report
from .manager_params import TUNABLE, check_params
from .planner_loop import DECISION_CACHE, apply_changes, checked_params
from .samples import ActionSample, BeliefSample

#: Planners kept for sub-problems (decided targets, budget left), least recently used dropped.
PLANNER_CACHE = 32
COUNTERS = ("decisions", "partial_decisions", "cached_decisions", "deadline_misses", "budget_exhausted",
            "refused_decisions", "bad_beliefs", "stale_beliefs", "out_of_window", "resyncs", "resent_actions")
#: Counts that make the report WARN when they grew since the previous one.
PROBLEMS = ("deadline_misses", "refused_decisions", "bad_beliefs", "out_of_window", "resyncs")


# ---------------------------------------------------------------- records
@dataclass(frozen=True)
class Allocation:
    """One decision's joint record: the action in force of every target (``None``: none yet)."""

    decision: int
    actions: tuple[ActionSample | None, ...]
    effort: Fraction
    budget: Fraction


@dataclass(frozen=True, eq=False)
class JointJob:
    """A decision taken from the mailboxes: decide ``beliefs`` (target index -> belief) within
    ``budget``; ``cached`` are answered from the decision cache, every other target is held.
    ``due``: when the decision became due; ``taken``: every belief taken, with the position its
    target had before (to put them back if the decision is refused)."""

    beliefs: dict[int, BeliefSample]
    cached: dict[int, ActionSample]
    budget: Fraction
    due: float
    params: Mapping[str, Any]
    taken: dict[int, tuple[int | None, BeliefSample]] = field(default_factory=dict)
    reset_price: bool = False

    @property
    def decided(self) -> tuple[int, ...]:
        return tuple(sorted(self.beliefs))


@dataclass(frozen=True)
class Searched:
    """What :meth:`ManagerLoop.search` found: the decision, or why there is none."""

    decision: JointDecision | None
    error: str = ""


@dataclass
class ManagerOutput:
    """What one call asks the node to do: publish ``actions`` (target index, action) and
    ``allocation``, log ``logs``, try a decision now if ``decide_now``, and call again at
    ``wake_at`` (``None``: nothing timed is pending)."""

    actions: list[tuple[int, ActionSample]] = field(default_factory=list)
    allocation: Allocation | None = None
    logs: list[Log] = field(default_factory=list)
    decide_now: bool = False
    wake_at: float | None = None


# ---------------------------------------------------------------- one target
class TargetInbox:
    """One target's belief stream, as the planner's loop keeps its one (module docstring), and its
    action in force. ``now``: the time the manager starts (silence is counted from it)."""

    def __init__(self, name: str, model: POMDP, live: Liveness, now: float):
        self.name = name
        self.model = model
        self.line = EpochLine(live.epoch_window, now=now)  # position: the last belief epoch decided for
        self.stream = -1  # the newest belief epoch accepted (the beliefs so far lead up to it)
        self.join = JoinWait()
        self.watch = InputWatch(f"{name}/belief", "belief", started=now)
        self.resender = Resender(live.resend_period)
        self.mailbox: BeliefSample | None = None
        self.since: float | None = None  # when the mailbox got its first belief since the last decision
        self.in_force: ActionSample | None = None
        self.pace = BeliefPace()  # when beliefs come (a filter resuming after a pause)
        self.decisions: OrderedDict[int, int] = OrderedDict()  # action epoch -> priority (recent ones)

    def join_afresh(self, now: float) -> None:
        """The expected writer replaced a stray that was followed (rule "One writer"): the stray's
        epochs, mailbox and decisions are dropped and the target's beliefs are joined as at the start;
        its action in force stays (what the target applies)."""
        self.line = EpochLine(self.line.window, now=now)
        self.stream = -1
        self.join = JoinWait()
        self.mailbox, self.since = None, None
        self.decisions.clear()

    def offer(self, bel: BeliefSample, now: float) -> None:
        """A new belief: the mailbox keeps the newest."""
        if self.mailbox is None or bel.epoch > self.mailbox.epoch:
            self.mailbox = bel
        if self.since is None:
            self.since = now

    def ready_at(self) -> float | None:
        """When the mailbox's belief may be decided: at once, or once the join has settled."""
        if self.mailbox is None:
            return None
        if self.line.position is None:
            return max(self.since, self.join.first_seen + self.join.delay)
        return self.since

    def ready(self, now: float) -> bool:
        at = self.ready_at()
        return at is not None and at <= now

    def stalled(self, live: Liveness, now: float) -> bool:
        """No new belief for ``stall_warn_after`` (or since start): the others do not wait for it."""
        return self.watch.silent_for(now) >= live.stall.warn_after

    def remember(self, action: ActionSample) -> None:
        self.decisions[action.epoch] = action.priority
        while len(self.decisions) > DECISION_CACHE:
            self.decisions.popitem(last=False)


# ---------------------------------------------------------------- the loop
class ManagerLoop:
    """The sensor manager for ``problem`` (its ``names`` are the targets' namespaces) with the
    :data:`TUNABLE` parameters ``params``. ``search``, ``variant``, ``constant`` and
    ``max_evaluations`` go to every :class:`~pomdp_planner.core.multitarget.planner.MultiTargetPlanner`.
    ``active=False``: the loop starts inactive (module docstring; :meth:`activate`)."""

    def __init__(self, problem: MultiTargetProblem, params: Mapping[str, Any], live: Liveness, *, now: float,
                 search: str = "bnb", variant: str = "tight", constant: str = DEFAULT_CONSTANT,
                 max_evaluations: int = DEFAULT_EVALUATIONS, active: bool = True):
        params = checked_params(params, TUNABLE, check_params)
        check_choice(search, SEARCH_MODES, "search")
        check_variant(variant, "bound_variant")
        check_constant(constant, "bound_constant")
        self.problem = problem
        self.live = live
        self.params = params
        self._knobs = {"search": search, "variant": variant, "constant": constant, "max_evaluations": max_evaluations}
        self.inboxes = [TargetInbox(n, m, live, now) for n, m in zip(problem.names, problem.models, strict=True)]
        self.health = LoopHealth(COUNTERS, PROBLEMS, [ib.watch for ib in self.inboxes], live.stall)
        for ib in self.inboxes:
            self.health.forget[ib.watch.name] = ib.join_afresh
        self._planners: OrderedDict[tuple, MultiTargetPlanner] = OrderedDict()  # the planning side's only
        self.planner = self._planner_for(tuple(range(problem.K)), problem.budget, self.params)  # checks the set-up
        self.least = tuple(min(range(m.A), key=lambda a, row=row: row[a]) for m, row in
                           zip(problem.models, problem.efforts, strict=True))
        self.planning = False
        self.active = active
        self.decision_count = 0
        self._reset_price = False
        self.last: JointDecision | None = None
        self.last_job: JointJob | None = None
        self.last_info: dict[str, Any] = {}
        self.health.log("info", f"sensor manager: {problem.describe()}; search {search}, time_budget "
                        f"{self.params['time_budget']:g} s, max_depth {self.params['max_depth']}, gather_timeout "
                        f"{self.params['gather_timeout']:g} s")
        for ib in self.inboxes:
            self.health.log("info", f"target {ib.name}: {ib.model.describe()}; listens on {ib.name}/belief, "
                            f"publishes {ib.name}/action")
        self.health.log("info", f"gate: {self.planner.describe()}; dual bound "
                        + ("guaranteed (every target searched exhaustively)" if self.planner.bound_guaranteed
                           else "an estimate, not a bound (branch-and-bound values; search: exhaustive makes it one)"))
        if self.planner.note:
            self.health.log("warning", self.planner.note)

    @property
    def names(self) -> tuple[str, ...]:
        return self.problem.names

    @property
    def hardware_id(self) -> str:
        """What the diagnostics name as the hardware: the targets' models."""
        return "+".join(m.name for m in self.problem.models)

    # ----------------------------------------------------------- parameters
    def set_params(self, changed: Mapping[str, Any]) -> list[Log]:
        """Parameters changed at run time (checked with :func:`check_params`); in force from the next decision."""
        self.params, logs = apply_changes(self.params, changed, TUNABLE)
        return logs

    def _planner_for(self, decided: tuple[int, ...], budget: Fraction, params: Mapping[str, Any]) -> MultiTargetPlanner:
        """The planner of the sub-problem ``decided`` within ``budget`` (built once, kept in an LRU cache)."""
        key = (decided, budget, params["time_budget"], params["max_depth"])
        planner = self._planners.get(key)
        if planner is not None:
            self._planners.move_to_end(key)
            return planner
        p = self.problem
        if len(decided) == p.K and budget == p.budget:
            problem = p
        else:  # the models are already the problem's (one discount): no replacement needed
            problem = make_problem([p.models[k] for k in decided], budget=budget,
                                   efforts=[p.efforts[k] for k in decided], names=[p.names[k] for k in decided])
        k = self._knobs
        planner = MultiTargetPlanner(problem, search=k["search"], time_budget=float(params["time_budget"]),
                                     max_depth=int(params["max_depth"]), max_evaluations=k["max_evaluations"],
                                     variant=k["variant"], constant=k["constant"])
        self._planners[key] = planner
        while len(self._planners) > PLANNER_CACHE:
            self._planners.popitem(last=False)
        return planner

    # ----------------------------------------------------------- lifecycle
    def activate(self, now: float) -> ManagerOutput:
        """Decide and publish again (module docstring): the input watches count silence from now,
        every action in force that no belief has answered is sent again, the mailboxes are decided."""
        if self.active:
            return self._result(now)
        self.active = True
        self.health.resume(now)
        actions = []
        for k, ib in enumerate(self.inboxes):
            if ib.resender.waiting and ib.in_force is not None:
                actions.append((k, ib.in_force))
                ib.resender.resending(now)
                self.health.count("resent_actions")
        waiting = [ib.name for ib in self.inboxes if ib.mailbox is not None]
        self.health.log("info", "activated: deciding " + (
            f"the waiting beliefs of {', '.join(waiting)}" if waiting else "the next beliefs"))
        return self._result(now, actions=actions)

    def deactivate(self, now: float) -> ManagerOutput:
        """Stop deciding and publishing (module docstring); the actions in force, the decision cache
        and the newest beliefs stay."""
        if self.active:
            self.active = False
            self.health.log("info", "deactivated: not deciding or publishing; the newest beliefs are kept for "
                            "the activation")
        return self._result(now)

    # ----------------------------------------------------------- beliefs
    def start(self, now: float) -> ManagerOutput:
        """The start-up lines."""
        return self._result(now)

    def belief(self, k: int, bel: BeliefSample, now: float) -> ManagerOutput:
        """A decoded belief of target ``k``: the newest valid, not-yet-decided one within the window
        goes to its mailbox; every other one is counted (and kept as evidence for the re-sync rule)."""
        ib = self.inboxes[k]
        verdict = belief_verdict(ib.line, ib.stream, ib.pace, self.health, bel.epoch, now, who=f"{ib.name}: ",
                                 acted="decided")
        new = verdict in ("join", "next", "ahead")
        ib.watch.arrived(now, new, bel.epoch)
        if new:
            ib.resender.answered()
            ib.offer(bel, now)
            if verdict == "join":  # the newest of what comes within JOIN_DELAY (a filter's history is one burst)
                ib.join.note(bel.epoch, now)
            else:
                ib.stream = max(ib.stream, bel.epoch)
                ib.line.clear_evidence()
                if not self.active:  # the epochs skipped while inactive are never decided ("Inactive")
                    ib.line.advance(ib.mailbox.epoch - 1, now)
        else:
            off_stream_belief(ib.line, self.health, verdict, bel.epoch, bel, stream=ib.stream,
                              window=self.live.epoch_window, stall_warn=self.live.stall.warn_after, now=now,
                              who=f"{ib.name}: ", acted="decided")
        self._resync_if_due(ib, now)
        return self._result(now)

    def rejected_belief(self, k: int, problem: str, now: float) -> ManagerOutput:
        ib = self.inboxes[k]
        self.health.reject(ib.watch, "bad_beliefs", f"{ib.name}: ignored {problem}; no action published", now)
        return self._result(now)

    def _resync_if_due(self, ib: TargetInbox, now: float) -> None:
        """The jump and re-sync rules (:class:`~.epochs.EpochLine`): the newest off-line belief goes to
        the mailbox."""
        due = ib.line.resync_due(self.live.stall.warn_after, now, jump_after=0.0)
        if due is None:
            return
        if ib.line.jump(due):
            self.health.warn(None, f"{ib.name}: followed the beliefs from epoch {ib.stream} to epoch {due.epoch}: two "
                             "consecutive beliefs beyond the newest (a jump of the filter)", now)
        else:
            self.health.warn("resyncs", f"{ib.name}: " + ib.line.resync_reason(due, "beliefs", "filter", now), now)
            self._reset_price = True  # the warm start came from another numbering of that target
        ib.line.resync(due.epoch - 1, now)  # so that the belief of due.epoch is the next one
        ib.stream = due.epoch
        ib.mailbox, ib.since = None, None
        ib.offer(due.payload, now)

    # ----------------------------------------------------------- deciding
    def due(self, now: float) -> bool:
        """The rule "When to decide" (module docstring); never while inactive."""
        if self.planning or not self.active:
            return False
        ready = [ib for ib in self.inboxes if ib.ready(now)]
        if not ready:
            return False
        if all(ib.ready(now) or ib.stalled(self.live, now) for ib in self.inboxes):
            return True
        return now - min(ib.ready_at() for ib in ready) >= self.params["gather_timeout"]

    def wake_at(self, now: float) -> float | None:
        """The next time :meth:`due` can turn true without a new input (a join settling, the gather
        timeout, a waited-for target stalling), if any."""
        if self.planning or not self.active:
            return None
        times = [at for ib in self.inboxes if (at := ib.ready_at()) is not None and at > now]
        ready = [ib.ready_at() for ib in self.inboxes if ib.ready(now)]
        if ready:
            times.append(min(ready) + self.params["gather_timeout"])
            warn = self.live.stall.warn_after
            times += [now + warn - ib.watch.silent_for(now) for ib in self.inboxes
                      if not ib.ready(now) and not ib.stalled(self.live, now)]
        later = [t for t in times if t > now]
        return min(later) if later else None

    def _effort(self, k: int, action: ActionSample | None) -> Fraction:
        """Target ``k``'s effort of ``action`` in force (``None``: its least effort)."""
        return self.problem.efforts[k][self.least[k] if action is None else action.priority - 1]

    def _effort_in_force(self, actions: Sequence[ActionSample | None]) -> Fraction:
        """``sum_k e_k`` of the actions in force (a target without one: its least effort), exactly."""
        return self.problem.effort_of([self.least[k] if a is None else a.priority - 1 for k, a in enumerate(actions)])

    def take(self, now: float) -> JointJob | None:
        """The decision to make now, if one is due (``None`` otherwise): every ready target's belief
        is taken from its mailbox (its position advances to it); a target whose next action epoch
        is in its decision cache is answered from there; the others are held."""
        if not self.due(now):
            return None
        beliefs: dict[int, BeliefSample] = {}
        cached: dict[int, ActionSample] = {}
        taken: dict[int, tuple[int | None, BeliefSample]] = {}
        for k, ib in enumerate(self.inboxes):
            if not ib.ready(now):
                continue
            bel, ib.mailbox, ib.since = ib.mailbox, None, None
            taken[k] = (ib.line.position, bel)
            ib.line.advance(bel.epoch, now)
            ib.stream = max(ib.stream, bel.epoch)
            hit = ib.decisions.get(bel.epoch + 1)
            if hit is None:
                beliefs[k] = bel
            else:
                cached[k] = ActionSample(bel.epoch + 1, hit)
        held = sum((self._effort(k, cached.get(k, ib.in_force)) for k, ib in enumerate(self.inboxes)
                    if k not in beliefs), Fraction(0))
        self.planning = True
        job = JointJob(beliefs, cached, self.problem.budget - held, now, dict(self.params), taken,
                       self._reset_price)
        self._reset_price = False
        return job

    def search(self, job: JointJob) -> Searched:
        """Decide ``job`` (not under the node's lock: only the planning side calls it); no decision
        when every target of it is held or cached, or when the planner refuses (its one line)."""
        if not job.beliefs:
            return Searched(None)
        try:
            planner = self._planner_for(job.decided, job.budget, job.params)
            if job.reset_price:
                planner.reset()
            return Searched(planner.decide([job.beliefs[k].belief for k in job.decided]))
        except InputError as exc:
            return Searched(None, str(exc))

    def decided(self, job: JointJob, searched: Searched, now: float) -> ManagerOutput:
        """The answer to ``job``: the decided targets' actions, the cached ones again, the joint record."""
        self.planning = False
        if not self.active:  # deactivated during the search: nothing published, the beliefs wait
            self._give_back(job, now)
            return self._result(now)
        decision = searched.decision
        new: dict[int, ActionSample] = dict(job.cached)
        if job.beliefs:
            if decision is None or len(decision.priorities) != len(job.beliefs):
                return self._refuse(job, searched.error or "the planner returned no joint action for the decided "
                                    "targets", now)
            for k, p in zip(job.decided, decision.priorities, strict=True):
                new[k] = ActionSample(job.beliefs[k].epoch + 1, int(p))
        in_force = tuple(new.get(k, ib.in_force) for k, ib in enumerate(self.inboxes))
        bad = [k for k, a in new.items() if not 1 <= a.priority <= self.problem.models[k].A]
        effort = None if bad else self._effort_in_force(in_force)
        if bad or effort > self.problem.budget:
            why = (f"priority out of range for {', '.join(self.names[k] for k in bad)}" if bad else
                   f"the actions in force would cost {format_effort(effort)}, above the budget "
                   f"{format_effort(self.problem.budget)}")
            return self._refuse(job, why, now)
        actions = []
        for k, act in sorted(new.items()):
            ib = self.inboxes[k]
            ib.in_force = act
            ib.remember(act)
            ib.resender.published(now)
            actions.append((k, act))
        self.decision_count += 1
        self.health.count("decisions")
        self.health.count("partial_decisions", len(job.beliefs) < self.problem.K)
        self.health.count("cached_decisions", len(job.cached))
        latency = now - job.due
        missed = latency > job.params["time_budget"] + job.params["deadline_slack"]
        if decision is not None:
            self.last = decision
            self.health.count("budget_exhausted", bool(decision.deadline_hit))
        if missed:
            self.health.warn("deadline_misses", f"decision {self.decision_count}: took {latency * 1e3:.1f} ms "
                             f"(budget {job.params['time_budget'] * 1e3:.0f} ms)", now, log=False)
        self.last_job = job
        self.last_info = {"decision": self.decision_count, "latency": latency, "effort": effort,
                          "deadline_miss": missed, **{f"param.{k}": v for k, v in job.params.items()}}
        record = Allocation(self.decision_count, in_force, effort, self.problem.budget)
        return self._result(now, actions=actions, allocation=record)

    def _refuse(self, job: JointJob, why: str, now: float) -> ManagerOutput:
        """Publish nothing for ``job``: its beliefs go back to the mailboxes, their positions back."""
        self.health.warn("refused_decisions", f"refused a decision: {why}; nothing published", now)
        self._give_back(job, now)
        return self._result(now)

    def _give_back(self, job: JointJob, now: float) -> None:
        """``job``'s beliefs back to the mailboxes (a newer one there stays), their positions back
        (unless a newer belief has moved one on since, while inactive)."""
        for k, (position, bel) in job.taken.items():
            ib = self.inboxes[k]
            if ib.line.position == bel.epoch:
                ib.line.position = position
            ib.offer(bel, now)

    def watchdog(self, now: float) -> ManagerOutput:
        """Re-send each target's action in force while the belief it leads to has not come; the
        time-based re-sync; a decision that has become due."""
        actions = []
        if self.active and not self.planning:
            for k, ib in enumerate(self.inboxes):
                if ib.resender.due(now) and ib.in_force is not None:
                    actions.append((k, ib.in_force))
                    ib.resender.resending(now)
                    self.health.count("resent_actions")
        for ib in self.inboxes:
            self._resync_if_due(ib, now)
        return self._result(now, actions=actions)

    def _result(self, now: float, **kw) -> ManagerOutput:
        return ManagerOutput(logs=self.health.drain_logs(), decide_now=self.due(now), wake_at=self.wake_at(now), **kw)

    # ----------------------------------------------------------- diagnostics
    def report(self, now: float) -> Report:
        """The diagnostics (rule "Report" of the package docstring): the problem, the last decision's
        price, dual bound and gap (labelled as the planner says: a bound only when guaranteed),
        the budget in force, and per target its epochs, its action in force and its input."""
        p = self.problem
        in_force = tuple(ib.in_force for ib in self.inboxes)
        effort = self._effort_in_force(in_force)
        values: dict[str, object] = {
            "targets": ",".join(p.names), "effort_budget": format_effort(p.budget),
            "budget_binds": p.budget_binds, "search": self._knobs["search"],
            "bound_guaranteed": self.planner.bound_guaranteed,
            "effort_in_force": format_effort(effort),
            "budget_use": round(float(effort / p.budget), 6) if p.budget else 1.0,
            **{f"param.{k}": v for k, v in self.params.items()}}
        silent = []
        for k, (ib, setup) in enumerate(zip(self.inboxes, self.planner.setups, strict=True)):
            t = f"target.{ib.name}"
            a = ib.in_force
            state = "no action yet" if a is None else (
                "decided" if self.last_job is not None and k in self.last_job.beliefs else "held")
            values.update({
                f"{t}.model": ib.model.name, f"{t}.efforts": ",".join(format_effort(e) for e in p.efforts[k]),
                f"{t}.gate": setup.describe(),
                f"{t}.belief_epoch": "none" if ib.line.position is None else ib.line.position,
                f"{t}.action_epoch": "none" if a is None else a.epoch,
                f"{t}.priority": "none" if a is None else a.priority,
                f"{t}.effort": format_effort(self._effort(k, a)),
                f"{t}.state": state})
            if ib.stalled(self.live, now):
                silent.append(f"{ib.name} held at " + ("its least effort (no action yet)" if a is None else
                                                        f"priority {a.priority} (epoch {a.epoch})"))
        d, job = self.last, self.last_job
        if job is None:
            head = []
        else:
            label = "bound" if d is not None and d.bound_guaranteed else "estimate, not a bound"
            summary = f"decision {self.last_info['decision']}: {len(job.beliefs)} of {p.K} targets decided"
            if d is not None:
                summary += (f" at depth {d.depth}, lambda {d.lam:.4g}, dual bound {d.dual_bound:.4g}, "
                            f"gap {d.gap:.4g} ({label})")
            head = [summary + f", effort in force {format_effort(effort)}/{format_effort(p.budget)}"]
        if not self.active:
            head.insert(0, "inactive: not deciding or publishing")
        report = self.health.report(now, values, head=head, idle="waiting for beliefs", inactive=not self.active,
                                    stall_note="" if not silent or not self.active else "; " + "; ".join(silent))
        values = report.values
        if job is not None:
            values.update({
                "last.decision": self.last_info["decision"],
                "last.decided": ",".join(p.names[k] for k in job.decided) or "none",
                "last.cached": ",".join(p.names[k] for k in sorted(job.cached)) or "none",
                "last.held": ",".join(n for k, n in enumerate(p.names) if k not in job.beliefs
                                      and k not in job.cached) or "none",
                "last.budget_left": format_effort(job.budget), "last.latency": float(self.last_info["latency"]),
                "last.deadline_miss": bool(self.last_info["deadline_miss"]),
                **{f"last.{k}": v for k, v in self.last_info.items() if k.startswith("param.")}})
        if d is not None:
            values.update({
                "last.lambda": float(d.lam), "last.dual_bound": float(d.dual_bound),
                "last.lower_bound": float(d.lower_bound), "last.gap": float(d.gap),
                "last.bound_guaranteed": bool(d.bound_guaranteed),
                "last.bound": "upper bound on the decided targets' depth-d joint lookahead value (every target "
                "searched exhaustively)" if d.bound_guaranteed else "estimate, not a bound (branch-and-bound values)",
                "last.effort": format_effort(d.effort), "last.depth": int(d.depth),
                "last.time_used": float(d.time_used), "last.deadline_hit": bool(d.deadline_hit)})
        return report


__all__ = ["PLANNER_CACHE", "Allocation", "JointJob", "ManagerLoop", "ManagerOutput", "Searched", "TargetInbox"]
