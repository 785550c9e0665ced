"""pomdp-py's POUCT as a peer of the comparison, tuned.

POUCT (Silver and Veness 2010, the POMCP tree without particle beliefs) samples a state from
the root belief and descends a tree of action-observation histories with UCB1. It plans on
**states**: its rewards are the state rewards ``r(s, a)``; it cannot see the uncertainty term
``-w_a f(b)`` of ``rho`` (Eq. 3), which has no per-state value. It is scored with ``rho`` like
every other planner.

pomdp-py (the optional ``bench`` extra, ``pip install pomdp-py``) provides the tree search; we
subclass its ``POUCT`` (Cython ``cpdef`` methods, overridable from Python) in two places.
The settings of :data:`TUNED` and why:

* **Leaf value** (``leaf="exact"``): a new node is valued by the *expected* discounted return
  of the rollout policy from the sampled state, ``V_pi(s)``, the solution of
  ``(I - gamma P_pi) V = r_pi`` (``P_pi[s] = P[pi(s), s]``, ``r_pi[s] = r[s, pi(s)]``), computed
  once per model (:func:`rollout_values`). pomdp-py's own rollout samples one trajectory of that
  policy up to the tree's ``max_depth`` (20 with pomdp-py's defaults): at ``gamma = 0.99`` that
  drops ``0.99^20 = 82 %`` of the discounted weight and adds the noise of one trajectory;
  ``V_pi(s)`` is that rollout's expectation over the infinite horizon, exactly.
* **Rollout policy** (``rollout="greedy-state"``): ``pi(s) = argmax_a r(s, a)``. pomdp-py's
  rollouts (and hence ``V_pi``) see the sampled state, so a *state*-based policy is the natural
  one; greedy on the state reward is the standard domain-knowledge rollout of POMCP, needs no
  model solve, and on the tracking models it is "always priority 2", the state-reward optimum
  of the S = 3 model (so the sanity check also tests that the tree does not spoil a good leaf).
  ``"random"`` is pomdp-py's default.
* **Exploration constant** (``exploration="scaled"``): UCB1's ``c`` must be on the scale of
  the differences of the ``Q`` estimates. With the leaf above, a simulation's return from a
  node is ``r(s, a) + gamma (...)`` ending in some ``V_pi``; we take
  ``c = exploration_scale * R`` with ``R = (max r - min r) + gamma (max V_pi - min V_pi)``, the
  range of a one-step return with an exact leaf (:func:`return_spread`; printed in the report).
  pomdp-py's default is ``sqrt(2)``, the UCB1 constant for returns in ``[0, 1]``. The scale,
  0.25, was measured (docs/benchmarks.md, "The POUCT peer").
* Nodes start with 0 visits (``num_visits_init=0``, pomdp-py's current default; UCB1 then tries
  every action once), and the decision is the tried root action of largest value (pomdp-py's
  ``argmax`` would also consider untried actions at their initial value 0, which wins when all
  returns are negative).

Two more choices keep the comparison fair: the **budget** is measured on the same clock as
every other planner (``clock``, the process CPU time in the experiments; pomdp-py's own loop
reads ``time.time()``, so its ``_search`` is replaced by the same loop on ``clock``), and the
**tree is reused** between decisions like the belief MCTS does: the new belief is matched to
the posterior ``tau(b, a, z)`` of the last belief and action, and the subtree of ``(a, z)``
becomes the root (pomdp-py's ``update``). :data:`POMDP_PY_DEFAULTS` is pomdp-py's untuned
configuration (random rollouts truncated at depth 20, ``c = sqrt(2)``, a fresh tree per
decision), kept for the sanity check's diagnostic line.
"""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from ...core.belief import ETA_MIN, predict
from ...core.model import POMDP

ROLLOUTS = ("greedy-state", "random")
LEAVES = ("exact", "rollout")
#: Two beliefs are the same when they differ by at most this much in every entry (tree reuse).
REUSE_ATOL = 1e-9


def pouct_available() -> bool:
    """Whether pomdp-py (the optional ``bench`` extra) is installed."""
    try:
        import pomdp_py  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class POUCTSettings:
    """How POUCT is configured (module docstring). ``exploration``: ``"scaled"`` or a number."""

    rollout: str = "greedy-state"
    leaf: str = "exact"
    exploration: str | float = "scaled"
    exploration_scale: float = 0.25
    max_depth: int = 100
    reuse: bool = True

    def __post_init__(self) -> None:
        if self.rollout not in ROLLOUTS:
            raise ValueError(f"rollout: expected one of {', '.join(ROLLOUTS)}, got {self.rollout!r}")
        if self.leaf not in LEAVES:
            raise ValueError(f"leaf: expected one of {', '.join(LEAVES)}, got {self.leaf!r}")
        if self.exploration != "scaled" and not (isinstance(self.exploration, (int, float))
                                                 and self.exploration >= 0):
            raise ValueError(f"exploration: expected 'scaled' or a number >= 0, got {self.exploration!r}")

    def to_dict(self) -> dict:
        return asdict(self)


