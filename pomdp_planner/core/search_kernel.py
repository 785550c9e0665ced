"""The compiled search kernel: its tables and its calls (``core/search_kernel.c``).

The kernel is a C extension built when the package is installed (setup.py: the top-level
module ``_pomdp_planner_kernel``, so a source checkout on ``sys.path`` never hides the installed
build). It computes what :mod:`.search_reference` computes, with the same traversal (so the
same deadline readings), from the model's own ``P`` and ``O`` plus a few tables built here once
per planner: ``O`` transposed, ``O^2`` (Renyi) or ``O log O`` (Shannon), ``r`` transposed and the
bound matrices ``C_g``, ``C_h`` of Eq. 8. ``P`` and ``O`` may also be given as CSR rows per action
(:func:`csr_of`: what a planner does for a model stored sparse), for models with few non-zeros per
row; the kernel then predicts and observes through their non-zeros only, with the same results up
to rounding, and no table of size ``S x S`` or ``S x Z`` exists.

When the extension cannot be imported (installed without a C compiler) or is of another
version than this file expects, :func:`load` says why and the planner falls back to the numpy
reference with one warning per process (:func:`warn_fallback`).
"""

from __future__ import annotations

import importlib
import time
import warnings
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from .model import POMDP
from .myopic import MyopicBounds, TrivialBounds, transform_matrix
from .search_reference import ETA_FUSED_MIN, ETA_SKIP, _xlogx, uncertainty_kind
from .sparse import SparseStack

#: The extension module's name (top level: see the module docstring).
MODULE_NAME = "_pomdp_planner_kernel"
#: The version of the C interface this file speaks (``KERNEL_VERSION`` in search_kernel.c).
KERNEL_VERSION = 1
#: The uncertainty functions the kernel values (others: the numpy reference).
KINDS = {"none": 0, "renyi2": 1, "shannon": 2}

_loaded: tuple[ModuleType | None, str] | None = None
_warned = False


def load() -> tuple[ModuleType | None, str]:
    """``(module, "")`` when the compiled kernel is importable and of this version, else
    ``(None, reason)``. Imported once per process."""
    global _loaded
    if _loaded is None:
        try:
            mod = importlib.import_module(MODULE_NAME)
        except ImportError as exc:
            _loaded = (None, f"the compiled search kernel is not installed ({exc}; it is built by `pip install .` "
                             "when a C compiler is present)")
        else:
            version = getattr(mod, "KERNEL_VERSION", None)
            if version != KERNEL_VERSION:
                _loaded = (None, f"the installed search kernel is version {version}, this package needs "
                                 f"{KERNEL_VERSION} (reinstall the package)")
            elif (mod.ETA_SKIP, mod.ETA_FUSED_MIN) != (ETA_SKIP, ETA_FUSED_MIN):
                _loaded = (None, "the installed search kernel's constants differ from this package's (reinstall)")
            else:
                _loaded = (mod, "")
    return _loaded


def available() -> bool:
    """Whether the compiled kernel can be used in this process."""
    return load()[0] is not None


def warn_fallback() -> None:
    """The one warning (per process) that planners use the numpy reference instead of the kernel."""
    global _warned
    if not _warned:
        _warned = True
        warnings.warn(f"pomdp_planner: {load()[1]}; planning uses the numpy reference search, several times "
                      "slower", RuntimeWarning, stacklevel=3)


def searches(model: POMDP) -> bool:
    """Whether a planner of this process searches ``model`` with the kernel (installed, and the
    model's uncertainty function one it values): what the set-up estimate needs before any bounds
    exist (the gate's bounds are always of a type the kernel takes)."""
    return available() and uncertainty_kind(model) in KINDS


def unsupported(model: POMDP, bounds: Any) -> str:
    """Why the kernel cannot search ``model`` with ``bounds`` ("" when it can)."""
    if uncertainty_kind(model) not in KINDS:
        return f"uncertainty function {model.uncertainty.name!r} (the kernel values shannon, renyi2 and none)"
    if type(bounds) not in (MyopicBounds, TrivialBounds):
        return f"bounds of type {type(bounds).__name__} (the kernel takes MyopicBounds)"
    return ""


_same: bool | None = None


def native_clock(clock: Any) -> bool:
    """Whether ``clock`` reads the same time as the kernel's native clock (so the kernel may read
    its own, without the interpreter): ``time.perf_counter`` where that is ``CLOCK_MONOTONIC``."""
    global _same
    if clock is not time.perf_counter:
        return False
    if _same is None:
        mod = load()[0]
        info = time.get_clock_info("perf_counter").implementation
        _same = mod is not None and "CLOCK_MONOTONIC" in info and "RAW" not in info \
            and abs(mod.monotonic() - time.perf_counter()) < 1e-3
    return _same


