"""core/io/sensors.py: model file, per-sensor observation models and initial distribution of a
filter or simulated target; errors name the field (the nodes' parameter names)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from pomdp_planner.core.belief import BeliefError
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.io.sensors import initial_distribution, load_model_file, load_observation_models
from pomdp_planner.core.model import POMDP, ModelError

S3 = "config/models/tracking_s3_info.yaml"


def _write(path, doc):
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_model_file_errors_name_the_field(tmp_path):
    with pytest.raises(ModelError, match=r"^model_file: .*not found"):
        load_model_file("no/such/model.yaml")
    bad = _write(tmp_path / "bad.yaml", {"name": "x", "discount": 2.0})
    with pytest.raises(ModelError, match=r"^observation_model_files\[1\]: .*bad\.yaml"):
        load_model_file(bad, "observation_model_files[1]")
    assert load_model_file(S3).S == 3


def test_observation_models_one_per_sensor(tmp_path):
    model = load_model(S3)
    assert [O is model.O for O in load_observation_models(model, None, 2)] == [True, True]
    O2 = np.array([[[0.9, 0.1], [0.5, 0.5], [0.2, 0.8]]] * 3)
    other = _write(tmp_path / "radar.yaml", {"name": "radar", "discount": 0.9, "transition": model.P.tolist(),
                                              "observation": O2.tolist(), "reward": np.zeros((3, 3)).tolist()})
    sensors = load_observation_models(model, ["", other], 2)
    assert sensors[0] is model.O
    np.testing.assert_array_equal(sensors[1], O2)
    with pytest.raises(ModelError, match=r"observation_model_files: 3 entries for 2 observation_topics"):
        load_observation_models(model, ["", "", ""], 2)
    two_states = _write(tmp_path / "small.yaml", {"name": "small", "discount": 0.9, "transition": [[[1, 0], [0, 1]]],
                                                  "observation": [[[1, 0], [0, 1]]], "reward": [[0], [0]]})
    with pytest.raises(ModelError, match=r"observation_model_files\[0\]: observation model has shape \(1, 2, 2\)"):
        load_observation_models(model, [two_states], 1)


def test_initial_distribution_parameter_then_start_then_uniform():
    model = load_model(S3)
    np.testing.assert_allclose(initial_distribution(model, None), [1 / 3] * 3)
    started = POMDP(P=model.P, O=model.O, r=model.r, gamma=model.gamma, metadata={"start": [0.0, 0.5, 0.5]})
    np.testing.assert_allclose(initial_distribution(started, []), [0.0, 0.5, 0.5])
    np.testing.assert_allclose(initial_distribution(started, [1.0, 0.0, 0.0]), [1.0, 0.0, 0.0])
    with pytest.raises(BeliefError, match="initial_distribution: sums to"):
        initial_distribution(model, [0.5, 0.5, 0.5])
    bad_start = POMDP(P=model.P, O=model.O, r=model.r, gamma=model.gamma, metadata={"start": "nowhere"})
    with pytest.raises(ModelError, match="start"):
        initial_distribution(bad_start, None)