TUNED = POUCTSettings()
POMDP_PY_DEFAULTS = POUCTSettings(rollout="random", leaf="rollout", exploration=math.sqrt(2), max_depth=20,
                                  reuse=False)


def rollout_actions(model: POMDP, rollout: str) -> np.ndarray | None:
    """``pi(s)`` of the state-based rollout policy (``None`` for random)."""
    return np.argmax(model.r, axis=1) if rollout == "greedy-state" else None


def rollout_values(model: POMDP, rollout: str) -> np.ndarray:
    """``V_pi(s)``: the expected discounted state-reward return of the rollout policy from ``s``
    (the uniformly random policy averages ``P`` and ``r`` over actions)."""
    S = model.S
    pi = rollout_actions(model, rollout)
    if pi is None:
        P_pi, r_pi = model.P.mean(axis=0), model.r.mean(axis=1)
    else:
        P_pi, r_pi = model.P[pi, np.arange(S)], model.r[np.arange(S), pi]
    return np.linalg.solve(np.eye(S) - model.gamma * P_pi, r_pi)


def return_spread(model: POMDP, rollout: str = "greedy-state") -> float:
    """``R = (max r - min r) + gamma (max V_pi - min V_pi)``: the scale of ``c`` (module docstring)."""
    v = rollout_values(model, rollout)
    return float(np.ptp(model.r) + model.gamma * np.ptp(v))


def exploration_constant(model: POMDP, settings: POUCTSettings) -> float:
    if settings.exploration == "scaled":
        return settings.exploration_scale * return_spread(model, settings.rollout)
    return float(settings.exploration)


class POUCTPolicy:
    """A closed-loop policy running (tuned) POUCT at every decision on the exact belief.

    ``act(belief)`` plans for ``budget`` seconds of ``clock``; after it, ``last_sims`` is the
    number of simulations and ``last_depth()`` the deepest level of the tree below the root
    (:func:`tree_depth`); ``reused`` counts the decisions that started from the previous tree.
    """

    def __init__(self, model: POMDP, budget: float, settings: POUCTSettings = TUNED, seed: int = 0,
                 clock: Callable[[], float] = time.process_time):
        import pomdp_py  # optional extra 'bench'

        self.pp = pomdp_py
        self.model, self.budget, self.settings = model, float(budget), settings
        self.rng = random.Random(seed)
        self.c = exploration_constant(model, settings)
        self.leaf = rollout_values(model, settings.rollout)
        self.agent, self.states, self.actions, self.observations = _agent(pomdp_py, model, settings.rollout)
        self.planner = _tuned_class(pomdp_py)(
            leaf_values=self.leaf if settings.leaf == "exact" else None, clock=clock,
            max_depth=settings.max_depth, planning_time=self.budget, discount_factor=model.gamma,
            exploration_const=self.c, num_visits_init=0, value_init=0.0,
            rollout_policy=self.agent.policy_model)
        self._previous: tuple[np.ndarray, int] | None = None
        self.last_sims = 0
        self.reused = 0

    def _reuse(self, belief: np.ndarray) -> None:
        """Make the subtree of the observed posterior the new root, or start a fresh tree."""
        pp, tree = self.pp, getattr(self.agent, "tree", None)
        self.agent.tree = None
        if not self.settings.reuse or self._previous is None or tree is None:
            return
        b0, a = self._previous
        ba = predict(self.model, b0, a)
        unnorm = ba[None, :] * self.model.O[a].T  # (Z, S)
        eta = unnorm.sum(axis=1)
        qnode = tree[self.actions[a]]
        if qnode is None:
            return
        for z in np.flatnonzero(eta > ETA_MIN):
            if np.max(np.abs(unnorm[z] / eta[z] - belief)) <= REUSE_ATOL:
                child = qnode[self.observations[z]]
                if child is not None:
                    self.agent.tree = pp.RootVNode.from_vnode(child, self.agent.history)
                    self.reused += 1
                    return

    def act(self, belief: np.ndarray) -> int:
        pp = self.pp
        b = np.asarray(belief, dtype=float)
        self._reuse(b)
        self.agent.set_belief(pp.Histogram({self.states[i]: float(p) for i, p in enumerate(b) if p > 0}), prior=True)
        random.seed(self.rng.random())  # pomdp-py samples with the global `random`
        action = self.planner.plan(self.agent)
        self.last_sims = int(self.planner.last_num_sims)
        self._previous = (b, int(action.index))
        return int(action.index)

    def last_depth(self) -> int:
        """Deepest level of the current tree (a walk over the whole tree: 57 ms after a 1 s search
        on S = 8, so it is not part of the decision)."""
        return tree_depth(self.agent.tree)


