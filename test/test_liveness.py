"""The liveness rules (core/liveness.py) without ROS: epoch window, re-sync evidence, re-send,
stall levels. Time is a hand-driven clock."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.epoch_buffer import EpochBuffer
from pomdp_planner.core.liveness import (
    JOIN_MIN_INPUTS,
    RESYNC_MIN_INPUTS,
    EpochLine,
    InputWatch,
    Level,
    LogThrottle,
    Resender,
    StallLimits,
    classify,
    worst,
)


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


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


def test_one_forged_input_never_resyncs_a_node():
    clock = Clock()
    line = EpochLine(1000, position=50, clock=clock)
    line.off_line(10**15, "forged")
    clock.t += 3600.0  # however long the node then stalls
    assert line.resync_due(2.0) is None


def test_a_stalled_node_resyncs_to_the_newest_of_repeated_off_line_inputs():
    clock = Clock()
    line = EpochLine(1000, position=50, clock=clock)
    for k in range(RESYNC_MIN_INPUTS):
        line.off_line(7000 + k, f"b{k}")
        assert line.resync_due(2.0) is None  # not stalled yet
    clock.t += 2.0
    due = line.resync_due(2.0)
    assert (due.epoch, due.payload) == (7000 + RESYNC_MIN_INPUTS - 1, f"b{RESYNC_MIN_INPUTS - 1}")
    line.resync(due.epoch)
    assert line.position == due.epoch and line.resyncs == 1 and line.resync_due(2.0) is None
    # repeats of a waiting peer (the same epoch re-sent) are evidence too on a non-counting line
    line.off_line(12, "x")
    line.off_line(12, "x")
    line.off_line(12, "x")
    clock.t += 2.0
    assert line.resync_due(2.0).epoch == 12


def test_a_replay_after_a_long_wait_is_not_evidence_until_it_lasts():
    """A node that waited while its peer was dead (stalled for long) must not re-sync to the burst
    of old epochs the restarted peer replays: the evidence itself must be stall_after old."""
    clock = Clock()
    line = EpochLine(1000, position=500, clock=clock)
    clock.t += 60.0  # the peer was dead for a minute
    for e in range(400, 500):  # its replay, in a burst
        line.off_line(e)
    assert line.resync_due(2.0) is None
    clock.t += 1.0
    line.advance(501)  # the peer caught up
    clock.t += 10.0
    assert line.resync_due(2.0) is None


def test_advancing_clears_the_evidence():
    clock = Clock()
    line = EpochLine(1000, position=50, clock=clock)
    for k in range(5):
        line.off_line(9000 + k)
    line.advance(51)
    clock.t += 10.0
    assert line.resync_due(2.0) is None


def test_counting_line_needs_consecutive_epochs_not_a_repeated_stray():
    clock = Clock()
    line = EpochLine(1000, position=0, counting=True, clock=clock)
    line.advance(112)
    for _ in range(10):  # a stray repeating one stale reading
        line.off_line(5)
    clock.t += 5.0
    assert line.resync_due(2.0) is None
    # a restarted simulator counting from 1 (two sensors: each epoch twice)
    for e in (1, 1, 2, 2, 3):
        line.off_line(e, e)
    assert line.resync_due(2.0).epoch == 3
    # a break in the run starts it again
    line.off_line(7)
    assert line.resync_due(2.0) is None


def test_fresh_counting_line_joins_at_once_on_two_consecutive_readings():
    clock = Clock()
    line = EpochLine(1000, position=0, counting=True, clock=clock)
    line.off_line(50_000, "first")
    assert line.resync_due(2.0) is None  # one reading (maybe forged) is not enough
    line.off_line(50_001, "second")
    assert JOIN_MIN_INPUTS == 2 and line.resync_due(2.0).payload == "second"


def test_resender_repeats_every_period_until_answered():
    clock = Clock()
    r = Resender(1.0, clock)
    assert not r.due()
    r.published()
    clock.t += 0.99
    assert not r.due()
    clock.t += 0.01
    assert r.due()
    r.resending()
    assert not r.due() and r.resent == 1
    clock.t += 1.0
    assert r.due()
    r.answered()
    clock.t += 10.0
    assert not r.due() and not r.waiting
    off = Resender(0.0, clock)
    off.published()
    clock.t += 100.0
    assert not off.due()


def test_input_watch_levels_and_messages():
    clock = Clock()
    limits = StallLimits(2.0, 10.0)
    w = InputWatch("action", "action", clock)
    assert w.status(limits) == (Level.OK, "")
    clock.t += 2.0
    level, text = w.status(limits)
    assert level == Level.WARN and text == "action: no action since start (2.0 s)"
    w.arrived(True, 41)
    assert w.status(limits)[0] == Level.OK
    for _ in range(3):  # duplicates are not progress
        w.arrived(False, 41)
    clock.t += 10.0
    level, text = w.status(limits)
    assert level == Level.ERROR
    assert text == "action: no new action for 10.0 s (last: epoch 41); 3 received meanwhile, none new " \
                   "(repeats, stale or out of window)"
    assert w.values()["input.action.received_since_new"] == 3


def test_optional_input_is_quiet_until_it_has_advanced_once():
    clock = Clock()
    w = InputWatch("action", "action", clock, required=False)
    clock.t += 100.0
    assert w.status(StallLimits())[0] == Level.OK
    w.arrived(True, 3)
    clock.t += 100.0
    assert w.status(StallLimits())[0] == Level.ERROR


def test_worst_and_limits_and_log_throttle():
    assert worst([(Level.OK, ""), (Level.WARN, "a"), (Level.ERROR, "b"), (Level.ERROR, "c")]) == (Level.ERROR, "b; c")
    assert worst([]) == (Level.OK, "")
    with pytest.raises(ValueError, match="warn_after"):
        StallLimits(5.0, 1.0)
    clock = Clock()
    log = LogThrottle(10.0, clock)
    assert log.ready() == (True, 0)
    assert log.ready() == (False, 0)
    assert log.ready() == (False, 0)
    clock.t += 10.0
    assert log.ready() == (True, 2)


def test_buffer_never_holds_or_walks_beyond_the_window():
    clock = Clock()
    buf = EpochBuffer(1, timeout=0.5, max_pending=10, clock=clock, window=1000)
    assert buf.add(0, 1000, 0, 0) == "buffered"        # 999 ahead of the next epoch: inside
    assert buf.add(0, 1001, 0, 0) == "out_of_window"   # 1000 ahead: outside
    assert buf.add(0, 50_001, 0, 0) == "out_of_window"
    assert buf.pending_epochs == 1
    clock.t += 1.0
    out = buf.pop_ready()  # the lost epochs 1..999 are a gap of at most the window
    assert [e.epoch for e in out] == list(range(1, 1001)) and sum(e.gap for e in out) == 999
    assert not buf.command(10**15, 0) and buf.command(1002, 0)


def test_buffer_next_deadline_is_the_earliest_time_out():
    clock = Clock()
    buf = EpochBuffer(2, timeout=0.5, max_pending=10, clock=clock)
    assert buf.next_deadline() is None
    buf.add(0, 3, 1, 0)                   # a later epoch waits: the gap rule's time-out
    assert buf.next_deadline() == pytest.approx(100.5)
    clock.t += 0.2
    buf.add(0, 1, 1, 0)                   # the next epoch, incomplete: its own time-out
    assert buf.next_deadline() == pytest.approx(100.7)
    buf.add(1, 1, 1, 0)                   # complete: released now, nothing waits for epoch 1
    assert buf.next_deadline() is None
    assert [e.epoch for e in buf.pop_ready()] == [1]
    assert buf.next_deadline() == pytest.approx(100.5)
    buf.reset(10)
    assert buf.next_deadline() is None and buf.pending_epochs == 0 and buf.next_epoch == 10
