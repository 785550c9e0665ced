"""Point-based value iteration (PBVI) for POMDPs with LINEAR rewards (``f = 0``).

Used only by the experiments as an optimal-policy reference for the Sec. VI-B comparison
model at sizes where the grid reference (S <= 3) does not reach. It is Pineau et al.'s
point-based backup, vectorised over belief points, actions and observations::

    G[a, z, k, i] = sum_j P[a, i, j] O[a, j, z] alpha_k[j]
    alpha_{b,a}   = r[:, a] + gamma * sum_z G[a, z, argmax_k b . G[a, z, k]]

started from the blind-policy alpha vectors (a valid lower bound), so the value is a lower
bound of the optimal value that is exact at the belief points in the limit of a dense
point set. It is a *reference*, not an exact solver: on the beliefs we test it we also
report the Q-value gap between its best and second-best action (near-ties are excluded
from any comparison).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.model import POMDP


def _blind_alphas(model: POMDP) -> np.ndarray:
    """``alpha_a = (I - gamma P_a)^-1 r_a``: value of always taking action ``a``."""
    S = model.S
    return np.stack([np.linalg.solve(np.eye(S) - model.gamma * model.P[a], model.r[:, a]) for a in range(model.A)])


@dataclass
class PBVIPolicy:
    """Alpha vectors from :func:`pbvi` and the one-step-lookahead greedy policy."""

    model: POMDP
    alphas: np.ndarray  # (K, S)
    iterations: int
    residual: float

    def values(self, B: np.ndarray) -> np.ndarray:
        return (np.asarray(B, dtype=float) @ self.alphas.T).max(axis=-1)

    def q_values(self, B: np.ndarray) -> np.ndarray:
        """``Q(b, a) = b.r_a + gamma sum_z max_k b.G[a,z,k]`` for beliefs ``(N, S)`` -> ``(N, A)``."""
        B = np.atleast_2d(np.asarray(B, dtype=float))
        m = self.model
        M = m.P[:, :, :, None] * m.O[:, None, :, :]  # (A, S_i, S_j, Z)
        G = np.einsum("aijz,kj->azki", M, self.alphas)  # (A, Z, K, S)
        out = B @ m.r
        for a in range(m.A):
            vals = np.einsum("ns,zks->nzk", B, G[a])
            out[:, a] += m.gamma * vals.max(axis=-1).sum(axis=-1)
        return out

    def actions(self, B: np.ndarray) -> np.ndarray:
        return np.argmax(self.q_values(B), axis=-1)


def pbvi(model: POMDP, points: np.ndarray, max_iter: int = 3000, tol: float = 1e-7) -> PBVIPolicy:
    """Run point-based backups on ``points`` (N, S) until the values change by < ``tol``."""
    if model.uncertainty.name != "none" and np.any(model.w != 0):
        raise ValueError("pbvi: only linear rewards (uncertainty 'none' or zero weights) are supported")
    B = np.asarray(points, dtype=float)
    m = model
    M = m.P[:, :, :, None] * m.O[:, None, :, :]  # (A, S, S, Z)
    alphas = _blind_alphas(m)
    v_old = (B @ alphas.T).max(axis=-1)
    residual = np.inf
    iterations = 0
    for iterations in range(1, max_iter + 1):  # noqa: B007 - reported below
        G = np.einsum("aijz,kj->azki", M, alphas)  # (A, Z, K, S)
        best_q = np.full(B.shape[0], -np.inf)
        best_alpha = np.zeros_like(B)
        for a in range(m.A):
            vals = np.einsum("ns,zks->nzk", B, G[a])  # (N, Z, K)
            k = vals.argmax(axis=-1)  # (N, Z)
            chosen = G[a][np.arange(m.Z)[None, :], k]  # (N, Z, S)
            alpha = m.r[:, a][None, :] + m.gamma * chosen.sum(axis=1)  # (N, S)
            q = np.einsum("ns,ns->n", B, alpha)
            better = q > best_q
            best_q = np.where(better, q, best_q)
            best_alpha[better] = alpha[better]
        # Keep the old vectors too: the point values then never decrease (monotone lower bound).
        alphas = np.unique(np.round(np.vstack([best_alpha, alphas]), 12), axis=0)
        useful = np.unique((B @ alphas.T).argmax(axis=-1))
        alphas = alphas[useful]
        v_new = (B @ alphas.T).max(axis=-1)
        residual = float(np.max(np.abs(v_new - v_old)))
        v_old = v_new
        if residual < tol:
            break
    return PBVIPolicy(model=m, alphas=alphas, iterations=iterations, residual=residual)


def single_action_optimal(model: POMDP, tol: float = 1e-9) -> int | None:
    """The action that is optimal at EVERY belief, proven exactly, or ``None``.

    For linear rewards, if the blind-policy vector ``alpha = (I - gamma P_a*)^-1 r_a*``
    satisfies ``r_a + gamma P_a alpha <= alpha`` componentwise for every action ``a``, then
    ``V(b) = b . alpha`` is a fixed point of the Bellman operator (the backup of a linear
    ``V`` is ``max_a b . (r_a + gamma P_a alpha)``, since ``sum_z eta tau = b P_a``), hence
    ``V* = b . alpha`` and ``a*`` is optimal everywhere. Returns the smallest such ``a*``.
    """
    alphas = _blind_alphas(model)
    for a_star in range(model.A):
        alpha = alphas[a_star]
        backed = model.r.T + model.gamma * (model.P @ alpha)  # (A, S)
        if np.all(backed <= alpha[None, :] + tol * max(1.0, float(np.max(np.abs(alpha))))):
            return a_star
    return None
