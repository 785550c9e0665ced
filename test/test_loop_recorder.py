"""The run recorder's pairing rule (core/loop/recorder_loop.py) without ROS: which row holds what,
every delivery order, lost samples, time-outs, late and out-of-window samples, conflicts, checked
``plan_info`` (no bound or certificate the planner did not publish), bounded memory, and the rows
read back with the run-record reader. Time is passed in by hand."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.io.run_record import RunRecordWriter, read_run_record
from pomdp_planner.core.loop import ActionSample, BeliefSample, Level, PlanInfo
from pomdp_planner.core.loop.recorder_loop import RESYNC_AFTER, RecorderLoop, check_plan_info

S, A = 3, 3
T0 = 1000.0
NAN = math.nan


def belief_of(t: int) -> np.ndarray:
    """A belief that names its epoch (so a mis-paired row shows)."""
    b = np.array([1.0 + t % 7, 2.0 + t % 5, 0.5 + t % 3])
    return b / b.sum()


def info(epoch: int, priority: int, *, bounds=(NAN, NAN), certified: bool = False, depth: int = 2,
         latency: float = 0.01, **kw) -> dict[str, float]:
    """A decoded ``plan_info`` record (field -> float), as the node's decoder returns it."""
    return {"epoch": float(epoch), "action_priority": float(priority), "depth": float(depth),
            "nodes_expanded": 10.0, "pruned_percent": 50.0, "certified": float(certified), "time_used": latency / 2,
            "latency": latency, "deadline_hit": 0.0, "deadline_miss": 0.0, "bound_lower": float(bounds[0]),
            "bound_upper": float(bounds[1]), **{k: float(v) for k, v in kw.items()}}


class Run:
    """A recorder loop and every row it wrote, in order."""

    def __init__(self, **kw):
        self.loop = RecorderLoop(S, A, now=T0, **kw)
        self.rows = []
        self.logs = []
        self.due = None

    def _take(self, out):
        self.rows += out.rows
        self.logs += [line.text for line in out.logs]
        self.due = out.due
        return out

    def belief(self, t, now=T0):
        return self._take(self.loop.belief(BeliefSample(t, belief_of(t)), now))

    def action(self, epoch, p, now=T0):
        return self._take(self.loop.action(ActionSample(epoch, p), now))

    def plan_info(self, values, now=T0):
        return self._take(self.loop.plan_info(values, now))

    def true_state(self, t, s, now=T0):
        return self._take(self.loop.true_state(t, s, now))

    def poll(self, now):
        return self._take(self.loop.poll(now))

    def close(self, now=T0):
        return self._take(self.loop.close(now))

    def decision(self, t, p, s=None, **kw):
        """Everything the loop publishes about the decision from the belief of epoch ``t``."""
        if s is not None:
            self.true_state(t, s)
        self.belief(t)
        self.action(t + 1, p)
        self.plan_info(info(t + 1, p, **kw))

    @property
    def counts(self):
        return self.loop.health.counts


def test_row_t_holds_belief_and_state_of_t_and_the_action_and_plan_info_of_t_plus_1():
    run = Run()
    run.true_state(4, 2)
    run.belief(4)
    run.action(5, 3)
    assert run.rows == []  # the plan_info of the decision is awaited
    run.plan_info(info(5, 3, bounds=(2, 3), depth=4, latency=0.0125))
    (row,) = run.rows
    assert (row.epoch, row.true_state, row.priority, row.bounds) == (4, 2, 3, (2, 3))
    np.testing.assert_array_equal(row.belief, belief_of(4))
    assert row.record_fields() == {"true_state": 2, "bounds": (2, 3), "guaranteed": True, "depth": 4,
                                   "certified": False, "latency": 0.0125}


def test_certified_and_bounds_come_only_from_the_plan_info():
    run = Run()
    run.decision(0, 2, bounds=(2, 2), certified=True)  # agreeing guaranteed bounds
    run.decision(1, 1)  # the planner published no bounds (NaN): none in the record
    a, b = run.rows
    assert a.record_fields()["certified"] and a.bounds == (2, 2) and a.record_fields()["guaranteed"]
    assert b.bounds is None and not b.record_fields()["certified"] and not b.record_fields()["guaranteed"]


