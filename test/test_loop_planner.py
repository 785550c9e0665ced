"""The planner's loop (core/loop/planner_loop.py) without ROS: the mailbox, joining, the window,
re-sync, the decision cache, re-sending, deadline misses, bad beliefs, refusing, parameters, and
what the diagnostics may claim: a certificate only where the gate (core/gate.py) guarantees the
bounds. Time is passed in by hand; decisions come from the core's search, or from stub results
where the rule, not the search, is the subject."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import (
    JOIN_DELAY,
    ActionSample,
    BeliefSample,
    Level,
    Liveness,
    PlannerLoop,
    StallLimits,
    check_params,
)
from pomdp_planner.core.loop.planner_loop import DECISION_CACHE, Searched
from pomdp_planner.core.search import Planner, SearchResult

ROOT = Path(__file__).resolve().parents[1]
S3 = load_model_file(str(ROOT / "config" / "models" / "tracking_s3_info.yaml"))
FAILING = load_model_file(str(ROOT / "test" / "models" / "fails_assumption1_s3.yaml"))
LIVE = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))
PARAMS = {"time_budget": 5.0, "max_depth": 2, "use_bounds": True, "bound_variant": "tight", "bound_constant": "mlr",
          "deadline_slack": 0.02}
T0 = 100.0
B = np.array([0.2, 0.3, 0.5])


def make(model=S3, **params) -> PlannerLoop:
    loop = PlannerLoop(model, {**PARAMS, **params}, LIVE, now=T0)
    assert "assumptions hold; bounds tight, constant mlr: feasible" in loop.start(T0).logs[-1].text
    return loop


def bel(epoch, b=B):
    return BeliefSample(epoch, np.asarray(b, dtype=float))


def stub(priority=2, certified=False, depth=1, deadline_hit=False, partial=False) -> SearchResult:
    return SearchResult(action=priority - 1, priority=priority, q_values=np.zeros(3), depth=depth,
                        nodes_expanded=(3,) * depth, nodes_pruned=(1,) * depth, certified=certified,
                        root_bounds=None, time_used=0.001, deadline_hit=deadline_hit, partial=partial)


def joined(loop, epoch=0, now=T0):
    """Join at ``epoch`` (the join delay passed) and decide it with the core search."""
    loop.belief(bel(epoch), now)
    job = loop.take(now + JOIN_DELAY)
    return loop.decided(job, loop.search(job), now + JOIN_DELAY)


def test_join_plans_the_newest_belief_received_within_the_join_delay():
    loop = make()
    out = loop.belief(bel(0), T0)  # a restarted filter's history starts with its prior ...
    assert out.join_at == pytest.approx(T0 + JOIN_DELAY) and not out.plan_now
    loop.belief(bel(57), T0 + 0.05)  # ... a running one's ends at its epoch
    loop.belief(bel(12), T0 + 0.1)
    assert loop.take(T0 + JOIN_DELAY / 2) is None  # still collecting
    job = loop.take(T0 + JOIN_DELAY)
    assert job.epoch == 57 and job.arrived == T0 + JOIN_DELAY  # the deliberate delay is no decision latency
    out = loop.decided(job, loop.search(job), T0 + JOIN_DELAY + 0.01)
    assert out.actions == [ActionSample(58, out.plan_info.action_priority)] and out.join_at is None
    assert out.plan_info.latency == pytest.approx(0.01)


def test_a_decision_answers_the_belief_of_epoch_t_with_the_action_of_t_plus_1():
    loop = make(use_bounds=False)
    out = joined(loop, 4)
    expected = Planner(S3).search(B, 2, use_bounds=False).priority  # the core's exhaustive search
    assert out.actions == [ActionSample(5, expected)]
    info = out.plan_info
    assert (info.epoch, info.action_priority, info.depth, info.certified) == (5, expected, 2, False)
    assert loop.health.counts["decisions"] == 1 and loop.line.position == 4


def test_the_mailbox_keeps_the_newest_new_belief_and_a_stale_one_cannot_displace_it():
    loop = make()
    joined(loop, 10)
    for e, t in ((11, 1.0), (12, 1.1), (13, 1.2), (9, 1.3), (10, 1.4), (12, 1.5)):  # stale and repeated ones come later
        loop.belief(bel(e), T0 + t)
    assert loop.mailbox.epoch == 13 and loop.health.counts["stale_beliefs"] == 2
    job = loop.take(T0 + 2.0)
    assert job.epoch == 13 and job.arrived == T0 + 1.2 and loop.take(T0 + 2.0) is None
    loop.belief(bel(12), T0 + 2.1)  # planned past it: stale now
    assert loop.mailbox is None and loop.health.counts["stale_beliefs"] == 3


def test_a_belief_that_does_not_follow_the_beliefs_so_far_is_planned_only_if_the_next_one_follows_it():
    loop2 = make()
    joined(loop2, 10)
    out = loop2.belief(bel(40), T0 + 1.0)  # 30 ahead of the newest belief: inside the window, unexplained
    assert loop2.mailbox is None and loop2.health.counts["unexplained_epochs"] == 1
    assert "belief of epoch 40 does not follow the beliefs so far (newest: epoch 10)" in out.logs[0].text
    loop2.belief(bel(11), T0 + 1.1)  # the real stream goes on: planned; the stray is forgotten
    assert loop2.mailbox.epoch == 11
    loop2.take(T0 + 1.2)
    loop2.belief(bel(41), T0 + 1.3)  # 40 and 41, with 11 in between: no jump
    assert loop2.mailbox is None and loop2.health.counts["unexplained_epochs"] == 2
    for k in range(20):  # a single stray belief is never planned, however long the planner waits
        loop2.watchdog(T0 + 2.0 + k)
    assert loop2.line.position == 11
    # a jump of the filter (a lost run of readings, or a filter restarted ahead): two consecutive beliefs
    loop2.belief(bel(30), T0 + 30.0)
    out = loop2.belief(bel(31), T0 + 30.1)
    assert loop2.mailbox.epoch == 31 and out.plan_now
    assert "followed the beliefs from epoch 11 to epoch 31" in out.logs[0].text
    assert loop2.health.counts["resyncs"] == 0 and loop2.health.counts["unexplained_epochs"] == 3  # 40, 41, 30
    assert loop2.take(T0 + 30.2).epoch == 31
    assert loop2.belief(bel(32), T0 + 30.3).logs == [] and loop2.mailbox.epoch == 32


def test_plan_now_wakes_the_planning_side_only_when_it_would_miss_the_mailbox():
    loop = make()
    joined(loop, 0)
    assert not loop.belief(bel(1), T0 + 1).plan_now  # the planning reader takes this sample itself
    assert loop.belief(bel(2), T0 + 1, planner_ahead=True).plan_now  # it already ran past it
    assert loop.watchdog(T0 + 1).plan_now  # something waits in the mailbox
    loop.take(T0 + 1)
    assert not loop.watchdog(T0 + 1).plan_now


def test_a_belief_beyond_the_window_is_dropped_and_one_never_moves_the_planner():
    loop = make()
    joined(loop, 20)
    out = loop.belief(bel(10**15), T0 + 1)
    assert loop.mailbox is None and loop.health.counts["out_of_window"] == 1
    assert "belief of epoch 1000000000000000 is beyond the epoch window (50) of epoch 20" in out.logs[0].text
    for k in range(5):
        out = loop.watchdog(T0 + 100.0 * (k + 1))
        assert all(a.epoch == 21 for a in out.actions)  # at most the re-sent action of epoch 21
    assert loop.line.position == 20 and loop.health.counts["resyncs"] == 0


def test_a_stalled_planner_resyncs_to_a_restarted_filters_numbering_and_answers_from_the_cache():
    loop = make()
    decided = {}
    for e in range(0, 8):  # decisions for epochs 1..8
        loop.belief(bel(e), T0)
        job = loop.take(T0 + JOIN_DELAY)
        decided[e + 1] = loop.decided(job, loop.search(job), T0 + JOIN_DELAY).actions[0].priority
    # a filter restarted on an older numbering: beliefs 2, 3, 4 are stale (behind), for 2 s
    for e in (2, 3):
        assert not loop.belief(bel(e), T0 + 1).plan_now
    assert loop.mailbox is None
    out = loop.belief(bel(4), T0 + 3.0)
    assert out.plan_now and loop.mailbox.epoch == 4 and loop.health.counts["resyncs"] == 1
    assert "re-synced from epoch 7 to epoch 4" in out.logs[0].text
    job = loop.take(T0 + 3.0)
    assert job.cached == decided[5]  # decided before: the same action again, no search
    out = loop.decided(job, None, T0 + 3.0)
    assert out.actions == [ActionSample(5, decided[5])] and out.plan_info is None
    assert loop.health.counts["cached_decisions"] == 1 and loop.health.counts["decisions"] == 8


def test_the_decision_cache_keeps_the_last_epochs_only():
    loop = make()
    loop.belief(bel(0), T0)
    for e in range(DECISION_CACHE + 1):
        job = loop.take(T0 + JOIN_DELAY)
        loop.decided(job, Searched(stub(priority=1 + e % 3), True, True), T0 + 1)
        loop.belief(bel(e + 1), T0 + 1)
    assert 1 not in loop._decisions and 2 in loop._decisions and len(loop._decisions) == DECISION_CACHE


def test_the_last_action_is_re_sent_every_period_until_its_belief_comes_but_not_during_a_search():
    loop = make()
    (action,) = joined(loop, 3).actions  # published at T0 + JOIN_DELAY
    t = T0 + JOIN_DELAY
    assert loop.watchdog(t + 0.99).actions == []
    assert loop.watchdog(t + 1.0).actions == [action] and loop.health.counts["resent_actions"] == 1
    assert loop.watchdog(t + 1.5).actions == [] and loop.watchdog(t + 2.0).actions == [action]
    loop.belief(bel(4), t + 2.1)  # the answer
    job = loop.take(t + 2.1)
    assert loop.planning == 4 and loop.watchdog(t + 10.0).actions == []  # answered, and searching
    loop.decided(job, Searched(stub(), True, True), t + 10.0)
    assert loop.planning is None and loop.watchdog(t + 11.0).actions == [ActionSample(5, 2)]


def test_a_deadline_miss_is_latency_over_the_budget_plus_the_slack():
    loop = make(time_budget=0.05, deadline_slack=0.02)
    loop.belief(bel(0), T0)
    job = loop.take(T0 + JOIN_DELAY)
    out = loop.decided(job, Searched(stub(deadline_hit=True), True, True), T0 + JOIN_DELAY + 0.07)
    assert not out.plan_info.deadline_miss and out.plan_info.deadline_hit
    loop.belief(bel(1), T0 + 1)
    out = loop.decided(loop.take(T0 + 1), Searched(stub(), True, True), T0 + 1.0701)
    assert out.plan_info.deadline_miss and out.logs == []  # counted and reported, not logged per decision
    assert loop.health.counts["deadline_misses"] == 1 and loop.health.counts["budget_exhausted"] == 1
    r = loop.report(T0 + 1.1)
    assert r.level == Level.WARN and "1 deadline misses; last: epoch 2: decision took 70.1 ms (budget 50 ms)" \
        in r.message


def test_a_bad_belief_is_counted_and_answered_with_nothing():
    loop = make()
    out = loop.rejected_belief("belief: expected 3 probabilities, got 2 (layout size 2)", T0)
    assert out.actions == [] and loop.mailbox is None and loop.health.counts["bad_beliefs"] == 1
    assert out.logs[0].text == "ignored belief: expected 3 probabilities, got 2 (layout size 2); no action published"
    r = loop.report(T0 + 0.5)
    assert r.level == Level.WARN and r.message.startswith("since the last report: 1 bad beliefs")
    assert loop.report(T0 + 1.0).message == "waiting for a belief"


def test_a_silent_belief_stream_is_warn_then_error():
    loop = make()
    joined(loop, 0)  # the belief came at T0
    assert loop.report(T0 + 1.9).level == Level.OK
    r = loop.report(T0 + 2.0)
    assert r.level == Level.WARN and r.message.startswith("belief: no new belief for 2.0 s (last: epoch 0)")
    assert loop.report(T0 + 10.0).level == Level.ERROR


def test_parameters_are_checked_and_in_force_from_the_next_job():
    assert check_params({"bound_variant": "loose"}) == "bound_variant: expected one of tight, feasible, got 'loose'"
    assert check_params({"bound_constant": "paper"}) == "bound_constant: expected one of mlr, fosd, got 'paper'"
    assert check_params({"max_depth": 3, "bound_constant": "fosd"}) == ""
    with pytest.raises(OptionError, match=r"bound_constant: expected one of mlr, fosd, got 'paper'"):
        make(bound_constant="paper")
    loop = make()
    loop.belief(bel(0), T0)
    (log,) = loop.set_params({"max_depth": 1, "model_file": "ignored"})
    assert log.text == "parameters changed {'max_depth': 1}; in force from the next decision"
    job = loop.take(T0 + JOIN_DELAY)
    assert job.params["max_depth"] == 1 and loop.search(job).result.depth == 1


def test_a_set_up_refused_at_run_time_is_one_warning_and_the_planner_in_force_stays(monkeypatch):
    """A run-time bound choice whose set-up the gate refuses (its cost): one warning naming it and
    the reason, the decisions go on with the bounds in force, no retry at every decision."""
    from pomdp_planner.core import gate
    from pomdp_planner.core.loop import planner_loop

    calls = []

    def build(model, **kw):
        calls.append(kw["variant"])
        if kw["variant"] == "feasible":
            raise gate.SetupCostError("model: the planner's set-up needs about 9 TiB, more than the 1 GiB available")
        return gate.build_planner(model, **kw)

    loop = make()
    monkeypatch.setattr(planner_loop, "build_planner", build)
    joined(loop)
    loop.set_params({"bound_variant": "feasible"})
    for epoch in (1, 2):
        loop.belief(bel(epoch), T0 + epoch)
        job = loop.take(T0 + epoch)
        searched = loop.search(job)
        out = loop.decided(job, searched, T0 + epoch)
        assert out.actions and out.actions[-1].epoch == epoch + 1
        warnings = [x.text for x in searched.logs if x.level == "warning"]
        if epoch == 1:
            assert warnings == ["bounds feasible, constant mlr refused: model: the planner's set-up needs about 9 TiB, "
                                "more than the 1 GiB available; planning on with bounds tight, constant mlr"]
        else:
            assert warnings == []
        assert searched.use_bounds and searched.guaranteed  # the tight bounds still in force
    assert calls == ["feasible"]
    with pytest.raises(gate.SetupCostError):  # at start-up the refusal is the node's error
        PlannerLoop(S3, {**PARAMS, "bound_variant": "feasible"}, LIVE, now=T0)


def test_refusing_plans_nothing_and_reports_error():
    loop = PlannerLoop(FAILING, PARAMS, LIVE, now=T0, refuse=True)
    assert loop.refusing and loop.setup.planner is None
    assert any(x.level == "error" and "refusing to plan" in x.text for x in loop.start(T0).logs)
    loop.belief(BeliefSample(0, np.array([0.3, 0.4, 0.3])), T0)
    assert loop.take(T0 + JOIN_DELAY) is None
    r = loop.report(T0 + 1)
    assert (r.level, r.message) == (Level.ERROR, "refusing to plan: model fails the structural assumptions")


# ----------------------------------------------------------------- certificates only where the gate guarantees

def _claims(report) -> list[str]:
    """Everything in a report that would claim a certificate or a guarantee."""
    text = [report.message, *(f"{k}={v}" for k, v in report.values.items())]
    return [t for t in text if "certified" in t or "guarantee covers" in t or t in ("guaranteed=True",)]


def test_on_a_model_failing_assumption_1_nothing_claims_a_certificate_or_a_guarantee():
    loop = PlannerLoop(FAILING, PARAMS, LIVE, now=T0)
    start = loop.start(T0).logs
    assert not loop.setup.guaranteed and any("falling back to exhaustive search" in x.text for x in start)
    loop.belief(BeliefSample(0, np.array([0.3, 0.4, 0.3])), T0)
    job = loop.take(T0 + JOIN_DELAY)
    searched = loop.search(job)
    assert not searched.use_bounds and not searched.guaranteed
    out = loop.decided(job, searched, T0 + 1)
    assert out.plan_info.certified is False
    # even a search result that says "certified" (A = 1, or a planner built elsewhere) is not reported so
    loop.belief(BeliefSample(1, np.array([0.1, 0.8, 0.1])), T0 + 1)
    out = loop.decided(loop.take(T0 + 1), Searched(stub(certified=True), False, False), T0 + 1)
    assert out.plan_info.certified is False and loop.health.counts["certified"] == 0
    r = loop.report(T0 + 1.5)
    assert r.level == Level.WARN and r.message.startswith("assumptions fail: exhaustive search")
    assert _claims(r) == []
    assert r.values["guaranteed"] is False and "Assumption 1 fails" in r.values["guarantee"]
    assert "certified" not in r.values and "last.certified" not in r.values
    assert r.values["bounds"] == "not used (assumptions fail)"


def test_with_guaranteed_bounds_the_certificate_is_reported():
    loop = make()
    loop.belief(bel(0), T0)
    out = loop.decided(loop.take(T0 + JOIN_DELAY), Searched(stub(certified=True), True, True), T0 + 1)
    assert out.plan_info.certified is True
    r = loop.report(T0 + 1.5)
    assert r.values["guaranteed"] is True and r.values["guarantee"].startswith("valid bounds: Assumption 1 holds")
    assert r.values["certified"] == 1 and r.values["last.certified"] is True
    assert (r.level, r.message) == (Level.OK, "depth 1, certified")
    loop.set_params({"use_bounds": False})  # bounds switched off: exhaustive, nothing certified for it
    loop.belief(bel(1), T0 + 1.6)
    job = loop.take(T0 + 1.6)
    searched = loop.search(job)
    assert not searched.guaranteed
    loop.decided(job, searched, T0 + 1.7)
    r = loop.report(T0 + 1.8)
    assert "last.certified" not in r.values and r.message == "depth 2, exhaustive search"


# ----------------------------------------------------------------- inactive (a managed node)
def test_an_inactive_planner_plans_nothing_keeps_the_newest_belief_and_plans_it_when_activated():
    loop = make(use_bounds=False)
    joined(loop, 3)  # action 4 published at T0 + JOIN_DELAY
    t = T0 + 1
    assert loop.deactivate(t).logs[0].text.startswith("deactivated")
    for e in (4, 5, 6):  # a sensor that keeps stepping: beliefs come, nothing is planned
        out = loop.belief(bel(e), t + 0.1 * e)
        assert out.actions == [] and not out.plan_now
        assert loop.take(t + 0.1 * e) is None and loop.mailbox.epoch == e
    assert loop.watchdog(t + 5.0).actions == []  # no re-send while inactive
    out = loop.activate(t + 6.0)
    assert out.plan_now and out.actions == [] and "planning the belief of epoch 6" in out.logs[0].text
    job = loop.take(t + 6.0)
    assert job.epoch == 6  # the newest: epochs 4 and 5 are never planned for
    out = loop.decided(job, loop.search(job), t + 6.1)
    assert out.actions == [ActionSample(7, Planner(S3).search(B, 2, use_bounds=False).priority)]


def test_an_inactive_planner_follows_the_beliefs_beyond_its_window_without_a_resync():
    loop = make()
    joined(loop, 0)
    loop.deactivate(T0 + 1)
    for k in range(1, 3 * LIVE.epoch_window):  # three windows of epochs while inactive, 10 per second
        loop.belief(bel(k), T0 + 1 + k / 10)
        loop.watchdog(T0 + 1 + k / 10)
    assert loop.health.counts["out_of_window"] == 0 and loop.health.counts["resyncs"] == 0
    loop.activate(T0 + 20)
    assert loop.take(T0 + 20).epoch == 3 * LIVE.epoch_window - 1


def test_a_decision_finished_while_inactive_is_sent_when_activated_unless_answered():
    loop = make()
    joined(loop, 0)
    loop.belief(bel(1), T0 + 1)
    job = loop.take(T0 + 1)  # the search runs ...
    loop.deactivate(T0 + 1.05)  # ... when the node is deactivated
    out = loop.decided(job, Searched(stub(priority=3), True, True), T0 + 1.1)
    assert out.actions == [] and out.plan_info is None  # kept, not published
    out = loop.activate(T0 + 3.0)
    assert out.actions == [ActionSample(2, 3)] and loop.health.counts["resent_actions"] == 1
    # the same again, but the sensor stepped meanwhile: its belief answers the action
    loop.belief(bel(2), T0 + 3.1)
    job = loop.take(T0 + 3.1)
    loop.deactivate(T0 + 3.15)
    loop.decided(job, Searched(stub(priority=1), True, True), T0 + 3.2)
    loop.belief(bel(3), T0 + 3.3)
    out = loop.activate(T0 + 4.0)
    assert out.actions == [] and out.plan_now and loop.take(T0 + 4.0).epoch == 3


def test_an_inactive_planner_reports_no_stall_and_counts_silence_from_its_activation():
    loop = make()
    joined(loop, 0)
    loop.deactivate(T0 + 1)
    r = loop.report(T0 + 30)
    assert r.level == Level.OK and r.message.startswith("inactive: not planning or publishing")
    loop.activate(T0 + 40)
    assert loop.report(T0 + 41.9).level == Level.OK
    assert loop.report(T0 + 42.0).level == Level.WARN  # 2 s after the activation, not 42 s after the belief


def test_a_planner_made_inactive_joins_at_its_activation():
    loop = PlannerLoop(S3, PARAMS, LIVE, now=T0, active=False)
    loop.start(T0)
    for e in (0, 7, 9):
        assert not loop.belief(bel(e), T0 + e / 100).plan_now
    assert loop.take(T0 + 1) is None
    assert loop.activate(T0 + 5).plan_now and loop.take(T0 + 5).epoch == 9


def test_max_depth_beyond_the_memory_budget_is_capped_with_one_warning():
    """As every anytime search: the deepest depth within the planner's memory budget, said once."""
    from pomdp_planner.core.search import search_memory_estimate

    loop = make(max_depth=4, time_budget=5.0)
    planner = loop.setup.planner
    planner.memory_budget = search_memory_estimate(3, 3, 3, 2, planner.chunk_bytes)  # depth 2 fits, 3 does not
    loop.belief(bel(0), T0)
    job = loop.take(T0 + JOIN_DELAY)
    searched = loop.search(job)
    assert searched.result.depth <= 2 and [log.level for log in searched.logs] == ["warning"]
    assert searched.logs[0].text.startswith("max_depth capped at 2 (asked 4): a deeper search needs more than")
    loop.decided(job, searched, T0 + 1)
    loop.belief(bel(1), T0 + 1)
    assert loop.search(loop.take(T0 + 1)).logs == ()  # once


