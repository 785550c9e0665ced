"""The POMDP model object and its validation.

Conventions (used everywhere in this package; see docs/THEORY.md for the translation of
every formula of the paper):

* ``P[a, i, j] = P(next = j | prev = i, a)`` (row-stochastic, shape ``A x S x S``).
  The paper's ``T(s', s, a)``; its matrix ``T^a`` is written sometimes with previous states
  as rows and sometimes as columns, we always use rows.
* ``O[a, j, z] = P(z | next = j, a)`` (shape ``A x S x Z``). The paper's ``O^a_{z,j}``.
* ``r[s, a]`` (shape ``S x A``), ``w[a]`` (shape ``A``), discount ``gamma``.
* Storage (:attr:`POMDP.storage`): ``P`` and ``O`` are kept dense (numpy arrays) or sparse (one CSR
  matrix per action, :class:`~.sparse.SparseStack`: ``model.P_csr[a]``, ``model.O_csr[a]``),
  whichever :func:`~.sparse.choose_storage` finds smaller. ``model.P`` and ``model.O`` are always
  the dense ``A x S x S`` and ``A x S x Z`` arrays: a sparse model builds them on first use, up to
  :data:`MAX_DENSE_BYTES` each, and refuses larger ones in one line (code that can take a model of
  any size reads ``P_csr``/``O_csr``, or asks :attr:`POMDP.sparse`).
* States, actions and observations are 0-based. Action index ``a`` is the paper's tracking
  priority ``a + 1`` (1 = greatest priority); conversion happens only at user-facing edges
  (:func:`priority_of`, :func:`action_of_priority`).

The expected reward is ``rho(b, a) = b . r[:, a] - w[a] f(b)`` (paper Eq. 3).
"""

from __future__ import annotations

import hashlib
import json
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from dataclasses import replace as dataclass_replace

import numpy as np
import scipy.sparse as sp

from .checks import check_int, is_integer
from .errors import MESSAGE_VALUE_CHARS as MESSAGE_VALUE_CHARS  # re-exported
from .errors import BeliefError, ModelError, kind_of, short_repr
from .sparse import STORAGES, SparseStack, choose_storage, csr_bytes, row_sums
from .uncertainty import Uncertainty, get_uncertainty

#: Rows of ``P`` and ``O`` must sum to one within this absolute tolerance.
STOCHASTIC_ATOL = 1e-6
#: Largest model a loader or generator builds: bytes of ``P``, ``O`` and ``r`` as they are stored,
#: checked *before* anything is allocated (:func:`check_model_size`): dense, ``8 (A S S + A S Z +
#: S A)``; sparse, 12 bytes per non-zero of ``P`` and ``O`` plus the row pointers and ``r``.
#: Building a model needs a few times this transiently. 128 MiB holds e.g. a dense model with
#: S = Z = 1600 and A = 3, or S = Z = 256 and A = 64, and a sparse one with ten million non-zeros
#: (a 100 x 100 grid with A = 3 has about 200 000).
MAX_MODEL_BYTES = 128 * 2**20
#: Largest dense ``P`` or ``O`` (bytes, each) that a sparse model builds when a computation asks for
#: :attr:`POMDP.P` or :attr:`POMDP.O` (a computation that has no sparse form); above it that
#: computation is refused in one line naming the size.
MAX_DENSE_BYTES = 128 * 2**20
#: Longest model name; a name is one line of text (it is written into exported files).
MAX_NAME_CHARS = 256
#: Largest magnitude of a reward ``r(s, a)`` (and of every reward-generator parameter): a search
#: sums at most ``MAX_DEPTH_RANGE[1] + 1`` rewards and the bound LP's right-hand sides are
#: differences of rewards plus ``|w_a| K_f``, so every value stays finite and far inside the range
#: the LP solver treats as finite (HiGHS reads ``1e20`` as infinity).
MAX_REWARD_MAGNITUDE = 1e12
#: Largest magnitude of a weight ``w_a``: the information reward ``w_a f(b)`` and the LP's
#: ``|w_a| K_f`` (``K_f`` at most ``-log(epsilon)``, below 745 for any positive double) stay
#: within :data:`MAX_REWARD_MAGNITUDE`.
MAX_WEIGHT_MAGNITUDE = 1e9
#: ``epsilon`` (the Shannon bounds' domain ``B_eps``) when a model gives none: this value, or
#: ``1 / (2 S)`` when that is smaller (S > 500), so that ``0 < epsilon < 1/S`` holds at any size
#: (:func:`default_epsilon`).
DEFAULT_EPSILON = 1e-3


