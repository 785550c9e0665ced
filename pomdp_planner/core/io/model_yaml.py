"""YAML model files (schema in README.md, "Model files").

Loaded with ``yaml.safe_load``. Field names are fixed so that files written by others load::

    name: tracking_s3_info
    discount: 0.99
    states: 3            # a count or a list of names; same for actions, observations
    actions: 3
    observations: 3
    transition:  [...]   # A x S x S, transition[a][i][j] = P(next j | prev i, action a)
    observation: [...]   # A x S x Z, observation[a][j][z] = P(z | next j, action a)
    reward: [...]        # S x A
    uncertainty: {function: renyi2 | shannon | none, weights: [...], epsilon: 0.001}

Instead of ``transition`` and ``observation``, ``generator: {domain: tracking, S, A, q, x, y}``;
instead of ``reward``, ``reward_generator: {kind: tracking_comparison, c_a, c_p, c_d, k_r}``.
Every error is a :class:`~pomdp_planner.core.model.ModelError` that starts with the file
name and the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..belief import start_belief
from ..domains.tracking import comparison_reward, tracking_observations, tracking_transitions
from ..model import POMDP, ModelError
from .cassandra import load_pomdp_file

KNOWN_FIELDS = {
    "name", "discount", "states", "actions", "observations", "transition", "observation",
    "reward", "uncertainty", "generator", "reward_generator", "description", "start",
}


def _size(doc: dict, key: str) -> tuple[int | None, list[str] | None]:
    v = doc.get(key)
    if v is None:
        return None, None
    if isinstance(v, bool):
        raise ModelError(f"{key}: expected a count or a list of names, got {v!r}")
    if isinstance(v, int):
        if v < 1:
            raise ModelError(f"{key}: count must be at least 1, got {v}")
        return v, None
    if isinstance(v, list) and v:
        return len(v), [str(x) for x in v]
    raise ModelError(f"{key}: expected a positive count or a non-empty list of names, got {v!r}")


def _array(doc: dict, key: str, ndim: int) -> np.ndarray:
    try:
        arr = np.array(doc[key], dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{key}: not a rectangular array of numbers ({exc})") from None
    if arr.ndim != ndim:
        raise ModelError(f"{key}: expected a {ndim}-dimensional nested list, got {arr.ndim} dimensions "
                         f"(shape {arr.shape})")
    return arr


def model_from_dict(doc: Any, source: str = "<dict>") -> POMDP:
    """Build a :class:`POMDP` from a parsed YAML document."""
    try:
        return _model_from_dict(doc)
    except ModelError as exc:
        raise ModelError(f"{source}: {exc}") from None


def _model_from_dict(doc: Any) -> POMDP:
    if not isinstance(doc, dict):
        raise ModelError("top level: expected a mapping of fields")
    unknown = set(doc) - KNOWN_FIELDS
    if unknown:
        raise ModelError(f"unknown field(s) {sorted(unknown)}; known: {sorted(KNOWN_FIELDS)}")
    if "discount" not in doc:
        raise ModelError("discount: missing")
    S, state_names = _size(doc, "states")
    A, action_names = _size(doc, "actions")
    Z, obs_names = _size(doc, "observations")
    metadata: dict = {}
    if "generator" in doc:
        if "transition" in doc or "observation" in doc:
            raise ModelError("generator: give either generator or transition/observation, not both")
        gen = doc["generator"]
        if not isinstance(gen, dict) or gen.get("domain") != "tracking":
            raise ModelError("generator.domain: only 'tracking' is known")
        extra = set(gen) - {"domain", "S", "A", "q", "x", "y"}
        if extra:
            raise ModelError(f"generator: unknown field(s) {sorted(extra)}")
        try:
            gS, gA, q = int(gen["S"]), int(gen["A"]), float(gen["q"])
        except KeyError as exc:
            raise ModelError(f"generator.{exc.args[0]}: missing") from None
        except (TypeError, ValueError) as exc:
            raise ModelError(f"generator: S, A must be integers and q a number ({exc})") from None
        try:
            gx = None if gen.get("x") is None else np.asarray(gen["x"], dtype=float)
            gy = None if gen.get("y") is None else np.asarray(gen["y"], dtype=float)
        except (TypeError, ValueError):
            raise ModelError("generator.x/y: must be lists of numbers") from None
        P = tracking_transitions(gS, gA, gx, gy)
        O = tracking_observations(gS, gA, q)
        metadata["generator"] = dict(gen)
    else:
        for key in ("transition", "observation"):
            if key not in doc:
                raise ModelError(f"{key}: missing (give transition and observation, or generator)")
        P = _array(doc, "transition", 3)
        O = _array(doc, "observation", 3)
    for key, n, got in (("states", S, P.shape[1]), ("actions", A, P.shape[0]), ("observations", Z, O.shape[2])):
        if n is not None and n != got:
            raise ModelError(f"{key}: declares {n} but the matrices have {got}")
    if "reward_generator" in doc:
        if "reward" in doc:
            raise ModelError("reward_generator: give either reward or reward_generator, not both")
        rg = doc["reward_generator"]
        if not isinstance(rg, dict) or rg.get("kind") != "tracking_comparison":
            raise ModelError("reward_generator.kind: only 'tracking_comparison' is known")
        extra = set(rg) - {"kind", "c_a", "c_p", "c_d", "k_r"}
        if extra:
            raise ModelError(f"reward_generator: unknown field(s) {sorted(extra)}")
        try:
            kw = {k: float(v) for k, v in rg.items() if k != "kind"}
        except (TypeError, ValueError):
            raise ModelError("reward_generator: c_a, c_p, c_d, k_r must be numbers") from None
        r = comparison_reward(P.shape[1], P.shape[0], **kw)
        metadata["reward_generator"] = dict(rg)
    elif "reward" in doc:
        r = _array(doc, "reward", 2)
    else:
        raise ModelError("reward: missing (give reward or reward_generator)")
    unc = doc.get("uncertainty") or {"function": "none"}
    if not isinstance(unc, dict):
        raise ModelError("uncertainty: expected a mapping {function, weights, epsilon}")
    extra = set(unc) - {"function", "weights", "epsilon"}
    if extra:
        raise ModelError(f"uncertainty: unknown field(s) {sorted(extra)}")
    func = unc.get("function", "none")
    weights = unc.get("weights")
    if func != "none" and weights is None:
        raise ModelError("uncertainty.weights: missing (one weight per action)")
    if "start" in doc:
        metadata["start"] = doc["start"]
    if "description" in doc:
        metadata["description"] = str(doc["description"])
    model = POMDP(
        P=P, O=O, r=r, gamma=doc["discount"], uncertainty=func, w=weights,
        epsilon=unc.get("epsilon", 1e-3), name=doc.get("name", "pomdp"),
        state_names=state_names, action_names=action_names, observation_names=obs_names,
        metadata=metadata,
    )
    start_belief(model)  # validates 'start' now (ModelError naming the field), not at first use
    return model


def load_model(path: str | Path) -> POMDP:
    """Load a YAML model file (or a Cassandra ``.POMDP`` file, by extension)."""
    path = Path(path)
    if path.suffix.lower() == ".pomdp":
        return load_pomdp_file(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ModelError(f"{path}: cannot read model file ({exc.strerror})") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ModelError(f"{path}: not valid YAML ({exc})") from None
    return model_from_dict(doc, source=str(path))


def model_to_dict(model: POMDP) -> dict:
    """The explicit (matrix) form of a model, ready for ``yaml.safe_dump``."""
    def names_or_count(names, n):
        return list(names) if names is not None else n

    doc: dict = {
        "name": model.name,
        "discount": model.gamma,
        "states": names_or_count(model.state_names, model.S),
        "actions": names_or_count(model.action_names, model.A),
        "observations": names_or_count(model.observation_names, model.Z),
        "transition": model.P.tolist(),
        "observation": model.O.tolist(),
        "reward": model.r.tolist(),
        "uncertainty": {"function": model.uncertainty.name, "weights": model.w.tolist(),
                        "epsilon": model.epsilon},
    }
    if "start" in model.metadata:
        doc["start"] = model.metadata["start"]
    return doc


def save_model(model: POMDP, path: str | Path) -> None:
    """Write ``model`` as a YAML model file in explicit form."""
    Path(path).write_text(yaml.safe_dump(model_to_dict(model), sort_keys=False, default_flow_style=None))
