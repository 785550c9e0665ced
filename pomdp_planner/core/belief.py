"""Bayes filter for the belief state (paper Eqs. 1 and 2), single and vectorised.

Translation of the paper's formulas into our convention (``P[a, i, j] = P(j | i, a)``,
``O[a, j, z] = P(z | j, a)``), done here once:

* Eq. 1, prediction: ``b^a(s') = sum_s T(s', s, a) b(s)``  ->  ``b^a = b @ P[a]``.
* ``eta(z | b, a) = sum_s' O(z, s', a) b^a(s')``           ->  ``eta = b^a @ O[a]``.
* Eq. 2, update: ``tau(b, a, z)(s') = O(z, s', a) b^a(s') / eta(z | b, a)``
  ->  ``tau = b^a * O[a][:, z] / eta[z]``.

A sparse model (``model.sparse``: ``P`` and ``O`` stored as one CSR matrix per action) takes the
same functions: the products run over the non-zeros (``model.P_csr``, ``model.O_csr``), with the
same values to rounding; :func:`observation_branches` gives the posteriors of the observations
that can occur, with work proportional to the non-zeros involved.

An observation with ``eta(z | b, a) <= ETA_MIN`` is impossible under the belief: the single
update raises :class:`ImpossibleObservation`, which carries ``eta`` and the predicted belief.
The per-epoch filter of the nodes and of ``simulate`` (``core/filter.py``) has the project's one
recovery rule for it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .checks import check_int
from .errors import BeliefError
from .model import POMDP, ModelError, short_repr
from .sparse import row_sums, vecmat

#: Observations whose probability under the belief is at most this are impossible.
ETA_MIN = 1e-300


class ImpossibleObservation(ArithmeticError):
    """``eta(z | b, a) == 0``: the observation cannot occur under the current belief.

    Attributes: ``action``, ``observation``, ``eta`` (its probability) and ``predicted``
    (the predicted belief ``b^a`` of Eq. 1, a natural fallback belief).
    """

    def __init__(self, action: int, observation: int, eta: float, predicted: np.ndarray):
        self.action = action
        self.observation = observation
        self.eta = eta
        self.predicted = predicted
        super().__init__(
            f"observation {observation} has probability {eta:.3g} under the belief after action "
            f"{action} (priority {action + 1}): Bayes update undefined"
        )


def _state_vector(model: POMDP | int, values, field: str, what: str) -> np.ndarray:
    """``values`` as a float array of one finite entry per state of ``model`` (or ``S``), else a
    :class:`BeliefError` naming ``field``."""
    S = int(model) if isinstance(model, (int, np.integer)) else model.S
    v = np.asarray(values, dtype=float)
    if v.shape != (S,):
        got = f"{v.size}" if v.ndim == 1 else f"shape {v.shape}"
        raise BeliefError(f"{field}: expected {S} {what} (one per state), got {got}")
    if not np.all(np.isfinite(v)):
        raise BeliefError(f"{field}: contains non-finite values")
    return v


def check_belief(model: POMDP | int, b: np.ndarray, atol: float = 1e-6, field: str = "belief") -> np.ndarray:
    """Return ``b`` as a float array after checking it lies on the simplex of ``model``.

    The one belief rule of the package: ``S`` finite entries, none below ``-atol``, summing to 1
    within ``atol``; the result is clipped at 0 and renormalised. Errors are :class:`BeliefError`
    naming ``field``; the edges (CLI, nodes) translate them. ``model`` may be just the number of
    states ``S`` (for a message decoder, which knows nothing else of the model).
    """
    b = _state_vector(model, b, field, "probabilities")
    if np.any(b < -atol):
        raise BeliefError(f"{field}: entry {int(np.argmin(b))} is negative ({b.min():.3g})")
    total = b.sum()
    if abs(total - 1.0) > atol:
        raise BeliefError(f"{field}: sums to {total:.9g}, not 1 (tolerance {atol:g})")
    b = np.clip(b, 0.0, None)
    return b / b.sum()


def check_belief_rows(model: POMDP | int, rows, fields, atol: float = 1e-6) -> np.ndarray:
    """:func:`check_belief` for many beliefs of one model at once: ``rows`` (``n`` beliefs),
    ``fields[i]`` the name of row ``i``. Returns the ``n x S`` array of the checked beliefs (the
    same values :func:`check_belief` returns for each), validated with a few array operations
    instead of ``n`` calls; a row that breaks the rule is reported by :func:`check_belief` itself
    (the first such row, named by its field)."""
    S = int(model) if isinstance(model, (int, np.integer)) else model.S
    try:
        B = np.array(rows, dtype=float)
    except (TypeError, ValueError):
        B = None
    if B is None or B.shape != (len(fields), S) or not np.all(np.isfinite(B)) or np.any(B < -atol) \
            or np.any(np.abs(B.sum(axis=1) - 1.0) > atol):
        return np.array([check_belief(model, b, atol, field) for b, field in zip(rows, fields, strict=True)]
                        ).reshape(len(fields), S)
    B = np.clip(B, 0.0, None)
    return B / B.sum(axis=1, keepdims=True)


def check_likelihood(model: POMDP | int, values, field: str = "likelihood") -> np.ndarray:
    """Return ``values`` as a float array after checking it is a likelihood over the states of
    ``model``: ``S`` finite, non-negative entries, at least one positive (``l(s) = P(reading | s)``
    up to a constant factor: soft evidence, :mod:`~pomdp_planner.core.filter`). Errors are
    :class:`BeliefError` naming ``field``; ``model`` may be just ``S``, as for :func:`check_belief`."""
    lik = _state_vector(model, values, field, "values")
    if np.any(lik < 0):
        raise BeliefError(f"{field}: entry {int(np.argmin(lik))} is negative ({lik.min():.3g})")
    if not lik.max() > 0:
        raise BeliefError(f"{field}: every entry is 0 (a reading no state can produce is no evidence)")
    return lik


def check_action(model: POMDP, a: int) -> int:
    """Check a 0-based action index (the message shows the 1..A priority too)."""
    return check_int(a, "action", 0, model.A - 1, error=BeliefError, note=f"(0-based; priorities 1..{model.A})")


def check_observation(model: POMDP, z: int) -> int:
    """Check a 0-based observation index."""
    return check_int(z, "observation", 0, model.Z - 1, error=BeliefError)


def uniform_belief(model: POMDP) -> np.ndarray:
    return np.full(model.S, 1.0 / model.S)


# ----------------------------------------------------------------- single belief
def predict(model: POMDP, b: np.ndarray, a: int) -> np.ndarray:
    """Eq. 1: predicted belief ``b^a = b @ P[a]`` (``b`` of shape ``(S,)`` or ``(N, S)``)."""
    a = check_action(model, a)
    if model.sparse:
        return vecmat(model.P_csr, a, b)
    return np.asarray(b, dtype=float) @ model.P[a]


def observation_column(model: POMDP, a: int, z: int) -> np.ndarray:
    """``O[a][:, z]``: the likelihood of observation ``z`` in each next state, shape ``(S,)``."""
    if model.sparse:
        return model.O_csr.T.dense_row(a, z)
    return model.O[a, :, z]


def observation_probabilities(model: POMDP, b: np.ndarray, a: int) -> np.ndarray:
    """``eta(. | b, a)``, the distribution of the next observation, shape ``(Z,)``."""
    a = check_action(model, a)
    ba = predict(model, b, a)
    if model.sparse:
        return vecmat(model.O_csr, a, ba)
    return ba @ model.O[a]


def update(model: POMDP, b: np.ndarray, a: int, z: int) -> np.ndarray:
    """Eq. 2: posterior ``tau(b, a, z)``; raises :class:`ImpossibleObservation` if ``eta = 0``."""
    a = check_action(model, a)
    z = check_observation(model, z)
    ba = predict(model, b, a)
    unnorm = ba * observation_column(model, a, z)
    eta = float(unnorm.sum())
    if not eta > ETA_MIN:
        raise ImpossibleObservation(a, z, eta, ba)
    return unnorm / eta


# ----------------------------------------------------------------- many beliefs
def predict_all(model: POMDP, B: np.ndarray) -> np.ndarray:
    """Eq. 1 for every action and a batch of beliefs: ``B (..., S)`` -> ``(..., A, S)``."""
    B = np.asarray(B, dtype=float)
    if model.sparse:
        flat = B.reshape(-1, model.S)
        out = np.stack([vecmat(model.P_csr, a, flat) for a in range(model.A)], axis=1)
        return out.reshape((*B.shape[:-1], model.A, model.S))
    return np.einsum("...i,aij->...aj", B, model.P)


def posteriors_all(model: POMDP, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 1-2 for all actions and observations of a batch of beliefs.

    Returns ``(tau, eta)`` with ``tau`` of shape ``(..., A, Z, S)`` and ``eta`` of shape
    ``(..., A, Z)``. Where ``eta <= ETA_MIN`` the posterior is undefined and ``tau`` is set
    to the predicted belief (it carries zero weight in any expectation).
    """
    ba = predict_all(model, B)  # (..., A, S)
    unnorm = ba[..., :, None, :] * np.swapaxes(model.O, 1, 2)  # (..., A, Z, S)
    eta = unnorm.sum(axis=-1)
    ok = eta > ETA_MIN
    tau = np.where(ok[..., None], unnorm / np.where(ok, eta, 1.0)[..., None], ba[..., :, None, :])
    return tau, eta


