"""Replay: the filter and a planner run again, offline, on a recorded run's readings (``pomdp-planner
replay``; docs/cli.md, "replay").

The readings are the run's facts: each epoch ``t``'s observation ``(priority, z)`` was taken under
the action the loop applied (the priority it carries). So the replay filters them with those
actions, whatever it would decide itself, and compares, epoch by epoch:

* **beliefs**: the replayed belief ``b'_t`` (the recorded belief of the first row, then the
  filter's step, :class:`~..filter.EpochFilter`, with each reading; an epoch without a reading is
  a gap: predicted with the action applied, as the filter node does) against the recorded ``b_t``,
  by the L1 distance; they differ where it exceeds ``tol`` (another model, another prior, a
  different observation model);
* **decisions**: the replay's planner's priority at ``b'_t`` against the recorded one;
* **entropy** (Shannon, nats) of both belief sequences, and the **return** of each sequence of
  decisions on its beliefs, ``sum_k gamma^k rho(b_k, a_k)`` (paper Eq. 3; with the true state
  where the record has it also ``sum_k gamma^k r(s_k, a_k)``): what the replayed decisions would
  have scored on the beliefs the readings give. The readings stay the recorded ones, so this is
  the value of each decision where it was taken, not of a run the replayed planner steered.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..filter import EpochFilter
from ..io.run_record import RunRecord
from ..model import POMDP
from ..uncertainty import SHANNON

#: Beliefs closer than this (L1) are the same.
DEFAULT_TOL = 1e-9


@dataclass(frozen=True)
class ReplayStep:
    """One epoch of a replay: the recorded and the replayed belief, their L1 distance, the
    recorded and the replayed priority, the true state (``None``: unknown), and how the replayed
    belief came (``"start"``, ``"reading"``, ``"gap"``, ``"restart"``: an impossible reading
    restarted the filter, ``"dropped"``: a reading the model cannot explain)."""

    epoch: int
    recorded: np.ndarray
    replayed: np.ndarray
    distance: float
    recorded_priority: int
    replayed_priority: int
    true_state: int | None
    how: str


@dataclass
class ReplayReport:
    """A replay (module docstring): its steps, what was compared, and the sums."""

    model: str
    gamma: float
    tol: float
    steps: list[ReplayStep] = field(default_factory=list)
    readings: int = 0
    gaps: list[int] = field(default_factory=list)

    @property
    def belief_differences(self) -> list[int]:
        return [s.epoch for s in self.steps if s.distance > self.tol]

    @property
    def decision_differences(self) -> list[int]:
        return [s.epoch for s in self.steps if s.recorded_priority != s.replayed_priority]

    @property
    def largest_distance(self) -> float:
        return max((s.distance for s in self.steps), default=0.0)

    def _sum(self, model: POMDP, which: str) -> dict[str, float | None]:
        rec = which == "recorded"
        beliefs = np.array([s.recorded if rec else s.replayed for s in self.steps])
        actions = np.array([(s.recorded_priority if rec else s.replayed_priority) - 1 for s in self.steps])
        disc = self.gamma ** np.arange(len(self.steps))
        rho = model.rho(beliefs)[np.arange(len(actions)), actions]
        known = [(k, s.true_state) for k, s in enumerate(self.steps) if s.true_state is not None]
        state = None if not known else float(sum(disc[k] * model.r[st, actions[k]] for k, st in known))
        return {"mean_entropy": float(np.mean([SHANNON.value(b) for b in beliefs])),
                "discounted_return": float(disc @ rho), "discounted_state_return": state}

    def sums(self, model: POMDP) -> dict[str, dict[str, float | None]]:
        """Entropy and returns of the recorded and the replayed sequences (module docstring)."""
        return {"recorded": self._sum(model, "recorded"), "replayed": self._sum(model, "replayed")}


def replay(model: POMDP, record: RunRecord, observations: Mapping[int, tuple[int, int]],
           decide: Callable[[np.ndarray], int], *, tol: float = DEFAULT_TOL) -> ReplayReport:
    """Replay ``record`` (its rows: beliefs, priorities, true states) with ``observations``
    (epoch -> ``(priority, z)``, the readings) on ``model``, deciding with ``decide`` (belief ->
    0-based action); module docstring. The record's ``S`` must be the model's."""
    if record.S != model.S:
        raise ValueError(f"--model: {model.name} has {model.S} states, the record's beliefs {record.S}")
    flt = EpochFilter(model)
    report = ReplayReport(model.name, model.gamma, tol)
    applied = {int(e) + 1: int(p) for e, p in zip(record.epoch, record.action, strict=True)}  # [t + 1, p]
    b = None
    last = None
    for k, epoch in enumerate(int(e) for e in record.epoch):
        how = "start"
        if b is None:
            b = np.asarray(record.beliefs[k], dtype=float)
        else:
            for t in range(last + 1, epoch + 1):
                reading = observations.get(t)
                if reading is None:
                    p = applied.get(t)
                    b = flt.step(b, None if p is None else p - 1, {}).belief
                    report.gaps.append(t)
                    how = "gap"
                    continue
                p, z = reading
                if not (1 <= p <= model.A and 0 <= z < model.Z):
                    raise ValueError(f"observation of epoch {t}: [{p}, {z}] is out of range for {model.name} "
                                     f"(priorities 1..{model.A}, observations 0..{model.Z - 1})")
                step = flt.step(b, p - 1, {0: z})
                b = step.belief
                report.readings += 1
                how = "dropped" if step.dropped else "restart" if step.restarted else "reading"
        last = epoch
        recorded = np.asarray(record.beliefs[k], dtype=float)
        ts = int(record.true_state[k])
        report.steps.append(ReplayStep(epoch, recorded, b.copy(), float(np.abs(recorded - b).sum()),
                                       int(record.action[k]), int(decide(b)) + 1, None if ts < 0 else ts, how))
    return report


def finite(x: float | None) -> float | None:
    """``x``, ``None`` for NaN (for JSON)."""
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x
