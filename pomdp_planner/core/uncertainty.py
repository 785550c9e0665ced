"""Uncertainty functions ``f(b)`` of the information reward (paper Eq. 3).

The reward of the paper is ``rho(b, a) = sum_s r(s, a) b(s) - w_a f(b)`` (Sec. II-A, Eq. 3).
Every function here works on a single belief of shape ``(S,)`` or on a batch of shape
``(..., S)`` and returns values of shape ``(...)`` and gradients of shape ``(..., S)``.
Zero entries of a belief are handled without NaN (``0 log 0 = 0``); the Shannon gradient
``-(1 + log b)`` is unbounded at ``b_i = 0`` and is evaluated at ``max(b_i, tiny)`` there.

Names accepted in model files: ``"shannon"``, ``"renyi2"`` and ``"none"``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

_TINY = np.finfo(float).tiny


def _shannon(b: np.ndarray) -> np.ndarray:
    """Shannon entropy ``-sum_i b_i log b_i`` in nats (Sec. IV, Example 2)."""
    b = np.asarray(b, dtype=float)
    safe = np.where(b > 0.0, b, 1.0)
    return -np.sum(np.where(b > 0.0, b * np.log(safe), 0.0), axis=-1)


def _shannon_grad(b: np.ndarray) -> np.ndarray:
    """Gradient of Shannon entropy, ``-(1 + log b_i)`` (Example 2)."""
    b = np.asarray(b, dtype=float)
    return -(1.0 + np.log(np.maximum(b, _TINY)))


def _renyi2(b: np.ndarray) -> np.ndarray:
    """Renyi quadratic entropy ``-log sum_i b_i^2`` (Example 3)."""
    b = np.asarray(b, dtype=float)
    return -np.log(np.sum(b * b, axis=-1))


def _renyi2_grad(b: np.ndarray) -> np.ndarray:
    """Gradient of Renyi quadratic entropy, ``-2 b / sum_j b_j^2`` (Example 3)."""
    b = np.asarray(b, dtype=float)
    return -2.0 * b / np.sum(b * b, axis=-1, keepdims=True)


def _zero(b: np.ndarray) -> np.ndarray:
    b = np.asarray(b, dtype=float)
    return np.zeros(b.shape[:-1])


def _zero_grad(b: np.ndarray) -> np.ndarray:
    return np.zeros_like(np.asarray(b, dtype=float))


@dataclass(frozen=True)
class Uncertainty:
    """An uncertainty function ``f`` with its gradient, both vectorised over beliefs."""

    name: str
    value: Callable[[np.ndarray], np.ndarray]
    gradient: Callable[[np.ndarray], np.ndarray]

    def __call__(self, b: np.ndarray) -> np.ndarray:
        return self.value(b)


SHANNON = Uncertainty("shannon", _shannon, _shannon_grad)
RENYI2 = Uncertainty("renyi2", _renyi2, _renyi2_grad)
NONE = Uncertainty("none", _zero, _zero_grad)

UNCERTAINTY_FUNCTIONS: dict[str, Uncertainty] = {u.name: u for u in (SHANNON, RENYI2, NONE)}


def get_uncertainty(name: str) -> Uncertainty:
    """Return the uncertainty function called ``name`` (``shannon``, ``renyi2`` or ``none``).

    Anything else, including a value that is not a string (a list, a mapping, a number, null
    from a model file), is a ``ValueError`` naming ``uncertainty.function``; the message quotes
    at most 40 characters of the name.
    """
    known = ", ".join(sorted(UNCERTAINTY_FUNCTIONS))
    if not isinstance(name, str):
        got = "null" if name is None else f"a {type(name).__name__}"
        raise ValueError(f"uncertainty.function: must be the name of a function ({known}), got {got}")
    try:
        return UNCERTAINTY_FUNCTIONS[name]
    except KeyError:
        shown = repr(name) if len(name) <= 40 else repr(name[:37]) + "..."
        raise ValueError(f"uncertainty.function: unknown function {shown} (known: {known})") from None
