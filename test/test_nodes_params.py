"""Node parameters: run-time changes through the parameter service, rejections, shipped YAML files."""

from __future__ import annotations

import array
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import REPO, S3, S8, make_harness
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64MultiArray
from test_nodes_closed_loop import start_loop

from pomdp_planner.core.bounds import BOUND_CONSTANTS, DEFAULT_CONSTANT, sample_beliefs, solve_bounds
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.belief_visualizer import BeliefVisualizer
from pomdp_planner.nodes.measurement_adapter import MeasurementAdapter
from pomdp_planner.nodes.messages import decode_plan_info, encode_belief
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.processes import PARAMETER_SETS, node_parameters, parameter_set_model
from pomdp_planner.nodes.qos import LATCHED_QOS
from pomdp_planner.nodes.runtime import NodeConfigError
from pomdp_planner.nodes.sensor_manager import SensorManager
from pomdp_planner.nodes.target_simulator import TargetSimulator

harness = pytest.fixture(make_harness)
#: The nodes every parameter set has a file for.
SET_NODE_CLASSES = {"target_simulator": TargetSimulator, "belief_filter": BeliefFilter, "planner": PlannerNode,
                    "measurement_adapter": MeasurementAdapter}
#: Every node a shipped parameter file may configure (the sensor manager's files name several models).
NODE_CLASSES = {**SET_NODE_CLASSES, "sensor_manager": SensorManager, "belief_visualizer": BeliefVisualizer}
PARAM_FILES = sorted((REPO / "config").glob("*.yaml"))