@pytest.mark.parametrize(("fields", "problem"), [
    ({"certified": 1}, "certified without agreeing bounds"),  # no bounds at all
    ({"certified": 1, "bound_lower": 1, "bound_upper": 3}, "certified without agreeing bounds"),
    ({"bound_lower": 3, "bound_upper": 1}, "above bound_upper"),
    ({"bound_lower": 1, "bound_upper": NAN}, "bound_upper"),  # one bound only
    ({"bound_lower": 0, "bound_upper": 2}, "bound_lower"),  # not a priority
    ({"bound_lower": 1, "bound_upper": 4}, "bound_upper"),
    ({"bound_lower": 1.5, "bound_upper": 2}, "bound_lower"),
    ({"bound_lower": 3, "bound_upper": 3}, "outside the bounds"),  # the action must lie in between
    ({"epoch": 2.5}, "epoch"),
    ({"action_priority": 4}, "action_priority"),
    ({"depth": -1}, "depth"),
    ({"latency": NAN}, "latency"),
    ({"latency": -0.1}, "latency"),
    ({"deadline_miss": 2}, "deadline_miss"),
])
def test_a_plan_info_that_is_not_consistent_is_refused_and_the_row_written_without_it(fields, problem):
    values = info(3, 2, bounds=(1, 2))
    values.update({k: float(v) for k, v in fields.items()})
    with pytest.raises(ValueError, match=problem):
        check_plan_info(values, A)
    run = Run()
    run.belief(2)
    run.action(3, 2)
    run.plan_info(values)
    assert run.counts["bad_plan_info"] == 1
    assert run.rows == []  # still awaiting a good one
    run.decision(3, 1)  # the next decision: its plan_info gives up the one of row 2
    assert [r.epoch for r in run.rows] == [2, 3]
    assert run.rows[0].info is None and run.rows[0].record_fields()["depth"] is None
    assert not run.rows[0].record_fields()["certified"]


def test_check_plan_info_keeps_every_field():
    got = check_plan_info(info(7, 2, bounds=(2, 2), certified=True, depth=1, latency=0.004), A)
    assert got == PlanInfo(epoch=7, action_priority=2, depth=1, nodes_expanded=10, pruned_percent=50.0,
                           certified=True, time_used=0.002, latency=0.004, deadline_hit=False, deadline_miss=False,
                           bound_lower=2.0, bound_upper=2.0)


def test_a_plan_info_naming_another_priority_than_the_action_is_dropped_either_order():
    run = Run()
    run.belief(0)
    run.plan_info(info(1, 3))  # before the action
    run.action(1, 2)
    assert run.counts["bad_plan_info"] == 1
    run.belief(1)
    run.action(2, 1)
    run.plan_info(info(2, 3))  # after the action
    assert run.counts["bad_plan_info"] == 2
    run.close()
    assert [(r.epoch, r.priority, r.info) for r in run.rows] == [(0, 2, None), (1, 1, None)]


def test_a_second_different_action_is_a_conflict_and_the_first_is_kept():
    run = Run()
    run.belief(0)
    run.action(1, 2)
    run.action(1, 2)  # a re-send: harmless
    run.action(1, 3)  # a restarted planner deciding again
    run.belief(0)  # the filter's re-send: the same belief
    run.plan_info(info(1, 2))
    assert [(r.epoch, r.priority) for r in run.rows] == [(0, 2)]
    assert run.counts["conflicts"] == 1
    assert run.loop.report(T0).level == Level.WARN


