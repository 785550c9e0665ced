"""The MLR-exact constant of the Renyi bound LP (docs/THEORY.md, "Theorem M"), checked numerically.

Theorem M: for ``phi`` in R^S and a weight ``w``, the function

    psi(b) = phi . b + w log sum_i b_i^2        (rho_lower of Eq. 8 for Renyi quadratic entropy)

is MLR increasing on the closed simplex iff every step ``phi[i+1] - phi[i] >= 2 |w|``, and MLR
decreasing iff every step ``<= -2 |w|``.

Nothing here uses the bound LP (core/bounds.py): ``psi`` is evaluated from its definition, MLR
pairs are built from the definition of the order (and checked against it), and the proof's
inequality is evaluated from its own definitions. Every check has a counterpart showing that the
same harness does find violations when the constant is wrong (``2 |w| (1 - eta)``), so none of
them can pass vacuously.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.myopic import MyopicBounds

ROOT = Path(__file__).resolve().parents[1]
S3 = ROOT / "config" / "models" / "tracking_s3_info.yaml"
SIZES = (2, 3, 4, 5, 8, 16, 64)


# ------------------------------------------------------------------ definitions
def psi(phi: np.ndarray, w: float, B: np.ndarray) -> np.ndarray:
    """``phi . b + w log sum b^2`` for beliefs ``B`` of shape ``(..., S)``."""
    return B @ phi + w * np.log(np.sum(B * B, axis=-1))


def psi_shannon(phi: np.ndarray, w: float, B: np.ndarray) -> np.ndarray:
    """``phi . b + w sum b log b`` (rho_lower for Shannon entropy, ``-w f`` with ``f = -sum b log b``)."""
    return B @ phi + w * np.sum(B * np.log(B), axis=-1)


def mlr_geq(Bp: np.ndarray, B: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """``b' >=_r b`` by Definition 1.3: ``b'_i b_j <= b_i b'_j`` for every ``i < j``."""
    M = B[..., :, None] * Bp[..., None, :] - B[..., None, :] * Bp[..., :, None]  # b_i b'_j - b_j b'_i
    iu = np.triu_indices(B.shape[-1], 1)
    return np.all(M[..., iu[0], iu[1]] >= -tol, axis=-1)


def phi_with_steps(rng: np.random.Generator, S: int, w: float, factor: float = 1.0, extra: bool = True) -> np.ndarray:
    """A random ``phi`` whose steps are ``2 |w| factor`` plus (if ``extra``) random non-negative
    amounts, some exactly zero (those steps are exactly at the constant)."""
    steps = np.full(S - 1, 2 * abs(w) * factor)
    if extra:
        steps = steps + rng.exponential(3 * abs(w) + 1, S - 1) * (rng.random(S - 1) < 0.5)
    return rng.normal(0, 10) + np.concatenate([[0.0], np.cumsum(steps)])


def _normalise(X: np.ndarray) -> np.ndarray:
    return X / X.sum(axis=-1, keepdims=True)