def default_epsilon(S: int) -> float:
    """:data:`DEFAULT_EPSILON`, or ``1 / (2 S)`` when that is smaller: inside ``(0, 1/S)`` for every S."""
    return min(DEFAULT_EPSILON, 0.5 / S)


def as_number(value: object, field_name: str, finite: bool = True) -> float:
    """``value`` as a float, strictly: an int or float (numpy scalars too), not a bool or a string.

    Integers too large for a float and (with ``finite``) NaN or infinity are refused.
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ModelError(f"{field_name}: must be a number, got {kind_of(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise ModelError(f"{field_name}: number too large for a float ({short_repr(value)})") from None
    if finite and not math.isfinite(x):
        raise ModelError(f"{field_name}: must be a finite number, got {x}")
    return x


def as_count(value: object, field_name: str) -> int:
    """``value`` as a count ``>= 1``, strictly: an integer, not a bool, a string or a float.

    A float is refused even when integral (``3.0``): counts in model files are written as integers.
    """
    if not is_integer(value):
        raise ModelError(f"{field_name}: must be an integer count, got {kind_of(value)}")
    n = int(value)
    if n < 1:
        raise ModelError(f"{field_name}: count must be at least 1, got {n}")
    return n


def model_bytes(S: int, A: int, Z: int, nnz: int | None = None) -> int:
    """Bytes of ``P`` (A x S x S), ``O`` (A x S x Z) and ``r`` (S x A) as float64, dense; or, given
    ``nnz`` (the non-zeros of ``P`` and ``O`` together), stored sparse (:mod:`.sparse`: the CSR arrays
    and the row pointers of the transposes, which bound ``S`` and ``Z`` too)."""
    if nnz is None:
        return 8 * (A * S * S + A * S * Z + S * A)
    # the CSR arrays of P and O, the row pointers of their transposes (S + 1 and Z + 1 per action), r
    return csr_bytes(nnz, 2 * A, S) + 4 * A * (S + Z + 2) + 8 * S * A


def check_model_size(S: int, A: int, Z: int, field_name: str, limit: int | None = None,
                     nnz: int | None = None) -> None:
    """Refuse (``ModelError`` naming ``field_name``) a model whose matrices would exceed ``limit``
    bytes (default :data:`MAX_MODEL_BYTES`) as stored: dense, or sparse with ``nnz`` non-zeros in
    ``P`` and ``O`` (:func:`model_bytes`); call it before allocating anything of that size."""
    limit = MAX_MODEL_BYTES if limit is None else limit
    need = model_bytes(S, A, Z, nnz)
    if need > limit:
        form = "" if nnz is None else f" with {int(nnz):,} non-zeros"
        raise ModelError(f"{field_name}: S={short_repr(S)}, A={short_repr(A)}, Z={short_repr(Z)}{form} need "
                         f"{format_bytes(need)} for the transition, observation and reward matrices; "
                         f"the limit is {format_bytes(limit)} (MAX_MODEL_BYTES)")


def format_bytes(n: float) -> str:
    """``n`` bytes in a binary unit (``512 B``, ``1.5 GiB``; beyond PiB in powers of ten)."""
    if n < 1024:
        return f"{int(n)} B"
    if n >= 1024 ** 6:
        return f"about 1e{int(math.log10(n))} B"
    for k, unit in enumerate(("KiB", "MiB", "GiB", "TiB", "PiB"), start=1):
        if n < 1024 ** (k + 1) or unit == "PiB":
            return f"{n / 1024 ** k:.3g} {unit}"
    raise AssertionError  # unreachable


def check_name(value: object, field_name: str = "name") -> str:
    """A model name: one line of at most :data:`MAX_NAME_CHARS` characters (a string or a number)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (str, numbers.Real)):
        raise ModelError(f"{field_name}: must be a string, got {kind_of(value)}")
    text = value if isinstance(value, str) else short_repr(value)
    if len(text) > MAX_NAME_CHARS or not text.isprintable():
        raise ModelError(f"{field_name}: must be one line of at most {MAX_NAME_CHARS} printable characters, "
                         f"got {short_repr(text)} ({len(text)} characters)")
    return text