def test_a_model_too_large_for_even_depth_1_is_refused_at_construction(monkeypatch):
    import pomdp_planner.core.search as search

    monkeypatch.setattr(search, "search_memory_estimate", lambda *args: 2**40)  # 1 TiB per search
    with pytest.raises(OptionError, match=r"^max_depth: a search of depth 1 needs about"):
        PlannerLoop(S3, PARAMS, LIVE, now=T0)


def test_a_decision_cut_inside_depth_one_is_sent_and_reported_as_partial():
    """The budget ended inside depth 1: the best root action searched by then is published, the
    decision counts as budget-exhausted and the report says it was partial."""
    loop = make(time_budget=0.05, deadline_slack=0.02)
    loop.belief(bel(0), T0)
    job = loop.take(T0 + JOIN_DELAY)
    out = loop.decided(job, Searched(stub(priority=3, deadline_hit=True, partial=True), True, True),
                       T0 + JOIN_DELAY + 0.06)
    assert out.actions == [ActionSample(1, 3)] and out.plan_info.deadline_hit
    assert loop.health.counts["budget_exhausted"] == 1
    values = loop.report(T0 + 1.0).values
    assert values["last.partial"] is True and values["last.deadline_hit"] is True


def _pace_lines(out) -> list[str]:
    return [line.text for line in out.logs if "exceeds the period of the beliefs" in line.text]


