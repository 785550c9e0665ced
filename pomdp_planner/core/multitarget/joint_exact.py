"""The exact joint lookahead: expectimax over the joint belief and the joint actions within budget.

Written independently of the decomposition (:mod:`.planner`, :mod:`.knapsack`, :mod:`.dual`) and
of the single-target search (``core/search.py``): it imports only the problem's data. The K
targets are composed into ONE POMDP on the product state space (``S_1 ... S_K`` states, joint
state index in C order), for every joint action ``alpha`` within the budget:

* ``P_alpha = P_1[a_1] (x) ... (x) P_K[a_K]`` and ``O_alpha = O_1[a_1] (x) ... (x) O_K[a_K]``
  (Kronecker products: the targets move and are observed independently), joint observations in
  C order;
* the reward of a joint belief ``b`` is ``sum_k rho_k(m_k(b), a_k)`` with ``m_k`` the marginal of
  target ``k`` and ``rho_k`` Eq. 3, the entropies written out here;
* Bayes' rule on the joint belief (Eqs. 1-2 on the product space).

The depth-``d`` value is value iteration from ``V_1(b) = max_alpha rho(b, alpha)`` (the search
convention of ``core/search.py``: ``d`` levels below the root, ``d + 1`` decisions, every one of
them within the budget, the leaves included). Depth 0 is the one-step problem: the best joint
action for ``sum_k rho_k`` within the budget. The joint action set is enumerated (the feasible
part of ``A_1 x ... x A_K``), so the cost is ``(F Z_1 ... Z_K)^d`` belief nodes for ``F``
feasible joint actions: K = 2, 3 on S = 3 models at depths 1-3. Refused above
:data:`MAX_JOINT_NODES` nodes.
"""

from __future__ import annotations

import itertools
import math
from fractions import Fraction

import numpy as np

from ..errors import ModelError, OptionError
from .problem import MultiTargetProblem

#: Largest expectimax tree (belief nodes) :class:`ExactJointPlanner` builds.
MAX_JOINT_NODES = 5 * 10**6
#: Joint observations with probability at most this are not expanded (they carry no weight).
ETA_TINY = 1e-300
#: Parent beliefs expanded at once (bounds the memory of a level).
CHUNK = 4096


def _entropy(name: str, b: np.ndarray) -> np.ndarray:
    """The uncertainty function ``f`` of Eq. 3 by name, along the last axis (``b >= 0``)."""
    if name == "none":
        return np.zeros(b.shape[:-1])
    if name == "renyi2":
        return -np.log(np.sum(b * b, axis=-1))
    if name == "shannon":
        safe = np.where(b > 0.0, b, 1.0)
        return -np.sum(np.where(b > 0.0, b * np.log(safe), 0.0), axis=-1)
    raise ModelError(f"uncertainty.function: the exact joint planner knows none, renyi2, shannon, not {name!r}")