@dataclass(frozen=True)
class CSRRows:
    """A per-action matrix as CSR rows: ``indptr`` (``A x (rows + 1)``, offsets into the whole
    ``indices``/``data``), ``indices`` (column of each non-zero) and ``data``."""

    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray


def csr_rows(M: np.ndarray) -> CSRRows:
    """The CSR rows of a dense per-action matrix ``M (A, rows, cols)`` (its non-zeros, row-major)."""
    return csr_of(SparseStack.from_dense(M))


def csr_of(stack: SparseStack) -> CSRRows:
    """The CSR rows of a model's sparse per-action matrices (``model.P_csr``, ``model.O_csr``):
    their own non-zeros, with the row offsets made absolute over the actions."""
    mats = list(stack)
    starts = np.cumsum([0] + [M.nnz for M in mats[:-1]])
    indptr = np.concatenate([M.indptr.astype(np.int64) + s for M, s in zip(mats, starts, strict=True)])
    return CSRRows(indptr, np.concatenate([M.indices for M in mats]).astype(np.int64),
                   np.ascontiguousarray(np.concatenate([M.data for M in mats]), dtype=np.float64))


class KernelEngine:
    """The kernel's tables for one model and bounds (built once, with the planner).

    ``P``/``O``: the model's dense arrays unless given as :class:`CSRRows`. ``fused``: build the
    fused leaf table of dense ``O`` (``W[a][s] = [O | O r_0 | ... | O r_{A-1} | X (| O)]``,
    ``A + 2`` blocks, ``A + 3`` for Shannon, of ``Z`` columns padded to a multiple of the kernel's
    tile; search_kernel.c, leaf_products): one matrix-vector product per block.
    """

    def __init__(self, model: POMDP, bounds: Any, fused: bool, P: CSRRows | None = None, O: CSRRows | None = None):
        mod = load()[0]
        if mod is None:
            raise RuntimeError(load()[1])
        self.mod = mod
        S, A, Z = model.S, model.A, model.Z
        kind = uncertainty_kind(model)

        def dense(x: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(x, dtype=np.float64)

        r = dense(model.r)
        Cg = Ch = None
        parts = [r]
        if isinstance(bounds, MyopicBounds):
            Cg, Ch = dense(transform_matrix(model, bounds.g)), dense(transform_matrix(model, bounds.h))
            parts += [Cg.T, Ch.T]  # one product gives r^T b, C_g b, C_h b
        pad = -(-A * len(parts) // mod.PAD) * mod.PAD - A * len(parts)  # zero columns: the kernel's tiles
        MT = np.concatenate([*parts, np.zeros((S, pad))], axis=1)
        self.sparse = (P is not None, O is not None)
        p_arg: Any = dense(model.P) if P is None else (P.indptr, P.indices, dense(P.data))
        X = W = OT = None
        if O is None:
            Od = dense(model.O)
            o_arg: Any = Od
            OT = np.ascontiguousarray(np.swapaxes(Od, 1, 2))
            if kind == "renyi2":
                X = Od * Od
            elif kind == "shannon":  # O log O (0 where O = 0), in place
                X = np.where(Od > 0.0, Od, 1.0)
                np.log(X, out=X)
                X *= Od
            if fused:  # blocks of Z columns padded to a multiple of PAD; filled in place
                Zp = -(-Z // mod.PAD) * mod.PAD
                blocks = A + 1 + (kind != "none") + (kind == "shannon")
                W = np.zeros((A, S, blocks * Zp))
                W[:, :, :Z] = Od
                for a in range(A):  # one S x Z temporary at a time
                    for k in range(A):
                        W[a, :, (k + 1) * Zp:(k + 1) * Zp + Z] = Od[a] * r[:, k:k + 1]
                if X is not None:
                    W[:, :, (A + 1) * Zp:(A + 1) * Zp + Z] = X
                if kind == "shannon":
                    W[:, :, (A + 2) * Zp:(A + 2) * Zp + Z] = Od
        else:
            o_arg = (O.indptr, O.indices, dense(O.data))
            if kind == "renyi2":
                X = O.data * O.data
            elif kind == "shannon":
                X = _xlogx(O.data)
        self.tables = mod.Tables(S, A, Z, float(model.gamma), KINDS[kind], dense(model.w), r,
                                 np.ascontiguousarray(r.T), Cg, Ch, p_arg, o_arg, OT,
                                 None if X is None else dense(X), W, dense(MT))
        self.has_bounds = Cg is not None
        self.fused = W is not None
