"""Perimeter defence: how much of a robot's time to give an intruder approaching an asset.

A sensor-management family inside the paper's Assumption 1 (Sec. III) on which the myopic
policy loses measurably (docs/MODEL_SEARCH.md). Everything lives on the normalised
*penetration depth* ``x`` in ``[0, 1]`` (0 = outside the perimeter, 1 = at the protected
asset), cut into ``S`` equal bands; band ``s`` has centre ``x_s = (s + 1/2) / S``.

* **States** ``s = 0..S-1``: the band the intruder is in (``S-1`` = at the asset, the paper's
  red-alert state ``S``).
* **Actions** ``a = 0..A-1``: the tracking priority ``a + 1`` the robot gives the intruder,
  i.e. its share of the robot's time (1 = escort it, ``A`` = leave it to the fixed sensors).
* **Transitions** (an AR(1) target with a priority-dependent set point, "deterrence"): the
  next depth is ``x' ~ N(lambda x_s + (1 - lambda) c_a, sigma^2)`` with tails clipped to the
  end bands (overshooting the asset ends at the asset, retreating past the perimeter ends
  outside). ``lambda`` is the intruder's inertia, ``c_a`` the depth it drifts to when given
  priority ``a + 1`` (increasing in ``a``: the less it is watched, the closer it comes),
  ``sigma`` its per-step manoeuvre noise.
* **Observations** ``z = 0..Z-1``: the band of a range measurement ``x' + N(0, sigma_z,a^2)``
  (clipped likewise); ``sigma_z,a`` may grow with ``a`` (less dwell time, a blurrier fix).
* **Reward** ``r(s, a) = -effort_cost[a] - damage(x_s) (1 - interception[a])``,
  ``damage(x) = damage * max(0, (x - damage_from) / (1 - damage_from))``: the robot's other
  duties lose ``effort_cost[a]`` per step, and an intruder deep inside the inner zone does
  damage, of which priority ``a + 1`` prevents the share ``interception[a]``. The belief
  reward (paper Eq. 3) subtracts ``w f(b)``, the operator's cost of an uncertain track
  (Renyi quadratic entropy by default), with the same ``w`` for every priority.

Why it satisfies Assumption 1 (checked by ``pomdp-planner check``, proven numerically in
the tests): the Gaussian kernel is TP2 and integrating a TP2 kernel over ordered intervals
keeps it TP2 (A1); ``c_a`` increasing makes every predicted observation distribution move up
with ``a`` (A3). (A2) is the binding constraint. With one sensor for all priorities, (A2) is
exactly "``b P[a+1]`` is MLR-above ``b P[a]`` for every belief ``b``" (the observation
likelihood, positive here, cancels in the likelihood ratios). Here ``b P[a+1]`` is the band
discretisation of the density behind ``b P[a]`` shifted up by ``(1 - lambda)(c_{a+1} - c_a)``,
and a shift family is MLR ordered iff its density is log-concave. ``b P[a]`` is a Gaussian mixture with component means
spread over ``lambda (x_{S-1} - x_0)``; ``(log g)'' = (Var(mean | x) - sigma^2) / sigma^4``, so
every such mixture is log-concave iff that spread is at most ``2 sigma``:

    lambda <= 2 sigma / (x_{S-1} - x_0)          (:func:`inertia_limit`)

This is sufficient for the banded model too (integrating the ordered pair of densities over
ordered bands, the clipped end bands included, keeps the likelihood-ratio order), for any
``Z``, set points and shared sensor; it is necessary only in the continuous idealisation and
for small set-point spacing (discretisation moves the exact edge up at small ``S``; measured in
docs/MODEL_SEARCH.md; ``test/test_perimeter_domain.py`` checks sufficiency by brute force and
against the exact checker). A persistent target (``lambda`` near 1) with little manoeuvre
noise, the case in which information stays useful for long, is therefore *outside* the
assumption class whenever the priority shifts the target's motion; the lookahead that pays
inside it is the consequence of the action on where the target goes next and what the next
decision will know. A priority-dependent
sensor adds the factor ``O[a,j,z] O[a+1,j+1,z] / (O[a,j+1,z] O[a+1,j,z])`` to (A2), which is
below 1 for high readings when the lower priority's sensor is blurrier: only small sharpness
differences fit (measured in docs/MODEL_SEARCH.md).

Not wired into ``core/io`` yet: a YAML ``generator: {domain: perimeter, S, A, Z, inertia,
set_points, process_sd, sensor_sd}`` plus ``reward_generator: {kind: perimeter, effort_cost,
damage, damage_from, interception}`` would map one-to-one onto :func:`perimeter_model`'s
arguments (the shipped ``config/models/perimeter_*.yaml`` are written in explicit form by
``python -m tools.lookahead_models --write-models`` from :data:`PRESETS`, in the source tree).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.special import ndtr

from ..checks import check_int
from ..model import POMDP, ModelError, per_action_vector

__all__ = [
    "PRESETS",
    "band_centres",
    "band_probabilities",
    "damage_profile",
    "default_set_points",
    "inertia_limit",
    "perimeter_model",
    "perimeter_observations",
    "perimeter_reward",
    "perimeter_transitions",
    "preset_model",
]


def band_centres(S: int) -> np.ndarray:
    """``x_s = (s + 1/2) / S``: centres of ``S`` equal bands of ``[0, 1]``."""
    return (np.arange(S) + 0.5) / S


def band_probabilities(n_bands: int, mean: np.ndarray | float, sd: float) -> np.ndarray:
    """``P(band k)`` of ``N(mean, sd^2)`` on ``[0, 1]`` cut into ``n_bands`` equal bands.

    The tails below 0 and above 1 go to the first and last band (clipping). ``mean`` may be a
    vector; the result has shape ``(len(mean), n_bands)`` (rows sum to one).
    """
    mean = np.atleast_1d(np.asarray(mean, dtype=float))
    edges = np.concatenate([[-np.inf], np.linspace(0.0, 1.0, n_bands + 1)[1:-1], [np.inf]])
    z = (edges[None, :] - mean[:, None]) / sd  # (len(mean), n_bands + 1)
    lo, hi = z[:, :-1], z[:, 1:]
    # A band above the mean from the upper tail, Phi(-lo) - Phi(-hi): 1 - Phi rounds to multiples of
    # 2^-53 there, and those rounded tails broke (A1) at the 1e-27 level (S = 6, sd = 0.086)
    return np.where(lo > 0.0, ndtr(-lo) - ndtr(-hi), ndtr(hi) - ndtr(lo))


def inertia_limit(S: int, process_sd: float) -> float:
    """The largest inertia for which (A2) holds in the continuous idealisation (module docstring).

    ``2 sigma / (x_{S-1} - x_0)``: every predicted belief is then a log-concave Gaussian mixture.
    """
    if S < 2:
        return math.inf
    x = band_centres(S)
    return 2.0 * float(process_sd) / float(x[-1] - x[0])


def _per_action(name: str, value: float | Sequence[float], A: int) -> np.ndarray:
    """``generator.<name>``: one number, or one per priority (:func:`~..model.per_action_vector`)."""
    return per_action_vector(f"generator.{name}", value, A)


def _check_sizes(S: int, A: int) -> None:
    for name, n in (("S", S), ("A", A)):
        check_int(n, f"generator.{name}", 2 if name == "S" else 1, error=ModelError)


def _positive(name: str, v: np.ndarray | float) -> None:
    if np.any(np.asarray(v) <= 0.0):
        raise ModelError(f"generator.{name}: must be > 0, got {np.asarray(v).tolist()}")


def default_set_points(A: int) -> np.ndarray:
    """``c_a`` evenly spaced on ``[0.2, 0.8]``: escorted intruders keep to the outer band."""
    return np.linspace(0.2, 0.8, A) if A > 1 else np.array([0.5])


def perimeter_transitions(S: int, A: int, inertia: float, set_points: Sequence[float] | None,
                          process_sd: float) -> np.ndarray:
    """``P[a, s, :]`` = bands of ``N(inertia x_s + (1 - inertia) c_a, process_sd^2)`` (A x S x S)."""
    _check_sizes(S, A)
    c = default_set_points(A) if set_points is None else _per_action("set_points", set_points, A)
    if not 0.0 <= float(inertia) < 1.0:
        raise ModelError(f"generator.inertia: must satisfy 0 <= inertia < 1, got {inertia}")
    if np.any(np.diff(c) < 0.0):
        raise ModelError(f"generator.set_points: must be non-decreasing in the priority number, got {c.tolist()}")
    _positive("process_sd", process_sd)
    x = band_centres(S)
    return np.stack([band_probabilities(S, inertia * x + (1.0 - inertia) * ca, float(process_sd)) for ca in c])


def perimeter_observations(S: int, A: int, sensor_sd: float | Sequence[float], Z: int | None = None) -> np.ndarray:
    """``O[a, s, :]`` = bands (``Z`` of them) of ``N(x_s, sensor_sd[a]^2)`` (A x S x Z)."""
    _check_sizes(S, A)
    Z = S if Z is None else Z
    check_int(Z, "generator.Z", 2, error=ModelError)
    sd = _per_action("sensor_sd", sensor_sd, A)
    _positive("sensor_sd", sd)
    x = band_centres(S)
    return np.stack([band_probabilities(Z, x, s) for s in sd])


def damage_profile(S: int, damage: float, damage_from: float) -> np.ndarray:
    """``damage * max(0, (x_s - damage_from) / (1 - damage_from))`` per band."""
    if not 0.0 <= float(damage_from) < 1.0:
        raise ModelError(f"generator.damage_from: must satisfy 0 <= damage_from < 1, got {damage_from}")
    if not (math.isfinite(float(damage)) and float(damage) >= 0.0):
        raise ModelError(f"generator.damage: must be a finite number >= 0, got {damage}")
    x = band_centres(S)
    return float(damage) * np.clip((x - damage_from) / (1.0 - damage_from), 0.0, None)


def perimeter_reward(S: int, A: int, effort_cost: Sequence[float], damage: float, damage_from: float,
                     interception: Sequence[float]) -> np.ndarray:
    """``r[s, a] = -effort_cost[a] - damage(x_s) (1 - interception[a])`` (S x A)."""
    _check_sizes(S, A)
    cost = _per_action("effort_cost", effort_cost, A)
    share = _per_action("interception", interception, A)
    if np.any((share < 0.0) | (share > 1.0)):
        raise ModelError(f"generator.interception: shares must lie in [0, 1], got {share.tolist()}")
    D = damage_profile(S, damage, damage_from)
    return -cost[None, :] - D[:, None] * (1.0 - share[None, :]) + 0.0  # + 0.0: no -0.0 in files


def perimeter_model(S: int, A: int = 3, *, inertia: float, process_sd: float, sensor_sd: float | Sequence[float],
                    effort_cost: Sequence[float], damage: float, damage_from: float,
                    interception: Sequence[float], set_points: Sequence[float] | None = None,
                    Z: int | None = None, track_weight: float = 0.0, uncertainty: str = "renyi2",
                    gamma: float = 0.95, epsilon: float = 1e-3, name: str | None = None) -> POMDP:
    """A complete perimeter-defence POMDP (see the module docstring for every parameter)."""
    P = perimeter_transitions(S, A, inertia, set_points, process_sd)
    O = perimeter_observations(S, A, sensor_sd, Z)
    r = perimeter_reward(S, A, effort_cost, damage, damage_from, interception)
    c = default_set_points(A) if set_points is None else _per_action("set_points", set_points, A)
    params = {
        "domain": "perimeter", "S": int(S), "A": int(A), "Z": int(O.shape[2]), "inertia": float(inertia),
        "set_points": [float(v) for v in c], "process_sd": float(process_sd),
        "sensor_sd": [float(v) for v in _per_action("sensor_sd", sensor_sd, A)],
        "effort_cost": [float(v) for v in _per_action("effort_cost", effort_cost, A)],
        "damage": float(damage), "damage_from": float(damage_from),
        "interception": [float(v) for v in _per_action("interception", interception, A)],
        "track_weight": float(track_weight), "uncertainty": uncertainty, "gamma": float(gamma),
    }
    return POMDP(P=P, O=O, r=r, gamma=gamma, uncertainty=uncertainty, w=[float(track_weight)] * A,
                 epsilon=epsilon, name=name or f"perimeter_s{S}", metadata={"generator": params})


#: Parameters of the shipped models ``config/models/<name>.yaml`` (reasons in docs/MODEL_SEARCH.md
#: and in each file's header). The S = 3 and S = 8 models share the physics; only the band
#: resolution differs.
_SHIPPED_PHYSICS: dict = {
    "A": 3, "inertia": 0.3, "process_sd": 0.15, "set_points": [0.1, 0.4, 0.7], "sensor_sd": 0.15,
    "effort_cost": [0.8, 0.3, 0.0], "damage": 5.0, "damage_from": 0.3, "interception": [0.8, 0.4, 0.0],
    "track_weight": 0.05, "uncertainty": "renyi2", "gamma": 0.95,
}
PRESETS: dict[str, dict] = {
    "perimeter_s3": {"S": 3, **_SHIPPED_PHYSICS},
    "perimeter_s8": {"S": 8, **_SHIPPED_PHYSICS},
}


def preset_model(name: str) -> POMDP:
    """The shipped model ``name`` (a key of :data:`PRESETS`) built from its parameters."""
    if name not in PRESETS:
        raise ModelError(f"model: unknown perimeter preset {name!r} (known: {', '.join(sorted(PRESETS))})")
    return perimeter_model(**PRESETS[name], name=name)