def test_waiting_rows_time_out_one_by_one_in_epoch_order():
    run = Run(row_timeout=5.0)
    run.belief(0, now=T0)
    run.action(1, 1, now=T0)
    run.belief(1, now=T0 + 1.0)
    run.action(2, 2, now=T0 + 1.0)  # neither plan_info comes, and the topic does not move on
    assert run.due == T0 + 5.0
    run.poll(T0 + 5.0)
    assert [r.epoch for r in run.rows] == [0] and run.due == T0 + 6.0
    run.poll(T0 + 6.0)
    assert [(r.epoch, r.info) for r in run.rows] == [(0, None), (1, None)] and run.due is None


def test_a_lost_plan_info_is_given_up_when_a_later_one_arrives_not_before():
    run = Run()
    run.belief(0)
    run.action(1, 1)
    run.poll(T0 + 4.0)
    assert run.rows == [] and run.due == T0 + 5.0  # the default row_timeout
    run.belief(1)
    run.action(2, 2)
    assert run.rows == []
    run.plan_info(info(2, 2))  # the topic moved past: plan_info 1 is lost
    assert [(r.epoch, r.info is None) for r in run.rows] == [(0, True), (1, False)]
    assert run.counts["rows_without_plan_info"] == 1


def test_a_topic_that_stopped_is_given_up_after_row_timeout_counted_from_belief_and_action():
    run = Run(row_timeout=2.0, expect_true_state=True)  # a simulated run, but no simulator
    run.belief(0, now=T0)
    run.action(1, 1, now=T0 + 1.0)
    run.plan_info(info(1, 1), now=T0 + 1.0)
    assert run.due == T0 + 3.0
    run.poll(T0 + 2.9)
    assert run.rows == []
    run.poll(T0 + 3.0)
    assert [(r.epoch, r.true_state) for r in run.rows] == [(0, None)]
    assert run.due is None and run.counts["rows_without_true_state"] == 1


def test_true_states_are_awaited_once_one_has_arrived():
    run = Run()
    run.decision(0, 1)  # no true_state yet: not a simulated run as far as it knows
    assert [r.true_state for r in run.rows] == [None]
    run.true_state(1, 2)
    run.decision(1, 1)
    run.belief(2)
    run.action(3, 2)
    run.plan_info(info(3, 2))
    assert [r.epoch for r in run.rows] == [0, 1]  # row 2 waits for its true state now
    run.true_state(2, 0)
    assert [(r.epoch, r.true_state) for r in run.rows] == [(0, None), (1, 2), (2, 0)]


def test_a_row_without_belief_or_action_is_dropped_once_its_topic_moved_past_never_on_time():
    run = Run()
    # a filter's gap: epochs 1 and 2 have true states but no belief; the belief of 3 ends the gap
    run.decision(0, 1, s=0)
    run.true_state(1, 1)
    run.true_state(2, 2)
    run.poll(T0 + 1e6)  # a slow planner or filter loses no row to time
    assert [r.epoch for r in run.rows] == [0]
    run.decision(3, 2, s=0)
    assert [r.epoch for r in run.rows] == [0, 3]
    assert run.counts["dropped_rows"] == 2
    # a belief the planner skipped (it plans the newest): no action for row 4
    run.true_state(4, 1)
    run.belief(4)
    run.decision(5, 3, s=1)
    assert [r.epoch for r in run.rows] == [0, 3, 5] and run.counts["dropped_rows"] == 3


def test_late_and_out_of_window_samples_are_dropped_and_counted():
    run = Run(epoch_window=10)
    run.decision(0, 1)
    run.decision(1, 2)
    run.belief(0)  # a restarted filter's prior
    run.action(1, 3)
    run.plan_info(info(2, 2))
    assert run.counts["late_samples"] == 3 and run.counts["conflicts"] == 0
    run.belief(12)  # beyond the last row written (1) + 10
    run.action(12, 1)  # row 11: in the window
    assert run.counts["out_of_window"] == 1
    assert run.loop.report(T0).level == Level.WARN
    run.action(0, 1)  # answers no belief
    assert run.counts["late_samples"] == 4
    run.close()
    assert [r.epoch for r in run.rows] == [0, 1]  # row 11 had no belief: dropped at close