def priority_of(action: int | np.ndarray) -> int | np.ndarray:
    """0-based action index -> the paper's tracking priority 1..A (user-facing)."""
    return action + 1


def action_of_priority(priority: int, num_actions: int) -> int:
    """Tracking priority 1..A -> 0-based action index, with a clear error when out of range."""
    return check_int(priority, "action: priority", 1, num_actions, error=BeliefError) - 1


def array_digest(*arrays: np.ndarray, digest_size: int = 20) -> bytes:
    """A content digest (BLAKE2b) of ``arrays``: each one's dtype, shape and bytes, in order.

    Two arrays digest alike iff they hold the same values in the same dtype and shape; used to
    key caches by model content (:func:`model_digest`, ``core.gate.model_key``).
    """
    h = hashlib.blake2b(digest_size=digest_size)
    for M in arrays:
        M = np.ascontiguousarray(M)
        h.update(f"{M.dtype.str}{M.shape}".encode())
        h.update(M.tobytes())
    return h.digest()


def model_digest(model: POMDP, digest_size: int = 20) -> bytes:
    """A content digest of everything that defines ``model``: ``P``, ``O``, ``r``, ``w``, ``gamma``,
    the uncertainty function, ``epsilon``, the names and the metadata (e.g. the start belief).

    Equal for an equal copy (e.g. a model sent to a worker process), different when any of
    these differ; hashes data only, never code (no pickle).
    """
    names = {"name": model.name, "uncertainty": model.uncertainty.name, "gamma": repr(model.gamma),
             "epsilon": repr(model.epsilon), "states": model.state_names, "actions": model.action_names,
             "observations": model.observation_names, "metadata": model.metadata}
    text = json.dumps(names, sort_keys=True, default=repr).encode()
    return hashlib.blake2b(matrix_digest(model) + array_digest(model.r, model.w) + text,
                           digest_size=digest_size).digest()


def matrix_digest(model: POMDP, digest_size: int = 20) -> bytes:
    """A content digest of ``P`` and ``O`` as stored (their storage, shapes and values), without
    building a dense form of a sparse model."""
    if model.sparse:
        parts = [np.array(model.P_csr.shape + model.O_csr.shape), *model.P_csr.arrays(), *model.O_csr.arrays()]
        return b"sparse" + array_digest(*parts, digest_size=digest_size)
    return array_digest(model.P, model.O, digest_size=digest_size)


def frozen_copy(x: np.ndarray) -> np.ndarray:
    """A read-only, C-contiguous float copy of ``x`` (the arrays of a model and of a bounds solution;
    a generator's transposed view would otherwise keep its strides, and products with it, e.g.
    ``P @ O``, take several times longer)."""
    x = np.array(x, dtype=float, copy=True, order="C")
    x.setflags(write=False)
    return x


def _check_stochastic(name: str, M: np.ndarray, row_label: str, col_label: str) -> None:
    """Check a stack of matrices ``M[a]`` is finite, non-negative and row-stochastic."""
    if not np.all(np.isfinite(M)):
        a, i, j = np.argwhere(~np.isfinite(M))[0]
        raise ModelError(f"{name}[{a}][{i}][{j}]: value is not finite ({M[a, i, j]})")
    if np.any(M < 0.0):
        a, i, j = np.argwhere(M < 0.0)[0]
        raise ModelError(f"{name}[{a}][{i}][{j}]: probability is negative ({M[a, i, j]:.6g})")
    sums = M.sum(axis=-1)
    bad = np.abs(sums - 1.0) > STOCHASTIC_ATOL
    if np.any(bad):
        a, i = np.argwhere(bad)[0]
        raise ModelError(
            f"{name}[{a}][{i}]: row ({row_label} {i}, action {a}) sums to {sums[a, i]:.9g}, "
            f"not 1 (over {col_label}; tolerance {STOCHASTIC_ATOL:g})"
        )


