"""A non-trivial Sec. VI-B comparison model (the paper's Table III / Fig. 4 problem family).

The paper's Sec. VI-B uses the tracking dynamics of Sec. VI with the state reward
:func:`~pomdp_planner.core.domains.tracking.comparison_reward` (``f = 0``, ``q = 0.8``,
``gamma = 0.99``) but never says which ``x`` and ``y`` sequences it used for ``S > 3``.

With the "natural" sequences (the S = 3 ones stretched to any S: ``x_i = 3i/S``, ``y`` evenly
spaced on ``[-9, -1]``) every entry of ``y`` is negative, so every action pulls the target
towards state 1 (the poor-tracking region, reward ``-c_p``), and the lowest priority ``A``
pulls it there the *least* while also costing the least effort. The lowest priority is then
optimal at every belief (proven exactly by
``pomdp_planner.bench.experiments.pbvi.single_action_optimal`` -- the value of always playing
``A`` is a Bellman fixed point -- on S = 4 and 5 and on every Table III size, and confirmed by
the exact alpha-vector solver of ``core/reference.py``); the bounds then trivially agree at
``A`` and every pruning figure would be meaningless.

Our choice (documented in docs/RESULTS.md): keep ``x_i = 3i/S`` and spread ``y`` evenly and
symmetrically on ``[-2, 2]`` (``S*A`` points; spreads 1.5-5 were scanned, 2 gives a
belief-dependent optimum on every small size checked). Then high priorities (small ``a``) pull the
target down into the poor-tracking region, low priorities push it up into the dangerous
region, and the effort cost ``c_a (A - a + 1)`` makes high priority expensive: the optimal
policy is an intermediate, belief-dependent priority: no single action is optimal everywhere
(exact certificate) and two adjacent priorities share the simplex on S = 4, 5
(``test/test_experiments_models.py``). With this generator the next-state distribution is
chosen mostly by the action (the previous state only shifts the tilt within one block of
``y``), so optimal policies switch between two adjacent priorities rather than many.
All other constants are the paper's:
``c_a = 1/(2A)``, ``c_p = 1``, ``c_d = 0.1``, ``k_r = 2/S``, ``q = 0.8``, ``gamma = 0.99``,
``f = 0``. Both sequences are strictly increasing, so the transition kernel stays TP2.
"""

from __future__ import annotations

import numpy as np

from ..model import POMDP, ModelError
from .tracking import comparison_reward, default_x, tracking_model

#: Default half-width of the symmetric ``y`` range ``[-Y_SPREAD, Y_SPREAD]``.
Y_SPREAD = 2.0


def comparison_y(S: int, A: int, spread: float = Y_SPREAD) -> np.ndarray:
    """``S*A`` evenly spaced values on ``[-spread, spread]`` (our Sec. VI-B ``y``)."""
    if not spread > 0.0:
        raise ModelError(f"generator.y_spread: must be positive, got {spread}")
    return np.linspace(-spread, spread, S * A)


def comparison_model(S: int, A: int, q: float = 0.8, gamma: float = 0.99, spread: float = Y_SPREAD,
                     natural: bool = False) -> POMDP:
    """The Sec. VI-B model with our non-trivial ``y`` (or the trivial ``natural=True`` one).

    ``f = 0`` (no uncertainty term): a standard POMDP with the state reward of Sec. VI-B.
    """
    if S < 2 or A < 2:
        raise ModelError(f"generator: comparison model needs S >= 2 and A >= 2, got S={S}, A={A}")
    y = None if natural else comparison_y(S, A, spread)
    name = f"comparison_s{S}_a{A}" + ("_natural" if natural else "")
    model = tracking_model(S, A, q, comparison_reward(S, A), gamma=gamma, x=default_x(S), y=y,
                           uncertainty="none", name=name)
    return model
