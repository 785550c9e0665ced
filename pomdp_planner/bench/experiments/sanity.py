"""Sanity check of every peer before its numbers are reported: can it find a known
optimum?

The check model is the *state-reward-only* version of a shipped model: the same dynamics and
state reward with the uncertainty weights set to 0 (:func:`state_reward_only`), so the belief
reward is linear and the optimum can be proven exactly:

* :func:`~.pbvi.single_action_optimal`: if always playing one action ``a*`` has a value vector
  ``alpha = (I - gamma P_a*)^-1 r_a*`` with ``r_a + gamma P_a alpha <= alpha`` for every ``a``,
  then ``b . alpha`` is the Bellman fixed point and ``a*`` is optimal at every belief. For the
  shipped S = 3 tracking model this proves "always priority 2"; the smallest margin
  ``min_b max_(a != a*) [alpha - r_a - gamma P_a alpha] . b`` (the Q gap at the hardest belief)
  is reported.
* otherwise exact alpha-vector value iteration (``core.reference``), certified at a belief when
  its Q gap exceeds twice the horizon's error bound; uncertified beliefs are not used.

Each peer decides, from scratch (a fresh policy, no tree reuse), at the check beliefs: the
simplex vertices, its centre, and beliefs reached from random initial beliefs under random
actions (``sampling.reachable_beliefs``; on the tracking models these concentrate near the
states the dynamics drive to, where the action gaps are smallest). It passes at a budget when
it picks the proven optimal action at every certified belief; the largest value loss
``Q*(b, a*) - Q*(b, a)`` of its decisions is reported beside (a sampling planner that misses a
near-tie loses about that tie's gap). Budgeted peers are checked at every budget of the
comparison. ``required`` says whether failing matters: greedy, the bound
policies and random are baselines whose failure is possible by design.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...core.model import POMDP
from ...core.reference import alpha_vector_value_iteration, certified_actions
from .datafile import register
from .pbvi import single_action_optimal
from .peer_policies import BUDGETED, ReferenceSpec, make_peer
from .pouct import POMDP_PY_DEFAULTS, POUCTSettings
from .sampling import reachable_beliefs

#: Peers whose failure of the check is expected and does not disqualify them.
NOT_REQUIRED = ("greedy", "lower-bound", "upper-bound", "random")


def state_reward_only(model: POMDP) -> POMDP:
    """``model`` with every uncertainty weight 0: ``rho(b, a) = b . r[:, a]``."""
    return dataclasses.replace(model, w=np.zeros(model.A), name=f"{model.name} (w = 0)")


@dataclass(frozen=True)
class KnownOptimum:
    """Proven optimal actions at the check beliefs (``certified`` marks those that are proven)."""

    beliefs: np.ndarray
    actions: np.ndarray
    certified: np.ndarray
    how: str
    min_gap: float
    q: np.ndarray  # Q*(b, a) at the beliefs (exact, or within the alpha-vector error bound)

    def to_dict(self) -> dict:
        return {"beliefs": len(self.beliefs), "certified": int(self.certified.sum()),
                "actions": np.bincount(self.actions[self.certified], minlength=1).tolist(), "how": self.how,
                "min_gap": float(self.min_gap)}


def check_beliefs(model: POMDP, reachable: int, seed: int) -> np.ndarray:
    """Vertices, centre and ``reachable`` beliefs reached under random actions (seeded)."""
    S = model.S
    parts = [np.eye(S), np.full((1, S), 1.0 / S)]
    if reachable:
        parts.append(reachable_beliefs(model, reachable, np.random.default_rng([seed, 41])))
    return np.vstack(parts)


def known_optimum(model: POMDP, beliefs: np.ndarray, horizon: int | None = None) -> KnownOptimum:
    """The optimum of a belief-linear ``model`` at ``beliefs`` (module docstring)."""
    a_star = single_action_optimal(model)
    if a_star is not None:
        S = model.S
        alpha = np.linalg.solve(np.eye(S) - model.gamma * model.P[a_star], model.r[:, a_star])
        margin = alpha[None, :] - (model.r.T + model.gamma * (model.P @ alpha))  # (A, S), >= 0
        others = np.delete(margin, a_star, axis=0)
        gaps = (beliefs @ others.T).min(axis=1) if len(others) else np.full(len(beliefs), np.inf)
        q = beliefs @ (model.r.T + model.gamma * (model.P @ alpha)).T  # Q*(b, a) = b . (r_a + gamma P_a alpha)
        return KnownOptimum(beliefs, np.full(len(beliefs), a_star), np.ones(len(beliefs), bool),
                            f"always priority {a_star + 1}, proven at every belief (Bellman inequality of "
                            "its value vector)", float(gaps.min()), q)
    if horizon is None:  # error bound gamma^H (max r - min r) / (2 (1 - gamma)) below 1e-6 of the range
        horizon = int(np.ceil(np.log(1e-6 * (1 - model.gamma)) / np.log(model.gamma)))
    sol = alpha_vector_value_iteration(model, horizon)
    act, cert, Q = certified_actions(sol, beliefs)
    top2 = np.sort(Q, axis=1)[:, -2:]
    gap = top2[:, 1] - top2[:, 0]
    return KnownOptimum(beliefs, act, cert, f"exact alpha-vector value iteration, horizon {horizon}, certified "
                        f"where the Q gap exceeds {2 * sol.error_bound:.2g}",
                        float(gap[cert].min()) if cert.any() else float("nan"), Q)


@register
@dataclass
class SanityResult:
    """One peer (at one budget) on one check model."""

    model: str
    planner: str
    budget: float | None
    correct: int
    checked: int
    required: bool
    label: str = ""  # e.g. "pouct (pomdp-py defaults)"
    worst_loss: float = 0.0  # largest Q*(b, a*) - Q*(b, a) of its decisions

    @property
    def passed(self) -> bool:
        return self.checked > 0 and self.correct == self.checked

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "passed": self.passed}


def run_sanity(models: dict[str, POMDP], planners: Sequence[str], budgets: Sequence[float], *, max_depth: int,
               reachable: int = 12, seed: int = 0, references: dict[str, ReferenceSpec] | None = None,
               pouct: POUCTSettings | None = None, pouct_defaults: bool = True) -> dict:
    """The check of every peer in ``planners`` on the state-reward-only version of each model.

    ``references[label]``: the model's optimal reference (checked like a peer). With
    ``pouct_defaults`` POUCT is also checked in pomdp-py's default configuration
    (:data:`~.pouct.POMDP_PY_DEFAULTS`), a diagnostic row.
    """
    out: dict = {"models": {}, "results": []}
    for label, model in models.items():
        check = state_reward_only(model)
        beliefs = check_beliefs(check, reachable, seed)
        opt = known_optimum(check, beliefs)
        out["models"][label] = opt.to_dict()
        ok = opt.certified
        runs: list[tuple[str, str, float | None, POUCTSettings | None]] = []
        for name in planners:
            if name == "optimal" and (references or {}).get(label) is None:
                continue
            for b in (budgets if name in BUDGETED else (None,)):
                runs.append((name, name, b, pouct))
                if name == "pouct" and pouct_defaults:
                    runs.append((name, "pouct (pomdp-py defaults)", b, POMDP_PY_DEFAULTS))
        for name, shown, b, settings in runs:
            correct, loss = 0, 0.0
            for i in np.flatnonzero(ok):
                peer = make_peer(name, check, b, max_depth=max_depth, seed=seed + int(i),
                                 reference=(references or {}).get(label), pouct=settings)
                a = peer.act(beliefs[i].copy())
                correct += int(a == opt.actions[i])
                loss = max(loss, float(opt.q[i, opt.actions[i]] - opt.q[i, a]))
            required = name not in NOT_REQUIRED and shown == name  # the untuned POUCT row is a diagnostic
            out["results"].append(SanityResult(label, name, b, correct, int(ok.sum()), required, shown, loss))
    return out


def failed(sanity: dict | None, model: str, planner: str, budget: float | None) -> bool | None:
    """Whether ``planner`` failed its required check at ``budget`` (``None``: not checked on ``model``)."""
    if not sanity:
        return None
    rows = [r for r in sanity["results"] if r.model == model and r.planner == planner and r.budget == budget
            and r.label == planner]
    return None if not rows else not rows[0].passed