def _check_stochastic_sparse(name: str, M: SparseStack, row_label: str, col_label: str) -> None:
    """:func:`_check_stochastic` for a sparse stack (its stored values; the others are 0)."""
    for a in range(len(M)):
        C = M[a]
        bad = ~np.isfinite(C.data)
        neg = C.data < 0.0
        if np.any(bad) or np.any(neg):
            k = int(np.argmax(bad | neg))
            i = int(np.searchsorted(C.indptr, k, side="right") - 1)
            j = int(C.indices[k])
            if bad[k]:
                raise ModelError(f"{name}[{a}][{i}][{j}]: value is not finite ({C.data[k]})")
            raise ModelError(f"{name}[{a}][{i}][{j}]: probability is negative ({C.data[k]:.6g})")
        sums = row_sums(C)
        off = np.abs(sums - 1.0) > STOCHASTIC_ATOL
        if np.any(off):
            i = int(np.argmax(off))
            raise ModelError(
                f"{name}[{a}][{i}]: row ({row_label} {i}, action {a}) sums to {sums[i]:.9g}, "
                f"not 1 (over {col_label}; tolerance {STOCHASTIC_ATOL:g})"
            )


def _is_sparse_input(M: object) -> bool:
    """Whether a model matrix argument is given sparse: a :class:`SparseStack` or a sequence of
    scipy sparse matrices (one per action)."""
    if isinstance(M, SparseStack):
        return True
    return isinstance(M, (list, tuple)) and len(M) > 0 and all(sp.issparse(x) for x in M)


def _sparse_input(M: object, rows: int, name: str, cols: int | None = None) -> SparseStack:
    if isinstance(M, SparseStack):
        stack = M
    else:
        try:
            stack = SparseStack.from_matrices(list(M), rows, cols if cols is not None else M[0].shape[1])
        except ValueError as exc:
            raise ModelError(f"{name}: sparse matrices of inconsistent shape ({short_repr(str(exc), 80)})") from None
    if stack.shape[1] != rows or (cols is not None and stack.shape[2] != cols):
        want = f"{rows} x {cols}" if cols is not None else f"{rows} x ..."
        raise ModelError(f"{name}: expected matrices of shape {want}, got {stack.shape[1]} x {stack.shape[2]}")
    return stack


class _DenseView:
    """``model.P`` / ``model.O`` of a sparse model: the dense array, built on first use (up to
    :data:`MAX_DENSE_BYTES`) and kept; refused in one line above it. A dense model holds the array
    itself (an instance attribute, which takes precedence over this non-data descriptor)."""

    def __init__(self, name: str, attr: str, label: str, dims: str):
        self.name, self.attr, self.label, self.dims = name, attr, label, dims

    def __get__(self, model, owner=None):
        if model is None:
            return self
        stack = getattr(model, self.attr)
        need = 8 * int(np.prod(stack.shape))
        if need > MAX_DENSE_BYTES:
            A, n, m = stack.shape
            raise ModelError(f"{self.label}: this computation needs the dense {self.dims} array of a sparse model "
                             f"(A={A}, S={n}, {self.dims[-1]}={m}, {stack.nnz:,} non-zeros): {format_bytes(need)}, "
                             f"more than the limit of {format_bytes(MAX_DENSE_BYTES)} (MAX_DENSE_BYTES)")
        dense = stack.to_dense()
        dense.setflags(write=False)
        model.__dict__[self.name] = dense
        return dense


