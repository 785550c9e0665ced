"""Monte Carlo tree search in belief space with the true belief reward (rho-POMCP / PFT idea).

An anytime, information-aware online planner for the discrete POMDPs of this package. Every
node of the tree is an **exact** Bayes belief (paper Eqs. 1-2), every edge is rewarded with the
true belief reward ``rho(b, a) = b . r[:, a] - w_a f(b)`` (paper Eq. 3), so the planner sees the
uncertainty term that a state-sampling planner (POMCP, POUCT) cannot. Options, benchmark and how
the defaults were chosen: docs/benchmarks.md, "Belief-space MCTS".

**Tree.** A belief node is expanded on its second visit: for every action ``a`` and observation
``z`` at once it stores ``eta(z | b, a) = b^a @ O[a][:, z]`` (``b^a = b @ P[a]``), the posterior
``tau(b, a, z) ∝ b^a ∘ O[a][:, z]`` and ``rho(tau, .)``. With finite, small ``Z`` the child for
``(a, z)`` is unique, so no progressive widening is needed: a simulation descends by sampling
``z ~ eta(. | b, a)``; impossible observations (``eta <= ETA_MIN``) are never sampled. Actions
are chosen by UCB1, ``Q(b, a) + c sqrt(ln N(b) / N(b, a))``, after the untried actions, which are
tried in greedy order (largest ``rho(b, a)`` first); ties are broken by the seeded generator.
``c = exploration_scale * (max rho - min rho)`` over the simplex (:func:`rho_range`), unless
``exploration`` sets it.

**Backups** (``backup``). ``"bellman"`` (default): partial Bellman backups with the exact
observation probabilities (DP-UCT, Keller and Helmert, ICAPS 2013), ``Q(b, a) = rho(b, a) +
gamma sum_z eta_z V(z) / sum_z eta_z`` over the children visited so far; once every child of a
finite tree has been visited it is the expectimax value exactly (paper Eqs. 4-6). ``"mean"``:
the Monte Carlo means of POMCP and PFT-DPW. ``test/test_belief_mcts.py`` checks both against a
brute-force expectimax recursion.

**Leaf values** (``leaf``). ``"rollout"`` (default): ``rollout_depth`` greedy steps along one
sampled observation path with exact Bayes updates, then a tail (``tail``): ``"average"``
(default, ``gamma^D rho_bar / (1 - gamma)`` with ``rho_bar`` the long-run mean reward of the
greedy policy, :func:`average_greedy_reward`), ``"leaf"`` (the last greedy reward held forever)
or ``"none"`` (the truncated return). ``"rho"``: ``max_a rho(b, a)``, the leaf of
:mod:`~pomdp_planner.core.search`, so the tree estimates the expectimax values of Algorithm 1.
``"zero"``: 0.

**Speed.** Tree statistics are plain Python lists; the numerical work is vectorised per node:
an expansion is one product of the belief with a precomputed ``S x A (Z + Z A + Z S)`` matrix
holding ``eta``, the linear reward and the unnormalised posterior of every ``(a, z)``; a rollout
step carries the belief unnormalised. Random numbers are drawn in blocks.

**Anytime and determinism.** A search stops after ``simulations`` simulations or when
``time_budget`` seconds have passed (the clock, injectable as in
:class:`~pomdp_planner.core.search.Planner`, is read after every simulation), whichever comes
first; at least one simulation is always run. Given the seed and a number of simulations the
result is reproducible. Tree reuse (:class:`BeliefMCTSPolicy`): if the next belief is a child
posterior of the last root under the action taken (equal up to :data:`REUSE_ATOL`), that
subtree becomes the new root; otherwise a fresh tree is built.
"""

from __future__ import annotations

import math
import time
import weakref
from bisect import bisect_right
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from itertools import accumulate
from typing import Any

import numpy as np

from .belief import ETA_MIN, check_belief
from .checks import check_choice, check_int, check_number, is_integer, parse_flag
from .errors import OptionError
from .gc_pause import paused_gc
from .model import POMDP, priority_of
from .options import (
    MAX_DEPTH_RANGE,
    ROLLOUT_DEPTH_RANGE,
    SIMULATIONS_RANGE,
    TIME_BUDGET_RANGE,
    check_depth,
    check_time_budget,
)
from .search import DEFAULT_MEMORY_BUDGET