def test_a_loop_restarted_on_another_numbering_is_followed_after_a_re_sync():
    run = Run()
    for t in range(500):
        run.decision(t, 1 + t % A)
    # the whole loop restarted: epochs from 0 again (late), for RESYNC_AFTER seconds
    for k, now in enumerate(np.arange(T0 + 0.1, T0 + RESYNC_AFTER, 0.5)):
        run.belief(k, now)
        run.action(k + 1, 1, now)
    assert len(run.rows) == 500 and run.counts["resyncs"] == 0
    run.belief(5, T0 + RESYNC_AFTER + 0.2)
    assert run.counts["resyncs"] == 1
    assert any(line.startswith("re-synced from epoch 499 to epoch 5") for line in run.logs), run.logs
    for t in range(6, 9):
        run.decision(t, 2)
    assert [r.epoch for r in run.rows[500:]] == [6, 7, 8]
    assert run.loop.report(T0 + 3).level == Level.WARN


def test_re_sends_never_re_sync_nor_does_a_forged_epoch_while_the_loop_advances():
    run = Run(epoch_window=100)
    run.decision(0, 1)
    for k in range(20):  # the planner's and the filter's re-sends of the last row, for 10 s
        now = T0 + 0.5 * k
        run.action(1, 1, now)
        run.belief(0, now)
    assert run.counts["late_samples"] == 40 and run.counts["resyncs"] == 0
    for t in range(1, 40):  # a forged epoch now and then while the loop goes on
        now = T0 + 10 + 0.5 * t
        if t % 3 == 0:
            run._take(run.loop.belief(BeliefSample(10**15, belief_of(0)), now))  # forged
        run.belief(t, now)
        run.action(t + 1, 2, now)
        run.plan_info(info(t + 1, 2), now)
    assert run.counts["resyncs"] == 0 and run.counts["out_of_window"] == 13
    assert [r.epoch for r in run.rows] == list(range(40))


def test_a_planner_back_after_a_long_outage_is_recorded_again():
    """The planner dead for longer than the window (beliefs keep coming, no action): the rows are
    forced out, so the window moves with the beliefs and the planner's first new action is recorded."""
    for max_pending in (50, 5000):  # below and above the window
        run = Run(max_pending_rows=max_pending, epoch_window=1000)
        run.decision(0, 1)
        for t in range(1, 3000):
            run.belief(t, T0 + t * 0.01)
        now = T0 + 40
        for t in range(3000, 3004):
            run.belief(t, now)
            run.action(t + 1, 2, now)
            run.plan_info(info(t + 1, 2), now)
            now += 1.0
        assert [r.epoch for r in run.rows][-3:] == [3001, 3002, 3003], max_pending


def test_close_writes_the_waiting_rows_with_what_they_have():
    run = Run(expect_true_state=True)
    run.decision(0, 1, s=0)
    run.belief(1)
    run.action(2, 2)  # no plan_info, no true state yet
    run.belief(2)  # no action
    run.close()
    assert [(r.epoch, r.true_state, r.info is None) for r in run.rows] == [(0, 0, False), (1, None, True)]
    assert run.counts["dropped_rows"] == 1 and run.loop.pending == {}


def test_memory_is_bounded_when_a_part_never_comes():
    """A planner that never answers, a burst of true states far ahead, a million epochs: at most
    ``max_pending_rows`` rows wait, the oldest forced out."""
    run = Run(max_pending_rows=50)  # below the epoch window: the beliefs stay within it
    run.decision(0, 1)
    tracemalloc.start()
    try:
        for t in range(1, 20_001):
            run.belief(t)
            run.true_state(t, t % S)
            assert len(run.loop.pending) <= 50
        size = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert size < 2_000_000
    assert run.counts["forced_rows"] >= 20_000 - 50 and run.counts["dropped_rows"] == run.counts["forced_rows"]
    assert [r.epoch for r in run.rows] == [0]