def tree_depth(root) -> int:
    """Depth of a pomdp-py search tree in action-observation levels (root 0): the deepest
    belief node the sampled tree reached (not a complete tree of that depth)."""
    best, stack = 0, [(root, 0)]
    while stack:
        v, d = stack.pop()
        best = max(best, d)
        stack.extend((child, d + 1) for q in v.children.values() for child in q.children.values())
    return best


_CLASSES: dict = {}


def _tuned_class(pp):
    """``pomdp_py.POUCT`` with the exact leaf and the injectable clock (the class is built once)."""
    if "tuned" in _CLASSES:
        return _CLASSES["tuned"]

    class _TunedPOUCT(pp.POUCT):
        def __init__(self, *, leaf_values, clock, **kwargs):
            super().__init__(**kwargs)
            self._leaf_values = None if leaf_values is None else [float(v) for v in leaf_values]
            self._clock = clock
            # pomdp-py's attributes are C fields, invisible from Python: keep our own copies
            self._budget = float(kwargs["planning_time"])
            self._py_agent = None

        def plan(self, agent):
            self._py_agent = agent
            return super().plan(agent)

        def _rollout(self, state, history, root, depth):
            if self._leaf_values is None:
                return super()._rollout(state, history, root, depth)
            return self._leaf_values[state.index]

        def _search(self):
            agent, clock = self._py_agent, self._clock
            t0 = clock()
            sims = 0
            while True:  # until the budget is spent and at least one root action has been tried
                self._simulate(agent.sample_belief(), agent.history, agent.tree, None, None, 0)
                sims += 1
                elapsed = clock() - t0
                if elapsed >= self._budget:
                    best = _best_tried(agent.tree)
                    if best is not None:
                        return best, elapsed, sims

    _CLASSES["tuned"] = _TunedPOUCT
    return _TunedPOUCT


def _best_tried(root):
    """The tried root action of largest value (``None`` if none was tried yet)."""
    best, best_value = None, -math.inf
    for action in root.children:
        q = root[action]
        if q.num_visits > 0 and q.value > best_value:
            best, best_value = action, q.value
    return best


def _agent(pp, model: POMDP, rollout: str):
    """A pomdp-py Agent for ``model`` (state reward only) and its state/action/observation objects."""
    S, A, Z = model.S, model.A, model.Z
    P, O, r = np.asarray(model.P), np.asarray(model.O), np.asarray(model.r)
    cP, cO = np.cumsum(P, axis=-1), np.cumsum(O, axis=-1)

    class _Indexed:
        """Equality and hashing by index, shared by the state, action and observation classes."""

        def __init__(self, i):
            self.index = i

        def __hash__(self):
            return self.index

        def __eq__(self, other):
            return type(other) is type(self) and other.index == self.index

    class St(_Indexed, pp.State):
        pass

    class Ac(_Indexed, pp.Action):
        pass

    class Ob(_Indexed, pp.Observation):
        pass

    states = [St(i) for i in range(S)]
    actions = [Ac(a) for a in range(A)]
    observations = [Ob(z) for z in range(Z)]
    pi = rollout_actions(model, rollout)
    greedy = None if pi is None else [actions[int(a)] for a in pi]
    rows_P = [[c.tolist() for c in cP[a]] for a in range(A)]
    rows_O = [[c.tolist() for c in cO[a]] for a in range(A)]
    rew = r.tolist()

    def draw(c):  # inverse CDF on a Python list (faster than numpy for S of a few states)
        u = random.random() * c[-1]
        for i, x in enumerate(c):
            if u < x:
                return i
        return len(c) - 1

    class T(pp.TransitionModel):
        def probability(self, ns, s, a):
            return float(P[a.index, s.index, ns.index])

        def sample(self, s, a):
            return states[draw(rows_P[a.index][s.index])]

        def get_all_states(self):
            return states

    class Om(pp.ObservationModel):
        def probability(self, o, ns, a):
            return float(O[a.index, ns.index, o.index])

        def sample(self, ns, a):
            return observations[draw(rows_O[a.index][ns.index])]

        def get_all_observations(self):
            return observations

    class R(pp.RewardModel):
        def sample(self, s, a, ns):
            return rew[s.index][a.index]

    class Pol(pp.RolloutPolicy):
        def rollout(self, s, history=None):
            return actions[random.randrange(A)] if greedy is None else greedy[s.index]

        def get_all_actions(self, state=None, history=None):
            return actions

    init = pp.Histogram({s: 1.0 / S for s in states})
    agent = pp.Agent(init, Pol(), T(), Om(), R())
    return agent, states, actions, observations
