"""Transformed rewards (paper Eq. 8) and the myopic bound policies (paper Sec. IV).

Eq. 8 in the paper reads ``rho_lower(b,a) = rho(b,a) + [(I - gamma (T^a)^T) g]^T b``, with
``T^a`` there taken column-stochastic. The term comes from ``V_g(b) = V(b) + g^T b`` and
``E_z[tau(b,a,z)] = b^a``: ``g^T b - gamma g^T b^a``. In our row-stochastic convention
``b^a = b @ P[a]``, so (the single translation of Eq. 8 in this package):

    rho_lower(b, a) = rho(b, a) + b @ (I - gamma P[a]) @ g
    rho_upper(b, a) = rho(b, a) + b @ (I - gamma P[a]) @ h

The myopic policies are ``argmax_a`` of these (Sec. IV, after Theorem 2). Ties are broken
conservatively: the lower bound takes the smallest maximiser and the upper bound the
largest, so that ``lower <= optimal <= upper`` cannot fail through a tie.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import POMDP

#: Two transformed rewards closer than this (relative) count as a tie.
TIE_RTOL = 1e-12


def transform_matrix(model: POMDP, v: np.ndarray) -> np.ndarray:
    """``C[a] = (I - gamma P[a]) v`` for all actions, shape ``(A, S)`` (Eq. 8, our convention)."""
    v = np.asarray(v, dtype=float)
    if model.sparse:
        return v[None, :] - model.gamma * np.stack([model.P_csr[a] @ v for a in range(model.A)])
    return v[None, :] - model.gamma * (model.P @ v)


def argmax_smallest(Q: np.ndarray, axis: int = -1) -> np.ndarray:
    """The smallest index maximising ``Q`` along ``axis``, values within ``TIE_RTOL`` (relative)
    of the maximum counting as ties: the lower bound's tie rule (the search uses it too)."""
    top = Q.max(axis=axis, keepdims=True)
    tol = TIE_RTOL * np.maximum(1.0, np.abs(top))
    return np.argmax(Q >= top - tol, axis=axis)


def _argmax_largest(Q: np.ndarray) -> np.ndarray:
    """The largest maximiser along the last axis (the upper bound's tie rule)."""
    return Q.shape[-1] - 1 - argmax_smallest(Q[..., ::-1])


@dataclass(frozen=True, eq=False)
class MyopicBounds:
    """Myopic lower/upper bound policies from vectors ``g`` and ``h`` (Theorem 2, Eq. 8).

    ``lower(B)``/``upper(B)`` return 0-based action indices, vectorised over beliefs of
    shape ``(..., S)``. Under Assumption 1 and MLR-monotone transformed rewards,
    ``lower(b) <= mu*(b) <= upper(b)`` (priorities ``lower+1 .. upper+1``).
    """

    model: POMDP
    g: np.ndarray
    h: np.ndarray

    def __post_init__(self) -> None:
        for name in ("g", "h"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (self.model.S,):
                raise ValueError(f"{name}: expected {self.model.S} entries, got shape {v.shape}")
            v = v.copy()
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "_Cg", transform_matrix(self.model, self.g))
        object.__setattr__(self, "_Ch", transform_matrix(self.model, self.h))

    def transformed_rewards(self, B: np.ndarray, rho: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(rho_lower, rho_upper)`` of shape ``(..., A)``; pass ``rho`` if already known."""
        B = np.asarray(B, dtype=float)
        if rho is None:
            rho = self.model.rho(B)
        return rho + B @ self._Cg.T, rho + B @ self._Ch.T

    def lower(self, B: np.ndarray, rho: np.ndarray | None = None) -> np.ndarray:
        """Myopic lower-bound action (smallest maximiser of ``rho_lower``)."""
        B = np.asarray(B, dtype=float)
        if rho is None:
            rho = self.model.rho(B)
        return argmax_smallest(rho + B @ self._Cg.T)

    def upper(self, B: np.ndarray, rho: np.ndarray | None = None) -> np.ndarray:
        """Myopic upper-bound action (largest maximiser of ``rho_upper``)."""
        B = np.asarray(B, dtype=float)
        if rho is None:
            rho = self.model.rho(B)
        return _argmax_largest(rho + B @ self._Ch.T)

    def actions(self, B: np.ndarray, rho: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` action indices; computes ``rho`` once for both."""
        B = np.asarray(B, dtype=float)
        if rho is None:
            rho = self.model.rho(B)
        return self.lower(B, rho), self.upper(B, rho)


@dataclass(frozen=True, eq=False)
class TrivialBounds:
    """The non-informative bounds ``[0, A-1]``; same interface as :class:`MyopicBounds`."""

    model: POMDP

    def actions(self, B: np.ndarray, rho: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        shape = np.asarray(B).shape[:-1]
        return np.zeros(shape, dtype=int), np.full(shape, self.model.A - 1, dtype=int)

    def lower(self, B: np.ndarray, rho: np.ndarray | None = None) -> np.ndarray:
        return self.actions(B)[0]

    def upper(self, B: np.ndarray, rho: np.ndarray | None = None) -> np.ndarray:
        return self.actions(B)[1]
