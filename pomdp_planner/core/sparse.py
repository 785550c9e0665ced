"""Sparse storage of a model's transition and observation matrices: one CSR matrix per action.

A :class:`SparseStack` holds ``A`` matrices of shape ``n x m`` (``P``: ``S x S``; ``O``: ``S x Z``),
matrix ``a`` as a :class:`scipy.sparse.csr_array` in canonical form: column indices sorted within
each row, no duplicates, no stored zeros, ``int32`` indices and ``indptr``, ``float64`` data, all
read-only. Row ``i`` of matrix ``a`` is ``stack[a].indices[stack[a].indptr[i]:stack[a].indptr[i+1]]``
(its columns) and the same slice of ``stack[a].data`` (its values): e.g. for ``P``, the states
reachable from ``i`` under ``a`` and their probabilities. ``stack.T`` is the stack of the transposes,
in the same form (computed once, on first use): for ``P`` its row ``j`` lists the predecessors of
``j``, so the prediction ``b^a = b @ P[a]`` (paper Eq. 1) is ``P.T[a] @ b``, a product over the
non-zeros.

:func:`choose_storage` is the one rule for which form a model keeps (:class:`~.model.POMDP`):
sparse when the CSR arrays take at most :data:`SPARSE_MAX_FRACTION` of the dense bytes and the
dense form is at least :data:`SPARSE_MIN_DENSE_BYTES` (below that, dense products are faster than
sparse ones and the memory does not matter).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

#: A model is stored sparse when its CSR arrays take at most this share of the dense bytes ...
SPARSE_MAX_FRACTION = 0.25
#: ... and its dense ``P`` and ``O`` together would take at least this many bytes.
SPARSE_MIN_DENSE_BYTES = 2**20
#: The storage choices of a model (``POMDP(storage=...)``): ``auto`` applies :func:`choose_storage`.
STORAGES = ("auto", "dense", "sparse")
#: Bytes per stored non-zero (a float64 value and an int32 column index).
BYTES_PER_NONZERO = 12


def csr_bytes(nnz: int, A: int, n: int) -> int:
    """Bytes of ``A`` CSR matrices with ``n`` rows and ``nnz`` non-zeros in all (int32 indices)."""
    return BYTES_PER_NONZERO * int(nnz) + 4 * A * (n + 1)


def choose_storage(A: int, S: int, Z: int, nnz_P: int, nnz_O: int) -> str:
    """``"sparse"`` or ``"dense"`` for a model with these sizes and non-zero counts (module docstring)."""
    dense = 8 * A * S * (S + Z)
    stored = csr_bytes(nnz_P, A, S) + csr_bytes(nnz_O, A, S)
    return "sparse" if dense >= SPARSE_MIN_DENSE_BYTES and stored <= SPARSE_MAX_FRACTION * dense else "dense"


def _freeze(M: sp.csr_array) -> sp.csr_array:
    for arr in (M.data, M.indices, M.indptr):
        arr.setflags(write=False)
    return M


def canonical_csr(M, shape: tuple[int, int]) -> sp.csr_array:
    """``M`` (a dense array or any scipy sparse matrix of ``shape``) as a canonical, read-only
    ``csr_array`` (module docstring): duplicates summed, stored zeros dropped, indices sorted."""
    if sp.issparse(M):
        C = sp.csr_array(M, dtype=float, copy=True)
    else:
        C = sp.csr_array(np.asarray(M, dtype=float))
    if C.shape != shape:
        raise ValueError(f"shape {C.shape}, expected {shape}")
    C.sum_duplicates()
    C.eliminate_zeros()
    C.sort_indices()
    idx = np.int32 if max(shape) < 2**31 - 1 and C.nnz < 2**31 - 1 else np.int64
    C = sp.csr_array((np.ascontiguousarray(C.data, dtype=float), C.indices.astype(idx, copy=False),
                      C.indptr.astype(idx, copy=False)), shape=shape, copy=False)
    C.has_canonical_format = True
    return _freeze(C)


class SparseStack:
    """``A`` canonical CSR matrices of shape ``n x m`` (module docstring). Immutable."""

    def __init__(self, mats: Sequence[sp.csr_array], shape: tuple[int, int, int]):
        self._mats = tuple(mats)
        self.shape = tuple(int(x) for x in shape)
        self._T: SparseStack | None = None
        self._stacked: sp.csr_array | None = None

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_matrices(cls, mats: Sequence, n: int, m: int) -> SparseStack:
        """From ``A`` matrices (dense or scipy sparse) of shape ``n x m``."""
        return cls([canonical_csr(M, (n, m)) for M in mats], (len(mats), n, m))

    @classmethod
    def from_dense(cls, M: np.ndarray) -> SparseStack:
        """From a dense ``A x n x m`` array."""
        M = np.asarray(M, dtype=float)
        return cls.from_matrices(list(M), M.shape[1], M.shape[2])

    @classmethod
    def from_coo(cls, A: int, n: int, m: int, a: np.ndarray, i: np.ndarray, j: np.ndarray, v: np.ndarray
                 ) -> SparseStack:
        """From coordinates: matrix ``a[k]`` has ``v[k]`` at ``(i[k], j[k])`` (duplicates summed)."""
        a = np.asarray(a, dtype=np.int64)
        order = np.argsort(a, kind="stable")
        bounds = np.searchsorted(a[order], np.arange(A + 1))
        mats = []
        for act in range(A):
            k = order[bounds[act]:bounds[act + 1]]
            mats.append(canonical_csr(sp.coo_array((np.asarray(v, float)[k], (np.asarray(i)[k], np.asarray(j)[k])),
                                                   shape=(n, m)), (n, m)))
        return cls(mats, (A, n, m))

    # ---------------------------------------------------------------- access
    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, a: int) -> sp.csr_array:
        """Matrix ``a`` (a read-only canonical ``csr_array``)."""
        return self._mats[a]

    def __iter__(self):
        return iter(self._mats)

    @property
    def nnz(self) -> int:
        """Stored non-zeros of all matrices."""
        return int(sum(M.nnz for M in self._mats))

    @property
    def nbytes(self) -> int:
        """Bytes of the stored arrays (data, indices, indptr)."""
        return int(sum(M.data.nbytes + M.indices.nbytes + M.indptr.nbytes for M in self._mats))

    def row_nnz(self) -> np.ndarray:
        """Non-zeros per row, shape ``(A, n)``."""
        return np.stack([np.diff(M.indptr) for M in self._mats]) if self._mats else np.zeros((0, self.shape[1]), int)

    def row(self, a: int, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Row ``i`` of matrix ``a``: ``(columns, values)`` (views, read-only)."""
        M = self._mats[a]
        lo, hi = M.indptr[i], M.indptr[i + 1]
        return M.indices[lo:hi], M.data[lo:hi]

    def dense_row(self, a: int, i: int) -> np.ndarray:
        """Row ``i`` of matrix ``a`` as a dense vector of length ``m``."""
        cols, vals = self.row(a, i)
        out = np.zeros(self.shape[2])
        out[cols] = vals
        return out

    def stacked(self) -> sp.csr_array:
        """All matrices stacked as one ``A n x m`` CSR matrix (row ``a n + i`` is row ``i`` of matrix
        ``a``); built once."""
        if self._stacked is None:
            self._stacked = _freeze(sp.csr_array(sp.vstack(self._mats, format="csr")))
        return self._stacked

    def dense_rows(self, a: np.ndarray, i: np.ndarray) -> np.ndarray:
        """Rows ``i[k]`` of matrices ``a[k]`` as a dense ``(k, m)`` array."""
        return self.stacked()[np.asarray(a, dtype=np.int64) * self.shape[1] + np.asarray(i, dtype=np.int64)].toarray()

    @property
    def T(self) -> SparseStack:  # noqa: N802 - the transpose, as numpy names it
        """The stack of the transposed matrices (``m x n`` each), same form; computed once."""
        if self._T is None:
            A, n, m = self.shape
            T = SparseStack([canonical_csr(M.T.tocsr(), (m, n)) for M in self._mats], (A, m, n))
            T._T = self
            self._T = T
        return self._T

    def to_dense(self) -> np.ndarray:
        """The dense ``A x n x m`` array (the caller decides whether that size is acceptable)."""
        out = np.zeros(self.shape)
        for a, M in enumerate(self._mats):
            r = np.repeat(np.arange(self.shape[1]), np.diff(M.indptr))
            out[a, r, M.indices] = M.data
        return out

    def same(self, a: int, b: int) -> bool:
        """Whether matrices ``a`` and ``b`` are equal (same pattern and values)."""
        Ma, Mb = self._mats[a], self._mats[b]
        return (Ma.nnz == Mb.nnz and np.array_equal(Ma.indptr, Mb.indptr) and np.array_equal(Ma.indices, Mb.indices)
                and np.array_equal(Ma.data, Mb.data))

    def arrays(self) -> list[np.ndarray]:
        """Every stored array, in order (for content digests)."""
        return [x for M in self._mats for x in (M.indptr, M.indices, M.data)]

    def __getstate__(self) -> dict:
        return {"mats": [(M.data, M.indices, M.indptr) for M in self._mats], "shape": self.shape}

    def __setstate__(self, state: dict) -> None:
        A, n, m = state["shape"]
        mats = []
        for data, indices, indptr in state["mats"]:
            M = sp.csr_array((np.array(data), np.array(indices), np.array(indptr)), shape=(n, m), copy=False)
            M.has_canonical_format = True
            mats.append(_freeze(M))
        self._mats, self.shape, self._T, self._stacked = tuple(mats), (A, n, m), None, None

    def __repr__(self) -> str:
        A, n, m = self.shape
        return f"SparseStack({A} x {n} x {m}, {self.nnz} non-zeros)"


