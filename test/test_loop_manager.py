"""The sensor manager's loop (core/loop/manager_loop.py) without ROS: pairing, the actions in force
and the budget, when to decide, silent and stalled targets, the join, the window, re-sync, the
decision cache, re-sending, a refused decision, the parameters, and what the diagnostics may
claim (a bound only where the planner says it is one). Time is passed in by hand; decisions come
from the core's multi-target planner. Efforts are checked against the table written out here
(priority p costs 3 - p), never against the loop's own arithmetic."""

from __future__ import annotations

import dataclasses
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import JOIN_DELAY, ActionSample, BeliefSample, Level, Liveness, ManagerLoop, StallLimits
from pomdp_planner.core.loop.manager_loop import Searched
from pomdp_planner.core.loop.manager_params import check_params, check_targets, manager_problem, split_efforts
from pomdp_planner.core.multitarget.planner import MultiTargetPlanner

ROOT = Path(__file__).resolve().parents[1]
PERIMETER = load_model_file(str(ROOT / "config" / "models" / "perimeter_s3.yaml"))
TRACKING = load_model_file(str(ROOT / "config" / "models" / "tracking_s3_info.yaml"))
NAMES = ("target1", "target2", "target3")
LIVE = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))
PARAMS = {"time_budget": 5.0, "max_depth": 1, "gather_timeout": 0.125, "deadline_slack": 0.02}
EFFORT = {1: 2, 2: 1, 3: 0}  # the default efforts of a 3-priority model, written out: priority p costs 3 - p
BUDGET = 2
T0 = 100.0
BELIEFS = (np.array([0.6, 0.3, 0.1]), np.array([0.1, 0.2, 0.7]), np.array([0.2, 0.5, 0.3]))


def make(search="exhaustive", budget=BUDGET, **params) -> ManagerLoop:
    problem = manager_problem(NAMES, [PERIMETER, PERIMETER, TRACKING], budget, discount=0.95)
    loop = ManagerLoop(problem, {**PARAMS, **params}, LIVE, now=T0, search=search)
    assert loop.start(T0).logs
    return loop


def bel(epoch, k=0):
    return BeliefSample(epoch, BELIEFS[k])


def decide(loop, now, force=None):
    """Take the due decision at ``now`` and answer it (``force``: 0-based actions replacing the planner's)."""
    job = loop.take(now)
    assert job is not None, "no decision due"
    searched = loop.search(job)
    if force is not None:
        searched = Searched(dataclasses.replace(searched.decision, actions=tuple(force)))
    return job, loop.decided(job, searched, now)


def joined(loop, epochs=(0, 0, 0), now=T0, force=None):
    """Every target joins at its epoch; the first decision after the join delay."""
    for k, e in enumerate(epochs):
        loop.belief(k, bel(e, k), now)
    return decide(loop, now + JOIN_DELAY, force)


def cost(actions) -> int:
    """The effort of a set of actions in force (``None``: none yet, at the least effort, 0)."""
    return sum(0 if a is None else EFFORT[a.priority] for a in actions)


# ----------------------------------------------------------------- pairing and the budget
def test_every_action_names_its_targets_own_belief_epoch():
    loop = make()
    job, out = joined(loop, epochs=(4, 17, 0))
    assert {k: b.epoch for k, b in job.beliefs.items()} == {0: 4, 1: 17, 2: 0}
    assert [(k, a.epoch) for k, a in out.actions] == [(0, 5), (1, 18), (2, 1)]
    assert out.allocation.decision == 1 and list(out.allocation.actions) == [a for _, a in out.actions]
    assert cost(out.allocation.actions) <= BUDGET


def test_the_joint_action_is_the_planners_for_the_same_beliefs_in_target_order():
    loop = make()
    _, out = joined(loop)
    problem = manager_problem(NAMES, [PERIMETER, PERIMETER, TRACKING], BUDGET, discount=0.95)
    expected = MultiTargetPlanner(problem, search="exhaustive", depth=1).decide(list(BELIEFS)).priorities
    assert tuple(a.priority for _, a in out.actions) == expected


