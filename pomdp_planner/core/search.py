"""Branch-and-bound tree search with myopic policy bounds (paper Sec. V, Algorithm 1).

Depth and node counting follow the paper's Table II (Sec. VI-A): a search of *depth* ``d``
builds the tree of ``d`` action-observation levels below the root. Level 0 is the root
``b0``; level ``i`` holds the beliefs reachable after ``i`` decisions, at most
``N_i = (A Z)^i`` of them, so a complete tree has ``sum_{i=0}^d (A Z)^i`` belief nodes
(:func:`complete_tree_nodes`). Beliefs at level ``d`` are leaves, valued ``max_a rho(b, a)``
over *all* actions. In the notation of Algorithm 1 our depth ``d`` is ``Search(b0, d + 1)``
(the algorithm's ``d = 1`` is the leaf).

At every non-leaf node ``b`` the actions expanded are ``A ∩ [lower(b), upper(b)]`` from a
:class:`~pomdp_planner.core.myopic.MyopicBounds`; the exhaustive baseline is the *same code*
with :class:`~pomdp_planner.core.myopic.TrivialBounds` (``[0, A-1]``), the action filter being
the only difference. If a bounds object ever returns ``lower > upper`` at a node (impossible
for valid bounds, possible for arbitrary ``g, h``) the node keeps all actions, rather than none.

Node counting: ``nodes_expanded[i]`` is the number of belief nodes in the tree of depth
``i + 1`` (root, internal nodes and leaves; what Table II counts), ``nodes_pruned[i]`` the
complete-tree count minus it, and the percentage pruned is ``100 (1 - expanded / complete)``.
The B&B tree of depth ``d`` contains the tree of every smaller depth (bounds depend on the
belief only), so one search gives the counts of all depths ``1..d``.

Observation branches with ``eta(z | b, a) <= ETA_SKIP`` (the filter's ``ETA_MIN``) are not
generated: they are impossible, contribute ``eta * V = 0`` to the Q value, and count as
*not expanded* (so, for models with zero observation probabilities, even exhaustive search
"prunes" relative to the complete-tree formula; the tracking models reach every branch from
a full-support belief because ``P > 0``).

Speed: the tree is processed level by level on arrays of beliefs, in chunks (depth-first over
chunks, so memory stays bounded at any depth). The leaf level, which dominates, needs no
posterior beliefs: for a batch of parents with predicted beliefs ``b^a``, with
``u = b^a ∘ O[a][:, z]`` and ``eta = sum u``,
``eta * V(leaf) = max_a' (u · r_a' - w_a' eta f(u / eta))`` where ``u · r_a'``, ``eta`` and

* Renyi: ``eta f = -eta log(sum_s u_s^2 / eta^2)``, ``sum_s u_s^2 = (b^a)^2 @ O[a]^2``;
* Shannon: ``eta f = eta log eta - sum_s u_s log u_s`` with
  ``sum_s u_s log u_s = (b^a log b^a) @ O[a] + b^a @ (O[a] log O[a])``

are all matrix products. Branches with tiny ``eta < ETA_FUSED_MIN`` (where ``u_s^2`` could
underflow) are recomputed from the normalised posterior, so no division blows up. Products
over the small ``S`` dimension are ``einsum`` loops, not BLAS calls: on a shared 2-core
machine multi-threaded BLAS waiting for a busy core made the leaf level several times slower.

Leaf tables: ``eta`` and ``u · r_a'`` for every ``a'`` are one product per action. Up to
:data:`FUSED_TABLE_MAX_BYTES` the planner keeps the *fused* table ``WT[a]`` (rows ``O[a][:, z]``
and ``O[a][:, z] r[:, a']``: ``A (A + 1) Z S`` floats) and multiplies it with ``b^a``; beyond it
(2.3 GiB at S = Z = 256, A = 64, seconds to fill) it multiplies ``O[a]^T`` with ``b^a`` stacked
with ``r_a' ∘ b^a``: the same sums with the products taken in another order (equal up to
rounding), ``S (A + 1)`` floats per parent of temporary instead of the table, and no slower at
that size (``pomdp-planner bench configure``).

Anytime (:meth:`Planner.plan`): iterative deepening ``1..max_depth``; the deadline is checked
before every chunk (about 4 MB of work, a few ms), an interrupted depth is discarded and the
deepest completed one returned; depth 1 ignores the deadline; a depth predicted not to finish
is not started (:func:`next_depth_cannot_finish`). If the root bounds agree and the planner's
bounds are *guaranteed* (Assumption 1 holds and the LP is feasible: the gate of
:mod:`~pomdp_planner.core.gate` decides, and only it builds guaranteed planners) the action is
certified (Proposition 1) and ``plan`` returns after depth 1 of that one action (the other Q
values are ``nan``); :meth:`Planner.search` always searches the depth it is given. Bounds
without the guarantee (a model failing Assumption 1 pruned on the user's explicit request, or
arbitrary bounds given to the constructor) still prune, but never certify: agreeing root bounds
prove nothing then, so the anytime search does not stop early and deepens as the budget allows.
Crossed root bounds (lower > upper; impossible for valid bounds) are reported as such
(:attr:`SearchResult.crossed`).
The bounds bracket the infinite-horizon optimal action, not a finite lookahead's argmax, so
B&B and exhaustive search may choose differently; B&B's value never exceeds exhaustive's, and
they agree whenever no node of the exhaustive-optimal subtree has its argmax pruned
(docs/THEORY.md).
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .belief import ETA_MIN, check_belief
from .checks import check_int
from .errors import BeliefError, OptionError, short_repr
from .model import POMDP, format_bytes, priority_of
from .myopic import MyopicBounds, TrivialBounds, argmax_smallest, transform_matrix
from .options import MAX_DEPTH_RANGE as MAX_DEPTH_RANGE  # re-exported: the ranges live in options.py
from .options import TIME_BUDGET_RANGE as TIME_BUDGET_RANGE
from .options import check_depth, check_time_budget

#: Observation branches with ``eta <= ETA_SKIP`` are impossible and not generated.
ETA_SKIP = ETA_MIN
#: Below this ``eta`` the fused leaf formulas are replaced by the normalised computation.
ETA_FUSED_MIN = 1e-100
#: Leaf chunks of at most this many parents evaluate all actions in one batch.
LEAF_STACK_MAX = 256
#: A leaf chunk's action computed for all parents (and masked) if at least this share may take it.
LEAF_GATHER_FRACTION = 0.7
#: Anytime stop rule: depth ``d + 1`` is not started when its predicted time exceeds this many
#: times the budget left (prediction: last depth's time times its growth over the depth before).
PREDICT_MARGIN = 1.5
#: Default memory budget (bytes) for one chunk of the leaf level.
DEFAULT_CHUNK_BYTES = 4 * 2**20
#: Default memory budget (bytes) of one search: 1 GiB (``Planner(memory_budget=...)`` overrides it).
DEFAULT_MEMORY_BUDGET = 2**30
#: Deepest search accepted: the search recurses once per level (Python's stack is finite), and
#: any depth near this has ``(A Z)^d`` leaves, far beyond any time budget unless ``A = Z = 1``.
MAX_SEARCH_DEPTH = 100
#: A fixed-depth search whose complete tree (:func:`complete_tree_nodes`, what exhaustive search
#: expands and an upper bound of what branch-and-bound expands) has more belief nodes than this
#: is refused by the entry points (:func:`check_tree_size`) unless the user lifts the limit:
#: at the 25-35 M nodes/s measured for exhaustive search on the S = 8 model, 1e10 nodes take
#: minutes, and every further level multiplies that by ``A Z`` (24 there). The anytime search
#: (under a time budget) is not limited: its deadline stops it.
MAX_TREE_NODES = 10**10
#: Fixed part of :func:`search_memory_estimate` (root arrays, results, small temporaries).
SEARCH_OVERHEAD_BYTES = 64 * 2**10
#: Fixed part of :func:`planner_table_bytes` (the planner object and its array headers).
TABLE_OVERHEAD_BYTES = 8 * 2**10
#: The planner builds the fused leaf table (module docstring, "Leaf tables") only up to this size.
FUSED_TABLE_MAX_BYTES = 64 * 2**20

Bounds = MyopicBounds | TrivialBounds


def complete_level_sizes(A: int, Z: int, depth: int) -> tuple[int, ...]:
    """``N_i = (A Z)^i`` for ``i = 0..depth``: beliefs at each level of a complete tree (Table II)."""
    return tuple((A * Z) ** i for i in range(depth + 1))


def complete_tree_nodes(A: int, Z: int, depth: int) -> int:
    """``sum_{i=0}^depth (A Z)^i``: belief nodes of the complete tree of ``depth`` (Sec. VI-A)."""
    return sum(complete_level_sizes(A, Z, depth))


def count_text(n: int) -> str:
    """A node count in three significant digits (``1.1e+11``), also beyond the range of a float."""
    return f"{n:.3g}" if n < 10**300 else f"about 1e{len(str(n)) - 1}"


class SearchSizeError(OptionError):
    """A fixed-depth search whose tree is too large to finish in reasonable time (:data:`MAX_TREE_NODES`);
    an :class:`~.errors.OptionError`, so the command line reports it as exit code 2."""


def check_tree_size(A: int, Z: int, depth: int, field: str = "depth", limit: int | None = None,
                    hint: str = "") -> int:
    """Refuse (:class:`SearchSizeError`) a fixed-depth search whose complete tree has more than
    ``limit`` belief nodes (default :data:`MAX_TREE_NODES`, read when called); returns the node
    count. The message gives the count, the limit and the deepest depth within it, then ``hint``
    (how the caller's user lifts the limit or switches to the anytime search)."""
    limit = MAX_TREE_NODES if limit is None else int(limit)
    nodes = complete_tree_nodes(A, Z, depth)
    if nodes <= limit:
        return nodes
    fits = 0
    while fits < depth and complete_tree_nodes(A, Z, fits + 1) <= limit:
        fits += 1
    deepest = f"the deepest depth within it is {fits}" if fits else "not even depth 1 is within it"
    raise SearchSizeError(
        f"{field}: a search of depth {depth} has up to {count_text(nodes)} belief nodes (complete tree, "
        f"A={A}, Z={Z}; branch-and-bound prunes an unknown share), more than the limit of "
        f"{count_text(limit)} (MAX_TREE_NODES: minutes of search); {deepest}" + (f"; {hint}" if hint else ""))


def next_depth_cannot_finish(depth_times: Sequence[float], remaining: float, margin: float = PREDICT_MARGIN) -> bool:
    """The anytime stop rule of :meth:`Planner.plan`: is the next depth hopeless?

    ``depth_times`` are the times of the completed depths ``1..d``; the next depth is predicted
    to take ``t_d * max(1, t_d / t_{d-1})`` and is hopeless when that exceeds ``margin *
    remaining``. With fewer than two depths there is no growth to go by: never hopeless.
    """
    if len(depth_times) < 2:
        return False
    t_prev, t_last = float(depth_times[-2]), float(depth_times[-1])
    growth = t_last / t_prev if t_prev > 0.0 else 1.0
    return t_last * max(1.0, growth) > margin * max(remaining, 0.0)


class SearchMemoryError(OptionError):
    """A search would need more memory than the planner's budget (the message gives both figures).

    An :class:`~.errors.OptionError` (hence a ``ValueError``), like the other refusals of a request
    the planner cannot serve, so the command line reports it as exit code 2."""


def _chunk_sizes(S: int, A: int, Z: int, chunk_bytes: int) -> tuple[int, int, int]:
    """``(leaf chunk, expand chunk, bytes per leaf parent)``: parents per chunk of :class:`Planner`."""
    per_parent = 8 * (Z * (1 + 3 * A + 4) + 2 * S)  # leaf: about (Z + 3 Z A + 4 Z + 2 S) floats per parent
    leaf = max(64, int(chunk_bytes // per_parent))
    expand = max(16, int(chunk_bytes // (8 * A * Z * (S + 4))))
    return leaf, expand, per_parent


def search_memory_estimate(S: int, A: int, Z: int, depth: int, chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> int:
    """Upper estimate of the peak bytes that :class:`Planner` allocates for a depth-``depth`` search.

    The search is depth-first over chunks (module docstring), so memory does not grow with the
    tree, ``(A Z)^depth`` leaves, but with the depth: at its deepest point it holds, for every
    level ``k = 1 .. depth - 1``, the children of one chunk of the level above, at most
    ``n_k = min(n_{k-1}, E) A Z`` columns (``n_0 = 1``, ``E`` parents per expand chunk), each
    with its belief (``S`` floats), ``Q`` values and allowed actions (``A`` each), key, ``eta``
    and ``rho`` (``3 A`` floats with bounds: ``rho`` is a view of the bounds' product); plus the
    temporaries of one expansion (about ``3 S A Z`` floats per parent) or of one leaf chunk
    (whichever is larger: they never coexist); a quarter more for the small temporaries around
    them, plus a fixed :data:`SEARCH_OVERHEAD_BYTES`. Exhaustive search reaches these sizes;
    branch-and-bound prunes, so it needs at most as much (``tracemalloc`` peaks are below the
    estimate in test/test_search_memory.py). Once ``n_k`` saturates, each further level adds
    ``E A Z`` columns: an estimated 9.8 MB per level for S = Z = 8, A = 3 with the default
    ``chunk_bytes`` (RSS measured: about 5.7 MB per level).
    """
    leaf, expand, per_parent = _chunk_sizes(S, A, Z, chunk_bytes)
    per_column = 8 * (S + 4 * A + 2) + A
    total, n, widest = 0, 1, 1
    for _ in range(1, depth):
        widest = min(n, expand)
        n = widest * A * Z
        total += n * per_column
    expansion = (8 * (3 * S + 4) + 1) * A * Z * widest if depth > 1 else 0
    leaf_chunk = 3 * per_parent * min(leaf, n) // 2
    return 5 * (total + max(expansion, leaf_chunk)) // 4 + SEARCH_OVERHEAD_BYTES


def fused_table_bytes(S: int, A: int, Z: int) -> int:
    """Bytes of the fused leaf table ``WT`` (module docstring, "Leaf tables"): ``A (A + 1) Z S`` floats."""
    return 8 * A * (A + 1) * Z * S


def uses_fused_table(S: int, A: int, Z: int, fused: bool | None = None) -> bool:
    """Whether :class:`Planner` builds the fused leaf table: ``fused`` if given, else when it takes
    at most :data:`FUSED_TABLE_MAX_BYTES`."""
    return fused_table_bytes(S, A, Z) <= FUSED_TABLE_MAX_BYTES if fused is None else bool(fused)


def planner_table_bytes(S: int, A: int, Z: int, fused: bool | None = None) -> int:
    """Peak bytes :class:`Planner` allocates when it is built (its tables, before any search).

    The fused leaf table ``WT`` (module docstring, "Leaf tables": ``A (A + 1) Z S`` floats) when
    :func:`uses_fused_table` says so; then ``O`` transposed twice and one table of the leaf
    formula (``O`` squared or ``O log O``: ``(A, Z, S)`` each), three ``(A, Z, S)`` temporaries
    while that one is built, ``P`` transposed (``A S^2``), ``r`` twice, and the action masks
    (``A^3`` bytes), plus :data:`TABLE_OVERHEAD_BYTES`. Needs only the sizes, so an entry point can
    refuse before it builds anything. (``count_nodes`` builds two more ``(A, Z, S)`` tables on its
    first call.)"""
    floats = 6 * A * Z * S + A * S * S + 2 * S * A
    table = fused_table_bytes(S, A, Z) if uses_fused_table(S, A, Z, fused) else 0
    return table + 8 * floats + A**3 + A * Z + TABLE_OVERHEAD_BYTES


def deepest_depth_within_budget(S: int, A: int, Z: int, upto: int, memory_budget: int,
                                chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> int:
    """The deepest depth ``<= upto`` (and ``<= MAX_SEARCH_DEPTH``) whose :func:`search_memory_estimate`
    is within ``memory_budget`` bytes; 0 if not even depth 1 is (the estimate grows with the depth)."""
    fits = 0
    while fits < min(upto, MAX_SEARCH_DEPTH) and \
            search_memory_estimate(S, A, Z, fits + 1, chunk_bytes) <= memory_budget:
        fits += 1
    return fits


def check_search_memory(S: int, A: int, Z: int, depth: int, memory_budget: int, name: str = "depth",
                        chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> None:
    """Refuse (:class:`SearchMemoryError`) a search of ``depth`` beyond :data:`MAX_SEARCH_DEPTH` or
    whose :func:`search_memory_estimate` exceeds ``memory_budget`` bytes; the message (starting with
    ``name``) gives the figures and the deepest depth that fits. Needs only the sizes, so an entry
    point can refuse before it builds anything."""
    nodes = count_text(complete_tree_nodes(A, Z, min(depth, MAX_SEARCH_DEPTH)))
    if depth > MAX_SEARCH_DEPTH:
        raise SearchMemoryError(f"{name}: {depth} is deeper than MAX_SEARCH_DEPTH = {MAX_SEARCH_DEPTH} (a complete "
                                f"tree of depth {MAX_SEARCH_DEPTH} already has {nodes} belief nodes)")
    need = search_memory_estimate(S, A, Z, depth, chunk_bytes)
    if need <= memory_budget:
        return
    fits = deepest_depth_within_budget(S, A, Z, depth, memory_budget, chunk_bytes)
    deepest = f"the deepest depth within it is {fits}" if fits else "not even depth 1 fits"
    raise SearchMemoryError(
        f"{name}: a search of depth {depth} needs about {format_bytes(need)} (estimate for S={S}, A={A}, "
        f"Z={Z}; complete tree {nodes} belief nodes), more than the memory budget of "
        f"{format_bytes(memory_budget)}; {deepest}")


class DeadlineExceeded(Exception):
    """Raised inside a depth when the wall-clock deadline passes: :meth:`Planner.plan` catches it
    (never lets it escape); :meth:`Planner.search` with a ``deadline`` raises it to its caller."""


@dataclass(frozen=True)
class SearchResult:
    """The outcome of :meth:`Planner.search` or :meth:`Planner.plan`.

    ``action`` is 0-based (``priority = action + 1`` is the paper's tracking priority).
    ``q_values[a]`` is the depth-``depth`` estimate ``Q(b0, a)`` of Algorithm 1, ``nan`` for
    actions pruned at the root. ``nodes_expanded[i]`` / ``nodes_pruned[i]`` refer to the
    tree of depth ``i + 1`` (see the module docstring). ``certified`` means the root bounds
    agree and are guaranteed (``guaranteed``: Assumption 1 holds, the LP is feasible), so the
    action is the optimal one (Proposition 1); ``crossed``: the root bounds cross (lower > upper),
    which valid bounds never do.
    """

    action: int
    priority: int
    q_values: np.ndarray
    depth: int
    nodes_expanded: tuple[int, ...]
    nodes_pruned: tuple[int, ...]
    certified: bool
    root_bounds: tuple[int, int] | None
    time_used: float
    deadline_hit: bool
    value: float = math.nan
    level_sizes: tuple[int, ...] = ()
    used_bounds: bool = True
    depth_times: tuple[float, ...] = field(default=())
    predicted_stop: bool = False
    guaranteed: bool = False

    @property
    def crossed(self) -> bool:
        """The root bounds cross (``lower > upper``): no guarantee, every action was searched."""
        return self.root_bounds is not None and self.root_bounds[0] > self.root_bounds[1]

    @property
    def complete_nodes(self) -> tuple[int, ...]:
        """Complete-tree node counts for depths ``1..depth`` (formula)."""
        return tuple(e + p for e, p in zip(self.nodes_expanded, self.nodes_pruned, strict=True))

    @property
    def percent_pruned(self) -> tuple[float, ...]:
        """``100 (1 - expanded / complete)`` per depth ``1..depth`` (Table II's figure)."""
        return tuple(100.0 * p / (e + p) for e, p in zip(self.nodes_expanded, self.nodes_pruned, strict=True))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary; actions as priorities ``1..A``, ``nan`` Q values as ``None``."""
        q = [None if not math.isfinite(x) else float(x) for x in np.asarray(self.q_values, dtype=float)]
        return {
            "action": int(self.priority),
            "q_values": q,
            "value": float(self.value) if math.isfinite(self.value) else None,
            "depth": int(self.depth),
            "nodes_expanded": [int(x) for x in self.nodes_expanded],
            "nodes_pruned": [int(x) for x in self.nodes_pruned],
            "nodes_complete": [int(x) for x in self.complete_nodes],
            "percent_pruned": [round(x, 4) for x in self.percent_pruned],
            "certified": bool(self.certified),
            "guaranteed": bool(self.guaranteed),
            "root_bounds": None if self.root_bounds is None else [int(x) + 1 for x in self.root_bounds],
            "root_bounds_crossed": bool(self.crossed),
            "used_bounds": bool(self.used_bounds),
            "time_used": float(self.time_used),
            "deadline_hit": bool(self.deadline_hit),
            "predicted_stop": bool(self.predicted_stop),
        }


def _mm(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``M @ X`` for a small ``M`` (``k x S``) and a wide ``X`` (``S x n``), single-threaded.

    ``einsum`` runs its own vectorised loops instead of a multi-threaded BLAS; on a shared
    machine (other processes, a ROS node) BLAS threads waiting for a busy core made the
    leaf level several times slower, and these products are memory-bound anyway.
    """
    return np.einsum("ks,sn->kn", M, X)


def _xlogx(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.0, x * np.log(np.where(x > 0.0, x, 1.0)), 0.0)


class Planner:
    """Anytime branch-and-bound planner (Algorithm 1) and its exhaustive baseline.

    ``bounds`` is a :class:`MyopicBounds` (or anything with its ``actions(B, rho)``
    interface); ``None`` means :class:`TrivialBounds`, i.e. only exhaustive search.
    ``guaranteed``: the bounds are proven valid for ``model``, so agreeing root bounds certify
    the action (and stop the anytime search); entry points get planners from
    :func:`pomdp_planner.core.gate.build_planner`, which sets it only when Assumption 1 holds
    and the LP is feasible. ``chunk_bytes`` bounds the memory of one chunk (smaller chunks:
    finer deadline checks). ``memory_budget`` bounds the memory of one search: a depth whose
    :func:`search_memory_estimate` exceeds it is refused before it starts
    (:class:`SearchMemoryError`), as is a depth beyond :data:`MAX_SEARCH_DEPTH`. ``clock`` is
    the wall clock used for deadlines and timings (injectable for tests). ``fused``: build the
    fused leaf table (module docstring, "Leaf tables"; ``None``: :func:`uses_fused_table` decides
    by its size); both ways give the same values up to rounding.
    """

    def __init__(self, model: POMDP, bounds: Bounds | None = None, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 clock: Callable[[], float] = time.perf_counter, guaranteed: bool = False,
                 memory_budget: int = DEFAULT_MEMORY_BUDGET, fused: bool | None = None):
        self.model = model
        self.clock = clock
        self.guaranteed = bool(guaranteed) and bounds is not None
        self.chunk_bytes = chunk_bytes
        self.memory_budget = check_int(memory_budget, "memory_budget", 1, note="(bytes)")
        self.trivial = TrivialBounds(model)
        self.bounds = self.trivial if bounds is None else bounds
        if getattr(self.bounds, "model", model) is not model:
            bm = self.bounds.model
            if (bm.S, bm.A, bm.Z) != (model.S, model.A, model.Z):
                raise ValueError("bounds: built for a model of different size")
        self._bound_cache: tuple[Any, np.ndarray] | None = None
        ar = np.arange(model.A)
        lo, up = ar[None, :, None], ar[None, None, :]
        # _range_mask[a, lo, up]: a in [lo, up]; crossed bounds (lo > up) keep every action
        self._range_mask = ((ar[:, None, None] >= lo) & (ar[:, None, None] <= up)) | (lo > up)
        S, A, Z = model.S, model.A, model.Z
        P, O, r = model.P, model.O, model.r
        self.fused = uses_fused_table(S, A, Z, fused)
        self._OT = np.ascontiguousarray(np.swapaxes(O, 1, 2))  # (A, Z, S)
        self._r = np.ascontiguousarray(r)
        self._WT: np.ndarray | None = None
        if self.fused:
            # Transposed leaf matrices: WT[a] rows = O[a][:, z] (z = 0..Z-1), then O[a][:, z] * r[:, a']
            # for a' = 0..A-1 (Z rows each). Filled in place: A^2 S Z floats (planner_table_bytes).
            self._WT = np.empty((A, Z * (A + 1), S))
            self._WT[:, :Z] = self._OT
            for k in range(A):
                np.multiply(self._OT, r[:, k], out=self._WT[:, Z * (k + 1):Z * (k + 2)])
        self._PT = np.ascontiguousarray(np.swapaxes(P, 1, 2))
        self._PTs = self._PT.reshape(A * S, S)  # stacked P[a]^T
        self._OS = np.ascontiguousarray(np.swapaxes(O, 0, 1))  # (S, A, Z)
        self._w = np.asarray(model.w, dtype=float)
        self._rT = np.ascontiguousarray(r.T)
        self._gamma = float(model.gamma)
        self._kind = model.uncertainty.name if model.uncertainty.name in ("none", "renyi2", "shannon") else "generic"
        if self._kind != "none" and not np.any(self._w):
            self._kind = "none"
        # only the leaf formula of the model's uncertainty needs its table
        self._O2T = np.ascontiguousarray(np.swapaxes(O * O, 1, 2)) if self._kind == "renyi2" else None
        self._OlogOT = np.ascontiguousarray(np.swapaxes(_xlogx(O), 1, 2)) if self._kind == "shannon" else None
        self._count_tables: tuple[np.ndarray, np.ndarray] | None = None  # count_nodes only: built on first use
        self._leaf_chunk, self._expand_chunk, _ = _chunk_sizes(S, A, Z, chunk_bytes)

    @property
    def has_bounds(self) -> bool:
        """Whether the planner has informative bounds (not :class:`TrivialBounds`)."""
        return not isinstance(self.bounds, TrivialBounds)

    # ----------------------------------------------------------------- public
    def root_bounds(self, belief: np.ndarray) -> tuple[int, int]:
        """0-based ``(lower, upper)`` myopic bound actions at ``belief``."""
        b = check_belief(self.model, belief)
        rb = self._root(b, self.bounds)[3]
        return (0, self.model.A - 1) if rb is None else rb

    def search(self, belief: np.ndarray, depth: int, use_bounds: bool = True, *, all_root_actions: bool = False,
               deadline: float | None = None) -> SearchResult:
        """Algorithm 1 to ``depth`` action-observation levels (``Search(b, depth + 1)``).

        Always searches the full requested depth (also when the root bounds agree; then
        only one root action is expanded). ``use_bounds=False`` is the exhaustive search.
        ``all_root_actions``: every root action is expanded (the bounds prune below the root
        only), so every Q value is finite; a caller that must compare the root actions under a
        constraint the bounds do not know (the multi-target budget) needs them all.
        ``deadline`` (a reading of :attr:`clock`): checked before every chunk;
        :class:`DeadlineExceeded` is raised when it has passed.
        """
        depth = check_depth(depth)
        self.check_memory(depth, "depth")
        b = check_belief(self.model, belief)
        t0 = self.clock()
        bounds = self.bounds if use_bounds else self.trivial
        root = self._root(b, bounds)
        if all_root_actions:
            root = (*root[:2], np.ones_like(root[2]), root[3])
        q, sizes = self._run(root, depth, bounds, deadline)
        t = self.clock() - t0
        return self._result(q, sizes, depth, root[3], t, False, (t,))

    def plan(self, belief: np.ndarray, max_depth: int, time_budget: float | None = None,
             use_bounds: bool = True, predict_stop: bool = True) -> SearchResult:
        """Anytime search: iterative deepening ``1, 2, ..., max_depth`` under a deadline.

        The deadline (``time_budget`` seconds from the call) is checked between chunks inside
        a depth; an interrupted depth is discarded and the result of the deepest completed
        depth is returned (``deadline_hit=True``). Depth 1 always completes. If guaranteed
        bounds agree at the root the action is certified: the planner returns at once after the
        (tiny) depth-1 search of that single action, so the other Q values are ``nan``.
        Bounds without the guarantee never stop it early (module docstring).

        ``predict_stop``: after two completed depths, depth ``d + 1`` is not started when it
        cannot finish: its predicted time (time of depth ``d`` times the growth ``t_d / t_{d-1}``)
        exceeds :data:`PREDICT_MARGIN` times the budget left. An interrupted depth is discarded
        anyway, so this returns the same decision sooner (``deadline_hit`` and
        ``predicted_stop`` set); the growth measured at shallow depths underestimates the real
        one (fixed per-call costs), so the rule errs towards trying.
        """
        max_depth = check_depth(max_depth, "max_depth")
        self.check_memory(max_depth, "max_depth")
        if time_budget is not None:
            time_budget = check_time_budget(time_budget)
        b = check_belief(self.model, belief)
        t0 = self.clock()
        deadline = None if time_budget is None else t0 + time_budget
        bounds = self.bounds if use_bounds else self.trivial
        best: tuple[np.ndarray, list[int], int] | None = None
        hit = predicted = False
        times: list[float] = []
        root = self._root(b, bounds)  # rho, allowed actions and bounds at b: once per call
        last = 1 if self._is_certified(root[3]) else max_depth
        for d in range(1, last + 1):
            ts = self.clock()
            try:
                q, sizes = self._run(root, d, bounds, None if d == 1 else deadline)
            except DeadlineExceeded:
                hit = True
                break
            best = (q, sizes, d)
            now = self.clock()
            times.append(now - ts)
            if deadline is None or d == last:
                continue
            if now >= deadline:
                hit = True
                break
            if predict_stop and next_depth_cannot_finish(times, deadline - now):
                hit = predicted = True
                break
        assert best is not None  # depth 1 runs without a deadline
        q, sizes, d = best
        return self._result(q, sizes, d, root[3], self.clock() - t0, hit, tuple(times), predicted)

    def priced(self, action_cost: np.ndarray | Sequence[float]) -> Planner:
        """This planner for the rewards ``r[s, a] - action_cost[a]``: an action-only price, e.g.
        ``lambda e(a)`` of the multi-target relaxation (``core/multitarget``).

        A shallow copy; only the reward arrays differ (``rho(b, a) - action_cost[a]`` everywhere,
        leaves included), so a copy costs microseconds. The bounds and ``guaranteed`` carry over
        unchanged: an action-only term changes neither Assumption 1 (``P``, ``O`` only) nor the
        Theorem 2 LP (its rows hold differences of ``r_a`` over states, where a constant per action
        cancels), so the same ``g, h`` bound the optimal policy of the priced problem for every
        price (docs/THEORY.md, "Several targets: an action-only price"). The myopic bound actions
        move with the price; the guarantee does not. ``self.model`` stays the unpriced model.
        """
        A = self.model.A
        try:
            c = np.asarray(action_cost, dtype=float)
        except (TypeError, ValueError):
            c = np.full(0, np.nan)
        if c.shape != (A,) or not np.all(np.isfinite(c)):
            raise OptionError(f"action_cost: expected {A} finite numbers (one per action), "
                              f"got {short_repr(action_cost)}")
        new = copy.copy(self)
        # every table that holds r: r itself (the unfused leaf products), r^T (rho, bounds), and
        # the fused leaf table when there is one
        new._r = np.ascontiguousarray(self._r - c[None, :])
        new._rT = np.ascontiguousarray(new._r.T)
        if self._WT is not None:
            # _WT[a] = [O[a]^T; (O[a] * r[:, a'])^T for a' = 0..A-1]: the reward blocks lose c[a'] O[a]^T.
            WT = self._WT.reshape(A, 1 + A, self.model.Z, self.model.S).copy()
            WT[:, 1:] -= c[None, :, None, None] * WT[:, :1]
            new._WT = np.ascontiguousarray(WT.reshape(self._WT.shape))
        new._bound_cache = None
        return new

    def q_values_batch(self, beliefs: np.ndarray, depth: int, use_bounds: bool = True, *,
                       deadline: float | None = None) -> np.ndarray:
        """``Q(b, a)`` for every row ``b`` of ``beliefs`` (``n x S``) and every action, ``n x A``: the
        root Q values of :meth:`search` with ``all_root_actions=True``, for ``n`` roots in one
        vectorised pass (the roots are columns of the first level, as every level's beliefs are).
        ``depth = 0`` gives ``rho(b, a)``. ``deadline`` as in :meth:`search`."""
        depth = check_depth(depth, "depth", (0, None))
        B = np.asarray(beliefs, dtype=float)
        if B.ndim != 2 or B.shape[1] != self.model.S:
            raise BeliefError(f"beliefs: expected shape n x {self.model.S}, got {B.shape}")
        BT = np.ascontiguousarray(np.stack([check_belief(self.model, b, field=f"beliefs[{i}]")
                                            for i, b in enumerate(B)], axis=1) if len(B) else B.T)
        rhoT = self._rho(BT)
        if depth == 0 or not len(B):
            return np.ascontiguousarray(rhoT.T)
        self.check_memory(depth, "depth")
        bounds = self.bounds if use_bounds else self.trivial
        sizes = [B.shape[0]] + [0] * depth
        QT = self._values(BT, rhoT, np.ones((self.model.A, B.shape[0]), dtype=bool), depth, 0, sizes, bounds, deadline)
        return np.ascontiguousarray(QT.T)

    def count_nodes(self, belief: np.ndarray, depth: int, use_bounds: bool = True) -> tuple[int, ...]:
        """Level sizes ``(n_0, ..., n_depth)`` of the search tree, without valuing the leaves.

        Much cheaper than :meth:`search` at the same depth (the leaf level only needs
        ``eta``); ``nodes_expanded`` of depth ``i`` is ``sum(level_sizes[:i + 1])``.
        """
        depth = check_depth(depth)
        self.check_memory(depth, "depth")
        b = check_belief(self.model, belief)
        bounds = self.bounds if use_bounds else self.trivial
        sizes = [1] + [0] * depth
        BT = np.ascontiguousarray(b[:, None])
        self._count(BT, self._rho_allowed(bounds, BT)[1], depth, 0, sizes, bounds)
        return tuple(sizes)

    def memory_estimate(self, depth: int) -> int:
        """:func:`search_memory_estimate` for this planner's model and chunk size."""
        m = self.model
        return search_memory_estimate(m.S, m.A, m.Z, depth, self.chunk_bytes)

    def deepest_depth_within_budget(self, upto: int) -> int:
        """:func:`deepest_depth_within_budget` for this planner's model, chunk size and budget."""
        m = self.model
        return deepest_depth_within_budget(m.S, m.A, m.Z, upto, self.memory_budget, self.chunk_bytes)

    def check_memory(self, depth: int, name: str = "depth") -> None:
        """:func:`check_search_memory` for this planner's model, chunk size and budget; called
        before every search starts."""
        m = self.model
        check_search_memory(m.S, m.A, m.Z, depth, self.memory_budget, name, self.chunk_bytes)

    # --------------------------------------------------------------- internals
    def _root(self, b: np.ndarray, bounds: Bounds
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int] | None]:
        """``(BT, rho, allowed, root bounds)`` at ``b``: its column, ``rho(b, .)``, the allowed
        actions and the 0-based ``(lower, upper)`` (``None`` for :class:`TrivialBounds`)."""
        BT = np.ascontiguousarray(b[:, None])
        rhoT, lo, up = self._rho_bounds(bounds, BT)
        rb = None if lo is None else (int(lo[0]), int(up[0]))
        return BT, rhoT, self._allowed(lo, up, 1), rb

    def _is_certified(self, rb: tuple[int, int] | None) -> bool:
        """Guaranteed root bounds agree (Proposition 1), or there is only one action."""
        return self.model.A == 1 or (rb is not None and self.guaranteed and rb[0] == rb[1])

    def _rho(self, BT: np.ndarray, linear: np.ndarray | None = None) -> np.ndarray:
        """``rho(b, a)`` (Eq. 3) for beliefs given as columns ``BT (S, n)``; returns ``(A, n)``.

        ``linear`` may carry ``r^T BT`` if already computed (fused with the bounds' product).
        """
        out = _mm(self._rT, BT) if linear is None else linear
        kind = self._kind
        if kind == "none":
            return out
        if kind == "renyi2":
            f = -np.log(np.einsum("sn,sn->n", BT, BT))
        elif kind == "shannon":
            f = -_xlogx(BT).sum(axis=0)
        else:
            f = self.model.uncertainty.value(BT.T)
        out -= self._w[:, None] * f[None, :]
        return out

    def _rho_bounds(self, bounds: Bounds, BT: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """``(rho, lower, upper)`` for the columns ``BT``; ``lower = upper = None`` for
        :class:`TrivialBounds`. For ``MyopicBounds`` one product gives both ``r^T b`` and the
        bound terms ``C_g b``, ``C_h b`` of Eq. 8."""
        if isinstance(bounds, TrivialBounds):
            return self._rho(BT), None, None
        if type(bounds) is not MyopicBounds:
            rhoT = self._rho(BT)
            lo, up = bounds.actions(np.ascontiguousarray(BT.T), np.ascontiguousarray(rhoT.T))
            return rhoT, lo, up
        A = self.model.A
        X = _mm(self._bound_matrix(bounds), BT)  # rows: r^T b (A), C_g b (A), C_h b reversed (A)
        rhoT = self._rho(BT, X[:A])
        T = X[A:].reshape(2, A, -1)
        T[0] += rhoT
        T[1] += rhoT[::-1]
        lo, up = self._first_maximisers(T)
        return rhoT, lo, up

    def _rho_allowed(self, bounds: Bounds, BT: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(rho, allowed)``: boolean ``(A, n)`` of the actions in ``[lower(b), upper(b)]``
        (all of them if the bounds cross, or for :class:`TrivialBounds`)."""
        rhoT, lo, up = self._rho_bounds(bounds, BT)
        return rhoT, self._allowed(lo, up, BT.shape[1])

    def _allowed(self, lo: np.ndarray | None, up: np.ndarray | None, n: int) -> np.ndarray:
        """Boolean ``(A, n)``: ``a`` in ``[lo, up]`` (every action if the bounds cross or are absent)."""
        if lo is None:
            return np.ones((self.model.A, n), dtype=bool)
        return self._range_mask[:, lo, up]

    def _bound_matrix(self, bounds: MyopicBounds) -> np.ndarray:
        """``[r^T; C_g; C_h reversed]`` (``3A x S``), cached for the last bounds object."""
        cache = self._bound_cache
        if cache is None or cache[0] is not bounds:
            Ch = transform_matrix(self.model, bounds.h)[::-1]  # upper: actions in reversed order
            M = np.concatenate([self._rT, transform_matrix(self.model, bounds.g), Ch])
            cache = (bounds, np.ascontiguousarray(M))
            self._bound_cache = cache
        return cache[1]

    def _first_maximisers(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smallest maximiser of ``T[0]`` (lower) and largest of the un-reversed ``T[1]`` (upper):
        the tie rule of :mod:`~pomdp_planner.core.myopic`, over the action axis of columns."""
        first = argmax_smallest(T, axis=1)
        return first[0], self.model.A - 1 - first[1]

    def _result(self, q: np.ndarray, sizes: Sequence[int], depth: int, rb: tuple[int, int] | None,
                t: float, hit: bool, times: tuple[float, ...], predicted: bool = False) -> SearchResult:
        A, Z = self.model.A, self.model.Z
        finite = np.isfinite(q)
        action = int(np.argmax(np.where(finite, q, -np.inf)))
        q = np.where(finite, q, np.nan)
        q.setflags(write=False)
        expanded = tuple(int(sum(sizes[: i + 2])) for i in range(depth))
        pruned = tuple(complete_tree_nodes(A, Z, i + 1) - expanded[i] for i in range(depth))
        certified = self._is_certified(rb)
        return SearchResult(
            action=action, priority=int(priority_of(action)), q_values=q, depth=int(depth),
            nodes_expanded=expanded, nodes_pruned=pruned, certified=bool(certified), root_bounds=rb,
            time_used=float(t), deadline_hit=bool(hit), value=float(q[action]),
            level_sizes=tuple(int(x) for x in sizes), used_bounds=rb is not None,
            depth_times=times, predicted_stop=bool(predicted), guaranteed=self.guaranteed and rb is not None,
        )

    def _run(self, root: tuple, depth: int, bounds: Bounds, deadline: float | None
             ) -> tuple[np.ndarray, list[int]]:
        """Root Q values and level sizes of the depth-``depth`` search from ``root`` (:meth:`_root`)."""
        BT, rhoT, allowed, _ = root
        sizes = [1] + [0] * depth
        QT = self._values(BT, rhoT, allowed, depth, 0, sizes, bounds, deadline)
        return QT[:, 0], sizes

    def _check_deadline(self, deadline: float | None) -> None:
        if deadline is not None and self.clock() > deadline:
            raise DeadlineExceeded

    def _values(self, BT: np.ndarray, rhoT: np.ndarray, allowed: np.ndarray, remaining: int, level: int,
                sizes: list[int], bounds: Bounds, deadline: float | None) -> np.ndarray:
        """``Q(b, a)`` as ``(A, n)`` (``-inf`` where not allowed) for the belief columns ``BT (S, n)``
        with ``remaining`` action-observation levels below them (chunked, depth-first)."""
        A, n = self.model.A, BT.shape[1]
        QT = np.empty((A, n))
        if remaining == 1:
            step = self._leaf_chunk
            for s in range(0, n, step):
                self._check_deadline(deadline)
                QT[:, s:s + step], cnt = self._leaf_q(BT[:, s:s + step], rhoT[:, s:s + step], allowed[:, s:s + step])
                sizes[level + 1] += cnt
            return QT
        step = self._expand_chunk
        for s in range(0, n, step):
            self._check_deadline(deadline)
            al = allowed[:, s:s + step]
            m = al.shape[1]
            CT, key, eta = self._expand(BT[:, s:s + step], al)
            sizes[level + 1] += CT.shape[1]
            rho_c, allowed_c = self._rho_allowed(bounds, CT)
            Qc = self._values(CT, rho_c, allowed_c, remaining - 1, level + 1, sizes,
                              bounds, deadline)
            Vc = Qc.max(axis=0)
            acc = np.bincount(key, weights=eta * Vc, minlength=m * A).reshape(m, A).T
            QT[:, s:s + step] = np.where(al, rhoT[:, s:s + step] + self._gamma * acc, -np.inf)
            del CT, key, eta, rho_c, allowed_c, Qc, Vc, acc  # not held while the next chunk recurses
        return QT

    def _expand(self, BT: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Children of the columns ``BT (S, n)`` under allowed actions and possible observations.

        Eqs. 1-2: ``b^a = b @ P[a]``, ``u = b^a * O[a][:, z]``, ``eta = sum u``, ``tau = u / eta``,
        for all actions at once (then the allowed, possible ones are kept). Returns posteriors as
        columns ``(S, m)`` ordered by (action, observation, parent), key ``parent * A + action``
        and ``eta``.
        """
        S, A, Z = self.model.S, self.model.A, self.model.Z
        n = BT.shape[1]
        Ba = _mm(self._PTs, BT).reshape(A, S, n).transpose(1, 0, 2)  # (S, A, n)
        unnorm = (self._OS[:, :, :, None] * Ba[:, :, None, :]).reshape(S, A * Z * n)  # column (a, z, parent)
        eta = unnorm.sum(axis=0)
        keep = (eta.reshape(A, Z, n) > ETA_SKIP) & allowed[:, None, :]
        sel = np.flatnonzero(keep)
        e = eta[sel]
        key = (sel % n) * A + sel // (Z * n)
        return unnorm[:, sel] / e, key, e

    def _leaf_q(self, BT: np.ndarray, rhoT: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, int]:
        """``Q(b, a) = rho(b, a) + gamma sum_z eta max_a' rho(tau(b,a,z), a')`` for leaf parents.

        Fused formulas (module docstring): no posterior belief is formed; every per-leaf
        quantity is a contiguous ``Z x n`` block. Returns ``Q`` as ``(A, n)`` (``-inf`` where
        not allowed) and the number of leaves (branches with ``eta > ETA_SKIP``).
        """
        A = self.model.A
        n = BT.shape[1]
        w, kind = self._w, self._kind
        if n <= LEAF_STACK_MAX and kind != "generic" and self._WT is not None:
            out = self._leaf_q_stacked(BT, rhoT, allowed)
            if out is not None:
                return out
        QT = np.full((A, n), -np.inf)
        count = 0
        n_allowed = allowed.sum(axis=1)
        for a in range(A):
            masked = None  # columns computed but not allowed (cheaper than gathering when few)
            if n_allowed[a] == 0:
                continue
            if n_allowed[a] >= LEAF_GATHER_FRACTION * n:
                idx = slice(None)
                Ba = _mm(self._PT[a], BT)  # predicted beliefs as columns, (S, m)
                if n_allowed[a] < n:
                    masked = ~allowed[a]
            else:
                idx = np.flatnonzero(allowed[a])
                Ba = _mm(self._PT[a], BT[:, idx])
            XT = self._leaf_products(a, Ba)  # eta (Z x m), then u . r_a' for each a' (Z x m each)
            eta = XT[0]
            ok = eta > ETA_SKIP
            if kind == "none":
                val = XT[1].copy()
                for k in range(1, A):
                    np.maximum(val, XT[1 + k], out=val)
            elif kind == "generic":
                val = self._leaf_generic(Ba, a, eta, ok)
            else:
                with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                    if kind == "renyi2":
                        t = _mm(self._O2T[a], Ba * Ba)  # sum_s u_s^2, (Z, m)
                        np.divide(t, eta * eta, out=t)
                        np.log(t, out=t)
                        t *= eta  # -eta f(tau)
                    else:  # shannon
                        t = _mm(self._OT[a], _xlogx(Ba))
                        t += _mm(self._OlogOT[a], Ba)  # sum_s u_s log u_s
                        t -= eta * np.log(eta)  # -eta f(tau)
                    val = XT[1] + w[0] * t
                    for k in range(1, A):
                        np.maximum(val, XT[1 + k] + w[k] * t, out=val)
                tiny = ok & (eta < ETA_FUSED_MIN)
                if tiny.any():
                    val[tiny] = self._leaf_generic(Ba, a, eta, tiny)[tiny]
            if not ok.all():
                val = np.where(ok, val, 0.0)
            if masked is None:
                count += int(np.count_nonzero(ok))
                QT[a, idx] = rhoT[a, idx] + self._gamma * val.sum(axis=0)
            else:
                count += int(np.count_nonzero(ok[:, ~masked]))
                QT[a] = np.where(masked, -np.inf, rhoT[a] + self._gamma * val.sum(axis=0))
        return QT, count

    def _leaf_products(self, a: int, Ba: np.ndarray) -> np.ndarray:
        """``(A + 1, Z, m)``: ``eta = O[a]^T b^a`` and ``u . r_a'`` for every ``a'``, for the predicted
        beliefs ``Ba (S, m)`` (module docstring, "Leaf tables"): one product with the fused table
        ``WT[a]``, or, without it, ``O[a]^T`` times ``b^a`` stacked with ``r_a' * b^a``."""
        A, Z = self.model.A, self.model.Z
        m = Ba.shape[1]
        if self._WT is not None:
            return _mm(self._WT[a], Ba).reshape(A + 1, Z, m)
        R = np.empty((Ba.shape[0], A + 1, m))
        R[:, 0] = Ba
        np.multiply(self._r[:, :, None], Ba[:, None, :], out=R[:, 1:])
        return _mm(self._OT[a], R.reshape(Ba.shape[0], (A + 1) * m)).reshape(Z, A + 1, m).transpose(1, 0, 2)

    def _leaf_q_stacked(self, BT: np.ndarray, rhoT: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, int] | None:
        """:meth:`_leaf_q` for a few parents: all actions in one batch (fewer numpy calls), then
        the allowed ones kept. Same formulas; ``None`` if some ``eta`` needs the safe path."""
        A, Z = self.model.A, self.model.Z
        w, kind = self._w, self._kind
        Ba = _mm(self._PTs, BT).reshape(A, self.model.S, -1)  # (A, S, n)
        XT = np.einsum("aks,asn->akn", self._WT, Ba)  # (A, Z + Z A, n)
        eta = XT[:, :Z]
        ok = eta > ETA_SKIP
        if kind == "none":
            val = XT[:, Z:2 * Z].copy()
            for k in range(1, A):
                np.maximum(val, XT[:, Z * (1 + k):Z * (2 + k)], out=val)
        else:
            if np.any(ok & (eta < ETA_FUSED_MIN)):
                return None
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                if kind == "renyi2":
                    t = np.einsum("azs,asn->azn", self._O2T, Ba * Ba)
                    np.divide(t, eta * eta, out=t)
                    np.log(t, out=t)
                    t *= eta
                else:  # shannon
                    t = np.einsum("azs,asn->azn", self._OT, _xlogx(Ba))
                    t += np.einsum("azs,asn->azn", self._OlogOT, Ba)
                    t -= eta * np.log(eta)
                val = XT[:, Z:2 * Z] + w[0] * t
                for k in range(1, A):
                    np.maximum(val, XT[:, Z * (1 + k):Z * (2 + k)] + w[k] * t, out=val)
        val = np.where(ok, val, 0.0)
        count = int(np.count_nonzero(ok & allowed[:, None, :]))
        return np.where(allowed, rhoT + self._gamma * val.sum(axis=1), -np.inf), count

    def _leaf_generic(self, BaT: np.ndarray, a: int, eta: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """``eta max_a' rho(tau, a')`` from explicit posteriors, for the ``(z, parent)`` in ``mask``."""
        out = np.zeros(eta.shape)
        zi, pi = np.nonzero(mask)
        if pi.size:
            unnorm = BaT[:, pi].T * self._OT[a][zi]
            tau = unnorm / unnorm.sum(axis=1, keepdims=True)
            out[zi, pi] = eta[zi, pi] * self._rho(np.ascontiguousarray(tau.T)).max(axis=0)
        return out

    def _count(self, BT: np.ndarray, allowed: np.ndarray, remaining: int, level: int, sizes: list[int],
               bounds: Bounds) -> None:
        n = BT.shape[1]
        if remaining == 1:
            if self._count_tables is None:
                PO = self.model.P @ self.model.O  # (A, S, Z): eta(z | b, a) = b @ PO[a][:, z]
                self._count_tables = (np.ascontiguousarray(np.swapaxes(PO, 1, 2)), PO.min(axis=1) > 2.0 * ETA_SKIP)
            POT, sure_obs = self._count_tables
            step = self._leaf_chunk
            for s in range(0, n, step):
                Bp, al = BT[:, s:s + step], allowed[:, s:s + step]
                for a in range(self.model.A):
                    idx = np.flatnonzero(al[a])
                    if not idx.size:
                        continue
                    sure = sure_obs[a]  # eta >= min_s (P O)[a][s, z] > ETA_SKIP for any belief
                    sizes[level + 1] += idx.size * int(np.count_nonzero(sure))
                    if not sure.all():
                        eta = _mm(POT[a][~sure], Bp[:, idx])
                        sizes[level + 1] += int(np.count_nonzero(eta > ETA_SKIP))
            return
        step = self._expand_chunk
        for s in range(0, n, step):
            CT, _, _ = self._expand(BT[:, s:s + step], allowed[:, s:s + step])
            sizes[level + 1] += CT.shape[1]
            self._count(CT, self._rho_allowed(bounds, CT)[1], remaining - 1, level + 1, sizes, bounds)