def per_action_vector(field: str, value: object, A: int, noun: str = "value") -> np.ndarray:
    """A per-action quantity: one number for all ``A`` actions, or ``A`` numbers (finite reals;
    bools and strings refused). Errors are :class:`ModelError` naming ``field`` (and ``noun``)."""
    if isinstance(value, (list, tuple)):
        for i, x in enumerate(value):
            if isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real):
                raise ModelError(f"{field}[{i}]: must be a number, got {kind_of(x)}")
    elif isinstance(value, (str, dict, bool, np.bool_)):
        raise ModelError(f"{field}: must be numbers, got {kind_of(value)}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ModelError(f"{field}: must be numbers, got {short_repr(value)}") from None
    if arr.ndim == 0:
        arr = np.full(A, float(arr))
    if arr.shape != (A,):
        raise ModelError(f"{field}: expected {A} {noun}s (one per action), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{field}[{int(np.argmax(~np.isfinite(arr)))}]: {noun} is not finite")
    return arr


def _weights(w: object, A: int) -> np.ndarray:
    """The weights ``w_a`` of Eq. 3: ``None`` (zeros), one number for all actions, or ``A`` numbers,
    each of magnitude at most :data:`MAX_WEIGHT_MAGNITUDE`."""
    if w is None:
        return np.zeros(A)
    arr = per_action_vector("uncertainty.weights", w, A, "weight")
    _check_magnitude("uncertainty.weights", arr, MAX_WEIGHT_MAGNITUDE, "MAX_WEIGHT_MAGNITUDE")
    return arr


def _check_magnitude(field_name: str, values: np.ndarray, limit: float, limit_name: str) -> None:
    """Refuse (naming the first entry) finite values whose magnitude exceeds ``limit``."""
    big = np.abs(values) > limit
    if np.any(big):
        idx = np.argwhere(big)[0]
        where = "".join(f"[{int(k)}]" for k in idx)
        raise ModelError(f"{field_name}{where}: magnitude must be at most {limit:g} ({limit_name}: searches and the "
                         f"bound LP must stay finite), got {values[tuple(idx)]:g}")


def _names(field_name: str, names: Sequence[str] | None, n: int) -> tuple[str, ...] | None:
    if names is None:
        return None
    if isinstance(names, (str, bytes)) or not isinstance(names, Sequence):
        raise ModelError(f"{field_name}: names must be a list, got {kind_of(names)}")
    names = tuple(check_name(x, f"{field_name}[{i}]") for i, x in enumerate(names))
    if len(names) != n:
        raise ModelError(f"{field_name}: {len(names)} names given for {n} entries")
    if len(set(names)) != n:
        raise ModelError(f"{field_name}: names are not unique")
    return names


@dataclass(frozen=True, eq=False, repr=False)
class POMDP:
    """An immutable information-acquisition POMDP (paper Sec. II).

    Arrays are copied and made read-only on construction, and validated: shapes, finite
    values, non-negative probabilities, rows summing to 1 within :data:`STOCHASTIC_ATOL`,
    ``0 <= gamma <= 1``, rewards and weights within :data:`MAX_REWARD_MAGNITUDE` and
    :data:`MAX_WEIGHT_MAGNITUDE`, ``0 < epsilon < 1/S`` (``None``: :func:`default_epsilon`).
    Errors are :class:`ModelError` naming the field.

    ``P`` and ``O`` are dense ``A x S x S`` and ``A x S x Z`` arrays, or sparse: a
    :class:`~.sparse.SparseStack`, or a sequence of ``A`` scipy sparse matrices. ``storage``
    (:data:`~.sparse.STORAGES`): ``"auto"`` keeps the smaller form (:func:`~.sparse.choose_storage`),
    ``"dense"`` or ``"sparse"`` force one; afterwards it is the form kept (module docstring).

    ``gamma = 1`` is valid for a finite horizon only (the paper, Sec. II: a depth-limited search,
    a simulation of finitely many steps, an export); what needs an infinite horizon (the bound LP
    of Theorem 2, the reference solvers) refuses it (:func:`require_discount_below_one`).
    """

    P: np.ndarray
    O: np.ndarray
    r: np.ndarray
    gamma: float
    uncertainty: Uncertainty | str = "none"
    w: np.ndarray | Sequence[float] | None = None
    epsilon: float | None = None
    name: str = "pomdp"
    state_names: Sequence[str] | None = None
    action_names: Sequence[str] | None = None
    observation_names: Sequence[str] | None = None
    metadata: dict = field(default_factory=dict)
    storage: str = "auto"

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if self.storage not in STORAGES:
            raise ModelError(f"storage: must be one of {', '.join(STORAGES)}, got {short_repr(self.storage)}")
        try:
            r = np.asarray(self.r, dtype=float)
            if _is_sparse_input(self.P):
                rows = self.P.shape[1] if isinstance(self.P, SparseStack) else self.P[0].shape[0]
                P = _sparse_input(self.P, rows, "transition", rows)
            else:
                P = np.asarray(self.P, dtype=float)
            O = self.O if _is_sparse_input(self.O) else np.asarray(self.O, dtype=float)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ModelError(f"model matrices must be numeric arrays of consistent shape: "
                             f"{short_repr(str(exc), 120)}") from None
        if isinstance(P, SparseStack):
            A, S, S2 = P.shape
            if S != S2:
                raise ModelError(f"transition: expected shape A x S x S, got {P.shape}")
        else:
            if P.ndim != 3 or P.shape[1] != P.shape[2]:
                raise ModelError(f"transition: expected shape A x S x S, got {P.shape}")
            A, S, _ = P.shape
        if A < 1 or S < 1:
            raise ModelError(f"transition: needs at least one action and one state, got shape {tuple(P.shape)}")
        if _is_sparse_input(O):
            if len(O) != A:
                raise ModelError(f"observation: expected {A} matrices (one per action), got {len(O)}")
            O = _sparse_input(O, S, "observation")
        elif O.ndim != 3 or O.shape[0] != A or O.shape[1] != S:
            raise ModelError(f"observation: expected shape {A} x {S} x Z (A x S x Z), got {O.shape}")
        Z = O.shape[2]
        if Z < 1:
            raise ModelError("observation: needs at least one observation")
        if r.shape != (S, A):
            raise ModelError(f"reward: expected shape {S} x {A} (S x A), got {r.shape}")
        for name, M, rows, cols in (("transition", P, "previous state", "next states"),
                                    ("observation", O, "next state", "observations")):
            if isinstance(M, SparseStack):
                _check_stochastic_sparse(name, M, rows, cols)
            else:
                _check_stochastic(name, M, rows, cols)
        if not np.all(np.isfinite(r)):
            s, a = np.argwhere(~np.isfinite(r))[0]
            raise ModelError(f"reward[{s}][{a}]: value is not finite ({r[s, a]})")
        _check_magnitude("reward", r, MAX_REWARD_MAGNITUDE, "MAX_REWARD_MAGNITUDE")
        gamma = as_number(self.gamma, "discount")
        if not (0.0 <= gamma <= 1.0):
            raise ModelError(f"discount: must satisfy 0 <= gamma <= 1 (1: a finite horizon only), got {gamma}")
        unc = self.uncertainty
        if isinstance(unc, str):
            try:
                unc = get_uncertainty(unc)
            except ValueError as exc:
                raise ModelError(str(exc)) from None
        elif not isinstance(unc, Uncertainty):
            raise ModelError(f"uncertainty.function: must be the name of a function (none, renyi2, shannon), "
                             f"got {kind_of(unc)}")
        w = _weights(self.w, A)
        eps = default_epsilon(S) if self.epsilon is None else as_number(self.epsilon, "uncertainty.epsilon")
        if not (0.0 < eps < 1.0 / S or (S == 1 and 0.0 < eps <= 1.0)):
            raise ModelError(f"uncertainty.epsilon: must satisfy 0 < epsilon < 1/S = {1.0 / S:.6g}, got {eps}")
        storage = self.storage
        if storage == "auto":
            nnz = [M.nnz if isinstance(M, SparseStack) else int(np.count_nonzero(M)) for M in (P, O)]
            storage = choose_storage(A, S, Z, *nnz)
        set_(self, "storage", storage)
        set_(self, "_shape", (A, S, Z))
        if storage == "sparse":
            set_(self, "_P_csr", P if isinstance(P, SparseStack) else SparseStack.from_dense(P))
            set_(self, "_O_csr", O if isinstance(O, SparseStack) else SparseStack.from_dense(O))
            self.__dict__.pop("P", None)  # built on first use (_DenseView)
            self.__dict__.pop("O", None)
        else:
            set_(self, "P", frozen_copy(P.to_dense() if isinstance(P, SparseStack) else P))
            set_(self, "O", frozen_copy(O.to_dense() if isinstance(O, SparseStack) else O))
        set_(self, "r", frozen_copy(r))
        set_(self, "gamma", gamma)
        set_(self, "uncertainty", unc)
        set_(self, "w", frozen_copy(w))
        set_(self, "epsilon", eps)
        set_(self, "name", check_name(self.name))
        set_(self, "state_names", _names("states", self.state_names, S))
        set_(self, "action_names", _names("actions", self.action_names, A))
        set_(self, "observation_names", _names("observations", self.observation_names, Z))
        set_(self, "metadata", dict(self.metadata))

    # ------------------------------------------------------------------ storage
    @property
    def sparse(self) -> bool:
        """Whether ``P`` and ``O`` are stored sparse (``P_csr``, ``O_csr``; module docstring)."""
        return self.storage == "sparse"

    @property
    def P_csr(self) -> SparseStack:  # noqa: N802 - the paper's name for the matrix
        """``P`` as one CSR matrix per action (:class:`~.sparse.SparseStack`, ``S x S`` each): what is
        stored for a sparse model, built once from the dense array for a dense one."""
        return self._csr("P")

    @property
    def O_csr(self) -> SparseStack:  # noqa: N802
        """``O`` as one CSR matrix per action (``S x Z`` each); as :attr:`P_csr`."""
        return self._csr("O")

    def _csr(self, name: str) -> SparseStack:
        stack = self.__dict__.get(f"_{name}_csr")
        if stack is None:
            stack = SparseStack.from_dense(getattr(self, name))
            object.__setattr__(self, f"_{name}_csr", stack)
        return stack

    @property
    def stored_bytes(self) -> int:
        """Bytes of ``P``, ``O`` and ``r`` as stored (dense arrays, or the CSR arrays)."""
        A, S, Z = self._shape
        if self.sparse:
            return self.P_csr.nbytes + self.O_csr.nbytes + 8 * S * A
        return model_bytes(S, A, Z)

    def replace(self, **changes) -> POMDP:
        """A copy with ``changes`` (fields of the constructor), keeping the storage and, for a sparse
        model, its sparse matrices (``dataclasses.replace`` would pass the dense ``P`` and ``O``)."""
        if self.sparse:
            changes.setdefault("P", self.P_csr)
            changes.setdefault("O", self.O_csr)
        changes.setdefault("storage", self.storage)
        return dataclass_replace(self, **changes)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        if self.sparse:  # the dense views are rebuilt on use
            state.pop("P", None)
            state.pop("O", None)
        else:
            state.pop("_P_csr", None)
            state.pop("_O_csr", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

    def __repr__(self) -> str:
        return f"POMDP({self.describe()})"

    # ------------------------------------------------------------------ sizes
    @property
    def num_states(self) -> int:
        return self._shape[1]

    @property
    def num_actions(self) -> int:
        return self._shape[0]

    @property
    def num_observations(self) -> int:
        return self._shape[2]

    S = num_states
    A = num_actions
    Z = num_observations

    # ---------------------------------------------------------------- rewards
    def rho(self, b: np.ndarray) -> np.ndarray:
        """Expected reward ``rho(b, a) = b . r_a - w_a f(b)`` for all actions (paper Eq. 3).

        ``b`` has shape ``(..., S)``; the result has shape ``(..., A)``.
        """
        b = np.asarray(b, dtype=float)
        out = b @ self.r
        if self.uncertainty.name != "none":
            out = out - self.uncertainty.value(b)[..., None] * self.w
        return out

    def rho_gradient(self, b: np.ndarray) -> np.ndarray:
        """``d rho(b, a) / d b`` for all actions, shape ``(..., A, S)`` (used by Theorem 2)."""
        b = np.asarray(b, dtype=float)
        grad_f = self.uncertainty.gradient(b)  # (..., S)
        return self.r.T - self.w[:, None] * grad_f[..., None, :]

    def describe(self) -> str:
        """A one-line summary for logs and the CLI."""
        horizon = " (finite horizon only)" if self.gamma >= 1.0 else ""
        return (
            f"{self.name}: S={self.S} A={self.A} Z={self.Z} gamma={self.gamma:g}{horizon} "
            f"uncertainty={self.uncertainty.name}"
            + (f" storage=sparse ({self.P_csr.nnz + self.O_csr.nnz:,} non-zeros)" if self.sparse else "")
        )


POMDP.P = _DenseView("P", "_P_csr", "transition", "A x S x S")  # type: ignore[assignment]
POMDP.O = _DenseView("O", "_O_csr", "observation", "A x S x Z")  # type: ignore[assignment]


def infinite_horizon_refusal(model: POMDP, what: str) -> str:
    """``""`` if ``model.gamma < 1``; else one line saying that ``what`` (a computation over an
    infinite horizon) needs a discount below 1 and what a discount of 1 is valid for."""
    if model.gamma < 1.0:
        return ""
    return (f"discount: {what} needs discount < 1 (an infinite horizon); this model's discount is 1, valid for "
            "a finite horizon only (depth-limited search: plan, simulate, export)")


def require_discount_below_one(model: POMDP, what: str) -> None:
    """Raise :class:`ModelError` (:func:`infinite_horizon_refusal`) if ``model.gamma`` is 1."""
    reason = infinite_horizon_refusal(model, what)
    if reason:
        raise ModelError(reason)