def test_a_time_budget_over_the_belief_period_is_one_warning_once_beliefs_are_skipped():
    """Rule "Pace": beliefs every 0.1 s, each planned before the next comes (a loop that waits for
    its actions), are no warning whatever the budget; beliefs skipped while time_budget exceeds
    their period are one warning (again after time_budget changes), none when it does not."""
    loop = make(time_budget=0.2)
    joined(loop, 0)
    now, epoch, lines = T0 + 1.0, 0, []
    for _ in range(15):  # every belief planned: no warning, though 0.2 s > 0.1 s
        epoch, now = epoch + 1, now + 0.1
        lines += _pace_lines(loop.belief(bel(epoch), now))
        out = loop.decided(loop.take(now), Searched(stub(), True, True), now + 0.01)
        lines += _pace_lines(out)
    assert lines == []
    for k in range(10):  # now only every second belief is planned: the others are skipped
        epoch, now = epoch + 1, now + 0.1
        lines += _pace_lines(loop.belief(bel(epoch), now))
        if k % 2:
            loop.decided(loop.take(now), Searched(stub(), True, True), now + 0.01)
    assert len(lines) == 1, lines
    assert lines[0].startswith("time_budget 0.2 s exceeds the period of the beliefs (0.1 s, the mean of the last 16 "
                               "intervals)")
    assert "keep time_budget below the sensor period" in lines[0]
    loop.set_params({"time_budget": 0.3})
    for k in range(4):
        epoch, now = epoch + 1, now + 0.1
        lines += _pace_lines(loop.belief(bel(epoch), now))
        if k % 2:
            loop.decided(loop.take(now), Searched(stub(), True, True), now + 0.01)
    assert len(lines) == 2 and lines[1].startswith("time_budget 0.3 s exceeds")
    quick = make(time_budget=0.05)
    joined(quick, 0)
    now, lines = T0 + 1.0, []
    for e in range(1, 30):  # skipped beliefs, but the budget fits in their period: no warning
        now += 0.1
        lines += _pace_lines(quick.belief(bel(e), now))
        if e % 3 == 0:
            quick.decided(quick.take(now), Searched(stub(), True, True), now + 0.01)
    assert lines == []
