"""The epoch rules of the loop (core/loop/epochs.py) without ROS: the window and its verdicts, the
re-sync and join evidence, the join wait, re-send. Time is passed in by hand."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.loop import JOIN_DELAY, EpochLine, JoinWait, Liveness, Resender, StallLimits, classify
from pomdp_planner.core.loop.epochs import JOIN_MIN_INPUTS, RESYNC_MIN_INPUTS

T0 = 100.0


@settings(max_examples=200)
@given(st.integers(0, 10**18), st.integers(-3000, 3000), st.integers(1, 2000))
def test_classify_by_distance_from_the_position(position, d, window):
    epoch = position + d
    v = classify(epoch, position, window)
    expected = ("out_of_window" if abs(d) > window else "repeat" if d == 0 else "behind" if d < 0
                else "next" if d == 1 else "ahead")
    assert v == expected


def test_classify_before_joining_and_bad_window():
    assert classify(10**15, None, 5) == "join"
    with pytest.raises(ValueError, match="window"):
        classify(1, 0, 0)
    with pytest.raises(ValueError, match="epoch_window"):
        Liveness(epoch_window=0)


def test_one_forged_input_never_resyncs_a_node():
    line = EpochLine(1000, now=T0, position=50)
    line.off_line(10**15, "forged", T0)
    assert line.resync_due(2.0, T0 + 3600.0) is None  # however long the node then stalls


def test_a_stalled_node_resyncs_to_the_newest_of_repeated_off_line_inputs():
    line = EpochLine(1000, now=T0, position=50)
    for k in range(RESYNC_MIN_INPUTS):
        line.off_line(7000 + k, f"b{k}", T0)
        assert line.resync_due(2.0, T0) is None  # not stalled yet
    assert line.resync_due(2.0, T0 + 1.99) is None
    due = line.resync_due(2.0, T0 + 2.0)
    assert (due.epoch, due.payload) == (7000 + RESYNC_MIN_INPUTS - 1, f"b{RESYNC_MIN_INPUTS - 1}")
    assert "re-synced from epoch 50 to epoch 7002" in line.resync_reason(due, "beliefs", "filter", T0 + 2.0)
    line.resync(due.epoch, T0 + 2.0)
    assert line.position == due.epoch and line.resyncs == 1 and line.resync_due(2.0, T0 + 2.0) is None
    # repeats of a waiting peer (the same epoch re-sent) are evidence too on a non-counting line
    for _ in range(RESYNC_MIN_INPUTS):
        line.off_line(12, "x", T0 + 3.0)
    assert line.resync_due(2.0, T0 + 5.0).epoch == 12


def test_fewer_than_the_minimum_off_line_inputs_never_resync():
    line = EpochLine(1000, now=T0, position=50)
    for k in range(RESYNC_MIN_INPUTS - 1):
        line.off_line(9000 + k, None, T0)
    assert line.resync_due(2.0, T0 + 100.0) is None


def test_a_replay_after_a_long_wait_is_not_evidence_until_it_lasts():
    """A node that waited while its peer was dead (stalled for long) must not re-sync to the burst
    of old epochs the restarted peer replays: the evidence itself must be stall_after old."""
    line = EpochLine(1000, now=T0, position=500)
    t = T0 + 60.0  # the peer was dead for a minute
    for e in range(400, 500):  # its replay, in a burst
        line.off_line(e, None, t)
    assert line.resync_due(2.0, t) is None
    line.advance(501, t + 1.0)  # the peer caught up
    assert line.resync_due(2.0, t + 11.0) is None


def test_advancing_clears_the_evidence():
    line = EpochLine(1000, now=T0, position=50)
    for k in range(5):
        line.off_line(9000 + k, None, T0)
    line.advance(51, T0)
    assert line.resync_due(2.0, T0 + 10.0) is None and line.stalled_for(T0 + 10.0) == 10.0


def test_counting_line_needs_consecutive_epochs_not_a_repeated_stray():
    line = EpochLine(1000, now=T0, position=0, counting=True)
    line.advance(112, T0)
    for _ in range(10):  # a stray repeating one stale reading
        line.off_line(5, None, T0)
    assert line.resync_due(2.0, T0 + 5.0) is None
    # a restarted simulator counting from 1 (two sensors: each epoch twice)
    for e in (1, 1, 2, 2, 3):
        line.off_line(e, e, T0 + 5.0)
    assert line.resync_due(2.0, T0 + 5.0).epoch == 3
    line.off_line(7, None, T0 + 5.0)  # a break in the run starts it again
    assert line.resync_due(2.0, T0 + 5.0) is None


def test_fresh_counting_line_joins_at_once_on_two_consecutive_readings():
    line = EpochLine(1000, now=T0, position=0, counting=True)
    line.off_line(50_000, "first", T0)
    assert line.resync_due(2.0, T0) is None  # one reading (maybe forged) is not enough
    line.off_line(50_002, "not next", T0)
    assert line.resync_due(2.0, T0) is None  # not consecutive
    line.off_line(50_003, "second", T0)
    assert JOIN_MIN_INPUTS == 2 and line.resync_due(2.0, T0).payload == "second"


def test_join_wait_takes_the_newest_evidence_after_the_delay():
    join = JoinWait()
    assert not join.settled(T0) and join.wake_at(T0) is None
    join.note(7, T0)
    assert join.wake_at(T0) == T0 + JOIN_DELAY and not join.settled(T0 + JOIN_DELAY / 2)
    join.note(40, T0 + 0.1)   # the burst of a transient-local history: the newest wins
    join.note(3, T0 + 0.15)
    assert join.wake_at(T0 + 0.15) == T0 + JOIN_DELAY  # counted from the first
    assert join.settled(T0 + JOIN_DELAY) and join.newest == 40 and join.wake_at(T0 + JOIN_DELAY) is None


def test_resender_repeats_every_period_until_answered():
    r = Resender(1.0)
    assert not r.due(T0)
    r.published(T0)
    assert not r.due(T0 + 0.99) and r.due(T0 + 1.0)
    r.resending(T0 + 1.0)
    assert not r.due(T0 + 1.5) and r.resent == 1 and r.due(T0 + 2.0)
    r.answered()
    assert not r.due(T0 + 100.0) and not r.waiting
    off = Resender(0.0)
    off.published(T0)
    assert not off.due(T0 + 100.0)


@pytest.mark.parametrize(("resend", "warn", "period"), [(1.0, 2.0, 0.25), (0.0, 2.0, 0.5), (0.1, 2.0, 0.05),
                                                        (10.0, 20.0, 1.0), (0.3, 0.5, 0.075)])
def test_watchdog_period_is_a_quarter_of_the_shortest_time_within_limits(resend, warn, period):
    live = Liveness(resend_period=resend, stall=StallLimits(warn, 100.0))
    assert live.watchdog_period == pytest.approx(period)
