"""The epoch buffer of the belief filter (pure Python, no ROS): ordering, duplicates, gaps."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.nodes.epoch_buffer import EpochBuffer


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


@settings(max_examples=60, deadline=None)
@given(st.permutations([(t, k) for t in range(1, 7) for k in range(2)]), st.data())
def test_any_delivery_order_releases_epochs_in_order_with_their_own_readings(order, data):
    clock = Clock()
    buf = EpochBuffer(2, timeout=10.0, max_pending=100, clock=clock)
    priority = {t: 1 + t % 3 for t in range(1, 7)}
    released = []
    for t, k in order:
        assert buf.add(k, t, priority[t], 10 * t + k) == "buffered"
        if data.draw(st.booleans()):  # a redelivery of something already seen
            assert buf.add(k, t, priority[t], 10 * t + k) == "duplicate"
        released += buf.pop_ready()
    assert [e.epoch for e in released] == list(range(1, 7))
    for e in released:
        assert e.complete and e.priority == priority[e.epoch]
        assert e.readings == {0: 10 * e.epoch, 1: 10 * e.epoch + 1}


def test_conflicts_and_stale_readings():
    buf = EpochBuffer(1, clock=Clock())
    assert buf.add(0, 1, 2, 0) == "buffered"
    assert [e.epoch for e in buf.pop_ready()] == [1]
    assert buf.add(0, 1, 2, 0) == "duplicate"  # already applied
    assert buf.add(0, 3, 1, 0) == "buffered"
    assert buf.add(0, 3, 2, 0) == "conflict"   # same epoch, another action
    assert buf.add(0, 3, 1, 1) == "conflict"   # same sensor and epoch, another observation


def test_incomplete_epoch_after_timeout_and_gap_after_backlog():
    clock = Clock()
    buf = EpochBuffer(2, timeout=0.5, max_pending=3, clock=clock)
    buf.add(0, 1, 1, 4)
    assert buf.pop_ready() == []
    clock.t = 0.6
    (e,) = buf.pop_ready()
    assert e.epoch == 1 and not e.complete and e.readings == {0: 4}
    for t in (3, 4, 5):  # epoch 2 lost; three later epochs waiting force the gap
        buf.add(0, t, 1, 0)
        buf.add(1, t, 1, 0)
    out = buf.pop_ready()
    assert [(e.epoch, e.priority) for e in out] == [(2, None), (3, 1), (4, 1), (5, 1)]
