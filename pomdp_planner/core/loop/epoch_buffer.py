"""Assembling sensor readings into decision epochs, in epoch order.

An *epoch* ``t >= 1`` is one transition of the target under one action followed by one reading
from every configured sensor; :class:`~pomdp_planner.core.filter.EpochFilter` applies it. Readings
arrive as messages, possibly late, reordered, repeated or lost; they are buffered until their
epoch is next in line (rules "Epoch buffer", "Gaps" and "Explained epochs" of docs/ros.md):

* a reading of an epoch already applied, or a second reading of the same sensor and epoch, is a
  *duplicate* and dropped (identical content) or a *conflict* (different content; also dropped);
  readings of one epoch that carry different actions are a conflict as well. Of two conflicting
  readings the first is kept, unless it came ahead of the line (its epoch was not the next one)
  and the second comes in order (its epoch is the next one): then the second replaces it
  (``"replaced"``), so that a reading guessed ahead by a stray cannot take the real one's place;
* the next epoch is released when every sensor has reported, or *incomplete* (with the readings
  it has) after ``timeout`` seconds since its first reading or once ``max_pending`` later epochs
  are waiting;
* if the next epoch has no reading at all while later ones wait, it is released as a *gap*
  (``action is None``) only when the readings after it show that their source stepped on: the
  first two epochs after the gap both wait (one reading ahead proves nothing); then after the same
  time-out, or at once when ``max_pending`` later epochs wait;
* a reading more than ``max(max_pending, 2)`` epochs ahead of the next one is *far* and never
  buffered (the loop treats it as evidence of a jump, :mod:`.epochs`), and one ``window`` or more
  epochs ahead is *out of window* (a restarted peer or a forged message, not a gap to walk), so the
  buffer holds at most ``max(max_pending, 2) + 1`` epochs whatever arrives. The buffer also
  remembers the last :data:`ACTION_MEMORY` *commanded* actions (:meth:`EpochBuffer.command`, e.g.
  from the planner's action topic) up to the next epoch: a gap is applied with the commanded
  action of its epoch if known (:attr:`EpochReadings.action_to_apply`; the filter then predicts),
  otherwise held.

Actions are 0-based here, as everywhere in the core. Time is passed in (``now``, seconds on a
monotonic clock); :meth:`EpochBuffer.next_deadline` says when the next release by time-out is
due, so that a node can sleep until then instead of polling.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

from .epochs import DEFAULT_EPOCH_WINDOW

#: How many commanded actions (by epoch) are remembered for gaps and cross-checks.
ACTION_MEMORY = 256


@dataclass
class EpochReadings:
    """All readings of one epoch: ``readings[sensor] = observation`` (an index, or for a
    soft-evidence sensor its likelihood per state as a tuple: compared by value).

    ``action``: the action the readings carry (``None`` = a gap, no reading); ``commanded``: the
    action commanded for this epoch, if one was reported with :meth:`EpochBuffer.command`.
    """

    epoch: int
    action: int | None
    readings: dict[int, int | tuple[float, ...]] = field(default_factory=dict)
    first_seen: float = 0.0
    complete: bool = False
    commanded: int | None = None
    in_order: set[int] = field(default_factory=set)  # sensors whose reading came when the epoch was next

    @property
    def gap(self) -> bool:
        return self.action is None

    @property
    def action_to_apply(self) -> int | None:
        """The carried action; for a gap the commanded one (``None``: unknown, hold the belief)."""
        return self.commanded if self.action is None else self.action

    @property
    def mismatch(self) -> bool:
        """Readings taken under another action than the commanded one (expected when the target
        numbers epochs itself, e.g. a timer-driven simulator; the carried action is applied)."""
        return self.action is not None and self.commanded is not None and self.commanded != self.action


class EpochBuffer:
    """Orders readings of ``num_sensors`` sensors by epoch (see module docstring)."""

    def __init__(self, num_sensors: int, next_epoch: int = 1, timeout: float = 0.5, max_pending: int = 10,
                 window: int = DEFAULT_EPOCH_WINDOW):
        if num_sensors < 1:
            raise ValueError("num_sensors: at least one sensor is needed")
        self.num_sensors = num_sensors
        self.next_epoch = next_epoch
        self.timeout = timeout
        self.max_pending = max_pending
        self.window = window
        self._pending: dict[int, EpochReadings] = {}
        self._commanded: OrderedDict[int, int] = OrderedDict()

    @property
    def pending_epochs(self) -> int:
        return len(self._pending)

    @property
    def reach(self) -> int:
        """How far ahead of the next epoch a reading is buffered (``max(max_pending, 2)``)."""
        return max(self.max_pending, 2)

    def reset(self, next_epoch: int) -> None:
        """Drop every pending reading and continue at ``next_epoch`` (a join or a re-sync)."""
        self._pending.clear()
        self.next_epoch = next_epoch

    def command(self, epoch: int, action: int) -> bool:
        """Remember the action commanded for ``epoch`` (the last :data:`ACTION_MEMORY` epochs, up to
        the next one: no planner of the loop commands further ahead); another epoch is ignored (False)."""
        if not self.next_epoch - ACTION_MEMORY <= epoch <= self.next_epoch:
            return False
        self._commanded[epoch] = action
        self._commanded.move_to_end(epoch)
        while len(self._commanded) > ACTION_MEMORY:
            self._commanded.popitem(last=False)
        return True

    def add(self, sensor: int, epoch: int, action: int, observation: int | tuple[float, ...], now: float) -> str:
        """Buffer one reading (an observation index, or a likelihood tuple; arrived at ``now``);
        returns ``"buffered"``, ``"replaced"`` (it took the place of a conflicting one that had come
        ahead), ``"duplicate"``, ``"conflict"``, ``"far"`` (more than :attr:`reach` epochs ahead) or
        ``"out_of_window"`` (``window`` or more ahead); the last two are not buffered."""
        if not 0 <= sensor < self.num_sensors:
            raise ValueError(f"sensor: index {sensor} out of range 0..{self.num_sensors - 1}")
        if epoch < self.next_epoch:
            return "duplicate"
        if epoch >= self.next_epoch + self.window:
            return "out_of_window"
        if epoch > self.next_epoch + self.reach:
            return "far"
        in_order = epoch == self.next_epoch
        result = "buffered"
        entry = self._pending.get(epoch)
        if entry is None:
            entry = self._pending[epoch] = EpochReadings(epoch, action, first_seen=now)
        if entry.action != action:
            if not (in_order and not entry.in_order):
                return "conflict"
            entry = self._pending[epoch] = EpochReadings(epoch, action, first_seen=entry.first_seen)
            result = "replaced"
        if sensor in entry.readings:
            if entry.readings[sensor] == observation:
                return "duplicate"
            if not in_order or sensor in entry.in_order:
                return "conflict"
            result = "replaced"
        entry.readings[sensor] = observation
        if in_order:
            entry.in_order.add(sensor)
        entry.complete = len(entry.readings) == self.num_sensors
        return result

    def _gap_evidence(self, later: list[int]) -> bool:
        """Whether the readings waiting after a missing next epoch show that their source stepped on."""
        first = min(later)
        return first + 1 in self._pending

    def next_deadline(self) -> float | None:
        """When :meth:`pop_ready` will release the next epoch by time-out (the callers' time), or
        ``None`` if nothing waits for a time-out (nothing pending, or the next epoch complete)."""
        if not self._pending:
            return None
        entry = self._pending.get(self.next_epoch)
        if entry is not None:
            return None if entry.complete else entry.first_seen + self.timeout
        if not self._gap_evidence(list(self._pending)):
            return None  # nothing to release until more readings come
        return min(e.first_seen for e in self._pending.values()) + self.timeout

    def pop_ready(self, now: float) -> list[EpochReadings]:
        """Release, in epoch order, every epoch that is complete, timed out, or forced by the backlog."""
        out: list[EpochReadings] = []
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
                if not (self._gap_evidence(later) and (backlog or now - oldest >= self.timeout)):
                    break
                entry = EpochReadings(self.next_epoch, None, first_seen=now)
            entry.commanded = self._commanded.get(entry.epoch)
            out.append(entry)
            self.next_epoch += 1
        return out