@pytest.mark.parametrize("held_priority", [1, 2])
def test_a_held_targets_action_keeps_its_effort_and_the_others_share_the_rest(held_priority):
    loop = make()
    joined(loop, force=(2, 2, held_priority - 1))  # target3 in force at held_priority
    loop.belief(0, bel(1, 0), T0 + 1.0)
    loop.belief(1, bel(1, 1), T0 + 1.0)
    assert loop.take(T0 + 1.1) is None  # still waiting for target3 (gather_timeout 0.125 s)
    job, out = decide(loop, T0 + 1.125)
    assert job.decided == (0, 1) and job.budget == BUDGET - EFFORT[held_priority]
    decided = [a for k, a in out.actions]
    assert [k for k, _ in out.actions] == [0, 1] and [a.epoch for a in decided] == [2, 2]
    assert sum(EFFORT[a.priority] for a in decided) <= BUDGET - EFFORT[held_priority]
    if held_priority == 1:  # nothing is left: both decided targets get the least effort
        assert [a.priority for a in decided] == [3, 3]
    assert out.allocation.actions[2] == ActionSample(1, held_priority)  # target3's action in force, unchanged
    assert cost(out.allocation.actions) <= BUDGET
    values = loop.report(T0 + 1.2).values
    assert values["last.held"] == "target3" and values["last.decided"] == "target1,target2"
    assert values["target.target3.state"] == "held"
    assert values["last.budget_left"] == str(BUDGET - EFFORT[held_priority])


def test_a_target_without_any_action_counts_its_least_effort():
    loop = make()
    loop.belief(0, bel(0, 0), T0)
    loop.belief(1, bel(0, 1), T0)
    job, out = decide(loop, T0 + JOIN_DELAY + PARAMS["gather_timeout"])  # target3 never heard from: decided without it
    assert job.decided == (0, 1) and job.budget == BUDGET
    assert out.allocation.actions[2] is None and cost(out.allocation.actions) <= BUDGET


def test_a_refused_decision_publishes_nothing_and_gives_the_beliefs_back():
    loop = make()
    _, out = joined(loop, force=(0, 0, 0))  # every target at priority 1: effort 6 > 2
    assert out.actions == [] and out.allocation is None
    assert loop.health.counts["refused_decisions"] == 1 and loop.health.counts["decisions"] == 0
    assert "refused a decision" in " ".join(line.text for line in out.logs)
    assert loop.report(T0 + 1).level == Level.WARN
    _, out = decide(loop, T0 + JOIN_DELAY + 0.01)  # the same beliefs, decided again
    assert [a.epoch for _, a in out.actions] == [1, 1, 1] and cost(out.allocation.actions) <= BUDGET


# ----------------------------------------------------------------- when to decide
def test_a_decision_waits_for_every_target_until_the_gather_timeout():
    loop = make()
    joined(loop)
    out = loop.belief(0, bel(1, 0), T0 + 1.0)
    assert not out.decide_now and out.wake_at == pytest.approx(T0 + 1.125)
    out = loop.belief(1, bel(1, 1), T0 + 1.02)
    assert not out.decide_now
    out = loop.belief(2, bel(1, 2), T0 + 1.03)  # the last one: due at once
    assert out.decide_now
    job, _ = decide(loop, T0 + 1.03)
    assert job.decided == (0, 1, 2)


def test_a_stalled_target_is_not_waited_for_and_rejoins_with_its_next_belief():
    loop = make()
    joined(loop)
    t = T0 + JOIN_DELAY
    for e in range(1, 4):  # target3's filter is silent; the others go on
        t += 1.0
        loop.belief(0, bel(e, 0), t)
        loop.belief(1, bel(e, 1), t)
        if t - (T0 + JOIN_DELAY) < LIVE.stall.warn_after:
            assert loop.take(t) is None  # target3 still waited for
            t += PARAMS["gather_timeout"]
        job, _ = decide(loop, t)  # once stalled: at once
        assert job.decided == (0, 1)
    report = loop.report(t)
    assert report.level == Level.WARN and "target3/belief: no new belief" in report.message
    assert "target3 held at priority" in report.message
    loop.belief(2, bel(1, 2), t + 0.5)  # its filter back: the next decision includes it
    loop.belief(0, bel(4, 0), t + 0.5)
    loop.belief(1, bel(4, 1), t + 0.5)
    job, out = decide(loop, t + 0.5)
    assert job.decided == (0, 1, 2) and dict(out.actions)[2] == ActionSample(2, dict(out.actions)[2].priority)


