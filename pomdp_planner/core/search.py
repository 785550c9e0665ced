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

Two engines compute the search, with the same traversal and the same results: the compiled
kernel (``core/search_kernel.c`` through :mod:`.search_kernel`; built when the package is
installed) and its numpy reference (:mod:`.search_reference`, whose docstring gives the
traversal and the fused leaf formulas). A planner uses the kernel whenever it is installed and
takes the model (uncertainty Shannon, Renyi-2 or none; :class:`MyopicBounds` or none), else the
reference; ``Planner(kernel="numpy")`` asks for the reference. Without the installed kernel the
planner says so once per process (a ``RuntimeWarning``). The traversal takes a level in chunks
of parents and each chunk action by action (a *step*: the allowed parents' children under one
action, valued depth-first), so branch-and-bound forms children and leaf values only for the
(parent, action) pairs it keeps, and the deadline is read before every step.

Anytime (:meth:`Planner.plan`): iterative deepening ``1..max_depth``; the deadline is read
before every step at every depth, depth 1 included. An interrupted depth ``>= 2`` is discarded
and the deepest completed one returned; an interrupted depth 1 returns the root actions it
finished (``partial``; their Q values are depth-1 values, the others ``nan``): it takes the root
actions in decreasing order of ``rho(b0, a)`` and always finishes the first, so a valid action
always comes back. A depth predicted not to finish is not started
(:func:`next_depth_cannot_finish`). If the root bounds agree and the planner's bounds are
*guaranteed* (Assumption 1 holds and the LP is feasible: the gate of
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
import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import search_kernel
from .belief import check_belief
from .checks import check_int
from .errors import BeliefError, OptionError, short_repr
from .model import POMDP, format_bytes, priority_of
from .myopic import MyopicBounds, TrivialBounds
from .options import MAX_DEPTH_RANGE as MAX_DEPTH_RANGE  # re-exported: the ranges live in options.py
from .options import TIME_BUDGET_RANGE as TIME_BUDGET_RANGE
from .options import check_depth, check_time_budget
from .search_reference import ETA_FUSED_MIN as ETA_FUSED_MIN  # re-exported
from .search_reference import ETA_SKIP as ETA_SKIP
from .search_reference import DeadlineExceeded, ReferenceEngine, Traversal

#: Anytime stop rule: depth ``d + 1`` is not started when its predicted time exceeds this many
#: times the budget left (prediction: last depth's time times its growth over the depth before).
PREDICT_MARGIN = 1.5
#: The leaf prediction of the stop rule (:func:`next_depth_cannot_finish`) divides the measured time
#: per (parent, action) pair by this: a depth's time includes fixed costs and shallower levels, and
#: the kernel values the leaves of many parents together, so a pair of the next depth can cost
#: several times less than the last depth's average (a lower bound, not an estimate).
LEAF_PREDICTION_DISCOUNT = 8.0
#: Default memory budget (bytes) for one chunk of the leaf level.
DEFAULT_CHUNK_BYTES = 4 * 2**20
#: Most multiply-adds of one step (a chunk's parents under one action): the deadline is read
#: before every step, so this bounds how long it goes unread (about 0.2-1 ms in the kernel, a few
#: ms in numpy); on large models a step is one parent under one action, however long that takes.
STEP_WORK = 2**21
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
#: Fixed part of :func:`search_memory_estimate` (root arrays, results, small temporaries; the
#: kernel's per-search scratch comes on top: :func:`search_memory_estimate`).
SEARCH_OVERHEAD_BYTES = 16 * 2**10
#: Leaf parents whose leaves the kernel values together (``LEAF_BLOCK`` in search_kernel.c).
KERNEL_LEAF_BLOCK = 32
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


def next_depth_cannot_finish(depth_times: Sequence[float], remaining: float, margin: float = PREDICT_MARGIN,
                             level_sizes: Sequence[int] | None = None, A: int = 1) -> bool:
    """The anytime stop rule of :meth:`Planner.plan`: is the next depth hopeless?

    ``depth_times`` are the times of the completed depths ``1..d``. Two predictions of the next
    depth's time, the larger counts: its growth, ``t_d * max(1, t_d / t_{d-1})`` (two depths
    needed), and its leaves: ``level_sizes`` ``(n_0, ..., n_d)`` of depth ``d``, whose leaf level
    valued at most ``A n_{d-1}`` (parent, action) pairs in ``t_d``, while the next depth values at
    least one action of each of its ``n_d`` leaf parents, so it takes at least about
    ``t_d n_d / (A n_{d-1})``, counted divided by :data:`LEAF_PREDICTION_DISCOUNT` (also after
    depth 1: a model whose depth 1 takes a good part of the budget does not start a depth 2 that is
    hundreds of times longer). Hopeless when the prediction exceeds ``margin * remaining``; with
    one depth and no sizes, never.
    """
    t_last = float(depth_times[-1]) if len(depth_times) else 0.0
    predicted = 0.0
    if len(depth_times) >= 2:
        t_prev = float(depth_times[-2])
        predicted = t_last * max(1.0, t_last / t_prev if t_prev > 0.0 else 1.0)
    if level_sizes is not None and len(level_sizes) >= 2 and level_sizes[-2] > 0:
        leaves = t_last * level_sizes[-1] / (max(A, 1) * level_sizes[-2])
        predicted = max(predicted, leaves / LEAF_PREDICTION_DISCOUNT)
    return predicted > margin * max(remaining, 0.0)


class SearchMemoryError(OptionError):
    """A search would need more memory than the planner's budget (the message gives both figures).

    An :class:`~.errors.OptionError` (hence a ``ValueError``), like the other refusals of a request
    the planner cannot serve, so the command line reports it as exit code 2."""


def chunk_sizes(S: int, A: int, Z: int, chunk_bytes: int) -> tuple[int, int, int]:
    """``(leaf chunk, expand chunk, bytes per leaf parent)``: parents per chunk of :class:`Planner`.

    A chunk takes at most ``chunk_bytes`` of temporaries (numpy engine; at least 64 leaf parents or
    16 expanded ones) and one step of it (the chunk under one action) about :data:`STEP_WORK`
    multiply-adds (at least one parent): ``S^2 + Z S (A + 2)`` per leaf parent (prediction and the
    observation sums), ``S^2 + Z S (3 A + 3)`` per expanded parent (prediction, children, their
    rewards and bounds)."""
    per_parent = 8 * (Z * (A + 5) + 2 * S)  # leaf step: about (A + 5) Z + 2 S floats per parent
    leaf_work = S * S + Z * S * (A + 2)
    expand_work = S * S + Z * S * (3 * A + 3)
    leaf = max(1, min(max(64, int(chunk_bytes // per_parent)), STEP_WORK // leaf_work))
    expand = max(1, min(max(16, int(chunk_bytes // (8 * Z * (2 * S + 4)))), STEP_WORK // expand_work))
    return leaf, expand, per_parent


def search_memory_estimate(S: int, A: int, Z: int, depth: int, chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> int:
    """Upper estimate of the peak bytes that :class:`Planner` allocates for a depth-``depth`` search.

    The search is depth-first over steps (module docstring), so memory does not grow with the
    tree, ``(A Z)^depth`` leaves, but with the depth: at its deepest point it holds, for every
    level ``k = 1 .. depth - 1``, the children of one step of the level above, at most
    ``n_k = min(n_{k-1}, E) Z`` columns (``n_0 = 1``, ``E`` parents per expand chunk), each
    with its belief (``S`` floats), ``rho`` and ``Q`` values and allowed actions (``A`` each),
    parent, ``eta`` and the bound terms (``2 A`` floats with bounds); plus the temporaries of one
    expansion step (about ``2 S Z`` floats per parent) or of one leaf step (whichever is larger:
    they never coexist); a quarter more for the small temporaries around them, plus a fixed
    :data:`SEARCH_OVERHEAD_BYTES` and the kernel's scratch (one expansion step's sums and the arrays
    of :data:`KERNEL_LEAF_BLOCK` leaf parents). Both engines stay within it. Exhaustive search
    reaches these sizes; branch-and-bound prunes, so it needs at most as much (``tracemalloc``
    peaks are below the estimate in test/test_search_memory.py). Once ``n_k`` saturates, each
    further level adds ``E Z`` columns.
    """
    leaf, expand, per_parent = chunk_sizes(S, A, Z, chunk_bytes)
    per_column = 8 * (S + 5 * A + 3) + A
    total, n, widest = 0, 1, 1
    for _ in range(1, depth):
        widest = min(n, expand)
        n = widest * Z
        total += n * per_column
    expansion = 8 * (2 * S + 4) * Z * widest if depth > 1 else 0
    leaf_chunk = 3 * per_parent * min(leaf, n) // 2
    scratch = 8 * (widest + KERNEL_LEAF_BLOCK * (S + (A + 4) * Z) + 2 * S + 4 * A)
    return 5 * (total + max(expansion, leaf_chunk)) // 4 + SEARCH_OVERHEAD_BYTES + scratch


def fused_table_bytes(S: int, A: int, Z: int) -> int:
    """Bytes of the fused leaf table, at most ``A (A + 3) Z' S`` floats (``Z'``: ``Z`` rounded up to
    a multiple of 4): the kernel's ``[O | O r_a' | X (| O)]`` (:mod:`.search_kernel`; ``A + 3``
    blocks for Shannon, ``A + 2`` for Renyi, each padded to ``Z'`` columns) or the numpy engine's
    ``WT`` (``A + 1`` blocks of ``Z``, :mod:`.search_reference`, "Leaf tables")."""
    return 8 * A * (A + 3) * (-(-Z // 4) * 4) * S


def uses_fused_table(S: int, A: int, Z: int, fused: bool | None = None) -> bool:
    """Whether :class:`Planner` builds the fused leaf table: ``fused`` if given, else when it takes
    at most :data:`FUSED_TABLE_MAX_BYTES`."""
    return fused_table_bytes(S, A, Z) <= FUSED_TABLE_MAX_BYTES if fused is None else bool(fused)


def planner_table_bytes(S: int, A: int, Z: int, fused: bool | None = None, engine: str | None = None,
                        nnz: int | None = None) -> int:
    """Peak bytes :class:`Planner` allocates when it is built (its tables, before any search).

    ``engine``: ``"c"`` or ``"numpy"`` (``None``: the one a planner of this process uses, the
    kernel when it is installed). The fused leaf table (:func:`fused_table_bytes`) when
    :func:`uses_fused_table` says so; then, for the kernel, ``O`` transposed and one table of the
    leaf formula (``O`` squared or ``O log O``; ``(A, S, Z)`` floats each, and a mask of bytes
    while it is built), ``r`` twice and the reward and bound products (``3 S A``); for the numpy
    engine, ``O``
    transposed twice and the leaf formula's table, three temporaries while that one is built,
    ``P`` transposed (``A S^2``), ``r`` twice, and the action masks (``A^3`` bytes). Plus
    :data:`TABLE_OVERHEAD_BYTES`. Needs only the sizes, so an entry point can refuse before it
    builds anything. (The numpy engine's ``count_nodes`` builds two more ``(A, Z, S)`` tables on
    its first call.) ``nnz``: the non-zeros of ``P`` and ``O`` of a sparse model, which the kernel
    searches through them (:class:`Planner`): their CSR rows (an int64 index and a float each, the
    leaf formula's table on ``O``'s pattern) and row offsets instead of every dense table."""
    if engine is None:
        engine = "c" if search_kernel.available() else "numpy"
    if nnz is not None and engine == "c":
        return 24 * int(nnz) + 16 * A * (S + 1) + 40 * S * A + TABLE_OVERHEAD_BYTES
    table = fused_table_bytes(S, A, Z) if uses_fused_table(S, A, Z, fused) else 0
    if engine == "c":
        return table + 17 * A * Z * S + 40 * S * A + TABLE_OVERHEAD_BYTES
    floats = 6 * A * Z * S + A * S * S + 2 * S * A
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


@dataclass(frozen=True)
class SearchResult:
    """The outcome of :meth:`Planner.search` or :meth:`Planner.plan`.

    ``action`` is 0-based (``priority = action + 1`` is the paper's tracking priority).
    ``q_values[a]`` is the depth-``depth`` estimate ``Q(b0, a)`` of Algorithm 1, ``nan`` for
    actions pruned at the root. ``nodes_expanded[i]`` / ``nodes_pruned[i]`` refer to the
    tree of depth ``i + 1`` (see the module docstring). ``certified`` means the root bounds
    agree and are guaranteed (``guaranteed``: Assumption 1 holds, the LP is feasible), so the
    action is the optimal one (Proposition 1); ``crossed``: the root bounds cross (lower > upper),
    which valid bounds never do. ``deadline_hit``: the time budget limited the depth (a deeper
    depth was interrupted, or not started: ``predicted_stop``). ``partial``: the deadline
    interrupted depth 1 itself, so only the root actions with a finite Q value were searched (in
    decreasing order of ``rho(b0, a)``; at least the first) and ``action`` is the best of them.
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
    partial: bool = False

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
            "partial": bool(self.partial),
        }




#: What :meth:`Planner._run` returns.
_Run = tuple[np.ndarray, tuple[int, ...], "tuple[int, int] | None", bool, int, np.ndarray]
#: The engines a planner may be asked for (:class:`Planner`'s ``kernel``).
KERNELS = ("auto", "c", "numpy")
#: The belief rule's tolerance (:func:`~.belief.check_belief`'s default), as the kernel applies it.
BELIEF_ATOL = 1e-6


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
    the wall clock used for deadlines and timings (injectable for tests). ``fused``: the numpy
    engine builds its fused leaf table (:mod:`.search_reference`, "Leaf tables"; ``None``:
    :func:`uses_fused_table` decides by its size); both ways give the same values up to rounding.
    ``kernel``: ``"auto"`` (the compiled kernel when it is installed and takes the model, else
    the numpy reference; a missing kernel is warned about once per process), ``"c"`` (the
    kernel, or an :class:`~.errors.OptionError` saying why not) or ``"numpy"``; the attribute
    :attr:`kernel` says which one the planner uses.

    ``checked=True`` (:meth:`search`, :meth:`plan`, :meth:`q_values_batch`) skips the belief
    check: the caller promises beliefs of ``S`` finite float entries on the simplex, e.g.
    beliefs that :func:`~.belief.check_belief` (or the planner) already returned.
    """

    def __init__(self, model: POMDP, bounds: Bounds | None = None, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 clock: Callable[[], float] = time.perf_counter, guaranteed: bool = False,
                 memory_budget: int = DEFAULT_MEMORY_BUDGET, fused: bool | None = None, kernel: str = "auto"):
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
        if kernel not in KERNELS:
            raise OptionError(f"kernel: must be one of {', '.join(KERNELS)}, got {short_repr(kernel)}")
        S, A, Z = model.S, model.A, model.Z
        why = "" if kernel == "numpy" else (search_kernel.load()[1] or search_kernel.unsupported(model, self.bounds))
        if kernel == "c" and why:
            raise OptionError(f"kernel: the compiled kernel cannot be used: {why}")
        # A sparse model is searched by the kernel through its non-zeros (no fused table: that is
        # dense O); the numpy reference takes its dense P and O (model.P, up to MAX_DENSE_BYTES).
        on_csr = model.sparse and kernel != "numpy" and not why
        self.fused = False if on_csr else uses_fused_table(S, A, Z, fused)
        self._leaf_chunk, self._expand_chunk, _ = chunk_sizes(S, A, Z, chunk_bytes)
        self._cost = np.zeros(A)
        self._priced = False  # whether _cost holds a non-zero price
        self._A = A
        self._checked_depths: set[int] = set()
        self._complete = [1]
        self._reference: ReferenceEngine | None = None
        self._kernel: search_kernel.KernelEngine | None = None
        if on_csr:
            self._kernel = search_kernel.KernelEngine(model, self.bounds, False, P=search_kernel.csr_of(model.P_csr),
                                                      O=search_kernel.csr_of(model.O_csr))
        elif kernel != "numpy" and not why:
            self._kernel = search_kernel.KernelEngine(model, self.bounds, self.fused)
        else:
            if kernel == "auto" and not search_kernel.available():
                search_kernel.warn_fallback()
            self._engine()  # the numpy tables, now rather than in the first decision

    @property
    def kernel(self) -> str:
        """The engine this planner searches with: ``"c"`` (the compiled kernel) or ``"numpy"``."""
        return "c" if self._kernel is not None else "numpy"

    @property
    def has_bounds(self) -> bool:
        """Whether the planner has informative bounds (not :class:`TrivialBounds`)."""
        return not isinstance(self.bounds, TrivialBounds)

    # ----------------------------------------------------------------- public
    def root_bounds(self, belief: np.ndarray) -> tuple[int, int]:
        """0-based ``(lower, upper)`` myopic bound actions at ``belief``."""
        rb = self._run(self._belief(belief), 0, True, False, None, check=True)[2]
        return (0, self.model.A - 1) if rb is None else rb

    def search(self, belief: np.ndarray, depth: int, use_bounds: bool = True, *, all_root_actions: bool = False,
               deadline: float | None = None, checked: bool = False) -> SearchResult:
        """Algorithm 1 to ``depth`` action-observation levels (``Search(b, depth + 1)``).

        Always searches the full requested depth (also when the root bounds agree; then
        only one root action is expanded). ``use_bounds=False`` is the exhaustive search.
        ``all_root_actions``: every root action is expanded (the bounds prune below the root
        only), so every Q value is finite; a caller that must compare the root actions under a
        constraint the bounds do not know (the multi-target budget) needs them all.
        ``deadline`` (a reading of :attr:`clock`): read before every step (module docstring);
        :class:`DeadlineExceeded` is raised when it has passed. ``checked``: see the class.
        """
        depth = self._depth(depth, "depth")
        B = self._belief(belief)
        t0 = self.clock()
        q, sizes, rb, stopped, action, _ = self._run(B, depth, use_bounds, all_root_actions, deadline,
                                                     check=not checked)
        if stopped:
            raise DeadlineExceeded
        t = self.clock() - t0
        return self._result(q[0], action, sizes, depth, rb, t, False, (t,))

    def plan(self, belief: np.ndarray, max_depth: int, time_budget: float | None = None,
             use_bounds: bool = True, predict_stop: bool = True, *, checked: bool = False) -> SearchResult:
        """Anytime search: iterative deepening ``1, 2, ..., max_depth`` under a deadline.

        The deadline (``time_budget`` seconds from the call) is read before every step of every
        depth. An interrupted depth ``>= 2`` is discarded and the result of the deepest completed
        depth is returned (``deadline_hit=True``); an interrupted depth 1 returns the root actions
        it finished (``partial=True``: module docstring), so an action always comes back. If
        guaranteed bounds agree at the root the action is certified: the planner returns at once
        after the (tiny) depth-1 search of that single action, so the other Q values are ``nan``.
        Bounds without the guarantee never stop it early (module docstring).

        ``predict_stop``: depth ``d + 1`` is not started when it cannot finish: its predicted time
        (:func:`next_depth_cannot_finish`: the growth ``t_d / t_{d-1}``, and the leaves it must
        value at least) exceeds :data:`PREDICT_MARGIN` times the budget left. An interrupted depth is discarded
        anyway, so this returns the same decision sooner (``deadline_hit`` and
        ``predicted_stop`` set); the growth measured at shallow depths underestimates the real
        one (fixed per-call costs), so the rule errs towards trying. ``checked``: see the class.
        """
        max_depth = self._depth(max_depth, "max_depth")
        if time_budget is not None:
            time_budget = check_time_budget(time_budget)
        B = self._belief(belief)
        check = not checked  # at the first depth, which returns the checked belief
        t0 = self.clock()
        deadline = None if time_budget is None else t0 + time_budget
        best: tuple[np.ndarray, int, Any, int] | None = None
        hit = predicted = partial = False
        rb: tuple[int, int] | None = None
        times: list[float] = []
        last = max_depth
        for d in range(1, max_depth + 1):
            ts = self.clock()
            q, sizes, rb, stopped, action, B = self._run(B, d, use_bounds, False, deadline, first_free=d == 1,
                                                         check=check)
            check = False
            if stopped:
                hit = True
                if d == 1:  # the root actions finished (at least the first): module docstring
                    best, partial = (q, action, sizes, 1), True
                    times.append(self.clock() - ts)
                break
            best = (q, action, sizes, d)
            now = self.clock()
            times.append(now - ts)
            if d == 1 and self._is_certified(rb):
                last = 1
            if d == last:
                break
            if deadline is None:
                continue
            if now >= deadline:
                hit = True
                break
            if predict_stop and next_depth_cannot_finish(times, deadline - now, level_sizes=sizes, A=self._A):
                hit = predicted = True
                break
        assert best is not None  # depth 1 always finishes its first root action
        q, action, sizes, d = best
        return self._result(q[0], action, sizes, d, rb, self.clock() - t0, hit, tuple(times), predicted, partial)

    def priced(self, action_cost: np.ndarray | Sequence[float]) -> Planner:
        """This planner for the rewards ``r[s, a] - action_cost[a]``: an action-only price, e.g.
        ``lambda e(a)`` of the multi-target relaxation (``core/multitarget``).

        A shallow copy sharing every table: the price goes into the search as a cost vector
        (``rho(b, a) - action_cost[a]`` everywhere, leaves included), so a copy costs
        microseconds. The bounds and ``guaranteed`` carry over unchanged: an action-only term
        changes neither Assumption 1 (``P``, ``O`` only) nor the Theorem 2 LP (its rows hold
        differences of ``r_a`` over states, where a constant per action cancels), so the same
        ``g, h`` bound the optimal policy of the priced problem for every price (docs/THEORY.md,
        "Several targets: an action-only price"). The myopic bound actions move with the price;
        the guarantee does not. ``self.model`` stays the unpriced model; prices add up
        (``p.priced(c1).priced(c2)`` is priced by ``c1 + c2``).
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
        new._cost = self._cost + c
        new._cost.setflags(write=False)
        new._priced = bool(new._cost.any())
        return new

    def q_values_batch(self, beliefs: np.ndarray, depth: int, use_bounds: bool = True, *,
                       deadline: float | None = None, checked: bool = False) -> np.ndarray:
        """``Q(b, a)`` for every row ``b`` of ``beliefs`` (``n x S``) and every action, ``n x A``: the
        root Q values of :meth:`search` with ``all_root_actions=True``, for ``n`` roots in one
        pass (the roots are the first level's nodes, as every level's beliefs are).
        ``depth = 0`` gives ``rho(b, a)``. ``deadline`` as in :meth:`search`. ``checked``: the rows
        are beliefs already checked (see the class)."""
        depth = check_depth(depth, "depth", (0, None))
        B = np.asarray(beliefs, dtype=float)
        if B.ndim != 2 or B.shape[1] != self.model.S:
            raise BeliefError(f"beliefs: expected shape n x {self.model.S}, got {B.shape}")
        if not len(B):
            return np.empty((0, self.model.A))
        if depth:
            self._check_memory_once(depth, "depth")
        q, _, _, stopped, _, _ = self._run(np.array(B, order="C"), depth, use_bounds, True, deadline,
                                           rho_order=False, check=not checked, field="beliefs")
        if stopped:
            raise DeadlineExceeded
        return q

    def count_nodes(self, belief: np.ndarray, depth: int, use_bounds: bool = True) -> tuple[int, ...]:
        """Level sizes ``(n_0, ..., n_depth)`` of the search tree, without valuing the leaves.

        Much cheaper than :meth:`search` at the same depth (the leaf level only needs
        ``eta``); ``nodes_expanded`` of depth ``i`` is ``sum(level_sizes[:i + 1])``.
        """
        depth = self._depth(depth, "depth")
        return tuple(self._run(self._belief(belief), depth, use_bounds, False, None, count_only=True, check=True)[1])

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
    def _depth(self, depth: int, name: str) -> int:
        """``depth`` checked (an integer >= 1 whose search fits the memory budget)."""
        if type(depth) is int and depth in self._checked_depths:  # checked before
            return depth
        depth = check_depth(depth, name)
        self._check_memory_once(depth, name)
        return depth

    def _check_memory_once(self, depth: int, name: str) -> None:
        if depth not in self._checked_depths:  # the estimate depends on the depth only
            self.check_memory(depth, name)
            self._checked_depths.add(depth)

    def _belief(self, belief: np.ndarray) -> np.ndarray:
        """A copy of ``belief`` as one C-contiguous float row ``(1, S)`` (the belief rule itself is
        checked with the search: :meth:`_run`, which normalises the copy in place)."""
        b = np.array(belief, dtype=float)
        if b.shape != (self.model.S,):
            check_belief(self.model, b)  # its message for a wrong shape
        return np.ascontiguousarray(b).reshape(1, -1)

    def _engine(self) -> ReferenceEngine:
        if self._reference is None:
            self._reference = ReferenceEngine(self.model, self.fused, self._leaf_chunk, self._expand_chunk)
        return self._reference

    def _run(self, B: np.ndarray, depth: int, use_bounds: bool, all_root: bool, deadline: float | None,
             first_free: bool = False, rho_order: bool = True, count_only: bool = False, check: bool = False,
             field: str = "belief") -> _Run:
        """One search from the roots ``B (n, S)`` by the planner's engine: ``(Q (n, A), level sizes,
        the first root's bounds or None, interrupted by the deadline, the first root's best searched
        action, the roots searched)``. ``Q`` is ``nan`` where not searched. ``rho_order``: the root
        actions in decreasing ``rho`` (one root only). ``check``: the roots are checked and
        normalised by the belief rule first (:func:`~.belief.check_belief`; its error names
        ``field``, with the row for several roots): the kernel checks and normalises ``B`` in place."""
        n, A = B.shape[0], self._A
        cost = self._cost
        k = self._kernel
        if k is not None:
            Q = None if count_only else np.empty((n, A))
            args = [k.tables, B, n, depth, bool(use_bounds) and k.has_bounds, all_root, rho_order and n == 1,
                    cost if self._priced else None, self._leaf_chunk, self._expand_chunk, deadline,
                    None if search_kernel.native_clock(self.clock) else self.clock, first_free, count_only,
                    BELIEF_ATOL if check else None, Q]
            status, index, sizes, lo, up = k.mod.search(*args)
            if status == 2:  # a root breaks the belief rule: its message (or, at the rule's edge, its verdict)
                B = self._checked(B, field)
                args[1], args[14] = B, None
                status, index, sizes, lo, up = k.mod.search(*args)
            return Q, sizes, (None if lo < 0 else (lo, up)), status == 1, index, B
        if check:
            B = self._checked(B, field)
        eng = self._engine()
        bounds = self.bounds if use_bounds else self.trivial
        BT = np.ascontiguousarray(B.T)
        rhoT, lo, up = eng.rho_bounds(bounds, BT, cost)
        rb = None if lo is None else (int(lo[0]), int(up[0]))
        order = np.argsort(-rhoT[:, 0], kind="stable").tolist() if rho_order and n == 1 else range(A)
        tr = Traversal(bounds, cost, order, [n] + [0] * depth, deadline, self.clock, first_free, count_only)
        QT = np.full((A, n), -np.inf)
        stopped = False
        if depth == 0:
            QT = rhoT
        else:
            allowed = np.ones((A, n), dtype=bool) if all_root else eng._allowed(lo, up, n)
            try:
                eng._values(BT, rhoT, allowed, depth, 0, tr, QT)
            except DeadlineExceeded:
                stopped = True
        Q = np.ascontiguousarray(QT.T)
        index = int(np.argmax(Q[0])) if np.isfinite(Q[0]).any() else -1
        Q[Q == -np.inf] = np.nan
        return Q, tuple(tr.sizes), rb, stopped, index, B

    def _checked(self, B: np.ndarray, field: str) -> np.ndarray:
        """The rows of ``B`` checked and normalised by :func:`~.belief.check_belief`."""
        if B.shape[0] == 1 and field == "belief":
            return np.ascontiguousarray(check_belief(self.model, B[0])).reshape(1, -1)
        return np.stack([check_belief(self.model, b, field=f"{field}[{i}]") for i, b in enumerate(B)])

    def _is_certified(self, rb: tuple[int, int] | None) -> bool:
        """Guaranteed root bounds agree (Proposition 1), or there is only one action."""
        return self._A == 1 or (rb is not None and self.guaranteed and rb[0] == rb[1])

    def _complete_nodes(self, depth: int) -> list[int]:
        """:func:`complete_tree_nodes` for depths ``0..depth`` (cached)."""
        c, AZ = self._complete, self.model.A * self.model.Z
        while len(c) <= depth:
            c.append(c[-1] + AZ ** len(c))
        return c

    def _result(self, q: np.ndarray, action: int, sizes: Sequence[int], depth: int, rb: tuple[int, int] | None,
                t: float, hit: bool, times: tuple[float, ...], predicted: bool = False,
                partial: bool = False) -> SearchResult:
        q.setflags(write=False)
        expanded = tuple(itertools.accumulate(sizes))[1:]
        pruned = tuple([c - e for c, e in zip(self._complete_nodes(depth)[1:depth + 1], expanded, strict=True)])
        return SearchResult(action, int(priority_of(action)), q, depth, expanded, pruned, self._is_certified(rb), rb,
                            float(t), hit, float(q[action]), tuple(sizes), rb is not None, times, predicted,
                            self.guaranteed and rb is not None, partial)
