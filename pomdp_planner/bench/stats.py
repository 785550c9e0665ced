"""Statistics shared by the measurements (the peer comparison, the model search, the MCTS bench)."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import t as student_t


def mean_ci(x: np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and 95 % Student-t confidence interval (a single value: the interval is that value)."""
    x = np.asarray(x, dtype=float)
    m = float(np.mean(x))
    if x.size < 2:
        return m, (m, m)
    half = float(student_t.ppf(0.975, x.size - 1)) * float(np.std(x, ddof=1)) / math.sqrt(x.size)
    return m, (m - half, m + half)