def test_join_decides_the_newest_belief_of_a_burst():
    loop = make()
    for e in range(31):  # a running filter's history arrives as one burst
        loop.belief(0, bel(e, 0), T0 + e * 1e-4)
    loop.belief(1, bel(0, 1), T0)
    loop.belief(2, bel(0, 2), T0)
    assert loop.take(T0 + JOIN_DELAY / 2) is None
    job, out = decide(loop, T0 + JOIN_DELAY + 0.01)
    assert job.beliefs[0].epoch == 30 and dict(out.actions)[0].epoch == 31


def test_one_decision_at_a_time():
    loop = make()
    for k in range(3):
        loop.belief(k, bel(0, k), T0)
    job = loop.take(T0 + JOIN_DELAY)
    loop.belief(0, bel(1, 0), T0 + JOIN_DELAY + 0.01)
    assert loop.take(T0 + JOIN_DELAY + 1.0) is None and loop.wake_at(T0 + 1) is None  # planning
    out = loop.decided(job, loop.search(job), T0 + JOIN_DELAY + 0.02)
    assert out.allocation is not None
    assert [k for k, ib in enumerate(loop.inboxes) if ib.ready(T0 + JOIN_DELAY + 0.02)] == [0]


# ----------------------------------------------------------------- liveness per target
def test_a_forged_epoch_is_dropped_and_a_stale_one_counted():
    loop = make()
    joined(loop, epochs=(5, 5, 5))
    loop.belief(0, bel(10**15, 0), T0 + 1)
    loop.belief(0, bel(3, 0), T0 + 1)
    assert loop.health.counts["out_of_window"] == 1 and loop.health.counts["stale_beliefs"] == 1
    assert loop.inboxes[0].mailbox is None
    report = loop.report(T0 + 1.1)
    assert report.level == Level.WARN and "target1: belief of epoch 1000000000000000" in report.message


def test_a_targets_belief_that_does_not_follow_its_beliefs_so_far_is_decided_only_if_the_next_one_follows_it():
    loop = make()
    joined(loop, epochs=(10, 10, 10))
    out = loop.belief(0, bel(40, 0), T0 + 1.0)  # 30 ahead of target1's newest belief: inside the window, unexplained
    assert loop.inboxes[0].mailbox is None and loop.health.counts["unexplained_epochs"] == 1
    assert "target1: belief of epoch 40 does not follow the beliefs so far (newest: epoch 10)" in out.logs[0].text
    for k in range(20):  # a single stray belief is never decided, however long the manager waits
        loop.watchdog(T0 + 2.0 + k)
    assert loop.inboxes[0].line.position == 10 and loop.inboxes[0].mailbox is None
    loop.belief(1, bel(11, 1), T0 + 30.0)  # another target's stream is no evidence for target1's
    assert loop.inboxes[0].mailbox is None and loop.inboxes[1].mailbox.epoch == 11
    # a jump of target1's filter: two consecutive beliefs beyond its newest
    loop.belief(0, bel(30, 0), T0 + 30.0)
    out = loop.belief(0, bel(31, 0), T0 + 30.1)
    assert loop.inboxes[0].mailbox.epoch == 31
    assert "target1: followed the beliefs from epoch 10 to epoch 31" in out.logs[0].text
    assert loop.health.counts["resyncs"] == 0 and loop.health.counts["unexplained_epochs"] == 2  # 40, 30
    job, out = decide(loop, T0 + 30.2)
    assert {k: b.epoch for k, b in job.beliefs.items()} == {0: 31, 1: 11}
    assert loop.belief(0, bel(32, 0), T0 + 30.3).logs == [] and loop.inboxes[0].mailbox.epoch == 32


