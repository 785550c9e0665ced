"""Reference policies that regrets are measured against (docs/MODEL_SEARCH.md, docs/RESULTS.md).

* :class:`GridReferencePolicy` (S <= 3): the policy of grid policy iteration on the belief
  simplex (``core.reference.reference_policy``, Freudenthal interpolation, Lovejoy 1991): one
  exact Bellman backup (paper Eqs. 4-6) of the fine-grid value at the current belief. A decision
  is *certified* when its best-minus-second Q gap exceeds the grid's measured tie margin, i.e.
  the discretisation error cannot have changed the action; an uncertified decision is a near-tie.
* :class:`SearchReferencePolicy` (larger S): exhaustive search to a fixed depth at every step
  (Algorithm 1 without pruning), a finite-lookahead policy. It is *not* the infinite-horizon
  optimum, and it belongs to the same family as the anytime searches it is used to rank.
"""

from __future__ import annotations

import time

import numpy as np

from ..core.model import POMDP
from ..core.reference import ReferencePolicy
from ..core.search import Planner


class GridReferencePolicy:
    """``argmax_a`` of one Bellman backup of the fine-grid ``V`` (Eqs. 4-6); counts certified decisions."""

    def __init__(self, ref: ReferencePolicy):
        self.solution = ref.fine
        self.margin = ref.tie_margin
        self.decisions = 0
        self.certified = 0

    def act(self, belief: np.ndarray) -> int:
        q = self.solution.q_values(np.asarray(belief, dtype=float)[None, :])[0]
        top2 = np.sort(q)[-2:]
        self.decisions += 1
        self.certified += int(top2[1] - top2[0] > self.margin)
        return int(np.argmax(q))


class SearchReferencePolicy:
    """Exhaustive search to ``depth`` at every step; records times and the root value ``V_d(b)``."""

    def __init__(self, model: POMDP, depth: int):
        self.planner = Planner(model)
        self.depth = int(depth)
        self.times: list[float] = []
        self.values: list[float] = []
        self.actions: list[int] = []

    def act(self, belief: np.ndarray) -> int:
        t0 = time.perf_counter()
        res = self.planner.search(belief, self.depth, use_bounds=False)
        self.times.append(time.perf_counter() - t0)
        self.values.append(float(res.value))
        self.actions.append(int(res.action))
        return int(res.action)
