"""The per-epoch belief filter: one updater, one recovery rule, for every entry point.

An *epoch* is one transition of the target under one action ``a`` followed by one reading
``z_k`` from each of the sensors that reported (sensor ``k`` with its own observation array
``O_k``, ``A x S x Z_k``; sensor 0 of :func:`simulate` and of a one-sensor node is the model's
``O``). A *soft-evidence* sensor reports, instead of an observation index, its likelihood of the
reading in every state, ``l_k(s) = P(reading | next state s)`` up to a positive factor (a sensor
that computes a likelihood per state; ``likelihoods`` of :class:`EpochFilter`); for such a sensor
the column ``O_k[a][:, z_k]`` below is replaced by ``l_k``: a hard observation ``z`` is the soft
evidence ``l = O[a][:, z]``. :meth:`EpochFilter.step` applies an epoch to a belief ``b``:

1. **Prediction**, once, with the action the readings carry (paper Eq. 1):
   ``b^a = b @ P[a]``.
2. **Update** with each reading, in sensor order (Eq. 2, with that sensor's matrix):
   ``b <- b * O_k[a][:, z_k] / eta_k``; for soft evidence ``b <- b * l_k / eta_k``, i.e.
   ``b'(s) ∝ l_k(s) b^a(s)`` (Eq. 2 with the likelihood in place of ``O(z, s', a)``; ``l_k`` is
   first divided by its largest entry, which leaves the posterior unchanged and keeps the sums
   finite whatever its scale). The readings are conditionally independent given the
   state, so the result is ``b^a * prod_k O_k[a][:, z_k]`` normalised, whatever their order.
3. **Recovery** when a reading is impossible under the belief (``eta = 0``, i.e.
   ``<= belief.ETA_MIN``). The Bayes update is then undefined, and the reading proves that the
   belief excluded the true state: the belief is wrong, not the reading. Two simpler rules
   fail:

   * *discard the reading and keep the prediction*: a belief that
     excludes the truth can stay wrong for ever. With a static target and a perfect sensor,
     ``b = [1, 0]`` while the target is in state 1, every later reading is impossible too and
     is discarded in turn, so the filter never moves again;
   * *re-initialise to the normalised likelihood* ``O[a][:, z]``: it ignores
     the transition of this epoch, so it can put mass on states that no state reaches under
     ``a``.

   The rule here restarts the filter from the uninformative (uniform) prior, pushed through
   the same transition, and applies this epoch's readings to it: ``b ∝ (u @ P[a]) *
   prod_k O_k[a][:, z_k]`` over the readings applied so far in this epoch and this one. That
   is exactly the posterior the filter would have if it had started from no information one
   epoch ago, so the next epochs proceed as from a fresh start. It is counted as a *restart*
   of that sensor's reading.

   If the reading is impossible even from the restarted belief, no state reachable under
   ``a`` can produce it: it contradicts the model (a sensor fault, or the wrong observation
   model). It is *dropped* and the belief stays what it was before it (the prediction updated
   with the epoch's earlier readings); counted as *dropped*.

   Without a restart or a drop, the result does not depend on the order of the readings; with
   them, sensors are taken in index order.
4. **Gap**: an epoch without a reading. With the commanded action known, the belief is
   predicted with it (Eq. 1, no update); without it (``action=None``) the belief is held.

The result is checked with :func:`~pomdp_planner.core.belief.check_belief` (defensive: it
cannot leave the simplex from a valid belief); an invalid one raises
:class:`~pomdp_planner.core.belief.BeliefError`.

Used by the belief filter node (``nodes/belief_filter.py``) and by :func:`~pomdp_planner.core.simulate.simulate`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .belief import ETA_MIN, BeliefError, check_action, check_belief, check_likelihood, predict
from .checks import check_int
from .model import POMDP, ModelError
from .sparse import SparseStack


@dataclass(frozen=True, eq=False)
class EpochUpdate:
    """What :meth:`EpochFilter.step` did to the belief (module docstring).

    ``belief``: the belief after the epoch; ``predicted``: False for a gap with an unknown action
    (belief held); ``restarted``: sensors whose reading was impossible under the belief and
    restarted the filter; ``dropped``: sensors whose reading contradicts the model and was
    dropped.
    """

    belief: np.ndarray
    predicted: bool
    restarted: tuple[int, ...] = ()
    dropped: tuple[int, ...] = ()


class EpochFilter:
    """The per-epoch Bayes filter of ``model`` with one observation array per sensor, then
    ``likelihoods`` soft-evidence sensors.

    ``sensors``: ``A x S x Z_k`` arrays ``O_k[a, j, z] = P(z | next j, a)``, dense or sparse
    (:class:`~.sparse.SparseStack`); default the model's own ``O`` as the one sensor (its sparse
    form for a sparse model) (none when the filter has soft-evidence sensors only: pass
    ``[]``). Loaders check them against the model with the field name of their source
    (``core.io.sensors.load_observation_models``); the shapes are checked here too, as the last
    guard. Sensor indices ``0 .. len(sensors) - 1`` take observation indices, the next
    ``likelihoods`` take a likelihood per state (module docstring).
    """

    def __init__(self, model: POMDP, sensors: Sequence[np.ndarray | SparseStack] | None = None,
                 likelihoods: int = 0):
        self.model = model
        if sensors is None:
            sensors = [model.O_csr if model.sparse else model.O]
        else:
            sensors = [O if isinstance(O, SparseStack) else np.asarray(O, dtype=float) for O in sensors]
        self.num_likelihoods = check_int(likelihoods, "likelihoods", 0, error=ModelError)
        if not sensors and not self.num_likelihoods:
            raise ModelError("sensors: at least one observation model is needed")
        for k, O in enumerate(sensors):
            if len(O.shape) != 3 or tuple(O.shape[:2]) != (model.A, model.S):
                raise ModelError(f"sensors[{k}]: observation model has shape {tuple(O.shape)}, expected "
                                 f"{model.A} x {model.S} x Z")
        self.sensors = sensors
        self._uniform = np.full(model.S, 1.0 / model.S)

    @property
    def num_sensors(self) -> int:
        """Every sensor: observation arrays and soft-evidence sensors."""
        return len(self.sensors) + self.num_likelihoods

    def soft(self, sensor: int) -> bool:
        """Whether sensor ``sensor`` reports soft evidence (a likelihood per state)."""
        return sensor >= len(self.sensors)

    def num_observations(self, sensor: int) -> int:
        """``Z_k`` of sensor ``sensor`` (a sensor with an observation array)."""
        return self.sensors[sensor].shape[2]

    def _likelihood(self, sensor: int, a: int, reading) -> np.ndarray:
        """The checked likelihood column of one reading: ``O_k[a][:, z]``, or soft evidence ``l``
        divided by its largest entry."""
        sensor = check_int(sensor, "sensor", 0, self.num_sensors - 1, error=BeliefError)
        if self.soft(sensor):
            lik = check_likelihood(self.model, reading, field=f"likelihood (sensor {sensor})")
            return lik / lik.max()
        z = check_int(reading, f"observation (sensor {sensor})", 0, self.num_observations(sensor) - 1,
                      error=BeliefError)
        O = self.sensors[sensor]
        return O.T.dense_row(a, z) if isinstance(O, SparseStack) else O[a, :, z]

    def step(self, belief: np.ndarray, action: int | None, readings: Mapping[int, int | Sequence[float]]
             ) -> EpochUpdate:
        """Apply one epoch: ``action`` (0-based; ``None`` = unknown, only for a gap) and
        ``readings[sensor]``: an observation index, or for a soft-evidence sensor its likelihood
        per state (may be empty: a gap). See the module docstring."""
        b = np.asarray(belief, dtype=float)
        if action is None:
            if readings:
                raise BeliefError("action: an epoch with readings needs the action they were taken under")
            check_belief(self.model, b)
            return EpochUpdate(b.copy(), predicted=False)
        a = check_action(self.model, action)
        ordered = [(k, self._likelihood(k, a, readings[k])) for k in sorted(readings)]
        post = predict(self.model, b, a)                 # Eq. 1
        applied = np.ones(self.model.S)                  # product of this epoch's applied likelihoods
        restarted: list[int] = []
        dropped: list[int] = []
        for k, lik in ordered:
            unnorm = post * lik                          # Eq. 2 (soft evidence: l(s) b^a(s))
            eta = float(unnorm.sum())
            if not eta > ETA_MIN:                        # impossible under the belief: restart
                unnorm = predict(self.model, self._uniform, a) * applied * lik
                eta = float(unnorm.sum())
                if not eta > ETA_MIN:                    # impossible from any state: contradicts the model
                    dropped.append(k)
                    continue
                restarted.append(k)
            post = unnorm / eta
            applied = applied * lik
        # Defensive (cannot fail from a valid belief): the one simplex check of the core. The
        # belief is returned as computed, so every caller gets bit-identical results.
        check_belief(self.model, post)
        return EpochUpdate(post, predicted=True, restarted=tuple(restarted), dropped=tuple(dropped))