def test_a_bad_belief_is_counted_with_its_target():
    loop = make()
    out = loop.rejected_belief(1, "belief: expected 3 probabilities, got 4", T0)
    assert loop.health.counts["bad_beliefs"] == 1 and out.actions == []
    assert "target2: ignored belief: expected 3 probabilities" in out.logs[0].text


def test_a_filter_restarted_on_another_numbering_is_resynced_to():
    loop = make()
    joined(loop, epochs=(40, 40, 40))
    t = T0 + 1
    for e in (0, 1, 2):  # behind the position 40: off-line evidence
        loop.belief(0, bel(e, 0), t + 0.1 * e)
    assert loop.health.counts["resyncs"] == 0
    out = loop.watchdog(t + LIVE.stall.warn_after)
    assert loop.health.counts["resyncs"] == 1 and "target1: re-synced from epoch 40 to epoch 2" in out.logs[0].text
    assert loop.inboxes[0].mailbox.epoch == 2


def test_an_epoch_decided_before_is_answered_from_the_cache():
    loop = make()
    _, first = joined(loop, epochs=(2, 2, 2))
    a0 = dict(first.actions)[0]
    for k in range(3):
        loop.belief(k, bel(3, k), T0 + 1)
    decide(loop, T0 + 1)
    t = T0 + 2
    for e in (0, 1, 2):  # target1's filter back on an older numbering, ending at epoch 2 (decided before)
        loop.belief(0, bel(e, 0), t)
    loop.watchdog(t + LIVE.stall.warn_after)
    assert loop.inboxes[0].mailbox.epoch == 2
    job, out = decide(loop, t + LIVE.stall.warn_after + PARAMS["gather_timeout"])
    assert job.cached == {0: a0} and 0 not in job.beliefs
    assert dict(out.actions)[0] == a0 and loop.health.counts["cached_decisions"] == 1
    assert job.budget == BUDGET - cost(out.allocation.actions)  # nothing decided: every effort is held


def test_the_action_in_force_is_resent_until_its_belief_comes():
    loop = make()
    _, out = joined(loop)
    sent = dict(out.actions)
    t = T0 + JOIN_DELAY
    assert loop.watchdog(t + 0.5).actions == []
    loop.belief(1, bel(1, 1), t + 0.6)  # target2 answered
    again = loop.watchdog(t + LIVE.resend_period)
    assert again.actions == [(0, sent[0]), (2, sent[2])] and loop.health.counts["resent_actions"] == 2


def test_a_late_decision_is_a_deadline_miss():
    loop = make(time_budget=0.01)
    for k in range(3):
        loop.belief(k, bel(0, k), T0)
    job = loop.take(T0 + JOIN_DELAY)
    loop.decided(job, loop.search(job), T0 + JOIN_DELAY + 0.5)
    assert loop.health.counts["deadline_misses"] == 1 and loop.report(T0 + 1).level == Level.WARN


# ----------------------------------------------------------------- what the diagnostics claim
@pytest.mark.parametrize("search", ["exhaustive", "bnb"])
def test_the_report_calls_the_dual_bound_a_bound_only_when_the_planner_does(search):
    loop = make(search=search)
    assert loop.report(T0).message == "waiting for beliefs"
    joined(loop)
    report = loop.report(T0 + 0.3)
    v = report.values
    guaranteed = search == "exhaustive"
    assert v["bound_guaranteed"] is guaranteed and v["last.bound_guaranteed"] is guaranteed
    assert loop.last.bound_guaranteed is guaranteed  # the planner's own verdict
    if guaranteed:
        assert "(bound)" in report.message and v["last.bound"].startswith("upper bound")
    else:
        assert "(estimate, not a bound)" in report.message and v["last.bound"].startswith("estimate, not a bound")
    assert v["last.gap"] == pytest.approx(v["last.dual_bound"] - v["last.lower_bound"])
    effort = cost(ActionSample(0, v[f"target.{n}.priority"]) for n in NAMES)
    assert v["effort_in_force"] == str(effort) and v["budget_use"] == pytest.approx(effort / BUDGET)
    assert v["last.lambda"] >= 0 and v["last.depth"] == 1