# ------------------------------------------------------------------ MLR-ordered pairs
def tilt_pairs(rng: np.random.Generator, S: int, n: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """``b ~ Dirichlet(alpha)`` (sparse for small alpha, with exact zeros), ``b' ∝ b∘l`` with
    ``l >= 0`` increasing (a zero prefix of ``l`` gives ``b'`` a smaller support)."""
    B = rng.dirichlet(np.full(S, alpha), n)
    B[B < 1e-4] = 0.0
    B[np.arange(n), rng.integers(0, S, n)] += 1e-3  # never all zero
    B = _normalise(B)
    inc = rng.exponential(1.0, (n, S)) * (rng.random((n, S)) < 0.6)
    inc *= np.exp(rng.uniform(-8, 3, (n, 1)))  # tiny to large tilts
    inc[:, 0] = rng.exponential(1.0, n) * (rng.random(n) < 0.5)
    L = np.cumsum(inc, axis=1)
    L[:, -1] += 1e-9
    ok = (B * L).sum(axis=1) > 0
    return B[ok], _normalise(B[ok] * L[ok])


def near_vertex_pairs(rng: np.random.Generator, S: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Two-point beliefs on ``k < j``: ``b = (1-x1) e_k + x1 e_j``, ``b'`` the same with
    ``x2 >= x1``. Half of them sit at the lower vertex (``x1 = 0`` or small, ``x2`` log-uniform
    down to 1e-7), half mirrored at the upper one (``x2 = 1`` or close, ``x1`` just below)."""
    k = rng.integers(0, S - 1, n)
    d = np.where(rng.random(n) < 0.6, 1, rng.integers(1, S, n))
    j = np.minimum(k + d, S - 1)
    x2 = np.exp(rng.uniform(math.log(1e-7), 0, n))
    x1 = np.where(rng.random(n) < 0.5, 0.0, x2 * rng.random(n))
    upper = rng.random(n) < 0.5
    x1, x2 = np.where(upper, 1 - x2, x1), np.where(upper, 1 - x1, x2)
    B = np.zeros((n, S))
    Bp = np.zeros((n, S))
    r = np.arange(n)
    B[r, k] += 1 - x1
    B[r, j] += x1
    Bp[r, k] += 1 - x2
    Bp[r, j] += x2
    return B, Bp


def two_block_pairs(rng: np.random.Generator, S: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``b`` uniform on two contiguous blocks (random weights), ``b'`` its tilt across one cut
    ``m``: ``b' ∝ b∘(1 + c 1_{>=m})`` -- the extreme directions of the proof."""
    B = np.zeros((n, S))
    for t in range(n):
        a0 = rng.integers(0, S)
        a1 = rng.integers(a0, S)
        c0 = rng.integers(a1, S)
        c1 = rng.integers(c0, S)
        B[t, a0:a1 + 1] += (rng.random() + 0.01) / (a1 - a0 + 1)
        B[t, c0:c1 + 1] += (rng.random() + 0.01) / (c1 - c0 + 1)
    B = _normalise(B)
    m = rng.integers(1, max(S, 2), n)
    c = np.exp(rng.uniform(-12, 4, n))
    L = 1 + c[:, None] * (np.arange(S)[None, :] >= m[:, None])
    return B, _normalise(B * L)


def split_support_pairs(rng: np.random.Generator, S: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """General MLR pairs with different supports: from a common ``e`` and increasing ``l >= 0``,
    ``b`` = ``e`` cut to states ``<= k2`` and ``b'`` = ``e∘l`` cut to states ``>= k1`` (any
    ``k1, k2``; ``k1 > k2`` gives disjoint supports). Includes vertices vs mixtures."""
    out_b, out_bp = [], []
    while len(out_b) < n:
        e = rng.dirichlet(np.full(S, 0.4))
        e[rng.random(S) < 0.2] = 0.0
        l = np.cumsum(rng.exponential(1.0, S) * (rng.random(S) < 0.6))
        k1, k2 = rng.integers(0, S, 2)
        b = np.where(np.arange(S) <= k2, e, 0.0)
        bp = np.where(np.arange(S) >= k1, e * l, 0.0)
        if rng.random() < 0.2:  # a vertex against a mixture above it
            b = np.eye(S)[k2]
            bp = np.where(np.arange(S) >= k2, e + 1e-3 * (np.arange(S) == k2), 0.0)
        if b.sum() > 0 and bp.sum() > 0:
            out_b.append(b / b.sum())
            out_bp.append(bp / bp.sum())
    return np.array(out_b), np.array(out_bp)


def all_pairs(rng: np.random.Generator, S: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    parts = [tilt_pairs(rng, S, n, 1.0), tilt_pairs(rng, S, n, 0.05), near_vertex_pairs(rng, S, max(n, 16 * S)),
             two_block_pairs(rng, S, n), split_support_pairs(rng, S, n)]
    B = np.concatenate([p[0] for p in parts])
    Bp = np.concatenate([p[1] for p in parts])
    return B, Bp


def worst_gap(phi: np.ndarray, w: float, B: np.ndarray, Bp: np.ndarray, decreasing: bool = False) -> float:
    """Smallest ``psi(b') - psi(b)`` (largest for ``decreasing``, sign-flipped) over the pairs,
    relative to the size of the values (so rounding cannot count as a violation)."""
    d = psi(phi, w, Bp) - psi(phi, w, B)
    scale = 1.0 + np.max(np.abs(phi)) + abs(w) * math.log(B.shape[-1] + 1)
    return float(np.min(-d if decreasing else d) / scale)


TOL = 1e-11


# ------------------------------------------------------------------ the generators are MLR pairs
@pytest.mark.parametrize("S", SIZES)
def test_generated_pairs_are_mlr_ordered_and_varied(S: int) -> None:
    rng = np.random.default_rng(S)
    B, Bp = all_pairs(rng, S, 300)
    assert np.all(mlr_geq(Bp, B)) and np.allclose(B.sum(1), 1) and np.allclose(Bp.sum(1), 1)
    assert np.all(B >= 0) and np.all(Bp >= 0)
    # the families really reach the boundary: vertices, and pairs whose supports differ
    assert np.any(np.max(B, axis=1) == 1.0)
    if S > 2:
        assert np.any(((B > 0) != (Bp > 0)).any(axis=1))
    assert not np.all(mlr_geq(B, Bp))  # not all trivial (b' == b)


# ------------------------------------------------------------------ the theorem on adversarial pairs
@pytest.mark.parametrize("S", SIZES)
@pytest.mark.parametrize("w", [0.05, 1.0, 1.6, 30.0, -1.0])
def test_steps_of_two_w_make_psi_mlr_increasing(S: int, w: float) -> None:
    """Steps exactly 2|w| (and >= 2|w|): no MLR-ordered pair decreases psi (any sign of w)."""
    rng = np.random.default_rng(1000 * S + int(10 * abs(w)) + (w < 0))
    B, Bp = all_pairs(rng, S, 400)
    for extra in (False, True):
        phi = phi_with_steps(rng, S, w, extra=extra)
        assert worst_gap(phi, w, B, Bp) >= -TOL


@pytest.mark.parametrize("S", SIZES)
@pytest.mark.parametrize("eta", [1e-3, 1e-2, 0.2])
@pytest.mark.parametrize("w", [1.3, -1.3])
def test_same_harness_finds_violations_below_two_w(S: int, eta: float, w: float) -> None:
    """The harness has teeth: one step of 2|w|(1 - eta) (all others far above) is caught."""
    rng = np.random.default_rng(77 * S)
    B, Bp = all_pairs(rng, S, 400)
    phi = phi_with_steps(rng, S, w, factor=1.0 + 2.0)  # every step 6w or more
    k = int(rng.integers(0, S - 1))
    steps = np.diff(phi)
    steps[k] = 2 * abs(w) * (1 - eta)
    phi = phi[0] + np.concatenate([[0.0], np.cumsum(steps)])
    assert worst_gap(phi, w, B, Bp) < -TOL


@settings(max_examples=300)
@given(S=st.integers(2, 12), data=st.data())
def test_property_any_mlr_pair(S: int, data: st.DataObject) -> None:
    """Hypothesis draws any MLR pair (common weights ``e`` with zeros, increasing ``l >= 0``,
    supports cut at ``k1``, ``k2``), any weight sign and steps >= 2|w|; psi never decreases, and
    the h-side statement (steps <= -2|w| gives MLR decreasing) holds on the same pair."""
    pos = st.one_of(st.just(0.0), st.floats(1e-12, 1.0))
    e = np.array(data.draw(st.lists(pos, min_size=S, max_size=S)))
    l = np.cumsum(data.draw(st.lists(st.one_of(st.just(0.0), st.floats(0.0, 1e3)), min_size=S, max_size=S)))
    k1 = data.draw(st.integers(0, S - 1))
    k2 = data.draw(st.integers(0, S - 1))
    idx = np.arange(S)
    b = np.where(idx <= k2, e, 0.0)
    bp = np.where(idx >= k1, e * l, 0.0)
    if b.sum() <= 0 or bp.sum() <= 0:
        return
    b, bp = b / b.sum(), bp / bp.sum()
    assert mlr_geq(bp, b)
    w = data.draw(st.floats(-50, 50))
    extra = np.array(data.draw(st.lists(st.one_of(st.just(0.0), st.floats(0.0, 100.0)),
                                        min_size=S - 1, max_size=S - 1)))
    phi = data.draw(st.floats(-100, 100)) + np.concatenate([[0.0], np.cumsum(2 * abs(w) + extra)])
    assert worst_gap(phi, w, b[None], bp[None]) >= -TOL
    assert worst_gap(-phi, w, b[None], bp[None], decreasing=True) >= -TOL


def _min_normalised_gap(phi: np.ndarray, w: float, starts: int, seed: int) -> float:
    """Adversarial search: minimise ``(psi(b') - psi(b)) / (|w| ||b' - b||_1)`` over interior MLR
    pairs ``b = softmax(z)``, ``b' ∝ b∘exp(u)``, ``u`` increasing, from many starts (L-BFGS-B)."""
    S = phi.size
    rng = np.random.default_rng(seed)

    def pair(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z, s = x[:S], x[S:]
        u = np.concatenate([[0.0], np.cumsum(np.exp(s))])
        b = np.exp(z - z.max())
        bp = b * np.exp(u - u.max())
        return b / b.sum(), bp / bp.sum()

    def obj(x: np.ndarray) -> float:
        b, bp = pair(x)
        d = bp - b
        dist = np.abs(d).sum()
        if dist < 1e-7:  # below this, rounding would dominate the quotient
            return 0.0
        # psi(b') - psi(b) without cancellation: phi . d + w log(1 + sum d (b' + b) / sum b^2)
        gap = phi @ d + w * math.log1p(float(d @ (bp + b)) / float(b @ b))
        return float(gap / (abs(w) * dist))

    best = np.inf
    bounds = [(-40, 40)] * S + [(-25, 4)] * (S - 1)
    for _ in range(starts):
        x0 = np.concatenate([rng.normal(0, rng.choice([1.0, 5.0, 15.0]), S), rng.uniform(-10, 2, S - 1)])
        res = minimize(obj, x0, method="L-BFGS-B", bounds=bounds, options={"maxiter": 300})
        b, bp = pair(res.x)
        assert mlr_geq(bp, b, tol=1e-10)
        best = min(best, obj(res.x))
    return best


@pytest.mark.parametrize("S", [2, 3, 4, 6, 10])
def test_adversarial_search_finds_no_violation_and_has_teeth(S: int) -> None:
    rng = np.random.default_rng(S)
    w = 0.7
    phi = phi_with_steps(rng, S, w, extra=False)  # every step exactly 2w: the hardest case
    assert _min_normalised_gap(phi, w, starts=12, seed=S) >= -1e-7
    phi_bad = phi_with_steps(rng, S, w, factor=0.9, extra=False)  # 2w (1 - 0.1)
    assert _min_normalised_gap(phi_bad, w, starts=12, seed=S) < -1e-3


# ------------------------------------------------------------------ tightness (step 3 of the proof)
@pytest.mark.parametrize("S", [2, 3, 8, 64])
@pytest.mark.parametrize("eta", [1e-3, 1e-2, 0.1, 0.5, 3.0])
@pytest.mark.parametrize("w", [0.4, -0.4, 2.0, -2.0])
def test_one_step_below_two_w_gives_an_explicit_violating_pair(S: int, eta: float, w: float) -> None:
    """Step ``k`` = 2|w|(1 - eta), all other steps arbitrary (here large). For ``w > 0`` the pair
    ``b = e_k``, ``b' = (1-x) e_k + x e_{k+1}``; for ``w < 0`` the mirrored pair
    ``b = (1-x) e_{k+1} + x e_k``, ``b' = e_{k+1}``. With ``x = min(sqrt(eta), 1)/2`` the proof
    gives ``psi(b') - psi(b) <= -|w| eta x < 0`` (``eta > 1``: a negative step)."""
    rng = np.random.default_rng(S)
    k = int(rng.integers(0, S - 1))
    steps = 2 * abs(w) + rng.exponential(10.0, S - 1)
    steps[k] = 2 * abs(w) * (1 - eta)
    phi = rng.normal() + np.concatenate([[0.0], np.cumsum(steps)])
    x = min(math.sqrt(eta), 1.0) / 2
    e = np.eye(S)
    if w > 0:
        b, bp = e[k], (1 - x) * e[k] + x * e[k + 1]
    else:
        b, bp = (1 - x) * e[k + 1] + x * e[k], e[k + 1]
    assert mlr_geq(bp, b)
    gap = psi(phi, w, bp) - psi(phi, w, b)
    assert gap <= -abs(w) * eta * x * (1 - 1e-9)
    if eta >= 1:
        return
    # a positive step: the other pair is no counterexample, the sign of w decides which end bites
    if w > 0:
        c, cp = (1 - x) * e[k + 1] + x * e[k], e[k + 1]
    else:
        c, cp = e[k], (1 - x) * e[k] + x * e[k + 1]
    assert psi(phi, w, cp) - psi(phi, w, c) > 0


def test_vertex_expansion_is_x_times_step_minus_two_w() -> None:
    """``psi(b') - psi(b) = x (step_k - 2w) + (4/3) w x^3 + O(x^4)`` on the vertex pair (the
    second formula is the series of ``log((1-x)^2 + x^2)``, evaluated independently)."""
    phi = np.array([0.0, 1.7, 5.0])
    w = 1.1
    for x in (1e-2, 3e-3, 1e-3):
        gap = psi(phi, w, np.array([1 - x, x, 0.0])) - psi(phi, w, np.array([1.0, 0.0, 0.0]))
        series = x * (1.7 - 2 * w) + 4 / 3 * w * x**3
        assert abs(gap - series) <= 3 * w * x**4


# ------------------------------------------------------------------ the inequality of step 2
def _parts(b: np.ndarray, m: int) -> dict[str, np.ndarray]:
    """A, B, L, U, Q, D, P, R of the proof, from their definitions, for the cut before state
    ``m`` (left block ``i < m``, right block ``j >= m``); ``b`` of shape ``(..., S)``."""
    S = b.shape[-1]
    i = np.arange(m)
    j = np.arange(m, S)
    left, right = b[..., :m], b[..., m:]
    out = {"A": left.sum(-1), "B": right.sum(-1), "L": (left**2).sum(-1), "U": (right**2).sum(-1)}
    out["Q"] = out["L"] + out["U"]
    out["D"] = np.einsum("...i,...j,ij->...", left, right, j[None, :] - i[:, None])
    out["P"] = left @ (m - i).astype(float)  # left positions p = m - i = 1, 2, ...
    out["R"] = right @ (j - m + 1).astype(float)  # right positions q = j - m + 1 = 1, 2, ...
    return out


def f_value(b: np.ndarray, m: int, factor: float = 1.0) -> np.ndarray:
    """``factor Q D + A U - B L`` (``factor = 1``: the proof's F; ``1 - eta``: a wrong constant)."""
    p = _parts(b, m)
    return factor * p["Q"] * p["D"] + p["A"] * p["U"] - p["B"] * p["L"]


def _random_beliefs(rng: np.random.Generator, S: int, n: int) -> np.ndarray:
    B = np.concatenate([rng.dirichlet(np.full(S, a), n) for a in (0.05, 0.3, 1.0, 5.0)])
    near = np.eye(S)[rng.integers(0, S, n)] * 0.999 + 0.001 * rng.dirichlet(np.ones(S), n)
    return np.concatenate([B, near])


@pytest.mark.parametrize("S", [2, 3, 5, 8, 20])
def test_tilt_derivative_is_two_w_over_q_times_f(S: int) -> None:
    """Step 1's identity: along the tilt ``b(t) ∝ b∘exp(t 1_{>=m})`` with steps exactly 2w,
    ``d psi / dt = (2w / Q) F(b, m)`` (central differences against the closed form)."""
    rng = np.random.default_rng(S)
    w = 0.8
    phi = 3.0 + 2 * w * np.arange(S)
    for b in rng.dirichlet(np.ones(S), 20):
        for m in range(1, S):
            h = 1e-5
            step = (np.arange(S) >= m).astype(float)
            up, dn = _normalise(b * np.exp(h * step)), _normalise(b * np.exp(-h * step))
            fd = (psi(phi, w, up) - psi(phi, w, dn)) / (2 * h)
            p = _parts(b, m)
            assert fd == pytest.approx(2 * w / p["Q"] * f_value(b, m), rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("S", [2, 3, 4, 8, 16, 64])
def test_f_decomposition_and_nonnegativity(S: int) -> None:
    """``F = Q B (P - A) + L (A R - B) + A U (R + 1)`` (second formula) and ``F >= 0``; where
    ``A R < B`` also ``F >= A K`` and ``K >= A B^3 (4 - B - 2 B^2) / 3``."""
    rng = np.random.default_rng(S)
    Bs = _random_beliefs(rng, S, 300)
    n_case2 = 0
    for m in range(1, S):
        p = _parts(Bs, m)
        A, B_, L, U, Q, P, R = (p[k] for k in "ABLUQPR")
        f = f_value(Bs, m)
        tol = 1e-13 * (S + 1)
        np.testing.assert_allclose(f, Q * B_ * (P - A) + L * (A * R - B_) + A * U * (R + 1), rtol=0, atol=tol)
        idx = np.arange(S)  # D = A sum_{j>=m} j b_j - B sum_{i<m} i b_i (used by the search below)
        np.testing.assert_allclose(p["D"], A * (Bs[:, m:] @ idx[m:]) - B_ * (Bs[:, :m] @ idx[:m]), atol=tol)
        assert np.all(f >= -tol)
        case2 = A * R < B_
        n_case2 += int(case2.sum())
        K = A * A * (R - B_) + (1 + B_) * U - A * B_ * B_
        assert np.all((f >= A * K - tol)[case2])
        assert np.all((K >= A * B_**3 * (4 - B_ - 2 * B_**2) / 3 - 1e-14)[case2])
    assert n_case2 >= 20  # the hard case is exercised


def test_f_adversarial_minimisation_and_wrong_constant() -> None:
    """Minimise ``F(b, m) / (A B)`` over the simplex (L-BFGS-B on softmax coordinates, several
    starts): nothing below 0. The same search with ``(1 - eta) Q D`` in place of ``Q D`` (steps
    ``2w (1 - eta)``) finds negative values -- near ``-eta``, at a vertex."""
    rng = np.random.default_rng(5)
    for S in (3, 4, 6):
        for m in range(1, S):
            for factor, expect_negative in ((1.0, False), (0.95, True)):
                idx = np.arange(S, dtype=float)

                def obj(z: np.ndarray, factor: float = factor, m: int = m, idx: np.ndarray = idx) -> float:
                    b = np.exp(z - z.max())
                    b /= b.sum()
                    le, ri = b[:m], b[m:]
                    A, B_ = le.sum(), ri.sum()
                    L, U = le @ le, ri @ ri
                    D = A * (ri @ idx[m:]) - B_ * (le @ idx[:m])  # = sum_{i<m<=j} b_i b_j (j - i)
                    return float((factor * (L + U) * D + A * U - B_ * L) / max(A * B_, 1e-300))
                best = min(minimize(obj, rng.normal(0, rng.choice([1.0, 6.0]), S), method="L-BFGS-B",
                                    bounds=[(-30, 30)] * S, options={"maxiter": 200}).fun for _ in range(5))
                if expect_negative:
                    assert best < -0.01
                else:
                    assert best >= -1e-10


def k_value(beta: np.ndarray, B: float) -> float:
    A = 1 - B
    q = np.arange(1, beta.size + 1)
    return float(A * A * np.sum((q - 1) * beta) + (1 + B) * np.sum(beta**2) - A * B * B)


def k_minimiser(B: float, n: int = 400) -> np.ndarray:
    """The exact minimiser of K over ``beta >= 0``, ``sum beta = B`` (water filling: K is
    ``sum_q (A^2 (q-1) beta_q + (1+B) beta_q^2)`` minus a constant, separable and convex)."""
    A, c = 1 - B, 1 + B
    k = A * A * np.arange(n)
    lo, hi = 0.0, 2 * c * B + k[-1]
    for _ in range(200):
        lam = (lo + hi) / 2
        if np.sum(np.maximum(lam - k, 0)) / (2 * c) > B:
            hi = lam
        else:
            lo = lam
    beta = np.maximum(lo - k, 0) / (2 * c)
    return beta * (B / beta.sum())


def test_k_closed_form_lower_bound() -> None:
    """``K >= A B^3 (4 - B - 2 B^2) / 3`` on random right blocks and at K's exact minimiser; the
    minimiser is checked against SLSQP, and the bound is within a factor 3 of the minimum (so
    the adversarial instances are adversarial)."""
    rng = np.random.default_rng(9)
    ratios = []
    for B in np.linspace(0.01, 0.99, 99):
        A = 1 - B
        bound = A * B**3 * (4 - B - 2 * B * B) / 3
        beta = k_minimiser(B)
        kmin = k_value(beta, B)
        assert kmin >= bound - 1e-15
        ratios.append(kmin / bound)
        for _ in range(20):
            nq = int(rng.integers(1, 30))
            rb = rng.dirichlet(np.full(nq, rng.choice([0.1, 1.0]))) * B
            assert k_value(rb, B) >= kmin - 1e-12 >= bound - 1e-12
    assert 1.0 <= min(ratios) < 2.0 and max(ratios) < 3.0
    for B in (0.2, 0.5, 0.8):  # water filling is the minimum (independent solver)
        n = 30
        cons = ({"type": "eq", "fun": lambda x, B=B: x.sum() - B},)
        res = minimize(lambda x, B=B: k_value(x, B), np.full(n, B / n), method="SLSQP", bounds=[(0, 1)] * n,
                       constraints=cons, options={"ftol": 1e-14, "maxiter": 1000})
        assert k_value(k_minimiser(B, n), B) <= res.fun + 1e-9


# ------------------------------------------------------------------ weights, h side, FOSD vs MLR
def test_mlr_decreasing_side_and_its_teeth() -> None:
    """Steps <= -2|w| make psi MLR decreasing on the same adversarial pairs; -2|w|(1 - eta) does not."""
    for S in (2, 3, 8, 32):
        rng = np.random.default_rng(S)
        B, Bp = all_pairs(rng, S, 300)
        for w in (0.9, -0.9):
            phi = -phi_with_steps(rng, S, w)
            assert worst_gap(phi, w, B, Bp, decreasing=True) >= -TOL
            bad = -phi_with_steps(rng, S, w, factor=0.99, extra=False)
            assert worst_gap(bad, w, B, Bp, decreasing=True) < -TOL


@pytest.mark.parametrize("S", [3, 4, 8, 64])
def test_mlr_exact_phi_is_not_fosd_increasing(S: int) -> None:
    """FOSD monotonicity is strictly stronger (S >= 3): with every step exactly 2w, psi is MLR
    increasing (above) but decreases along the FOSD direction ``e_{i+1} - e_i`` at
    ``b_i = 1/sqrt(S-1)``, ``b_{i+1} = 0``, the rest equal, at rate ``2w (1 - C_S)``,
    ``C_S = (1 + sqrt(S-1))/2`` (the FOSD constant)."""
    w = 1.0
    phi = 2 * w * np.arange(S)
    i = S // 2 - 1
    b = np.full(S, (1 - 1 / math.sqrt(S - 1)) / (S - 2))
    b[i], b[i + 1] = 1 / math.sqrt(S - 1), 0.0
    t = 1e-7
    bp = b.copy()
    bp[i] -= t
    bp[i + 1] += t
    assert np.all(np.cumsum(bp[::-1]) >= np.cumsum(b[::-1]) - 1e-15)  # b' >=_s b
    rate = (psi(phi, w, bp) - psi(phi, w, b)) / t
    C_S = (1 + math.sqrt(S - 1)) / 2
    assert rate == pytest.approx(2 * w * (1 - C_S), rel=1e-5)
    assert rate < 0


def test_package_rho_lower_is_psi_and_obeys_the_theorem() -> None:
    """The package's transformed reward (``MyopicBounds``, Eq. 8) on the paper's S = 3 model is
    ``phi^a . b + w_a log sum b^2`` with ``phi^a = r_a + (I - gamma P_a) g``. With
    ``g = t (0, 1, 2)`` at the smallest ``t`` making every step of every ``phi^a`` >= 2|w_a|
    (one step exactly at the constant) every ``rho_lower(., a)`` is MLR increasing on the
    adversarial pairs; with 1 % less ``t`` the vertex pair of the binding step breaks it."""
    model = load_model(S3)
    S, idx = model.S, np.arange(model.S, dtype=float)
    r_steps = np.diff(model.r.T, axis=1)  # (A, S-1)
    slope = 1 - model.gamma * np.diff(model.P @ idx, axis=1)  # steps of (I - gamma P_a) idx
    assert np.all(slope > 0)
    need = 2 * np.abs(model.w)[:, None]
    t = float(np.max((need - r_steps) / slope))
    assert t > 0  # the reward alone is not enough: g matters
    B, Bp = all_pairs(np.random.default_rng(0), S, 400)
    for scale in (1.0, 0.99):
        g = scale * t * idx
        mb = MyopicBounds(model, g, -g)
        lo, lop = mb.transformed_rewards(B)[0], mb.transformed_rewards(Bp)[0]
        phis = np.array([model.r[:, a] + g - model.gamma * model.P[a] @ g for a in range(model.A)])
        for a in range(model.A):
            assert lo[:, a] == pytest.approx(psi(phis[a], model.w[a], B), rel=1e-12, abs=1e-12)
        short = np.diff(phis, axis=1) - need  # >= 0 iff the theorem's condition holds
        if scale == 1.0:
            assert short.min() == pytest.approx(0.0, abs=1e-9)
            assert float(np.min(lop - lo)) >= -1e-10
        else:
            a, k = np.unravel_index(int(np.argmin(short)), short.shape)
            assert short[a, k] < 0
            x = 1e-3
            e = np.eye(S)
            val = mb.transformed_rewards(np.array([e[k], (1 - x) * e[k] + x * e[k + 1]]))[0][:, a]
            assert val[1] < val[0]


# ------------------------------------------------------------------ Shannon on B_eps
def _shannon_ratio(Bs: np.ndarray, m: int) -> np.ndarray:
    """``sum_{i<m<=j} b_i b_j (log b_i - log b_j) / sum_{i<m<=j} b_i b_j (j - i)`` for beliefs
    ``Bs`` (N, S): the step that the tilt direction of the cut ``m`` needs at ``b`` (w = 1)."""
    S = Bs.shape[-1]
    num = np.zeros(Bs.shape[:-1])
    den = np.zeros(Bs.shape[:-1])
    for i in range(m):
        for j in range(m, S):
            wij = Bs[..., i] * Bs[..., j]
            num += wij * (np.log(Bs[..., i]) - np.log(Bs[..., j]))
            den += wij * (j - i)
    return num / den


def _shannon_threshold_s3(eps: float, n: int = 600) -> tuple[float, np.ndarray, int]:
    """``t*`` for S = 3: the largest ratio over a grid of ``B_eps`` and both cuts, refined by
    SLSQP from the best grid point; returns it with the maximiser and its cut."""
    S = 3
    g = eps + (1 - S * eps) * np.arange(n + 1) / n
    x0, x1 = np.meshgrid(g, g, indexing="ij")
    Bs = np.stack([x0, x1, 1 - x0 - x1], axis=-1).reshape(-1, S)
    Bs = Bs[Bs[:, 2] >= eps - 1e-12]
    Bs[:, 2] = np.maximum(Bs[:, 2], eps)
    best, arg, cut = -np.inf, None, 1
    for m in (1, 2):
        r = _shannon_ratio(Bs, m)
        k = int(np.argmax(r))
        if r[k] > best:
            best, arg, cut = float(r[k]), Bs[k], m
    cons = ({"type": "eq", "fun": lambda b: b.sum() - 1},)
    res = minimize(lambda b: -float(_shannon_ratio(np.maximum(b, eps), cut)), arg, method="SLSQP",
                   bounds=[(eps, 1)] * S, constraints=cons, options={"ftol": 1e-15, "maxiter": 500})
    if res.success and -res.fun > best and abs(res.x.sum() - 1) < 1e-12:
        best, arg = -float(res.fun), np.maximum(res.x, eps)
    return best, arg, cut


@pytest.mark.parametrize("eps", [0.001, 0.01, 0.1, 0.2, 0.3])
def test_shannon_mlr_threshold_is_strictly_below_fosd_value_s3(eps: float) -> None:
    """S = 3, ``L = log((1 - (S-1) eps) / eps)`` (the FOSD value). The MLR threshold ``t*`` (the
    largest step any tilt direction needs on ``B_eps``) satisfies the proven bracket
    ``L / (1 + eps (S(S-1)/2 - 1) / (1 - (S-1) eps)) <= t* <= L (1 - 4 eps^2 / (S-1)) < L``;
    steps ``w L (1 - 4 eps^2 / (S-1))`` keep psi MLR increasing on MLR pairs inside ``B_eps``;
    and steps ``0.98 w t*`` fail on a pair inside ``B_eps`` next to the maximiser."""
    S, w = 3, 1.0
    L = math.log((1 - (S - 1) * eps) / eps)
    t_up = L * (1 - 4 * eps**2 / (S - 1))
    t_star, arg, cut = _shannon_threshold_s3(eps)
    assert L / (1 + eps * (S * (S - 1) / 2 - 1) / (1 - (S - 1) * eps)) <= t_star * (1 + 1e-9)
    assert t_star <= t_up < L
    # sufficiency of the proven upper bound on pairs inside B_eps
    rng = np.random.default_rng(3)
    B = eps + (1 - S * eps) * rng.dirichlet(np.full(S, 0.3), 4000)
    B[:S] = eps + (1 - S * eps) * np.eye(S)  # the corners of B_eps
    u = np.cumsum(rng.exponential(1.0, B.shape), axis=1) * np.exp(rng.uniform(-6, 2, (B.shape[0], 1)))
    Bp = _normalise(B * np.exp(u))
    keep = np.all(Bp >= eps, axis=1)
    assert keep.sum() > 500
    phi = w * t_up * np.arange(S)
    assert np.min(psi_shannon(phi, w, Bp[keep]) - psi_shannon(phi, w, B[keep])) >= -1e-12
    # teeth: a point strictly inside B_eps where the ratio exceeds 0.98 t*, tilted a little
    phi_bad = 0.98 * w * t_star * np.arange(S)
    step = (np.arange(S) >= cut).astype(float)
    for delta in 10.0 ** -np.arange(1, 9):
        c = (1 - delta) * arg + delta / S
        if _shannon_ratio(c[None], cut)[0] > 0.99 * t_star:
            break
    h = 1e-3 * delta
    cp = _normalise(c * np.exp(h * step))
    assert np.all(c > eps) and np.all(cp > eps) and mlr_geq(cp[None], c[None])[0]
    assert psi_shannon(phi_bad, w, cp) < psi_shannon(phi_bad, w, c)
