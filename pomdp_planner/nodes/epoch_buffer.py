"""Assembling sensor readings into decision epochs, in epoch order (no rclpy here).

An *epoch* ``t >= 1`` is one transition of the target under one action followed by one reading
from every configured sensor. The belief filter applies an epoch as: prediction once with the
carried action (Eq. 1), then one Bayes update (Eq. 2) per sensor reading of that epoch, with that
sensor's observation model. Readings are buffered until their epoch is next in line:

* a reading of an epoch already applied, or a second reading of the same sensor and epoch, is a
  *duplicate* and dropped (identical content) or a *conflict* (different content; also dropped);
  readings of one epoch that carry different actions are a conflict as well (the first wins);
* the next epoch is released when every sensor has reported, or *incomplete* (with the readings
  it has) after ``timeout`` seconds since its first reading or once ``max_pending`` later epochs
  are waiting;
* if the next epoch has no reading at all while later ones wait (same timeout / backlog rule), it
  is released as a *gap* (``priority is None``): the caller decides (the filter predicts with the
  commanded action if it knows it, and reports the gap).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class EpochReadings:
    """All readings of one epoch: ``readings[sensor] = observation``; ``priority`` None = gap."""

    epoch: int
    priority: int | None
    readings: dict[int, int] = field(default_factory=dict)
    first_seen: float = 0.0
    complete: bool = False


class EpochBuffer:
    """Orders readings of ``num_sensors`` sensors by epoch (see module docstring)."""

    def __init__(self, num_sensors: int, next_epoch: int = 1, timeout: float = 0.5, max_pending: int = 10,
                 clock: Callable[[], float] | None = None):
        if num_sensors < 1:
            raise ValueError("num_sensors: at least one sensor is needed")
        import time

        self.num_sensors = num_sensors
        self.next_epoch = next_epoch
        self.timeout = timeout
        self.max_pending = max_pending
        self._clock = clock or time.monotonic
        self._pending: dict[int, EpochReadings] = {}

    @property
    def pending_epochs(self) -> int:
        return len(self._pending)

    def add(self, sensor: int, epoch: int, priority: int, observation: int) -> str:
        """Buffer one reading; returns ``"buffered"``, ``"duplicate"`` or ``"conflict"``."""
        if not 0 <= sensor < self.num_sensors:
            raise ValueError(f"sensor: index {sensor} out of range 0..{self.num_sensors - 1}")
        if epoch < self.next_epoch:
            return "duplicate"
        entry = self._pending.get(epoch)
        if entry is None:
            entry = self._pending[epoch] = EpochReadings(epoch, priority, first_seen=self._clock())
        if entry.priority != priority:
            return "conflict"
        if sensor in entry.readings:
            return "duplicate" if entry.readings[sensor] == observation else "conflict"
        entry.readings[sensor] = observation
        entry.complete = len(entry.readings) == self.num_sensors
        return "buffered"

    def pop_ready(self) -> list[EpochReadings]:
        """Release, in epoch order, every epoch that is complete, timed out, or forced by the backlog."""
        out: list[EpochReadings] = []
        now = self._clock()
        while self._pending:
            entry = self._pending.get(self.next_epoch)
            later = [e for e in self._pending if e > self.next_epoch]
            backlog = len(later) >= self.max_pending
            if entry is not None:
                if not (entry.complete or backlog or now - entry.first_seen >= self.timeout):
                    break
                del self._pending[self.next_epoch]
            else:
                oldest = min(self._pending[e].first_seen for e in later)
                if not (backlog or now - oldest >= self.timeout):
                    break
                entry = EpochReadings(self.next_epoch, None, first_seen=now)
            out.append(entry)
            self.next_epoch += 1
        return out