def test_parameters_change_at_the_next_decision():
    loop = make()
    joined(loop)
    assert check_params({"max_depth": 0}).startswith("max_depth")
    assert check_params({"gather_timeout": -1.0}).startswith("gather_timeout")
    logs = loop.set_params({"max_depth": 2, "model_file": "x"})
    assert "in force from the next decision" in logs[0].text and loop.params["max_depth"] == 2
    for k in range(3):
        loop.belief(k, bel(1, k), T0 + 1)
    decide(loop, T0 + 1)
    assert loop.report(T0 + 1.1).values["last.depth"] == 2


# ----------------------------------------------------------------- every event order
EVENTS = st.lists(st.tuples(st.sets(st.integers(0, 2)), st.integers(0, 3), st.floats(0.0, 1.5)),
                  min_size=1, max_size=12)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(EVENTS, st.sampled_from([1, 2, 3]))
def test_every_allocation_is_within_budget_and_every_action_follows_its_belief(events, budget):
    """Random deliveries (which targets deliver, how far their epochs jump, how much time passes),
    decisions and watchdog calls: every joint record costs at most B (the effort table above),
    every action published for a target is the successor of a belief epoch of that target that
    was delivered, and the record's entry for a target is the last action published for it."""
    loop = make(budget=budget, time_budget=0.001)
    delivered = [set() for _ in NAMES]
    epoch = [0, 0, 0]
    last = [None, None, None]
    t = T0

    def check(out):
        for k, a in out.actions:
            assert a.epoch - 1 in delivered[k], (k, a, sorted(delivered[k]))
            assert last[k] is None or a.epoch >= last[k].epoch
            last[k] = a
        if out.allocation is not None:
            assert cost(out.allocation.actions) <= budget
            assert list(out.allocation.actions) == last

    for who, jump, dt in events:
        for k in sorted(who):
            epoch[k] += jump
            delivered[k].add(epoch[k])
            check(loop.belief(k, bel(epoch[k], k), t))
        t += dt
        job = loop.take(t)
        if job is not None:
            check(loop.decided(job, loop.search(job), t))
        check(loop.watchdog(t))


# ----------------------------------------------------------------- parameters
def test_targets_are_namespaces_given_once():
    assert check_targets(["target1", "/site/t_2"]) == ("target1", "/site/t_2")
    for bad, text in [([], "at least one"), (["a", "a"], "targets[1]: 'a' is given twice"),
                      (["a", "2b"], "targets[1]: '2b' is not a namespace"), (["a/"], "targets[0]"),
                      (["a b"], "targets[0]"), ("a", "must be a list")]:
        with pytest.raises(OptionError, match=text.replace("[", r"\[").replace("]", r"\]")):
            check_targets(bad)


def test_efforts_are_one_list_for_every_target_or_every_targets_list_in_turn():
    models = [PERIMETER, PERIMETER, TRACKING]
    assert split_efforts(None, models) is None and split_efforts([], models) is None
    shared = split_efforts([2, 0.5, 0], models)
    assert shared == [[2, Fraction(1, 2), 0]] * 3
    each = split_efforts([3, 1, 0, 2, 1, 0, 1, 1, 0], models)
    assert each == [[3, 1, 0], [2, 1, 0], [1, 1, 0]]
    with pytest.raises(OptionError, match=r"efforts: 4 values; expected 3 .* or 9"):
        split_efforts([1, 2, 3, 4], models)
    with pytest.raises(OptionError, match=r"efforts\[4\]: must be >= 0"):
        split_efforts([3, 1, 0, 2, -1, 0, 1, 1, 0], models)
    problem = manager_problem(NAMES, models, 1.5, [3, 1, 0, 2, 1, 0, 1, 1, 0], discount=0.95)
    assert problem.efforts[2] == (1, 1, 0) and problem.budget == Fraction(3, 2)