def _result(future, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not future.done():  # the executor spins in another thread: poll, never spin here
        assert time.monotonic() < deadline, "parameter service did not answer"
        time.sleep(0.005)
    return future.result()


def _set(client, **values):
    res = _result(client.set_parameters([Parameter(k, value=v) for k, v in values.items()]))
    return res.results


def test_set_parameters_while_running_take_effect_at_next_decision(harness):
    h = harness
    _, _, _, rec = start_loop(h, time_budget=0.02, max_depth=2)
    client = AsyncParameterClient(rec, "planner")
    assert client.wait_for_services(timeout_sec=10.0)
    assert h.wait_until(lambda: len(rec.beliefs) > 20, timeout=15)

    results = _set(client, max_depth=1, time_budget=0.05)
    assert all(r.successful for r in results), [r.reason for r in results]
    got = _result(client.get_parameters(["max_depth", "time_budget"]))
    assert [v.integer_value for v in got.values[:1]] == [1] and got.values[1].double_value == 0.05
    n0 = len(rec.diagnostics)

    def changed():
        return any(d.get("last.max_depth") == "1" and d.get("last.time_budget") == "0.05"
                   and d.get("last.depth") == "1" for d in rec.diag_values("planner")[n0:])
    # upper bounds for a loaded CI machine (diagnostics come about once a second)
    assert h.wait_until(changed, timeout=15), rec.diag_values("planner")[-1]
    assert h.wait_until(lambda: len(rec.beliefs) > 60, timeout=15)  # still looping

    results = _set(client, use_bounds=False, bound_variant="feasible", max_depth=3)
    assert all(r.successful for r in results), [r.reason for r in results]
    n1 = len(rec.diagnostics)
    assert h.wait_until(lambda: any(d.get("last.use_bounds") == "false" and d.get("last.max_depth") == "3"
                                    for d in rec.diag_values("planner")[n1:]), timeout=15)


@pytest.mark.parametrize(("name", "value", "reason"), [
    ("time_budget", 100.0, "time_budget"),       # out of the FloatingPointRange
    ("time_budget", 0.0, "time_budget"),
    ("max_depth", 0, "max_depth"),               # out of the IntegerRange
    ("max_depth", 51, "max_depth"),
    ("time_budget", "fast", "type"),             # wrong type
    ("max_depth", 2.5, "type"),
    ("use_bounds", 1, "type"),
    ("bound_variant", "loose", "bound_variant"),  # not a known variant (custom validation)
    ("bound_constant", "paper", "bound_constant"),  # not a known constant (custom validation)
    ("bound_constant", "MLR", "bound_constant"),
    ("bound_constant", 1, "type"),
    ("model_file", "other.yaml", "read-only"),   # needs a restart
    ("time_budget", 60.000001, "time_budget: must be a number in 0.001..60, got 60.000001"),  # rclpy: 1e-6 slack
    ("deadline_slack", 10.000001, "deadline_slack: must be a number in 0..10, got 10.000001"),
    ("", 1.0, "a parameter name must not be empty"),  # rclpy answers success
])
def test_invalid_parameter_values_rejected_with_reason(harness, name, value, reason):
    h = harness
    planner = h.add(PlannerNode(context=h.context, parameter_overrides=[Parameter("model_file", value=S3)]))
    before = planner.get_parameter(name).value if name else None
    client_node = h.add(rclpy_node(h))
    client = AsyncParameterClient(client_node, "planner")
    h.start()
    assert client.wait_for_services(timeout_sec=10.0)
    (res,) = _set(client, **{name: value})
    assert not res.successful
    assert reason.lower() in res.reason.lower(), res.reason
    if name:
        assert planner.get_parameter(name).value == before
    else:
        assert not planner.has_parameter("")


def rclpy_node(h):
    return Node("test_param_client", context=h.context)


def test_bad_startup_parameters_refuse_to_start(harness):
    h = harness
    with pytest.raises(NodeConfigError, match="model_file"):
        PlannerNode(context=h.context, parameter_overrides=[Parameter("model_file", value="no/such/model.yaml")])
    with pytest.raises(NodeConfigError, match="bound_variant"):
        PlannerNode(context=h.context, parameter_overrides=[Parameter("model_file", value=S3),
                                                            Parameter("bound_variant", value="loose")])
    with pytest.raises(NodeConfigError, match=r"bound_constant: expected one of mlr, fosd, got 'paper'"):
        PlannerNode(context=h.context, parameter_overrides=[Parameter("model_file", value=S3),
                                                            Parameter("bound_constant", value="paper")])
    with pytest.raises(NodeConfigError, match="initial_state"):
        TargetSimulator(context=h.context, parameter_overrides=[Parameter("model_file", value=S3),
                                                                Parameter("initial_state", value=3)])
    with pytest.raises(NodeConfigError, match="observation_model_files"):
        BeliefFilter(context=h.context, parameter_overrides=[
            Parameter("model_file", value=S3), Parameter("observation_topics", value=["a", "b"]),
            Parameter("observation_model_files", value=["", "", ""])])


def test_shipped_yaml_files_exist_for_every_parameter_set():
    """Every parameter set (the demo's ``--model``) has a file per node and a closed-loop file, and
    all their sections name the same model, the one ``parameter_set_model`` (the demo's monitor)
    reads; the perimeter sets run the perimeter models."""
    names = {p.name for p in PARAM_FILES}
    assert PARAMETER_SETS == ("s3", "s8", "perimeter_s3", "perimeter_s8")
    for key in PARAMETER_SETS:
        files = [f"{node}_{key}.yaml" for node in SET_NODE_CLASSES] + [f"closed_loop_{key}.yaml"]
        assert set(files) <= names, key
        models = {section["ros__parameters"]["model_file"] for f in files
                  for section in yaml.safe_load((REPO / "config" / f).read_text()).values()}
        assert len(models) == 1, (key, models)
        model = parameter_set_model(key)
        assert model == (REPO / models.pop()).resolve() and model.is_file()
        if key.startswith("perimeter_"):
            assert model.name == f"{key}.yaml"


@pytest.mark.parametrize("path", PARAM_FILES, ids=lambda p: p.name)
def test_shipped_yaml_loads_and_matches_declared_parameters(harness, path):
    h = harness
    doc = yaml.safe_load(path.read_text())
    assert doc, f"{path.name}: no node section"
    for section in doc:
        assert section.startswith("/**/"), f"{path.name}: {section!r} would not apply in a namespace"
        namespace, _, node_name = section.removeprefix("/**").rpartition("/")
        assert node_name in NODE_CLASSES, f"{path.name}: unknown node {section!r}"
        params = parameter_dict_from_yaml_file(str(path), target_nodes=[section])
        assert params, f"{path.name}: {node_name}: no parameters"
        node = h.add(NODE_CLASSES[node_name](  # a section /**/<ns>/<node>: the node in that namespace
            context=h.context, namespace=namespace or "/", cli_args=["--ros-args", "--params-file", str(path)]))
        for name, msg in params.items():
            assert node.has_parameter(name), f"{path.name}: {node_name} declares no parameter {name!r}"
            expected = Parameter.from_parameter_msg(msg).value
            got = node.get_parameter(name).value
            if isinstance(expected, list | array.array):  # a double array comes as array('d')
                expected, got = list(expected), list(got)
            assert got == expected, f"{path.name}: {node_name}.{name} = {got!r}, file says {expected!r}"


def test_parameter_service_answers_during_a_search(harness):
    """Planning runs in its own callback group: a parameter set is answered while a search runs.

    The search is held at its start until the answer has come (a real 1 s budget is no way to
    keep it running: the anytime search does not start a depth it predicts not to finish, and on
    a loaded machine it stopped after 70 ms, before the test had seen it start)."""
    h = harness
    planner = h.add(PlannerNode(context=h.context, parameter_overrides=[
        Parameter("model_file", value=S8), Parameter("time_budget", value=0.05), Parameter("max_depth", value=3)]))
    release = threading.Event()
    search = planner.loop.setup.planner.plan

    def held_search(*args, **kwargs):
        assert release.wait(timeout=30.0), "the test never released the search"
        return search(*args, **kwargs)

    planner.loop.setup.planner.plan = held_search
    node = h.add(rclpy_node(h))
    pub = node.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    client = AsyncParameterClient(node, "planner")
    h.start()
    try:
        assert client.wait_for_services(timeout_sec=10.0)
        pub.publish(encode_belief(0, np.full(8, 1 / 8)))
        assert h.wait_until(lambda: planner.loop.planning == 0, timeout=10)
        (res,) = _set(client, time_budget=0.3)
        assert res.successful
        assert planner.loop.planning == 0  # answered while the planning callback was still running
        assert planner.loop.health.counts["decisions"] == 0
    finally:
        release.set()
    assert h.wait_until(lambda: planner.loop.health.counts["decisions"] == 1, timeout=10)  # the held search completes


def test_shipped_files_step_the_simulator_at_a_sensor_rate():
    """Realistic defaults: the shipped files run the simulator as a 10 Hz sensor, not free
    (which used about 1.4 cores doing nothing a tracker needs), and give the planner a budget that
    fits in a sensor period."""
    for model in PARAMETER_SETS:
        for name in (f"target_simulator_{model}.yaml", f"closed_loop_{model}.yaml"):
            doc = yaml.safe_load((REPO / "config" / name).read_text())
            assert node_parameters(doc, "target_simulator")["step_period"] == 0.1, name
        for name in (f"planner_{model}.yaml", f"closed_loop_{model}.yaml"):
            doc = yaml.safe_load((REPO / "config" / name).read_text())
            assert node_parameters(doc, "planner")["time_budget"] < 0.1, name


def test_an_integer_is_accepted_for_a_float_parameter(harness):
    """``time_budget 5`` (a parameter file, ``-p time_budget:=5`` or ``ros2 param set``) means 5.0 s;
    the range still applies, and other types are still refused."""
    h = harness
    planner = h.add(PlannerNode(context=h.context, cli_args=[
        "--ros-args", "-p", f"model_file:={S3}", "-p", "time_budget:=5", "-p", "deadline_slack:=0"]))
    assert planner.get_parameter("time_budget").value == 5.0
    assert isinstance(planner.loop.params["time_budget"], float) and planner.loop.params["deadline_slack"] == 0.0
    flt = h.add(BeliefFilter(context=h.context, cli_args=[
        "--ros-args", "-p", f"model_file:={S3}", "-p", "initial_distribution:=[1, 0, 0]", "-p", "epoch_timeout:=2"]))
    assert list(flt.get_parameter("initial_distribution").value) == [1.0, 0.0, 0.0]
    assert flt.loop.buffer.timeout == 2.0
    client = AsyncParameterClient(h.add(rclpy_node(h)), "planner")
    h.start()
    assert client.wait_for_services(timeout_sec=10.0)
    (res,) = _set(client, time_budget=2)
    assert res.successful, res.reason
    assert planner.get_parameter("time_budget").value == 2.0 and planner.loop.params["time_budget"] == 2.0
    (res,) = _set(client, time_budget=100)
    assert not res.successful and "time_budget" in res.reason
    (res,) = _set(client, time_budget="5")
    assert not res.successful and "type" in res.reason.lower()
    (res,) = _set(client, max_depth=3.0)  # the other way round stays refused: 3.0 is not an integer depth
    assert not res.successful


def test_bound_constant_set_at_run_time_re_solves_the_bounds_for_the_next_decision(harness):
    """``bound_constant``: declared with the core's choices and default; set at run time,
    the bounds are re-solved at the next decision, and that decision's diagnostics show it. On the
    natural S = 8 model, at a belief where the MLR-exact bounds agree and the FOSD ones do not, the
    decision is certified with ``mlr`` and not with ``fosd``; back to ``mlr``, certified again."""
    h = harness
    path = str(REPO / "config" / "models" / "tracking_s8_natural.yaml")
    model = load_model(path)
    B = sample_beliefs(model, 200, seed=5)
    lo_m, up_m = solve_bounds(model, constant="mlr").myopic.actions(B)
    lo_f, up_f = solve_bounds(model, constant="fosd").myopic.actions(B)
    belief = B[int(np.flatnonzero((lo_m == up_m) & (lo_f < up_f))[0])]
    planner = h.add(PlannerNode(context=h.context, parameter_overrides=[
        Parameter("model_file", value=path), Parameter("time_budget", value=0.05), Parameter("max_depth", value=2)]))
    desc = planner.describe_parameter("bound_constant")
    assert planner.get_parameter("bound_constant").value == DEFAULT_CONSTANT == "mlr"
    assert all(c in desc.additional_constraints for c in BOUND_CONSTANTS) and not desc.read_only
    rec = h.recorder()
    pub = rec.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    client = AsyncParameterClient(rec, "planner")
    h.start()
    assert client.wait_for_services(timeout_sec=10.0)
    solved = planner.loop.setup.planner

    def decision(epoch: int, constant: str, certified: bool) -> None:
        pub.publish(encode_belief(epoch, belief))
        n0 = len(rec.diagnostics)

        def shown():
            return [d for d in rec.diag_values("planner")[n0:] if d.get("last.belief_epoch") == str(epoch)]
        assert h.wait_until(shown, timeout=15)  # diagnostics come about once a second
        d = shown()[0]
        assert d["param.bound_constant"] == d["last.bound_constant"] == constant, d
        assert d["bounds"] == f"tight, constant {constant}: feasible", d
        assert d["last.certified"] == ("true" if certified else "false"), d
        assert planner.loop.setup.constant == planner.loop.setup.bounds.constant == constant

    decision(0, "mlr", True)
    (res,) = _set(client, bound_constant="fosd")
    assert res.successful, res.reason
    assert planner.loop.setup.planner is solved  # nothing re-solved before the next decision
    decision(1, "fosd", False)
    assert planner.loop.setup.planner is not solved
    (res,) = _set(client, bound_constant="mlr")
    assert res.successful, res.reason
    decision(2, "mlr", True)


def test_plan_info_carries_the_root_bounds_as_priorities(harness):
    """``plan_info.bound_lower``, ``bound_upper``: the myopic bounds at the planned belief, as
    priorities, equal to the bounds solved here independently of the planner (``solve_bounds``);
    ``certified`` exactly when they agree; NaN when the decision used no bounds (``use_bounds``
    false)."""
    h = harness
    path = str(REPO / "config" / "models" / "perimeter_s8.yaml")
    model = load_model(path)
    B = sample_beliefs(model, 200, seed=3)
    lo, up = solve_bounds(model).myopic.actions(B)
    picks = [int(np.flatnonzero(lo == up)[0]), int(np.flatnonzero(lo < up)[0])]  # one agreeing, one not
    h.add(PlannerNode(context=h.context, parameter_overrides=[
        Parameter("model_file", value=path), Parameter("time_budget", value=0.05), Parameter("max_depth", value=2)]))
    rec = h.recorder()
    infos = []
    rec.create_subscription(Float64MultiArray, "plan_info", lambda msg: infos.append(decode_plan_info(msg)), 10)
    pub = rec.create_publisher(Float64MultiArray, "belief", LATCHED_QOS)
    client = AsyncParameterClient(rec, "planner")
    h.start()
    assert client.wait_for_services(timeout_sec=10.0)
    for epoch, i in enumerate(picks):
        pub.publish(encode_belief(epoch, B[i]))
        assert h.wait_until(lambda n=epoch + 1: len(infos) >= n, timeout=15)
        info = infos[epoch]
        assert (info["bound_lower"], info["bound_upper"]) == (lo[i] + 1, up[i] + 1)
        assert info["certified"] == float(lo[i] == up[i])
    (res,) = _set(client, use_bounds=False)
    assert res.successful
    pub.publish(encode_belief(len(picks), B[picks[1]]))
    assert h.wait_until(lambda: len(infos) > len(picks), timeout=15)
    assert np.isnan(infos[-1]["bound_lower"]) and np.isnan(infos[-1]["bound_upper"])


def test_max_setup_seconds_limits_the_configure_and_a_long_set_up_is_announced(harness, monkeypatch, capfd):
    """The planner's ``max_setup_seconds`` is the gate's limit (0: none), as ``--no-limit`` on the
    command line; a set-up expected to take long is announced in the log with its estimate."""
    from pomdp_planner.core import gate

    h = harness
    with pytest.raises(NodeConfigError, match=r"more than the limit of 0.1 s \(MAX_SETUP_SECONDS\); the parameter "
                       r"max_setup_seconds raises the limit \(0: no limit\)"):
        PlannerNode(context=h.context, parameter_overrides=[Parameter("model_file", value=S3),
                                                            Parameter("max_setup_seconds", value=1e-6)])
    monkeypatch.setattr(gate, "SETUP_NOTICE_SECONDS", 0.0)  # every set-up is "long"
    capfd.readouterr()
    planner = h.add(PlannerNode(context=h.context, parameter_overrides=[Parameter("model_file", value=S3),
                                                                        Parameter("max_setup_seconds", value=0.0)]))
    assert planner.get_parameter("max_setup_seconds").value == 0.0
    err = capfd.readouterr().err
    assert "set-up for S=3, A=3, Z=3 is running, expected about" in err and "no time budget includes it" in err


def test_the_grid10_parameter_files_run_the_grid_model_in_every_node_of_the_closed_loop():
    """``closed_loop.launch.xml model_set:=grid10`` reads config/closed_loop_grid10.yaml for its three
    nodes (docs/ros.md, "Parameter files"): a section for each, in any namespace, naming the 10 x 10
    grid, as does each node's own file config/<node>_grid10.yaml (``ros2 run``)."""
    launch = (REPO / "launch" / "closed_loop.launch.xml").read_text()
    assert "config/closed_loop_$(var model_set).yaml" in launch
    for node in ("target_simulator", "belief_filter", "planner"):
        doc = yaml.safe_load((REPO / "config" / f"{node}_grid10.yaml").read_text())
        assert node_parameters(doc, node)["model_file"] == "config/models/grid_10x10.yaml" and f"/**/{node}" in doc
        closed = yaml.safe_load((REPO / "config" / "closed_loop_grid10.yaml").read_text())
        assert node_parameters(closed, node)["model_file"] == "config/models/grid_10x10.yaml"
    assert parameter_set_model("grid10").name == "grid_10x10.yaml"
