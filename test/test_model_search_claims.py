"""What docs/MODEL_SEARCH.md claims about persistent targets and Assumption 1, pinned.

The claim is scoped: slowly mixing targets whose motion the priority shifts fail (A2) in the
families tried at S >= 3; it is not a law. At S = 2 a birth-death chain that stays put with
probability 0.98 and whose up/down rates depend on the priority satisfies (A1)-(A3)
(``test/models/birth_death_s2.yaml``), and the same chain on three states does not.

The package's checker (``core.structure.check_assumptions``, and ``pomdp-planner check``) is
compared with a brute-force reading of the definitions written here: 2x2 minors for (A1), the
likelihood-ratio order of the two posteriors of Lemma 1 (L2) on a grid of beliefs for (A2), the
cumulative sums of the predicted observation for (A3).
"""

from __future__ import annotations

import itertools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.structure import check_assumptions
from tools.lookahead_models import birth_death_transitions

REPO = Path(__file__).resolve().parent.parent
FIXTURE = REPO / "test" / "models" / "birth_death_s2.yaml"
STAY = 0.98
UP_SHARE = (0.25, 0.5, 0.75)  # share of the 0.02 move that goes up, priorities 1, 2, 3


def birth_death(S: int) -> np.ndarray:
    """``P[a]``: one state up or down per step, stay 0.98; a blocked move stays put."""
    return birth_death_transitions(S, [((1 - STAY) * share, (1 - STAY) * (1 - share)) for share in UP_SHARE])


def sensor(S: int) -> np.ndarray:
    """One positive, TP2 sensor for every priority: a discretised Gaussian around the state."""
    k = np.exp(-0.5 * (np.subtract.outer(np.arange(S), np.arange(S)) / 0.6) ** 2)
    O = k / k.sum(axis=1, keepdims=True)
    return np.stack([O] * len(UP_SHARE))


def model(S: int) -> POMDP:
    r = -np.outer(np.linspace(0, 1, S), [1.0, 3.0, 5.0]) - np.array([0.8, 0.3, 0.0])
    return POMDP(P=birth_death(S), O=sensor(S), r=r, gamma=0.95, uncertainty="renyi2",
                 w=np.full(3, 0.05), name=f"birth_death_s{S}")


# ---------------------------------------------------------------- brute force, from the definitions
def tp2(M: np.ndarray) -> bool:
    rows, cols = M.shape
    return all(M[i, k] * M[j, l] - M[i, l] * M[j, k] >= -1e-15
               for i, j in itertools.combinations(range(rows), 2) for k, l in itertools.combinations(range(cols), 2))


def mlr_geq(x: np.ndarray, y: np.ndarray) -> bool:
    """``x >=_r y``: ``x_i y_j <= y_i x_j`` for every ``i < j`` (Definition 1)."""
    return all(x[i] * y[j] <= y[i] * x[j] + 1e-15 for i, j in itertools.combinations(range(len(x)), 2))


def posterior(P: np.ndarray, O: np.ndarray, b: np.ndarray, a: int, z: int) -> np.ndarray | None:
    u = (b @ P[a]) * O[a][:, z]
    return None if u.sum() <= 0 else u / u.sum()


def simplex_grid(S: int, n: int) -> list[np.ndarray]:
    return [np.array(k, dtype=float) / n for k in itertools.product(range(n + 1), repeat=S) if sum(k) == n]


def a2_counterexample(P: np.ndarray, O: np.ndarray, n: int) -> tuple | None:
    """A grid belief, priorities and observation where Lemma 1 (L2) fails, or None."""
    for b in simplex_grid(P.shape[1], n):
        for a in range(P.shape[0] - 1):
            for z in range(O.shape[2]):
                lo, hi = posterior(P, O, b, a, z), posterior(P, O, b, a + 1, z)
                if lo is not None and hi is not None and not mlr_geq(hi, lo):
                    return b, a, z
    return None


def a3_holds(P: np.ndarray, O: np.ndarray) -> bool:
    eta = np.einsum("aij,ajz->aiz", P, O)  # eta[a, i] = predicted observation from e_i
    c = np.cumsum(eta, axis=2)[:, :, :-1]
    return bool(np.all(c[:-1] >= c[1:] - 1e-15))


# ---------------------------------------------------------------------------------- the claims
def test_fixture_is_the_documented_chain():
    m = load_model(FIXTURE)
    np.testing.assert_allclose(m.P, birth_death(2), atol=1e-15)
    assert np.all(np.diagonal(m.P, axis1=1, axis2=2) >= STAY)
    assert len({tuple(row) for a in range(m.A) for row in m.P[a]}) == 2 * m.A  # the rates depend on the priority


def test_s2_birth_death_chain_satisfies_assumption_1_brute_force_and_checker():
    m = load_model(FIXTURE)
    assert all(tp2(m.P[a]) and tp2(m.O[a]) for a in range(m.A))
    assert a2_counterexample(m.P, m.O, n=400) is None
    assert a3_holds(m.P, m.O)
    report = check_assumptions(m)
    assert report.holds, report.summary()


def test_pomdp_planner_check_proves_the_s2_chain():
    exe = Path(sys.executable).with_name("pomdp-planner")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "pomdp_planner"]
    out = subprocess.run([*cmd, "check", str(FIXTURE)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Assumption 1 holds" in out.stdout


@pytest.mark.parametrize("S", [2, 3])
def test_same_chain_fails_a2_from_three_states_on(S):
    m = model(S)
    assert all(tp2(m.P[a]) and tp2(m.O[a]) for a in range(m.A))
    assert a3_holds(m.P, m.O)
    found = a2_counterexample(m.P, m.O, n=40)
    report = check_assumptions(m)
    if S == 2:
        assert found is None and report.holds
    else:
        assert found is not None, "brute force finds a belief where the posteriors break the MLR order"
        assert not report.holds and not report.copositivity.holds, report.summary()