def test_the_budget_and_the_discount_are_checked_with_the_parameters_names():
    models = [PERIMETER, TRACKING]
    with pytest.raises(OptionError, match=r"effort_budget: 1 is below the least effort"):
        manager_problem(("a", "b"), models, 1, [1, 1, 1], discount=0.95)
    with pytest.raises(OptionError, match="discount: the targets' models have different discounts"):
        manager_problem(("a", "b"), models, 2)
    with pytest.raises(OptionError, match="model_files: 1 model files for 2 targets"):
        manager_problem(("a", "b"), [PERIMETER], 2)


# ----------------------------------------------------------------- inactive (a managed node)
def test_an_inactive_manager_decides_nothing_and_its_positions_follow_the_newest_beliefs():
    loop = make()
    _, out = joined(loop)
    in_force = dict(out.actions)
    t = T0 + JOIN_DELAY
    loop.deactivate(t)
    for e in range(1, 40):  # a long pause beside targets that keep stepping
        for k in range(3):
            assert not loop.belief(k, bel(e, k), t + 0.01 * e).decide_now
    assert loop.take(t + 5.0) is None and loop.wake_at(t + 5.0) is None
    assert loop.watchdog(t + 5.0).actions == []  # no re-send while inactive
    assert [ib.line.position for ib in loop.inboxes] == [38, 38, 38]  # the skipped epochs are never decided
    assert loop.report(t + 20.0).level == Level.OK and "inactive" in loop.report(t + 20.0).message
    out = loop.activate(t + 20.0)
    assert out.actions == [] and out.decide_now  # every in-force action was answered; the mailboxes wait
    job, out = decide(loop, t + 20.0)
    assert {k: b.epoch for k, b in job.beliefs.items()} == {0: 39, 1: 39, 2: 39}
    assert sorted(a.epoch for _, a in out.actions) == [40, 40, 40] and set(in_force) == {0, 1, 2}


def test_a_decision_ending_while_inactive_publishes_nothing_and_activate_resends_the_unanswered():
    loop = make()
    _, out = joined(loop)
    first = dict(out.actions)
    t = T0 + JOIN_DELAY
    for k in range(3):
        loop.belief(k, bel(1, k), t + 0.1)
    job = loop.take(t + 0.1)
    assert job is not None
    loop.deactivate(t + 0.2)
    out = loop.decided(job, loop.search(job), t + 0.3)
    assert out.actions == [] and out.allocation is None and loop.decision_count == 1
    assert all(ib.in_force == first[k] for k, ib in enumerate(loop.inboxes))  # what the targets apply
    assert [ib.mailbox.epoch for ib in loop.inboxes] == [1, 1, 1]  # given back
    out = loop.activate(t + 5.0)
    assert out.actions == [] and out.decide_now  # the beliefs of epoch 1 answered the actions in force
    job, out = decide(loop, t + 5.0)
    assert sorted(a.epoch for _, a in out.actions) == [2, 2, 2]


def test_activate_sends_again_the_actions_in_force_no_belief_answered():
    loop = make()
    _, out = joined(loop)
    sent = dict(out.actions)
    t = T0 + JOIN_DELAY
    loop.deactivate(t + 0.1)
    loop.belief(1, bel(1, 1), t + 0.2)  # target2 answered, the others not
    out = loop.activate(t + 0.3)
    assert out.actions == [(0, sent[0]), (2, sent[2])] and loop.health.counts["resent_actions"] == 2
    assert loop.activate(t + 0.4).actions == []  # already active


def test_a_targets_filter_that_resumes_after_a_pause_is_decided_without_a_stray_warning():
    loop = make()
    joined(loop)
    t = T0 + JOIN_DELAY
    for e in range(1, 8):  # every target at 50 Hz
        t += 0.02
        for k in range(3):
            loop.belief(k, bel(e, k), t)
        if loop.take(t) is not None:
            loop.planning = False
    out = loop.belief(0, bel(20, 0), t + 0.5)  # target1's filter was inactive for 12 epochs
    assert loop.inboxes[0].mailbox.epoch == 20 and loop.health.counts["unexplained_epochs"] == 0
    assert any("target1: belief of epoch 20 after 0.50 s without a belief" in ln.text for ln in out.logs)