class ExactJointPlanner:
    """Exact depth-``depth`` expectimax of a :class:`~.problem.MultiTargetProblem` (module docstring)."""

    def __init__(self, problem: MultiTargetProblem, depth: int):
        self.problem = problem
        self.depth = int(depth)
        if self.depth < 0:
            raise OptionError(f"depth: must be >= 0, got {depth!r}")
        models = problem.models
        self.sizes = tuple(m.S for m in models)
        self.N = math.prod(self.sizes)
        self.Zj = math.prod(m.Z for m in models)
        joint = []
        for alpha in itertools.product(*(range(m.A) for m in models)):
            used = sum((problem.efforts[k][a] for k, a in enumerate(alpha)), Fraction(0))
            if used <= problem.budget:
                joint.append(alpha)
        self.actions = tuple(joint)
        F = len(joint)
        nodes = sum((F * self.Zj) ** i for i in range(self.depth + 1))
        if nodes > MAX_JOINT_NODES:
            raise OptionError(f"depth: the exact joint tree has {nodes:.3g} belief nodes ({F} joint actions within "
                             f"the budget, {self.Zj} joint observations), more than MAX_JOINT_NODES = "
                             f"{MAX_JOINT_NODES}")
        self.gamma = problem.gamma
        self.P = np.stack([self._kron([m.P[a] for m, a in zip(models, al, strict=True)]) for al in joint])
        self.O = np.stack([self._kron([m.O[a] for m, a in zip(models, al, strict=True)]) for al in joint])

    @staticmethod
    def _kron(mats: list[np.ndarray]) -> np.ndarray:
        out = mats[0]
        for M in mats[1:]:
            out = np.kron(out, M)
        return out

    def joint_belief(self, beliefs: list[np.ndarray]) -> np.ndarray:
        """The product belief ``b_1 (x) ... (x) b_K`` (C order)."""
        out = np.asarray(beliefs[0], dtype=float)
        for b in beliefs[1:]:
            out = np.kron(out, np.asarray(b, dtype=float))
        return out

    def rewards(self, B: np.ndarray) -> np.ndarray:
        """``rho(b, alpha)`` for joint beliefs ``B (n, N)`` and every joint action: ``(n, F)``."""
        n = B.shape[0]
        cube = B.reshape((n, *self.sizes))
        K = len(self.sizes)
        per_target = []
        for k, m in enumerate(self.problem.models):
            axes = tuple(1 + j for j in range(K) if j != k)
            marg = cube.sum(axis=axes) if axes else cube
            rho = marg @ m.r - _entropy(m.uncertainty.name, marg)[:, None] * m.w[None, :]  # (n, A_k)
            per_target.append(rho)
        out = np.zeros((n, len(self.actions)))
        for f, alpha in enumerate(self.actions):
            for k, a in enumerate(alpha):
                out[:, f] += per_target[k][:, a]
        return out

    def q_values(self, beliefs: list[np.ndarray]) -> np.ndarray:
        """``Q(b, alpha)`` at the product of ``beliefs`` for every joint action of :attr:`actions`."""
        b = self.joint_belief(beliefs)[None, :]
        return self._q(b, self.depth)[0]

    def value(self, beliefs: list[np.ndarray]) -> float:
        """The depth-``depth`` joint lookahead value ``max_alpha Q(b, alpha)``."""
        return float(self.q_values(beliefs).max())

    def act(self, beliefs: list[np.ndarray]) -> tuple[int, ...]:
        """The joint action maximising ``Q`` (ties: the first in :attr:`actions`, lexicographic)."""
        return self.actions[int(np.argmax(self.q_values(beliefs)))]

    def _q(self, B: np.ndarray, remaining: int) -> np.ndarray:
        """``Q(b, alpha)`` for joint beliefs ``B (n, N)`` with ``remaining`` levels below: ``(n, F)``."""
        rho = self.rewards(B)
        if remaining == 0:
            return rho
        n, F, Zj = B.shape[0], len(self.actions), self.Zj
        out = np.empty((n, F))
        for s in range(0, n, CHUNK):
            Bc = B[s:s + CHUNK]
            m = Bc.shape[0]
            pred = np.einsum("ni,fij->nfj", Bc, self.P)  # (m, F, N)
            unnorm = pred[:, :, :, None] * self.O[None]  # (m, F, N, Zj)
            eta = unnorm.sum(axis=2)  # (m, F, Zj)
            ok = eta > ETA_TINY
            idx = np.flatnonzero(ok)
            post = np.moveaxis(unnorm, 2, 3).reshape(m * F * Zj, self.N)[idx] / eta.reshape(-1)[idx, None]
            v = self._q(post, remaining - 1).max(axis=1)
            cont = np.zeros(m * F * Zj)
            cont[idx] = eta.reshape(-1)[idx] * v
            out[s:s + m] = rho[s:s + m] + self.gamma * cont.reshape(m, F, Zj).sum(axis=2)
        return out