#: Leaf evaluations accepted by :class:`BeliefMCTS` (see the module docstring).
LEAF_KINDS = ("rollout", "rho", "zero")
#: Default backup (measured).
DEFAULT_BACKUP = "bellman"
#: Tail values after a rollout (module docstring).
TAILS = ("average", "leaf", "none")
#: Greedy steps averaged by :func:`average_greedy_reward`.
AVERAGE_REWARD_STEPS = 2000
#: Backups accepted by :class:`BeliefMCTS`: Monte Carlo means or partial Bellman backups.
BACKUPS = ("mean", "bellman")
#: Default ``c / (max rho - min rho)`` of UCB1 (measured: docs/benchmarks.md, "Belief-space MCTS").
DEFAULT_EXPLORATION_SCALE = 1.0
#: Default number of greedy rollout steps before the tail value (measured).
DEFAULT_ROLLOUT_DEPTH = 1
#: Default maximum depth of the tree (action-observation levels below the root; measured).
DEFAULT_MAX_DEPTH = 3
#: Simulations per decision when neither a number of simulations nor a time budget is given.
DEFAULT_SIMULATIONS = 1000
#: Tree reuse: the next belief must equal a stored posterior within this (absolute) tolerance.
REUSE_ATOL = 1e-12
#: Beliefs sampled (besides vertices and centre) by :func:`rho_range`.
RHO_RANGE_SAMPLES = 512
#: Uniform random numbers drawn per block.
_RANDOM_BLOCK = 4096
#: A rollout's unnormalised belief is renormalised when its mass falls below this.
_RENORMALISE_BELOW = 1e-100


def rho_range(model: POMDP, samples: int = RHO_RANGE_SAMPLES) -> float:
    """``max rho - min rho`` over actions and beliefs (the scale of one step's reward, Eq. 3).

    Evaluated on the vertices of the simplex, its centre and ``samples`` beliefs drawn
    uniformly from it with a fixed seed (deterministic). For ``w_a >= 0`` the maximum is at a
    vertex: ``f >= 0`` vanishes at the vertices, so ``rho(b, a) <= max_s r[s, a] = rho(e_s, a)``
    (no concavity needed: Renyi quadratic entropy is not concave for S >= 3); the minimum is
    approximated.
    """
    S = model.S
    B = np.vstack([np.eye(S), np.full((1, S), 1.0 / S), np.random.default_rng(0).dirichlet(np.ones(S), samples)])
    rho = model.rho(B)
    return float(rho.max() - rho.min())


_AVERAGE_REWARD_CACHE: weakref.WeakKeyDictionary[POMDP, float] = weakref.WeakKeyDictionary()


def average_greedy_reward(model: POMDP, planner: BeliefMCTS | None = None) -> float:
    """Long-run mean reward ``rho`` of the greedy policy on the belief MDP (cached per model).

    One greedy path of :data:`AVERAGE_REWARD_STEPS` steps from the uniform belief, observations
    sampled from ``eta`` with a fixed seed (0) and exact Bayes updates: ``(1/T) sum_t rho(b_t, a_t)``.
    Deterministic for a model; the rollout tail of :class:`BeliefMCTS` is this value over ``1 - gamma``.
    """
    cached = _AVERAGE_REWARD_CACHE.get(model)
    if cached is None:
        planner = planner or BeliefMCTS(model, tail="none")
        b = np.full(model.S, 1.0 / model.S)
        total, _ = planner._greedy_path(b, planner._rho(b), AVERAGE_REWARD_STEPS, 1.0,
                                        _Uniforms(np.random.default_rng(0)))
        cached = _AVERAGE_REWARD_CACHE[model] = total / AVERAGE_REWARD_STEPS
    return cached


class _Uniforms:
    """A block of uniform numbers from ``rng`` and the index of the next one."""

    __slots__ = ("buf", "i", "rng")

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.buf: list[float] = []
        self.i = 0