def test_the_diagnostics_report_counts_and_pending_rows():
    run = Run()
    run.decision(0, 1)
    run.belief(1)
    r = run.loop.report(T0)
    assert r.level == Level.OK and r.values["rows_written"] == 1 and r.values["pending_rows"] == 1
    assert r.values["last_row_epoch"] == 0 and r.message.startswith("1 rows written")
    run.loop.rejected("belief", "belief: expected 3 probabilities, got 2", T0)
    r = run.loop.report(T0)
    assert r.level == Level.WARN and "malformed messages" in r.message and "expected 3" in r.message
    assert run.loop.report(T0 + 1).level == Level.OK


TOPICS = ("belief", "action", "plan_info", "true_state")


@st.composite
def deliveries(draw):
    """A run of ``n`` decisions (priorities, bounds, true states), each topic's messages in order
    with some lost, interleaved across topics in any order."""
    n = draw(st.integers(1, 12))
    decisions = []
    for t in range(n):
        p = draw(st.integers(1, A))
        lo = draw(st.integers(1, p))
        up = draw(st.integers(p, A))
        bounded = draw(st.booleans())
        decisions.append((t, p, draw(st.integers(0, S - 1)), (lo, up) if bounded else None))
    lost = draw(st.sets(st.tuples(st.sampled_from(TOPICS), st.integers(0, n - 1)), max_size=n))
    queues = {topic: [t for t in range(n) if (topic, t) not in lost] for topic in TOPICS}
    order = draw(st.permutations([topic for topic, q in queues.items() for _ in q]))
    return decisions, queues, order


@settings(max_examples=200, deadline=None)
@given(deliveries())
def test_any_delivery_order_gives_the_rows_of_what_was_delivered(tmp_path_factory, case):
    """Each topic delivers in order (one reliable writer), the topics interleave in any way, some
    samples are lost: the record holds exactly the decisions whose belief and action came, each
    with the parts that came, and reads back with the run-record reader."""
    decisions, queues, order = case
    run = Run(expect_true_state=True)
    pos = dict.fromkeys(TOPICS, 0)
    for topic in order:
        t = queues[topic][pos[topic]]
        pos[topic] += 1
        _, p, s, bounds = decisions[t]
        if topic == "belief":
            run.belief(t)
        elif topic == "action":
            run.action(t + 1, p)
        elif topic == "true_state":
            run.true_state(t, s)
        else:
            b = bounds or (NAN, NAN)
            run.plan_info(info(t + 1, p, bounds=b, certified=bounds is not None and b[0] == b[1], depth=t))
    run.close()
    came = {topic: set(q) for topic, q in queues.items()}
    expected = [(t, p, s if t in came["true_state"] else None,
                 bounds if t in came["plan_info"] else None, t if t in came["plan_info"] else None)
                for t, p, s, bounds in decisions if t in came["belief"] and t in came["action"]]
    got = [(r.epoch, r.priority, r.true_state, r.bounds, r.record_fields()["depth"]) for r in run.rows]
    assert got == expected
    for r in run.rows:
        np.testing.assert_array_equal(r.belief, belief_of(r.epoch))
    assert run.counts["conflicts"] == run.counts["bad_plan_info"] == run.counts["resyncs"] == 0
    if run.rows:
        path = tmp_path_factory.mktemp("record") / "run.csv"
        with open(path, "w", encoding="utf-8") as fh:
            w = RunRecordWriter(fh, "test", S, A, 0.05)
            for r in run.rows:
                w.write(r.epoch, r.belief, r.priority, **r.record_fields())
        rec = read_run_record(path)
        assert rec.epoch.tolist() == [e[0] for e in expected]
        assert rec.action.tolist() == [e[1] for e in expected]
        assert rec.true_state.tolist() == [-1 if e[2] is None else e[2] for e in expected]
        assert rec.lower.tolist() == [0 if e[3] is None else e[3][0] for e in expected]
        assert rec.upper.tolist() == [0 if e[3] is None else e[3][1] for e in expected]
        assert rec.certified.tolist() == [e[3] is not None and e[3][0] == e[3][1] for e in expected]
        np.testing.assert_array_equal(rec.beliefs, np.array([belief_of(e[0]) for e in expected]))
