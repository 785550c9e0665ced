"""Vectorised sampling of random reachable beliefs (paper Sec. VI-B: "randomly sampled
reachable belief states").

Each of ``n`` independent runs starts from a belief drawn uniformly from the simplex
(Dirichlet(1, ..., 1)) and a true state drawn from it, then takes ``k`` random actions
(``k`` uniform on ``1..max_steps``, per run), sampling the next state from ``P``, the
observation from ``O`` and updating the belief with Eq. 2. All runs advance together as
numpy arrays; the returned beliefs are where each run stopped.
"""

from __future__ import annotations

import numpy as np

from ...core.belief import update_batch
from ...core.model import POMDP


def _categorical(rng: np.random.Generator, probs: np.ndarray) -> np.ndarray:
    """One sample per row of ``probs`` (rows sum to ~1)."""
    c = np.cumsum(probs, axis=-1)
    u = rng.random(probs.shape[0]) * c[:, -1]
    return np.minimum((c < u[:, None]).sum(axis=-1), probs.shape[1] - 1)


def random_beliefs(S: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` beliefs uniform on the simplex."""
    return rng.dirichlet(np.ones(S), size=n)


def reachable_beliefs(model: POMDP, n: int, rng: np.random.Generator, max_steps: int = 20) -> np.ndarray:
    """``n`` beliefs reached from random initial beliefs under random actions (see module doc)."""
    B = random_beliefs(model.S, n, rng)
    s = _categorical(rng, B)
    steps = rng.integers(1, max_steps + 1, size=n)
    for t in range(int(steps.max())):
        active = steps > t
        idx = np.flatnonzero(active)
        a = rng.integers(0, model.A, size=idx.size)
        s_next = _categorical(rng, model.P[a, s[idx]])
        z = _categorical(rng, model.O[a, s_next])
        post, _ = update_batch(model, B[idx], a, z)
        B[idx] = post
        s[idx] = s_next
    return B
