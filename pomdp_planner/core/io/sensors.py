"""What a belief filter or a simulated target is configured with: the model file, one observation
model per sensor, the initial distribution. Errors are core errors that name the field (the
nodes' parameter names), so an adapter only translates them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..belief import check_belief, start_belief, uniform_belief
from ..model import POMDP, ModelError
from ..sparse import SparseStack
from .model_yaml import load_model
from .paths import resolve_path


def load_model_file(path: str, field: str = "model_file") -> POMDP:
    """The model in the file ``path`` names (found by :func:`~.paths.resolve_path`); a
    :class:`ModelError` names ``field`` (and, for a malformed file, the file and its field)."""
    return load_model(resolve_path(path, field), field)


def load_observation_models(model: POMDP, files: Sequence[str] | None, num_sensors: int) -> list[np.ndarray]:
    """One observation array ``O_k`` (``A x S x Z_k``) per sensor, from ``observation_model_files``.

    ``files``: one model file per sensor whose ``observation`` matrix is used; ``""`` (or no list
    at all) = the model's own ``O``. A file must have the model's actions and states; its
    observations may differ (``Z_k``).
    """
    files = list(files or [])
    if not files:
        files = [""] * num_sensors
    if len(files) != num_sensors:
        raise ModelError(
            f"observation_model_files: {len(files)} entries for {num_sensors} observation_topics "
            "(give one per topic, '' for the model's own)"
        )
    return [load_observation_model(model, f, f"observation_model_files[{k}]") for k, f in enumerate(files)]


def load_observation_model(model: POMDP, file: str, field: str) -> np.ndarray | SparseStack:
    """The observation array ``O`` (``A x S x Z``) of one sensor: the ``observation`` matrix of the
    model file ``file`` (``""``: the model's own), which must have the model's actions and states;
    errors name ``field``. A sparse model's matrices come in their sparse form
    (:class:`~pomdp_planner.core.sparse.SparseStack`)."""
    other = model if not file else load_model_file(file, field)
    O = other.O_csr if other.sparse else other.O
    if tuple(O.shape[:2]) != (model.A, model.S):
        raise ModelError(f"{field}: observation model has shape {tuple(O.shape)}, expected "
                         f"{model.A} x {model.S} x Z")
    return O


def initial_distribution(model: POMDP, values: Sequence[float] | None) -> np.ndarray:
    """``values`` (parameter ``initial_distribution``) if given, else the model's ``start``, else
    uniform. Raises :class:`~pomdp_planner.core.belief.BeliefError` for bad ``values`` and
    :class:`ModelError` for a bad ``start``."""
    if values is not None and len(values) > 0:
        return check_belief(model, np.asarray(values, dtype=float), field="initial_distribution")
    start = start_belief(model)
    return uniform_belief(model) if start is None else start
