"""YAML model files: shipped models, schema forms, round trip, errors naming file and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from pomdp_planner.core.domains.tracking import comparison_reward, tracking_observations, tracking_transitions
from pomdp_planner.core.io.model_yaml import load_model, model_from_dict, model_to_dict, save_model
from pomdp_planner.core.model import POMDP, ModelError

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted((ROOT / "config" / "models").glob("*.yaml"))


def explicit_doc(**overrides):
    doc = {
        "name": "tiny",
        "discount": 0.9,
        "states": ["lo", "hi"],
        "actions": 2,
        "observations": 2,
        "transition": [[[0.9, 0.1], [0.2, 0.8]], [[0.5, 0.5], [0.0, 1.0]]],
        "observation": [[[0.8, 0.2], [0.3, 0.7]], [[0.5, 0.5], [0.5, 0.5]]],
        "reward": [[1.0, 0.0], [0.0, 2.0]],
        "uncertainty": {"function": "shannon", "weights": [0.5, 1.0], "epsilon": 0.01},
    }
    doc.update(overrides)
    return {k: v for k, v in doc.items() if v is not None}


def test_shipped_models_exist_and_load():
    names = {p.stem for p in MODELS}
    assert {"tracking_s3_info", "tracking_s8_info"} <= names
    for path in MODELS:
        m = load_model(path)
        assert m.name == path.stem
        assert m.describe().startswith(path.stem)


def test_s8_model_is_the_table_ii_size():
    m = load_model(ROOT / "config/models/tracking_s8_info.yaml")
    assert (m.S, m.A, m.Z) == (8, 3, 8) and m.uncertainty.name == "renyi2" and m.gamma == 0.99
    # x = 1..8, y = 24 points evenly spaced on [-9, -1] (printed to 6 digits in the file)
    expected = tracking_transitions(8, 3, x=np.arange(1, 9), y=np.linspace(-9.0, -1.0, 24))
    np.testing.assert_allclose(m.P, expected, rtol=0, atol=1e-5)
    np.testing.assert_allclose(m.O, tracking_observations(8, 3, 0.7), rtol=0, atol=1e-15)


def test_explicit_form():
    m = model_from_dict(explicit_doc())
    assert (m.S, m.A, m.Z) == (2, 2, 2) and m.state_names == ("lo", "hi") and m.action_names is None
    assert m.P[1, 1, 1] == 1.0 and m.O[0, 1, 1] == 0.7 and m.r[1, 1] == 2.0
    assert m.uncertainty.name == "shannon" and m.w.tolist() == [0.5, 1.0] and m.epsilon == 0.01


def test_generator_form_equals_explicit_matrices():
    doc = {"name": "g", "discount": 0.95, "generator": {"domain": "tracking", "S": 4, "A": 2, "q": 0.8},
           "reward_generator": {"kind": "tracking_comparison"}}
    m = model_from_dict(doc)
    explicit = model_from_dict({"name": "g", "discount": 0.95, "transition": tracking_transitions(4, 2).tolist(),
                                "observation": tracking_observations(4, 2, 0.8).tolist(),
                                "reward": comparison_reward(4, 2).tolist()})
    np.testing.assert_array_equal(m.P, explicit.P)
    np.testing.assert_array_equal(m.O, explicit.O)
    np.testing.assert_array_equal(m.r, explicit.r)
    assert m.uncertainty.name == "none"
    custom = model_from_dict({**doc, "reward_generator": {"kind": "tracking_comparison", "c_a": 1.0, "k_r": 3}})
    np.testing.assert_array_equal(custom.r, comparison_reward(4, 2, c_a=1.0, k_r=3.0))


@pytest.mark.parametrize("start", [None, [0.25, 0.75], "uniform", "hi"])
def test_round_trip_through_file(tmp_path, start):
    m = model_from_dict(explicit_doc(start=start, actions=["fast", "slow"], observations=["1", "2"]))
    save_model(m, tmp_path / "m.yaml")
    back = load_model(tmp_path / "m.yaml")
    for field in ("P", "O", "r", "w"):
        np.testing.assert_array_equal(getattr(back, field), getattr(m, field))
    assert (back.gamma, back.epsilon, back.name, back.uncertainty.name) == (m.gamma, m.epsilon, m.name, "shannon")
    assert back.state_names == ("lo", "hi") and back.action_names == ("fast", "slow")
    assert back.observation_names == ("1", "2")
    assert back.metadata.get("start") == start
    # the written file is plain YAML that loads with a safe loader
    assert yaml.safe_load((tmp_path / "m.yaml").read_text())["discount"] == 0.9


def test_round_trip_of_shipped_models(tmp_path):
    for path in MODELS:
        m = load_model(path)
        save_model(m, tmp_path / path.name)
        back = load_model(tmp_path / path.name)
        for field in ("P", "O", "r", "w"):
            np.testing.assert_array_equal(getattr(back, field), getattr(m, field))
        assert back.uncertainty.name == m.uncertainty.name and back.gamma == m.gamma


def test_model_to_dict_is_yaml_safe():
    m = POMDP(P=np.ones((1, 2, 2)) / 2, O=np.ones((1, 2, 1)), r=np.zeros((2, 1)), gamma=0.5)
    text = yaml.safe_dump(model_to_dict(m))
    assert model_from_dict(yaml.safe_load(text)).S == 2


@pytest.mark.parametrize(("doc", "pattern"), [
    ([1, 2], "top level: expected a mapping"),
    (explicit_doc(colour="red"), r"unknown field\(s\) \['colour'\]"),
    (explicit_doc(discount=None), "discount: missing"),
    (explicit_doc(transition=None), "transition: missing"),
    (explicit_doc(reward=None), "reward: missing"),
    (explicit_doc(states=3), "states: declares 3 but the matrices have 2"),
    (explicit_doc(states=0), "states: count must be at least 1"),
    (explicit_doc(states=True), r"states: expected a positive count or a non-empty list of names, got a boolean"),
    (explicit_doc(actions="two"), "actions: expected a positive count or a non-empty list"),
    (explicit_doc(transition=[[0.5, 0.5]]), "transition: expected a 3-dimensional nested list"),
    (explicit_doc(transition=[[[0.5, "x"]]]), r"transition\[0\]\[0\]\[1\]: must be a number, got a string 'x'"),
    (explicit_doc(reward=[[1.0, 0.0]]), r"reward: expected shape 2 x 2"),
    (explicit_doc(transition=[[[0.9, 0.2], [0.2, 0.8]], [[0.5, 0.5], [0.0, 1.0]]]),
     r"transition\[0\]\[0\]: row \(previous state 0, action 0\) sums to 1.1"),
    (explicit_doc(uncertainty={"function": "renyi2"}), "uncertainty.weights: missing"),
    (explicit_doc(uncertainty={"function": "gini", "weights": [1, 1]}), "uncertainty.function: unknown function"),
    (explicit_doc(uncertainty={"function": "none", "alpha": 2}), r"uncertainty: unknown field\(s\) \['alpha'\]"),
    (explicit_doc(uncertainty=[1]), "uncertainty: expected a mapping"),
    (explicit_doc(generator={"domain": "tracking", "S": 2, "A": 2, "q": 0.8}), "give either generator or"),
    (explicit_doc(transition=None, observation=None, generator={"domain": "maze"}),
     "generator.domain: one of grid, tracking, got a string 'maze'"),
    (explicit_doc(transition=None, observation=None, generator={"domain": "tracking", "S": 2, "A": 2}),
     "generator.q: missing"),
    (explicit_doc(transition=None, observation=None, generator={"domain": "tracking", "S": 2, "A": 2, "q": 0.8,
                                                                "z": 1}), r"generator: unknown field\(s\)"),
    (explicit_doc(transition=None, observation=None, generator={"domain": "tracking", "S": 2, "A": 2, "q": 0.8,
                                                                "x": ["a", "b"]}),
     r"generator.x\[0\]: must be a number, got a string 'a'"),
    (explicit_doc(reward_generator={"kind": "tracking_comparison"}), "give either reward or reward_generator"),
    (explicit_doc(reward=None, reward_generator={"kind": "other"}),
     "reward_generator.kind: one of effort, tracking_comparison, got a string 'other'"),
    (explicit_doc(reward=None, reward_generator={"kind": "tracking_comparison", "c_a": "x"}),
     "reward_generator.c_a: must be a number, got a string 'x'"),
    (explicit_doc(start=[0.5, 0.6]), "start: sums to 1.1"),
    (explicit_doc(start=[1.0]), "start: expected 2 probabilities"),
    (explicit_doc(start="middle"), "start: expected a list of 2 probabilities, 'uniform' or a state name"),
])
def test_errors_name_the_source_and_field(doc, pattern):
    with pytest.raises(ModelError, match=r"^my\.yaml: .*" + pattern):
        model_from_dict(doc, source="my.yaml")


def test_file_errors(tmp_path):
    with pytest.raises(ModelError, match="cannot read model file"):
        load_model(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("discount: [0.9\n")
    with pytest.raises(ModelError, match=r"bad\.yaml: not valid YAML"):
        load_model(bad)
    unsafe = tmp_path / "unsafe.yaml"
    unsafe.write_text("discount: !!python/object/apply:os.system ['echo hi']\n")
    with pytest.raises(ModelError, match="not valid YAML"):
        load_model(unsafe)