def update_batch(model: POMDP, B: np.ndarray, a: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2 for a batch: ``B (N, S)``, actions ``a (N,)``, observations ``z (N,)``.

    Returns ``(posteriors, eta)``; rows with ``eta <= ETA_MIN`` keep the predicted belief
    and the caller decides what to do with them (their ``eta`` is returned).
    """
    B = np.asarray(B, dtype=float)
    a = np.asarray(a, dtype=int)
    z = np.asarray(z, dtype=int)
    if np.any((a < 0) | (a >= model.A)):
        raise BeliefError(f"action: indices out of range 0..{model.A - 1}")
    if np.any((z < 0) | (z >= model.Z)):
        raise BeliefError(f"observation: indices out of range 0..{model.Z - 1}")
    if model.sparse:
        ba = np.empty_like(B)
        lik = np.empty_like(B)
        for act in np.unique(a):
            sel = np.flatnonzero(a == act)
            ba[sel] = vecmat(model.P_csr, int(act), B[sel])
            lik[sel] = model.O_csr.T[int(act)][z[sel]].toarray()
        unnorm = ba * lik
    else:
        ba = np.einsum("ni,nij->nj", B, model.P[a])
        unnorm = ba * model.O[a, :, z]
    eta = unnorm.sum(axis=-1)
    ok = eta > ETA_MIN
    post = np.where(ok[:, None], unnorm / np.where(ok, eta, 1.0)[:, None], ba)
    return post, eta


def observation_branches(model: POMDP, b: np.ndarray, a: int) -> tuple[np.ndarray, np.ndarray, sp.csr_array]:
    """The observations that can follow action ``a`` from belief ``b`` and their posteriors (Eqs. 1-2).

    Returns ``(z, eta, tau)``: the observations with ``eta(z | b, a) > ETA_MIN`` in increasing
    order, their probabilities, and their posteriors ``tau(b, a, z)`` as the rows of a
    ``len(z) x S`` CSR matrix (the states outside a posterior's support are not stored). On a
    sparse model the work is proportional to the non-zeros of the rows of ``P[a]`` on the support
    of ``b`` and of ``O[a]`` on the support of ``b^a``; the values equal :func:`posteriors_all`'s
    to rounding.
    """
    a = check_action(model, a)
    b = np.asarray(b, dtype=float)
    if model.sparse:
        supp = np.flatnonzero(b)
        ba_rows = model.P_csr[a][supp]  # rows of P[a] reachable from b
        ba_sparse = sp.csr_array(b[supp][None, :]) @ ba_rows  # 1 x S
        ba_sparse.sum_duplicates()
        states, pred = ba_sparse.indices, ba_sparse.data
        keep = pred != 0.0
        states, pred = states[keep], pred[keep]
        joint = (sp.diags_array(pred) @ model.O_csr[a][states]).T.tocsr()  # Z x |support|: pred_j O[a, j, z]
        joint.sum_duplicates()
        eta_all = row_sums(joint)
        zs = np.flatnonzero(eta_all > ETA_MIN)
        rows = joint[zs]
        rows.sum_duplicates()
        counts = np.diff(rows.indptr)
        data = rows.data / np.repeat(eta_all[zs], counts)
        tau = sp.csr_array((data, states[rows.indices], rows.indptr), shape=(zs.size, model.S))
        tau.sort_indices()
        return zs, eta_all[zs], tau
    ba = b @ model.P[a]
    unnorm = ba[None, :] * model.O[a].T  # (Z, S)
    eta = unnorm.sum(axis=-1)
    zs = np.flatnonzero(eta > ETA_MIN)
    return zs, eta[zs], sp.csr_array(unnorm[zs] / eta[zs, None])


def start_belief(model: POMDP) -> np.ndarray | None:
    """The model's initial belief from ``metadata["start"]``, or ``None`` if it has none.

    Accepted forms (YAML ``start:`` field, or a Cassandra ``start:`` line after import): a
    list of ``S`` probabilities, the word ``uniform``, or the name of a state (all mass on
    it). Raises :class:`~pomdp_planner.core.model.ModelError` naming ``start`` otherwise.
    """
    start = model.metadata.get("start")
    if start is None:
        return None
    if isinstance(start, str):
        if start == "uniform":
            return uniform_belief(model)
        if model.state_names is not None and start in model.state_names:
            b = np.zeros(model.S)
            b[model.state_names.index(start)] = 1.0
            return b
        raise ModelError(f"start: expected a list of {model.S} probabilities, 'uniform' or a state name, "
                         f"got {short_repr(start)}")
    try:
        b = np.asarray(start, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ModelError(f"start: expected a list of {model.S} numbers, got {short_repr(start)}") from None
    try:
        return check_belief(model, b, field="start")
    except BeliefError as exc:
        raise ModelError(str(exc)) from None


def posterior_floor(model: POMDP) -> float:
    """Smallest coordinate of any posterior ``tau(b, a, z)`` (with ``eta > 0``) over the simplex.

    Each coordinate of ``tau(b, a, z)`` (Eq. 2) is a linear-fractional function of ``b`` with a
    positive denominator, so its minimum over the simplex is attained at a vertex ``e_i``: the
    minimum over the posteriors of the point-mass beliefs. If ``epsilon <= posterior_floor``,
    every posterior lies in ``B_epsilon``, which the Shannon bounds need (docs/THEORY.md).

    On a sparse model a zero in a row of some ``P[a]`` makes the floor 0 (that state is absent
    from every posterior of that point mass), found without building the posteriors.
    """
    if model.sparse and model.S > 1 and np.any(model.P_csr.row_nnz() < model.S):
        return 0.0
    tau, eta = posteriors_all(model, np.eye(model.S))  # (S, A, Z, S), (S, A, Z)
    mins = tau.min(axis=-1)[eta > ETA_MIN]
    return float(mins.min()) if mins.size else 0.0