class _Node:
    """A belief node: belief, ``rho(b, .)``, visit statistics and (once expanded) its children."""

    __slots__ = ("b", "crho", "cum", "depth", "eta", "kids", "n", "na", "post", "q", "rho", "sn", "sw", "untried",
                 "v")

    def __init__(self, b: np.ndarray, rho: list[float], depth: int):
        self.b = b
        self.rho = rho
        self.depth = depth
        self.n = 0
        self.na: list[int] | None = None  # visits per action
        self.q: list[float] | None = None  # mean return per action
        self.untried: list[int] | None = None
        self.cum: list[list[float]] | None = None  # cumulative eta(. | b, a) per action
        self.post: np.ndarray | None = None  # (A Z, S) posteriors, row a Z + z
        self.crho: list[list[float]] | None = None  # rho of every posterior
        self.kids: list[_Node | None] | None = None
        self.v = 0.0  # Bellman backup: the node's value estimate
        self.eta: list[float] | None = None  # Bellman backup: eta of every (a, z), row a Z + z
        self.sw: list[float] | None = None  # Bellman backup: sum of eta V over the visited children of a
        self.sn: list[float] | None = None  # Bellman backup: sum of eta over the visited children of a


def expansion_bytes(S: int, A: int, Z: int) -> int:
    """An upper estimate of the memory one expansion adds to the tree: the node's ``(A Z, A + S)``
    float array (posteriors and the linear part of their rho), its Python lists (cumulative eta,
    eta, rho of every child, children, counts) and its ``A Z`` child nodes with their belief views.

    Checked against tracemalloc in ``test/test_belief_mcts.py`` (measured: 0.5-0.6 of the estimate
    on the shipped S = 3 and S = 8 models); with the default memory budget
    (:data:`~.search.DEFAULT_MEMORY_BUDGET`, 1 GiB) an S = Z = 8, A = 3 tree stops growing at
    55 142 expanded nodes (about 0.55 GB measured).
    """
    AZ = A * Z
    floats = 8 * AZ * (A + S) + 128  # the array Y and the view of its posteriors
    lists = (AZ * (64 + 8 * A) + AZ * A * 32  # rho of every child: one list of A floats each
             + A * (64 + 8 * Z) + AZ * 32  # cumulative eta per action
             + 3 * (64 + 8 * AZ) + AZ * 32  # eta, children, spare
             + 6 * (64 + 8 * A) + 4 * A * 32)  # counts, Q, sums, untried
    children = AZ * (256 + 128)  # a child node object and its belief view
    return floats + lists + children