def row_sums(M: sp.csr_array) -> np.ndarray:
    """The sum of each row's stored values (in column order), shape ``(n,)``."""
    rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
    return np.bincount(rows, weights=M.data, minlength=M.shape[0])


def matvec_rows(stack: SparseStack, a: int, x: np.ndarray) -> np.ndarray:
    """``stack[a] @ x`` for ``x`` of shape ``(m,)`` or ``(m, k)``."""
    return stack[a] @ x


def vecmat(stack: SparseStack, a: int, B: np.ndarray) -> np.ndarray:
    """``B @ stack[a]`` for beliefs ``B`` of shape ``(n,)`` or ``(N, n)``: the product over the
    non-zeros, through the transposed stack (``(stack.T[a] @ B.T).T``)."""
    B = np.asarray(B, dtype=float)
    if B.ndim == 1:
        return stack.T[a] @ B
    return np.ascontiguousarray((stack.T[a] @ B.T).T)


def row_of(M: np.ndarray | SparseStack, a: int, i: int) -> tuple[np.ndarray | None, np.ndarray]:
    """Row ``i`` of matrix ``a`` of a dense ``A x n x m`` array or a stack: ``(columns, values)``,
    the columns ``None`` for a dense row (all of them)."""
    if isinstance(M, SparseStack):
        return M.row(a, i)
    return None, M[a, i]


def sample_inverse_cdf(rng: np.random.Generator, M: np.ndarray | SparseStack, a: int, i: int) -> int:
    """An outcome of row ``i`` of matrix ``a`` by inverse CDF (``rng.random()`` scaled by the row's
    total: rows sum to 1 only within the model's tolerance). Dense and sparse rows give the same
    outcome for the same random number (the zeros add nothing to the cumulative sums)."""
    cols, p = row_of(M, a, i)
    c = np.cumsum(p)
    k = int(min(np.searchsorted(c, rng.random() * c[-1], side="right"), p.size - 1))
    return k if cols is None else int(cols[k])


def sample_choice(rng: np.random.Generator, M: np.ndarray | SparseStack, a: int, i: int) -> int:
    """``rng.choice(m, p=row)`` for row ``i`` of matrix ``a``, the same outcome and the same random
    numbers drawn for a dense and a sparse row (numpy's own rule: normalised cumulative sums,
    one ``rng.random()``)."""
    cols, p = row_of(M, a, i)
    if cols is None:
        return int(rng.choice(p.size, p=p))
    cdf = np.cumsum(p)
    cdf /= cdf[-1]
    return int(cols[int(cdf.searchsorted(rng.random(), side="right"))])
