"""How long a fixed-depth search is expected to take, before it starts (``pomdp-planner plan``).

The branch-and-bound search (``core/search.py``) expands at most the complete tree of its depth,
``sum_i (A Z)^i`` belief nodes (Sec. VI-A; pruning removes an unknown share), and a belief node
costs about ``node + state * S`` seconds (its prediction, update and leaf value are vectors over
the ``S`` states), with the constants of the engine that runs it (:data:`ENGINE_SECONDS`): the
compiled kernel (``core/search_kernel.py``) or the numpy reference. They come from exhaustive
searches of random models on one core of a shared 2-core machine: the kernel took 0.047 us per
node at S = 16, 0.19 us at S = 60 and 0.80 us at S = 200 (depth 3: 2.1e6, 1.1e8 and 8.0e6 nodes
in 0.1, 21.2 and 6.5 s), the numpy reference 0.09 us at S = 8, 0.6-0.8 us at S = 60 and 1.5 us at
S = 200; the estimates err on the long side. So it tells a search of seconds from one of
minutes, which is what :func:`search_notice` is for; it is no timing promise.
"""

from __future__ import annotations

from .errors import OptionError
from .search import complete_tree_nodes, count_text

#: Seconds per belief node and per node and state, by engine (see the module docstring).
ENGINE_SECONDS = {"compiled": (2e-8, 4e-9), "numpy": (1e-7, 1e-8)}
#: A fixed-depth search expected to take longer is announced before it starts.
ANNOUNCE_SECONDS = 3.0
#: ... and one expected to take longer than this is refused (unless the caller lifts the limit).
MAX_SEARCH_SECONDS = 600.0


def search_seconds(S: int, A: int, Z: int, depth: int, engine: str = "compiled") -> float:
    """The expected time of a search of ``depth`` over its complete tree on ``engine`` (a key of
    :data:`ENGINE_SECONDS`; module docstring)."""
    node, state = ENGINE_SECONDS[engine]
    return complete_tree_nodes(A, Z, depth) * (node + state * S)


def search_notice(S: int, A: int, Z: int, depth: int, field: str, *, engine: str = "compiled",
                  limit: float | None = MAX_SEARCH_SECONDS, hint: str = "") -> str:
    """``""`` for a search of ``depth`` expected to be quick on ``engine``; else one line announcing
    the expected time (above :data:`ANNOUNCE_SECONDS`). Above ``limit`` seconds (``None``: no
    limit) the search is refused: :class:`OptionError` naming ``field``, with the estimate and ``hint``."""
    seconds = search_seconds(S, A, Z, depth, engine)
    nodes = count_text(complete_tree_nodes(A, Z, depth))
    what = (f"a search of depth {depth} on this model (S={S}, A={A}, Z={Z}) is expected to take up to about "
            f"{_duration(seconds)} ({nodes} belief nodes in the complete tree; branch-and-bound prunes some)")
    if limit is not None and seconds > limit:
        raise OptionError(f"{field}: {what}, more than the limit of {_duration(limit)}" + (f"; {hint}" if hint else ""))
    return what if seconds > ANNOUNCE_SECONDS else ""


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h" if seconds < 1e6 else f"{seconds / 3600:.3g} h"
