"""Closed-loop runs of a joint policy on a multi-target problem, with common random numbers.

Every target has its own hidden state, its own belief and its own filter (``core/filter.py``,
the single-target rule of ``core/simulate.py`` per target). One step ``t``:

1. the joint policy sees the K beliefs and returns one action per target (0-based); the step
   records its effort ``sum_k e_k(a_k)`` and whether it is within the budget (decided exactly; a
   policy that exceeds it is counted, not stopped: the benchmark reports the count);
2. rewards: ``rho_k(b_k, a_k)`` per target (Eq. 3) and their sum, the joint reward;
3. each target's state moves, ``s' ~ P_k[a_k, s, :]``, and is observed, ``z ~ O_k[a_k, s', :]``;
4. each belief is updated by its epoch filter.

**Common random numbers.** Target ``k`` draws from its own generator seeded with
``(seed, k)``: first one number for its initial state, then exactly two per step (transition,
observation), each turned into an outcome by the inverse distribution function. The draws
do not depend on the actions, so two policies run with the same seed see the same random
numbers, and a difference of their returns is the policies', not the luck's.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np

from ..belief import check_belief
from ..errors import BeliefError, OptionError, short_repr
from ..filter import EpochFilter
from ..options import check_seed
from ..simulate import check_steps
from .planner import JointDecision
from .policies import initial_beliefs as default_beliefs
from .problem import MultiTargetProblem


def inverse_cdf(p: np.ndarray, u: float) -> int:
    """The outcome of the uniform number ``u`` under the distribution ``p`` (rows sum to 1 only
    within the model's tolerance, hence the scaling by the total)."""
    c = np.cumsum(p)
    return int(min(np.searchsorted(c, u * c[-1], side="right"), p.size - 1))


@dataclass(frozen=True, eq=False)
class JointStep:
    """One step ``t`` (0-based indices): ``states`` = ``s_t`` per target, ``actions`` = ``a_t``,
    ``observations`` = ``z_{t+1}``, ``beliefs`` = ``b_{t+1}``, ``rewards`` = ``rho_k(b_k, a_k)``,
    ``reward`` their sum, ``effort`` the joint action's effort, ``within_budget``, ``decision`` the
    planner's :class:`~.planner.JointDecision` (``None`` for the baselines without one)."""

    t: int
    states: tuple[int, ...]
    actions: tuple[int, ...]
    observations: tuple[int, ...]
    beliefs: tuple[np.ndarray, ...]
    rewards: tuple[float, ...]
    reward: float
    effort: Fraction
    within_budget: bool
    recovered: int
    decision: JointDecision | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready row; actions as priorities ``1..A``."""
        row: dict[str, Any] = {
            "step": self.t, "states": list(self.states), "priorities": [a + 1 for a in self.actions],
            "observations": list(self.observations), "rewards": list(self.rewards), "reward": self.reward,
            "effort": float(self.effort), "within_budget": self.within_budget, "recovered": self.recovered,
        }
        if self.decision is not None:
            d = self.decision
            row.update({"lambda": d.lam, "dual_bound": d.dual_bound, "lower_bound": d.lower_bound, "gap": d.gap,
                        "bound_guaranteed": d.bound_guaranteed, "depth": d.depth, "time_used": d.time_used})
        return row


class JointRunningSummary:
    """Running sums of a joint run (constant memory): the summary of :func:`simulate_targets`."""

    def __init__(self, gamma: float):
        self.gamma = float(gamma)
        self.steps = self.violations = self.recovered = self.decisions = 0
        self._discount = 1.0
        self._reward = self._return = self._gap = self._lam = self._effort = 0.0

    def add(self, step: JointStep) -> None:
        self.steps += 1
        self.violations += not step.within_budget
        self.recovered += step.recovered
        self._reward += step.reward
        self._return += self._discount * step.reward
        self._effort += float(step.effort)
        self._discount *= self.gamma
        if step.decision is not None:
            self.decisions += 1
            self._gap += step.decision.gap
            self._lam += step.decision.lam

    def summary(self) -> dict[str, Any]:
        n, m = self.steps, self.decisions
        nan = float("nan")
        return {"steps": n, "discounted_return": self._return, "mean_reward": self._reward / n if n else nan,
                "mean_effort": self._effort / n if n else nan, "budget_violations": self.violations,
                "recovered_steps": self.recovered, "mean_lambda": self._lam / m if m else None,
                "mean_gap": self._gap / m if m else None}


class JointSimulation:
    """A closed-loop run, one :class:`JointStep` at a time (module docstring); iterate it once.

    ``policy``: an object with ``act(beliefs) -> joint action`` (``last``: its decision, if any).
    ``initial_beliefs``: default every model's ``start``, else uniform; ``initial_states``:
    default drawn from the initial beliefs.
    """

    def __init__(self, problem: MultiTargetProblem, policy: Any, steps: int, seed: int = 0,
                 initial_beliefs: Sequence[np.ndarray] | None = None,
                 initial_states: Sequence[int] | None = None):
        self.problem = problem
        self.policy = policy
        self.steps = check_steps(steps)
        self.seed = check_seed(seed)
        K = problem.K
        self._rngs = [np.random.default_rng([self.seed, k]) for k in range(K)]
        if initial_beliefs is None:
            bs = default_beliefs(problem)
        else:
            if len(initial_beliefs) != K:
                raise BeliefError(f"initial_beliefs: {len(initial_beliefs)} beliefs for {K} targets")
            bs = [check_belief(m, b, field=f"initial_beliefs[{k}]")
                  for k, (m, b) in enumerate(zip(problem.models, initial_beliefs, strict=True))]
        self.initial_beliefs = [np.asarray(b, dtype=float) for b in bs]
        draws = [rng.random() for rng in self._rngs]  # always drawn: the streams stay aligned
        if initial_states is None:
            self.initial_states = [inverse_cdf(b, u) for b, u in zip(self.initial_beliefs, draws, strict=True)]
        else:
            if len(initial_states) != K:
                raise OptionError(f"initial_states: {len(initial_states)} states for {K} targets")
            for k, (s, m) in enumerate(zip(initial_states, problem.models, strict=True)):
                if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 0 <= s < m.S:
                    raise OptionError(f"initial_states[{k}]: {short_repr(s)} out of range 0..{m.S - 1}")
            self.initial_states = [int(s) for s in initial_states]
        self._started = False

    def __iter__(self) -> Iterator[JointStep]:
        if self._started:
            raise RuntimeError("a JointSimulation can be iterated once")
        self._started = True
        return self._run()

    def _run(self) -> Iterator[JointStep]:
        p = self.problem
        filters = [EpochFilter(m) for m in p.models]
        bs = list(self.initial_beliefs)
        ss = list(self.initial_states)
        for t in range(self.steps):
            raw = self.policy.act([b.copy() for b in bs])
            if len(raw) != p.K:
                raise ValueError(f"policy returned {len(raw)} actions at step {t} for {p.K} targets")
            actions = []
            for k, a in enumerate(raw):
                if isinstance(a, bool) or not isinstance(a, (int, np.integer)) or not 0 <= a < p.models[k].A:
                    raise ValueError(f"policy returned {short_repr(a)} for target {k} at step {t}: expected a "
                                     f"0-based action in 0..{p.models[k].A - 1}")
                actions.append(int(a))
            effort = p.effort_of(actions)
            rewards, obs, nexts, recovered = [], [], [], 0
            for k, (m, b, s, a) in enumerate(zip(p.models, bs, ss, actions, strict=True)):
                rewards.append(float(m.rho(b)[a]))
                u_move, u_see = self._rngs[k].random(2)
                s_next = inverse_cdf(m.P[a, s], u_move)
                z = inverse_cdf(m.O[a, s_next], u_see)
                epoch = filters[k].step(b, a, {0: z})
                bs[k] = epoch.belief
                recovered += bool(epoch.restarted)
                obs.append(z)
                nexts.append(s_next)
            decision = getattr(self.policy, "last", None)
            yield JointStep(t, tuple(ss), tuple(actions), tuple(obs), tuple(bs), tuple(rewards), float(sum(rewards)),
                            effort, effort <= p.budget, recovered,
                            decision if isinstance(decision, JointDecision) else None)
            ss = nexts


def simulate_targets(problem: MultiTargetProblem, policy: Any, steps: int, seed: int = 0,
                     initial_beliefs: Sequence[np.ndarray] | None = None,
                     initial_states: Sequence[int] | None = None) -> tuple[list[JointStep], dict[str, Any]]:
    """Run ``policy`` for ``steps`` steps; returns the steps and the summary
    (:class:`JointRunningSummary`). Same seed, same random numbers (module docstring)."""
    run = JointSimulation(problem, policy, steps, seed, initial_beliefs, initial_states)
    summary = JointRunningSummary(problem.gamma)
    out = []
    for st in run:
        summary.add(st)
        out.append(st)
    return out, summary.summary()
