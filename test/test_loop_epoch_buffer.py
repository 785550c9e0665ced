"""The epoch buffer (core/loop/epoch_buffer.py): ordering, duplicates, conflicts, time-outs, gaps,
commanded actions, the window. Time is passed in by hand."""

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
    buf.command(3, 0)           # epoch 3 commanded 0, but its reading says 1 (e.g. timer mode)
    for t, a in ((3, 1), (4, 1)):  # epoch 2: neither a reading nor a command
        buf.add(0, t, a, 0, 0.0)
    out = buf.pop_ready(1.0)    # the oldest waiting reading has waited past the timeout
    assert [(e.epoch, e.gap, e.action_to_apply, e.mismatch) for e in out] == [
        (1, True, 2, False), (2, True, None, False), (3, False, 1, True), (4, False, 1, False)]


def test_commanded_actions_are_remembered_for_the_last_epochs_only():
    buf = EpochBuffer(1, timeout=0.5)
    for t in range(1, ACTION_MEMORY + 2):
        buf.command(t, 1)
    buf.add(0, 3, 0, 0, 0.0)
    out = buf.pop_ready(1.0)
    # epoch 1 was forgotten (ACTION_MEMORY + 1 commands), epoch 2 is still known
    assert [(e.epoch, e.action_to_apply) for e in out] == [(1, None), (2, 1), (3, 0)]


def test_buffer_never_holds_or_walks_beyond_the_window():
    buf = EpochBuffer(1, timeout=0.5, max_pending=10, window=1000)
    assert buf.add(0, 1000, 0, 0, 0.0) == "buffered"        # 999 ahead of the next epoch: inside
    assert buf.add(0, 1001, 0, 0, 0.0) == "out_of_window"   # 1000 ahead: outside
    assert buf.add(0, 50_001, 0, 0, 0.0) == "out_of_window"
    assert buf.pending_epochs == 1
    out = buf.pop_ready(1.0)  # the lost epochs 1..999 are a gap of at most the window
    assert [e.epoch for e in out] == list(range(1, 1001)) and sum(e.gap for e in out) == 999
    assert not buf.command(10**15, 0) and buf.command(1002, 0)


def test_buffer_next_deadline_is_the_earliest_time_out():
    buf = EpochBuffer(2, timeout=0.5, max_pending=10)
    assert buf.next_deadline() is None
    buf.add(0, 3, 1, 0, 100.0)            # a later epoch waits: the gap rule's time-out
    assert buf.next_deadline() == pytest.approx(100.5)
    buf.add(0, 1, 1, 0, 100.2)            # the next epoch, incomplete: its own time-out
    assert buf.next_deadline() == pytest.approx(100.7)
    buf.add(1, 1, 1, 0, 100.2)            # complete: released now, nothing waits for epoch 1
    assert buf.next_deadline() is None
    assert [e.epoch for e in buf.pop_ready(100.2)] == [1]
    assert buf.next_deadline() == pytest.approx(100.5)
    buf.reset(10)
    assert buf.next_deadline() is None and buf.pending_epochs == 0 and buf.next_epoch == 10
