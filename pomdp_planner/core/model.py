"""The POMDP model object and its validation.

Conventions (used everywhere in this package; see docs/THEORY.md for the translation of
every formula of the paper):

* ``P[a, i, j] = P(next = j | prev = i, a)`` (row-stochastic, shape ``A x S x S``).
  The paper's ``T(s', s, a)``; its matrix ``T^a`` is written sometimes with previous states
  as rows and sometimes as columns, we always use rows.
* ``O[a, j, z] = P(z | next = j, a)`` (shape ``A x S x Z``). The paper's ``O^a_{z,j}``.
* ``r[s, a]`` (shape ``S x A``), ``w[a]`` (shape ``A``), discount ``gamma``.
* States, actions and observations are 0-based. Action index ``a`` is the paper's tracking
  priority ``a + 1`` (1 = greatest priority); conversion happens only at user-facing edges
  (:func:`priority_of`, :func:`action_of_priority`).

The expected reward is ``rho(b, a) = b . r[:, a] - w[a] f(b)`` (paper Eq. 3).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .uncertainty import Uncertainty, get_uncertainty

#: Rows of ``P`` and ``O`` must sum to one within this absolute tolerance.
STOCHASTIC_ATOL = 1e-6


class ModelError(ValueError):
    """A model is malformed: the message names the field and the problem."""


def priority_of(action: int | np.ndarray) -> int | np.ndarray:
    """0-based action index -> the paper's tracking priority 1..A (user-facing)."""
    return action + 1


def action_of_priority(priority: int, num_actions: int) -> int:
    """Tracking priority 1..A -> 0-based action index, with a clear error when out of range."""
    if isinstance(priority, bool) or not isinstance(priority, (int, np.integer)):
        raise ModelError(f"action: priority must be an integer in 1..{num_actions}, got {priority!r}")
    if not 1 <= priority <= num_actions:
        raise ModelError(f"action: priority {priority} is out of range 1..{num_actions}")
    return int(priority) - 1


def _frozen(x: np.ndarray) -> np.ndarray:
    x = np.array(x, dtype=float, copy=True)
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


def _names(field_name: str, names: Sequence[str] | None, n: int) -> tuple[str, ...] | None:
    if names is None:
        return None
    names = tuple(str(x) for x in names)
    if len(names) != n:
        raise ModelError(f"{field_name}: {len(names)} names given for {n} entries")
    if len(set(names)) != n:
        raise ModelError(f"{field_name}: names are not unique")
    return names


@dataclass(frozen=True, eq=False)
class POMDP:
    """An immutable information-acquisition POMDP (paper Sec. II).

    Arrays are copied and made read-only on construction, and validated: shapes, finite
    values, non-negative probabilities, rows summing to 1 within :data:`STOCHASTIC_ATOL`,
    ``0 <= gamma < 1``, finite weights. Errors are :class:`ModelError` naming the field.
    """

    P: np.ndarray
    O: np.ndarray
    r: np.ndarray
    gamma: float
    uncertainty: Uncertainty | str = "none"
    w: np.ndarray | Sequence[float] | None = None
    epsilon: float = 1e-3
    name: str = "pomdp"
    state_names: Sequence[str] | None = None
    action_names: Sequence[str] | None = None
    observation_names: Sequence[str] | None = None
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        try:
            P = np.asarray(self.P, dtype=float)
            O = np.asarray(self.O, dtype=float)
            r = np.asarray(self.r, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ModelError(f"model matrices must be numeric arrays of consistent shape: {exc}") from None
        if P.ndim != 3 or P.shape[1] != P.shape[2]:
            raise ModelError(f"transition: expected shape A x S x S, got {P.shape}")
        A, S, _ = P.shape
        if A < 1 or S < 1:
            raise ModelError(f"transition: needs at least one action and one state, got shape {P.shape}")
        if O.ndim != 3 or O.shape[0] != A or O.shape[1] != S:
            raise ModelError(f"observation: expected shape {A} x {S} x Z (A x S x Z), got {O.shape}")
        if O.shape[2] < 1:
            raise ModelError("observation: needs at least one observation")
        if r.shape != (S, A):
            raise ModelError(f"reward: expected shape {S} x {A} (S x A), got {r.shape}")
        _check_stochastic("transition", P, "previous state", "next states")
        _check_stochastic("observation", O, "next state", "observations")
        if not np.all(np.isfinite(r)):
            s, a = np.argwhere(~np.isfinite(r))[0]
            raise ModelError(f"reward[{s}][{a}]: value is not finite ({r[s, a]})")
        try:
            gamma = float(self.gamma)
        except (TypeError, ValueError):
            raise ModelError(f"discount: must be a number, got {self.gamma!r}") from None
        if not (0.0 <= gamma < 1.0):
            raise ModelError(f"discount: must satisfy 0 <= gamma < 1, got {gamma}")
        unc = self.uncertainty
        if isinstance(unc, str):
            try:
                unc = get_uncertainty(unc)
            except ValueError as exc:
                raise ModelError(str(exc)) from None
        try:
            w = np.zeros(A) if self.w is None else np.asarray(self.w, dtype=float)
        except (TypeError, ValueError):
            raise ModelError(f"uncertainty.weights: must be numbers, got {self.w!r}") from None
        if w.ndim == 0:
            w = np.full(A, float(w))
        if w.shape != (A,):
            raise ModelError(f"uncertainty.weights: expected {A} weights (one per action), got shape {w.shape}")
        if not np.all(np.isfinite(w)):
            raise ModelError(f"uncertainty.weights[{int(np.argmax(~np.isfinite(w)))}]: weight is not finite")
        try:
            eps = float(self.epsilon)
        except (TypeError, ValueError):
            raise ModelError(f"uncertainty.epsilon: must be a number, got {self.epsilon!r}") from None
        if not (0.0 < eps < 1.0 / S or (S == 1 and 0.0 < eps <= 1.0)):
            raise ModelError(f"uncertainty.epsilon: must satisfy 0 < epsilon < 1/S = {1.0 / S:.6g}, got {eps}")
        set_(self, "P", _frozen(P))
        set_(self, "O", _frozen(O))
        set_(self, "r", _frozen(r))
        set_(self, "gamma", gamma)
        set_(self, "uncertainty", unc)
        set_(self, "w", _frozen(w))
        set_(self, "epsilon", eps)
        set_(self, "name", str(self.name))
        set_(self, "state_names", _names("states", self.state_names, S))
        set_(self, "action_names", _names("actions", self.action_names, A))
        set_(self, "observation_names", _names("observations", self.observation_names, O.shape[2]))
        set_(self, "metadata", dict(self.metadata))

    # ------------------------------------------------------------------ sizes
    @property
    def num_states(self) -> int:
        return self.P.shape[1]

    @property
    def num_actions(self) -> int:
        return self.P.shape[0]

    @property
    def num_observations(self) -> int:
        return self.O.shape[2]

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
        return (
            f"{self.name}: S={self.S} A={self.A} Z={self.Z} gamma={self.gamma:g} "
            f"uncertainty={self.uncertainty.name}"
        )