@dataclass(frozen=True)
class MCTSResult:
    """Outcome of :meth:`BeliefMCTS.search`.

    ``action`` is 0-based (``priority = action + 1``): the tried root action with the largest
    ``Q`` (ties: the smallest index). ``q_values[a]`` is the Monte Carlo estimate of
    ``Q(b, a)`` (``nan`` for untried actions), ``visits[a]`` its number of simulations (with
    tree reuse these include the simulations of earlier decisions). ``simulations`` counts this
    call's simulations, ``depth`` is the deepest node below the root (action-observation
    levels) that they reached, ``nodes`` the belief nodes they created, ``reused`` whether the
    root came from the previous tree. ``expanded`` counts the expanded nodes of the tree (an upper
    bound when it was reused); ``memory_capped`` says the tree reached
    :attr:`BeliefMCTS.max_expansions` and the search went on without growing it.
    """

    action: int
    priority: int
    q_values: np.ndarray
    visits: np.ndarray
    simulations: int
    depth: int
    nodes: int
    time_used: float
    deadline_hit: bool
    reused: bool
    exploration: float
    root: _Node = field(repr=False, compare=False)
    expanded: int = 0
    memory_capped: bool = False

    @property
    def value(self) -> float:
        return float(self.q_values[self.action])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary; actions as priorities ``1..A``, untried Q values as ``None``."""
        return {
            "action": int(self.priority),
            "q_values": [float(x) if math.isfinite(x) else None for x in self.q_values],
            "visits": [int(x) for x in self.visits],
            "simulations": int(self.simulations),
            "depth": int(self.depth),
            "nodes": int(self.nodes),
            "time_used": float(self.time_used),
            "deadline_hit": bool(self.deadline_hit),
            "reused": bool(self.reused),
            "expanded": int(self.expanded),
            "memory_capped": bool(self.memory_capped),
            "exploration": float(self.exploration),
        }


class BeliefMCTS:
    """UCT on exact beliefs with the true belief reward (module docstring).

    ``exploration``: the UCB1 constant ``c`` (``None``: ``exploration_scale * rho_range``).
    ``max_depth``: action-observation levels below the root; nodes there are leaves.
    ``leaf``: ``"rollout"`` (greedy, ``rollout_depth`` steps + tail value), ``"rho"`` or ``"zero"``.
    ``seed``: the generator for observation sampling and tie breaking. ``clock``: the wall clock
    for ``time_budget`` (injectable for tests).
    """

    def __init__(self, model: POMDP, *, exploration: float | None = None,
                 exploration_scale: float = DEFAULT_EXPLORATION_SCALE, max_depth: int = DEFAULT_MAX_DEPTH,
                 leaf: str = "rollout", rollout_depth: int = DEFAULT_ROLLOUT_DEPTH, tail: str = "average",
                 backup: str = DEFAULT_BACKUP,
                 seed: int | None = 0,
                 clock: Callable[[], float] = time.perf_counter,
                 memory_budget: int = DEFAULT_MEMORY_BUDGET):
        self.model = model
        self.max_depth = check_int(max_depth, "max_depth", 1)
        self.rollout_depth = check_int(rollout_depth, "rollout_depth", 0)
        self.leaf = check_choice(leaf, LEAF_KINDS, "leaf")
        self.tail = check_choice(tail, TAILS, "tail")
        self.backup = check_choice(backup, BACKUPS, "backup")
        if leaf == "rollout" and tail != "none" and model.gamma >= 1.0:
            raise OptionError(f"tail: {tail} values the infinite horizon after a rollout (a factor 1 / (1 - gamma)), "
                              "undefined at discount 1 (a finite-horizon model); use tail=none or leaf=rho")
        self.exploration_scale = check_number(exploration_scale, "exploration_scale", 0.0)
        if exploration is None:
            exploration = self.exploration_scale * rho_range(model)
        self.exploration = check_number(exploration, "exploration", 0.0)
        if seed is not None:
            seed = check_int(seed, "seed", 0)
        self.seed = seed
        self.clock = clock
        self._rng = np.random.default_rng(seed)
        self._ubuf: list[float] = []  # uniform numbers of the tree policy, and the next index
        self._ui = 0
        self._runi = _Uniforms(self._rng)  # those of the rollouts
        S, A, Z = model.S, model.A, model.Z
        self._S, self._A, self._Z = S, A, Z
        self.memory_budget = check_int(memory_budget, "memory_budget", 1)
        #: The tree stops growing at this many expanded nodes (:func:`expansion_bytes`).
        self.max_expansions = max(1, self.memory_budget // expansion_bytes(S, A, Z))
        self._gamma = float(model.gamma)
        self._w = [float(x) for x in model.w]
        kind = model.uncertainty.name
        if not any(self._w):
            kind = "none"
        self._kind = kind if kind in ("none", "renyi2") else "generic"
        self._f = model.uncertainty.value
        self._wa = np.asarray(model.w, dtype=float)
        # K[a] = [ PO[a] | PO[a] r (Z x A) | P[a] * O[a][:, z] (Z x S) ] as an S x L matrix, with
        # L = Z + Z A + Z S: the product b @ K[a] gives, for every z, eta, the linear reward of
        # the unnormalised posterior and the unnormalised posterior itself (Eqs. 1-3).
        P, O, r = model.P, model.O, model.r
        U = P[:, :, None, :] * np.swapaxes(O, 1, 2)[:, None, :, :]  # (A, S, Z, S'): P[a,s,s'] O[a,s',z]
        eta = U.sum(axis=3)  # (A, S, Z)
        lin = U @ r  # (A, S, Z, A')
        K = np.concatenate([eta, lin.reshape(A, S, Z * A), U.reshape(A, S, Z * S)], axis=2)  # (A, S, L)
        self._L = K.shape[2]
        self._K = [np.ascontiguousarray(K[a]) for a in range(A)]  # rollouts: one action's block
        # expansions: all actions, and per (a, z) the linear reward and the posterior side by side,
        # so that one division normalises both
        Kx = np.concatenate([eta, np.concatenate([lin, U], axis=3).reshape(A, S, Z * (A + S))], axis=2)
        self._Kall = np.ascontiguousarray(np.moveaxis(Kx, 0, 1).reshape(S, A * self._L))
        self._sure = bool(np.all(eta > 2.0 * ETA_MIN))  # every observation possible from every belief
        tail_used = self.leaf == "rollout" and self.tail != "none"  # (checked above: then gamma < 1)
        self._tail_factor = self._gamma ** self.rollout_depth / (1.0 - self._gamma) if tail_used else 0.0
        self._average_reward = average_greedy_reward(model, self) if tail_used and self.tail == "average" else math.nan

    # ----------------------------------------------------------------- public
    def search(self, belief: np.ndarray, simulations: int | None = None, time_budget: float | None = None,
               previous: MCTSResult | None = None, action: int | None = None) -> MCTSResult:
        """Run simulations from ``belief`` until ``simulations`` are done or ``time_budget`` passes.

        With neither given, :data:`DEFAULT_SIMULATIONS`. ``previous`` and ``action``: the last
        result and the action then taken, for tree reuse (used only when ``belief`` is one of
        its stored posteriors under ``action``).
        """
        if simulations is not None:
            simulations = check_int(simulations, "simulations", 1)
        if time_budget is not None:
            time_budget = check_number(time_budget, "time_budget", 0.0)
        if simulations is None and time_budget is None:
            simulations = DEFAULT_SIMULATIONS
        clock = self.clock
        t0 = clock()
        b = check_belief(self.model, belief)
        root = None if previous is None or action is None else self._reusable(previous.root, action, b)
        reused = root is not None
        expanded = previous.expanded if reused else 0  # an upper bound: the subtree of the old tree
        if root is None:
            root = _Node(b, self._rho(b), 0)
        deadline = math.inf if time_budget is None else t0 + time_budget
        limit = math.inf if simulations is None else simulations
        horizon = root.depth + self.max_depth
        if root.kids is None:
            self._expand(root)
            expanded += 1
        done, created, deepest, hit, expanded = self._run(root, horizon, limit, deadline, expanded)
        A = self._A
        q = np.array([x if n > 0 else math.nan for x, n in zip(root.q, root.na, strict=True)])
        visits = np.array(root.na, dtype=int)
        best = max((a for a in range(A) if root.na[a] > 0), key=lambda a: (root.q[a], -a))
        q.setflags(write=False)
        visits.setflags(write=False)
        return MCTSResult(
            action=int(best), priority=int(priority_of(best)), q_values=q, visits=visits, simulations=done,
            depth=deepest - root.depth, nodes=created, time_used=clock() - t0, deadline_hit=hit, reused=reused,
            exploration=self.exploration, root=root, expanded=expanded,
            memory_capped=expanded >= self.max_expansions)

    # --------------------------------------------------------------- internals
    def _rho(self, b: np.ndarray) -> list[float]:
        return [float(x) for x in self.model.rho(b)]

    def _expand(self, node: _Node) -> None:
        """All ``A Z`` children of ``node`` at once (Eqs. 1-3): eta, posteriors and their rho."""
        A, Z, S, L = self._A, self._Z, self._S, self._L
        X = np.dot(node.b, self._Kall).reshape(A, L)
        eta = X[:, :Z]
        if self._sure:
            Y = X[:, Z:].reshape(A, Z, A + S) / eta[:, :, None]
        else:
            ok = eta > ETA_MIN
            eta = np.where(ok, eta, 0.0)
            Y = X[:, Z:].reshape(A, Z, A + S) / np.where(ok, eta, 1.0)[:, :, None]
            Y[~ok, A:] = 1.0 / S  # impossible children (never sampled): any valid belief
        crho = Y[:, :, :A]  # rho(tau, .) once the uncertainty term is added
        post = Y[:, :, A:]
        kind = self._kind
        if kind == "renyi2":
            crho += self._wa * np.log(np.einsum("azs,azs->az", post, post))[:, :, None]
        elif kind == "generic":
            crho -= self._wa * self._f(post)[:, :, None]
        node.cum = np.cumsum(eta, axis=1).tolist()
        node.post = post.reshape(A * Z, S)
        node.crho = crho.reshape(A * Z, A).tolist()
        node.kids = [None] * (A * Z)
        node.na = [0] * A
        rho = node.rho
        node.untried = sorted(range(A), key=lambda a: (rho[a], -a))  # popped from the end: greedy first
        if self.backup == "mean":
            node.q = [0.0] * A
        else:
            node.q = [-math.inf] * A  # V = max over the tried actions
            node.eta = eta.ravel().tolist()
            node.sw = [0.0] * A
            node.sn = [0.0] * A

    def _last_possible(self, cum: list[float]) -> int:
        """The last observation with positive probability (``u * total`` rounded up to ``total``)."""
        z = self._Z - 1
        while z > 0 and cum[z] == cum[z - 1]:
            z -= 1
        return z

    def _run(self, root: _Node, horizon: int, limit: float, deadline: float,
             expanded: int) -> tuple[int, int, int, bool, int]:
        """Simulations from ``root`` until ``limit`` of them are done or the clock passes ``deadline``.

        One simulation: from the root, choose ``a`` by UCB1 (untried actions first, greedy order;
        exact ties at random), sample ``z ~ eta(. | b, a)``, go to the child ``(a, z)``
        (creating it from the stored posterior if needed), until a node never visited (or, if
        visited once, expanded now) or the depth limit; value it with the leaf evaluation and back
        the discounted return up the path. The body is one loop with local names: the per-level
        work is plain Python (a numpy call costs more than the whole UCB1 step for a few actions).

        A node is expanded only while the tree has fewer than :attr:`max_expansions` expanded nodes
        (``expanded`` counts them); beyond, an unexpanded node is a leaf (memory stays bounded
        whatever the budget and depth; the existing tree keeps being refined).

        Returns (simulations done, nodes created, deepest node depth, deadline hit, expanded).
        """
        A, Z = self._A, self._Z
        gamma, c = self._gamma, self.exploration
        clock, expand, rng = self.clock, self._expand, self._rng
        leaf_kind, rollout = self.leaf, self._rollout
        bellman = self.backup == "bellman"
        buf, ui = self._ubuf, self._ui
        nbuf = len(buf)
        log, sqrt, inf = math.log, math.sqrt, math.inf
        actions = range(A)
        Node = _Node
        done = created = 0
        cap = self.max_expansions
        deepest = root.depth
        hit = False
        while done < limit:
            path = []
            node = root
            while node.depth < horizon:
                kids = node.kids
                if kids is None:
                    if node.n == 0 or expanded >= cap:
                        break
                    expand(node)
                    expanded += 1
                    kids = node.kids
                if ui > nbuf - 2:  # a level draws at most two numbers (a tie, an observation)
                    buf, ui = rng.random(_RANDOM_BLOCK).tolist(), 0
                    nbuf = len(buf)
                untried = node.untried
                if untried:
                    a = untried.pop()
                else:
                    q, na = node.q, node.na
                    cl = c * sqrt(log(node.n))
                    best, a, ties = -inf, 0, None
                    for x in actions:
                        s = q[x] + cl / sqrt(na[x])
                        if s > best:
                            best, a, ties = s, x, None
                        elif s == best:
                            ties = [a, x] if ties is None else [*ties, x]
                    if ties is not None:
                        a = ties[int(buf[ui] * len(ties))]
                        ui += 1
                cum = node.cum[a]
                z = bisect_right(cum, buf[ui] * cum[-1])
                ui += 1
                if z >= Z:
                    z = self._last_possible(cum)
                k = a * Z + z
                child = kids[k]
                if child is None:
                    child = kids[k] = Node(node.post[k], node.crho[k], node.depth + 1)
                    created += 1
                path.append((node, a, k))
                node = child
            if leaf_kind == "rollout":
                g = rollout(node.b, node.rho)
            elif leaf_kind == "rho":
                g = max(node.rho)
            else:
                g = 0.0
            n = node.n = node.n + 1
            if node.depth > deepest:
                deepest = node.depth
            if bellman:
                # the leaf's value is the mean of its evaluations; up the path, the partial Bellman
                # backup Q(b, a) = rho(b, a) + gamma sum eta V / sum eta over the visited children
                old = None if n == 1 else node.v
                new = node.v = g if n == 1 else node.v + (g - node.v) / n
                for parent, a, k in reversed(path):
                    e = parent.eta[k]
                    sw, sn = parent.sw, parent.sn
                    if old is None:
                        sw[a] += e * new
                        sn[a] += e
                    else:
                        sw[a] += e * (new - old)
                    q = parent.q
                    q[a] = parent.rho[a] + gamma * sw[a] / sn[a]
                    parent.n += 1
                    parent.na[a] += 1
                    old = parent.v if parent.n > 1 else None
                    new = parent.v = max(q)
            else:
                for parent, a, _ in reversed(path):
                    g = parent.rho[a] + gamma * g
                    parent.n += 1
                    na = parent.na
                    n = na[a] + 1
                    na[a] = n
                    q = parent.q
                    q[a] += (g - q[a]) / n
            done += 1
            if clock() >= deadline:
                hit = done < limit
                break
        self._ubuf, self._ui = buf, ui
        return done, created, deepest, hit, expanded

    def _rollout(self, b: np.ndarray, rho: list[float]) -> float:
        """The leaf value of ``leaf="rollout"``: greedy rewards for ``rollout_depth`` steps plus the tail."""
        g, rho_end = self._greedy_path(b, rho, self.rollout_depth, self._gamma, self._runi, self.tail == "leaf")
        if self.tail == "average":
            return g + self._tail_factor * self._average_reward
        if self.tail == "leaf":
            return g + self._tail_factor * max(rho_end)
        return g

    def _greedy_path(self, b: np.ndarray, rho: list[float], steps: int, gamma: float, uni: _Uniforms,
                     last_update: bool = False) -> tuple[float, list[float]]:
        """``sum_t gamma^t rho(b_t, a_t)`` over ``steps`` greedy steps ``a_t = argmax_a rho(b_t, a)``
        along one sampled observation path with exact Bayes updates; and ``rho(b_steps, .)`` if
        ``last_update`` (else the last belief is not computed and ``rho(b_{steps-1}, .)`` returned).

        The belief is carried unnormalised (``u``, mass ``m``): ``u @ K[a]`` gives ``m eta``,
        ``m eta tau . r`` and ``m eta tau`` for every observation, and the next mass is the
        sampled observation's ``m eta``. ``rho`` of the next belief then needs, for Renyi's
        entropy, one dot product ``u . u``.
        """
        A, Z, S = self._A, self._Z, self._S
        ZA = Z + Z * A
        w, K, kind = self._w, self._K, self._kind
        g = 0.0
        disc = 1.0
        u = b
        buf, i = uni.buf, uni.i
        for t in range(steps):
            a = max(range(A), key=rho.__getitem__)
            g += disc * rho[a]
            disc *= gamma
            if t == steps - 1 and not last_update:
                break
            X = np.dot(u, K[a])
            head = X[:ZA].tolist()
            cum = list(accumulate(head[:Z]))
            if i >= len(buf):
                buf, i = uni.rng.random(_RANDOM_BLOCK).tolist(), 0
            z = bisect_right(cum, buf[i] * cum[-1])
            i += 1
            if z >= Z:
                z = self._last_possible(cum)
            m = head[z]
            u = X[ZA + z * S:ZA + (z + 1) * S]
            lin = head[Z + z * A:Z + (z + 1) * A]
            if kind == "renyi2":
                l2 = math.log(float(np.dot(u, u)) / (m * m))
                rho = [lin[k] / m + w[k] * l2 for k in range(A)]
            elif kind == "none":
                rho = [x / m for x in lin]
            else:
                f = float(self._f(u / m))
                rho = [lin[k] / m - w[k] * f for k in range(A)]
            if m < _RENORMALISE_BELOW:
                u = u / m
        uni.buf, uni.i = buf, i
        return g, rho

    def _reusable(self, old: _Node, action: int, b: np.ndarray) -> _Node | None:
        """The child of ``old`` under ``action`` whose posterior equals ``b`` (rounding aside)."""
        if old.kids is None or not is_integer(action) or not 0 <= action < self._A:
            return None
        Z = self._Z
        rows = old.post[action * Z:(action + 1) * Z]
        err = np.abs(rows - b).max(axis=1)
        z = int(np.argmin(err))
        if not err[z] <= REUSE_ATOL or old.cum[action][z] <= (old.cum[action][z - 1] if z else 0.0):
            return None
        k = action * Z + z
        child = old.kids[k]
        if child is None:
            child = _Node(old.post[k], old.crho[k], old.depth + 1)
        return child


class BeliefMCTSPolicy:
    """A closed-loop policy that runs :class:`BeliefMCTS` at every decision (``act(belief)``).

    ``simulations`` and/or ``time_budget`` per decision; ``reuse`` keeps the subtree of the
    observed posterior between consecutive decisions. ``last`` is the last :class:`MCTSResult`.
    """

    def __init__(self, planner: BeliefMCTS, simulations: int | None = None, time_budget: float | None = None,
                 reuse: bool = True):
        self.planner = planner
        self.simulations = None if simulations is None else check_int(simulations, "simulations", 1)
        self.time_budget = None if time_budget is None else check_number(time_budget, "time_budget", 0.0)
        self.reuse = bool(reuse)
        self.last: MCTSResult | None = None

    def act(self, belief: np.ndarray) -> int:
        """One decision, with the cyclic garbage collector paused (:mod:`.gc_pause`: the tree is
        acyclic, so reference counting frees the old one; a collection scanning the rest of the
        process would otherwise land inside the decision)."""
        with paused_gc():
            last = self.last if self.reuse else None
            self.last = None  # drop the old tree before building the new one
            self.last = self.planner.search(belief, self.simulations, self.time_budget, previous=last,
                                            action=None if last is None else last.action)
            del last  # the rest of the old tree is freed here, inside the decision, not later
        return self.last.action


#: The largest ``simulations`` per decision a user may ask for (:data:`~.options.SIMULATIONS_RANGE`).
MAX_SIMULATIONS = SIMULATIONS_RANGE[1]
#: The largest ``rollout_depth`` a user may ask for (:data:`~.options.ROLLOUT_DEPTH_RANGE`).
MAX_ROLLOUT_DEPTH = ROLLOUT_DEPTH_RANGE[1]


#: Options of :func:`make_belief_mcts_policy` and their defaults.
POLICY_OPTIONS: dict[str, Any] = {
    "time_budget": None, "simulations": None, "max_depth": DEFAULT_MAX_DEPTH, "exploration": None,
    "exploration_scale": DEFAULT_EXPLORATION_SCALE, "leaf": "rollout", "rollout_depth": DEFAULT_ROLLOUT_DEPTH,
    "tail": "average", "backup": DEFAULT_BACKUP, "seed": 0, "reuse": True,
}


def make_belief_mcts_policy(model: POMDP, options: Mapping[str, Any] | None = None) -> BeliefMCTSPolicy:
    """Build a :class:`BeliefMCTSPolicy` from ``options`` (keys of :data:`POLICY_OPTIONS`).

    ``time_budget`` (seconds per decision) and/or ``simulations``; neither:
    :data:`DEFAULT_SIMULATIONS` simulations. Values come typed (numbers, strings for ``leaf``,
    ``tail``, ``backup``; ``reuse`` as a yes/no flag, :func:`~.checks.parse_flag`, also as the command
    line's ``--option KEY=VALUE`` gives it); ``None`` means the default. Other keys are ignored (the
    policy registry passes every policy the same options). A bad value raises ``OptionError``
    naming the option.
    """
    opts = dict(POLICY_OPTIONS)
    opts.update({k: v for k, v in (options or {}).items() if k in POLICY_OPTIONS and v is not None})
    # user-facing ranges, checked here: the checks of BeliefMCTS and BeliefMCTSPolicy would accept
    # an absurd but well-typed value (time_budget=1e9 or rollout_depth=1e8 would stall a run)
    if opts["time_budget"] is not None:
        check_time_budget(opts["time_budget"], "time_budget", TIME_BUDGET_RANGE)
    check_depth(opts["max_depth"], "max_depth", MAX_DEPTH_RANGE)
    if opts["simulations"] is not None:
        check_int(opts["simulations"], "simulations", *SIMULATIONS_RANGE)
    check_int(opts["rollout_depth"], "rollout_depth", *ROLLOUT_DEPTH_RANGE)
    reuse = parse_flag(opts["reuse"], "reuse")
    planner = BeliefMCTS(model, exploration=opts["exploration"], exploration_scale=opts["exploration_scale"],
                         max_depth=opts["max_depth"], leaf=opts["leaf"], rollout_depth=opts["rollout_depth"],
                         tail=opts["tail"], backup=opts["backup"], seed=opts["seed"])
    return BeliefMCTSPolicy(planner, simulations=opts["simulations"], time_budget=opts["time_budget"],
                            reuse=reuse)
