"""The epoch buffer (core/loop/epoch_buffer.py): ordering, duplicates, conflicts, time-outs, gaps
only on readings that count on, commanded actions up to the next epoch, the reach and the window.
Time is passed in by hand."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.loop import EpochBuffer
from pomdp_planner.core.loop.epoch_buffer import ACTION_MEMORY


@settings(max_examples=60, deadline=None)
@given(st.permutations([(t, k) for t in range(1, 7) for k in range(2)]), st.data())
def test_any_delivery_order_releases_epochs_in_order_with_their_own_readings(order, data):
    buf = EpochBuffer(2, timeout=10.0, max_pending=100)
    action = {t: t % 3 for t in range(1, 7)}
    released = []
    for t, k in order:
        assert buf.add(k, t, action[t], 10 * t + k, 0.0) == "buffered"
        if data.draw(st.booleans()):  # a redelivery of something already seen
            assert buf.add(k, t, action[t], 10 * t + k, 0.0) == "duplicate"
        released += buf.pop_ready(0.0)
    assert [e.epoch for e in released] == list(range(1, 7))
    for e in released:
        assert e.complete and e.action == action[e.epoch]
        assert e.readings == {0: 10 * e.epoch, 1: 10 * e.epoch + 1}


def test_conflicts_and_stale_readings():
    buf = EpochBuffer(1)
    assert buf.add(0, 1, 2, 0, 0.0) == "buffered"
    assert [e.epoch for e in buf.pop_ready(0.0)] == [1]
    assert buf.add(0, 1, 2, 0, 0.0) == "duplicate"  # already applied
    assert buf.add(0, 3, 1, 0, 0.0) == "buffered"
    assert buf.add(0, 3, 2, 0, 0.0) == "conflict"   # same epoch, another action
    assert buf.add(0, 3, 1, 1, 0.0) == "conflict"   # same sensor and epoch, another observation
    with pytest.raises(ValueError, match="sensor"):
        buf.add(1, 4, 1, 0, 0.0)


def test_incomplete_epoch_after_timeout_and_gap_after_backlog():
    buf = EpochBuffer(2, timeout=0.5, max_pending=3)
    buf.add(0, 1, 1, 4, 0.0)
    assert buf.pop_ready(0.49) == []
    (e,) = buf.pop_ready(0.6)
    assert e.epoch == 1 and not e.complete and e.readings == {0: 4}
    for t in (3, 4, 5):  # epoch 2 lost; three later epochs waiting force the gap
        buf.add(0, t, 1, 0, 0.6)
        buf.add(1, t, 1, 0, 0.6)
    out = buf.pop_ready(0.6)
    assert [(e.epoch, e.action) for e in out] == [(2, None), (3, 1), (4, 1), (5, 1)]


def test_gap_is_applied_with_the_commanded_action_if_known_else_held():
    buf = EpochBuffer(1, timeout=0.5, max_pending=10)
    buf.command(1, 2)           # epoch 1 was commanded action 2, its reading is lost
    for t, a in ((3, 1), (4, 1)):  # epoch 2: neither a reading nor a command
        buf.add(0, t, a, 0, 0.0)
    out = buf.pop_ready(1.0)    # the oldest waiting reading has waited past the timeout
    assert [(e.epoch, e.gap, e.action_to_apply, e.mismatch) for e in out] == [
        (1, True, 2, False), (2, True, None, False), (3, False, 1, False), (4, False, 1, False)]
    buf.command(5, 0)           # commanded 0, but its reading says 1 (e.g. timer mode)
    buf.add(0, 5, 1, 0, 1.0)
    (e,) = buf.pop_ready(1.0)
    assert (e.epoch, e.action_to_apply, e.mismatch) == (5, 1, True)


def test_commanded_actions_are_remembered_for_the_last_epochs_only_and_never_ahead():
    buf = EpochBuffer(1, next_epoch=ACTION_MEMORY + 1, timeout=0.5)
    for t in range(1, ACTION_MEMORY + 2):
        assert buf.command(t, 1)
    assert not buf.command(ACTION_MEMORY + 2, 1)  # beyond the next epoch: no planner of the loop sent it
    buf.reset(1)
    buf.add(0, 3, 0, 0, 0.0)
    buf.add(0, 4, 0, 0, 0.0)
    out = buf.pop_ready(1.0)
    # epoch 1 was forgotten (ACTION_MEMORY + 1 commands), epoch 2 is still known
    assert [(e.epoch, e.action_to_apply) for e in out] == [(1, None), (2, 1), (3, 0), (4, 0)]


def test_buffer_holds_only_its_reach_and_never_walks_beyond_it():
    buf = EpochBuffer(1, timeout=0.5, max_pending=10, window=1000)
    assert buf.reach == 10
    assert buf.add(0, 11, 0, 0, 0.0) == "buffered"          # 10 ahead of the next epoch: inside the reach
    assert buf.add(0, 12, 0, 0, 0.0) == "far"               # 11 ahead: far, not buffered
    assert buf.add(0, 1000, 0, 0, 0.0) == "far"
    assert buf.add(0, 1001, 0, 0, 0.0) == "out_of_window"   # 1000 ahead: outside the window
    assert buf.add(0, 50_001, 0, 0, 0.0) == "out_of_window"
    assert buf.pending_epochs == 1
    assert buf.pop_ready(100.0) == [] and buf.next_deadline() is None  # one reading ahead: no gap on its word
    assert buf.add(0, 10, 0, 0, 0.0) == "buffered"          # the readings count on: 10, 11
    out = buf.pop_ready(1.0)
    assert [e.epoch for e in out] == list(range(1, 12)) and sum(e.gap for e in out) == 9
    assert not buf.command(10**15, 0) and buf.command(12, 0) and not buf.command(13, 0)
    assert EpochBuffer(1, max_pending=1).reach == 2


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(2, 30), min_size=1, max_size=8, unique=True), st.integers(1, 12))
def test_no_epoch_is_declared_lost_unless_two_consecutive_epochs_wait_beyond_it(ahead, max_pending):
    buf = EpochBuffer(1, timeout=0.5, max_pending=max_pending)
    for t in ahead:  # epoch 1 never comes
        buf.add(0, t, 0, 0, 0.0)
    out = buf.pop_ready(1e9)
    waiting = {t for t in ahead if t <= 1 + buf.reach}
    evidence = min(waiting, default=0) + 1 in waiting
    assert bool(out) == evidence
    assert buf.pending_epochs <= buf.reach + 1


def test_a_reading_that_comes_in_order_replaces_a_conflicting_one_that_came_ahead():
    buf = EpochBuffer(2, timeout=0.5, max_pending=10)
    assert buf.add(0, 3, 2, 1, 0.0) == "buffered"     # a stray's guess, ahead of the line
    for t in (1, 2):
        buf.add(0, t, 1, 0, 0.0)
        buf.add(1, t, 1, 0, 0.0)
    assert [e.epoch for e in buf.pop_ready(0.0)] == [1, 2]
    assert buf.add(0, 3, 1, 0, 0.1) == "replaced"     # in order now, another action: replaces the whole epoch
    assert buf.add(0, 3, 2, 2, 0.1) == "conflict"     # the one that came in order stays
    assert buf.add(1, 3, 1, 2, 0.1) == "buffered"
    (e,) = buf.pop_ready(0.1)
    assert (e.epoch, e.action, e.readings) == (3, 1, {0: 0, 1: 2})
    assert buf.add(0, 4, 1, 0, 0.1) == "buffered"     # in order: a later guess conflicts, first wins
    assert buf.add(0, 4, 1, 1, 0.1) == "conflict"


def test_buffer_next_deadline_is_the_earliest_time_out():
    buf = EpochBuffer(2, timeout=0.5, max_pending=10)
    assert buf.next_deadline() is None
    buf.add(0, 3, 1, 0, 100.0)            # one later epoch waits: no evidence of a gap yet
    assert buf.next_deadline() is None
    buf.add(0, 4, 1, 0, 100.1)            # two consecutive: the gap rule's time-out
    assert buf.next_deadline() == pytest.approx(100.5)
    buf.add(0, 1, 1, 0, 100.2)            # the next epoch, incomplete: its own time-out
    assert buf.next_deadline() == pytest.approx(100.7)
    buf.add(1, 1, 1, 0, 100.2)            # complete: released now, nothing waits for epoch 1
    assert buf.next_deadline() is None
    assert [e.epoch for e in buf.pop_ready(100.2)] == [1]
    assert buf.next_deadline() == pytest.approx(100.5)
    buf.reset(10)
    assert buf.next_deadline() is None and buf.pending_epochs == 0 and buf.next_epoch == 10
