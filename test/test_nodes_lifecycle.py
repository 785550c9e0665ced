"""The planner and the belief filter as managed (lifecycle) nodes, driven through the standard
``lifecycle_msgs`` services (GetState, ChangeState, GetAvailableTransitions) from an rclpy client,
in process: the states and their transitions, the diagnostics in every state, a failing configure
(the node stays unconfigured with its reason and is configurable once the parameter is fixed),
configure-time parameters, and deactivate / activate during a running loop with no epoch
mis-paired: every action is the core planner's decision on the belief of the epoch before it, and
the filter's beliefs are Bayes' rule replayed on the observations the simulator sent.

The process-level behaviour (the log line of a failing configure, ``autostart`` and the
``[FATAL]`` line) is in ``test_nodes_lifecycle_process.py``."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticStatus
from nodes_support import REPO, S3, LifecycleClient, make_harness
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from pomdp_planner.core.gate import build_planner
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.options import TIME_BUDGET_RANGE
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.params import NodeConfigError
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.target_simulator import TargetSimulator

harness = pytest.fixture(make_harness)
PERIMETER = str(REPO / "config" / "models" / "perimeter_s3.yaml")  # its depth-1 decisions vary along a run
MANAGED = {"planner": PlannerNode, "belief_filter": BeliefFilter}
TB = f"{TIME_BUDGET_RANGE[0]:g}..{TIME_BUDGET_RANGE[1]:g}"


def _params(**kw):
    return [Parameter(k, value=v) for k, v in kw.items()]


def _client(h, target: str) -> LifecycleClient:
    node = h.add(Node(f"lifecycle_client_{target.strip('/')}", context=h.context))
    return LifecycleClient(node, target)


def _diag_in(rec, node: str, state: str) -> dict | None:
    """The newest diagnostics of ``node`` published in ``state``, if any."""
    found = [d for d in rec.diag_values(f"{node}:") if d.get("lifecycle_state") == state]
    return found[-1] if found else None


def _set(h, node: str, **values):
    client = AsyncParameterClient(h.add(Node(f"param_client_{len(h.nodes)}", context=h.context)), node)
    assert client.wait_for_services(timeout_sec=10.0)
    future = client.set_parameters([Parameter(k, value=v) for k, v in values.items()])
    assert h.wait_until(future.done, timeout=10.0)
    return future.result().results


# ------------------------------------------------------------------ states and transitions
@pytest.mark.parametrize("name", sorted(MANAGED))
def test_the_standard_services_walk_every_state_and_diagnostics_say_each(harness, name):
    h = harness
    node = h.add(MANAGED[name](context=h.context, parameter_overrides=_params(model_file=S3, autostart=False)))
    rec = h.recorder()
    lc = _client(h, f"/{name}")
    h.start()
    assert lc.wait_for_services()
    topic = {"planner": "action", "belief_filter": "belief"}[name]
    probe = h.nodes[-1]  # the client node counts the publishers of the node's output topic

    assert lc.state() == "unconfigured"
    assert lc.transitions() == [("configure", "configuring"), ("shutdown", "shuttingdown")]
    assert probe.count_publishers(topic) == 0  # nothing exists before configure
    assert h.wait_until(lambda: _diag_in(rec, name, "unconfigured"), timeout=10)
    d = _diag_in(rec, name, "unconfigured")
    assert d["_level"] == DiagnosticStatus.OK and d["_message"] == "unconfigured: waiting for configure"

    assert lc.change("configure") and lc.state() == "inactive"
    assert sorted(lc.transitions()) == [("activate", "activating"), ("cleanup", "cleaningup"),
                                        ("shutdown", "shuttingdown")]
    assert h.wait_until(lambda: probe.count_publishers(topic) == 1, timeout=10)
    assert h.wait_until(lambda: _diag_in(rec, name, "inactive"), timeout=10)
    assert "inactive" in _diag_in(rec, name, "inactive")["_message"]

    assert lc.change("activate") and lc.state() == "active"
    assert sorted(lc.transitions()) == [("deactivate", "deactivating"), ("shutdown", "shuttingdown")]
    assert h.wait_until(lambda: _diag_in(rec, name, "active"), timeout=10)
    if name == "belief_filter":  # activation published the prior
        assert h.wait_until(lambda: 0 in rec.belief_epochs(3), timeout=10)

    assert lc.change("deactivate") and lc.state() == "inactive"
    assert lc.change("cleanup") and lc.state() == "unconfigured"
    assert node.loop is None and node.model is None  # the model is released
    assert h.wait_until(lambda: probe.count_publishers(topic) == 0, timeout=10)
    assert not lc.change("activate")  # not a transition of this state
    assert lc.state() == "unconfigured"
    assert lc.change("configure") and lc.state() == "inactive"  # configurable again
    assert lc.change("shutdown") and lc.state() == "finalized"
    assert h.wait_until(lambda: _diag_in(rec, name, "finalized"), timeout=10)
    assert lc.transitions() == []


@pytest.mark.parametrize("name", sorted(MANAGED))
def test_autostart_walks_configure_and_activate_as_the_node_is_made(harness, name):
    h = harness
    node = h.add(MANAGED[name](context=h.context, parameter_overrides=_params(model_file=S3)))
    assert node.lifecycle_state == "active" and node.loop is not None and node.loop.active
    lc = _client(h, f"/{name}")
    h.start()
    assert lc.wait_for_services() and lc.state() == "active"


# ------------------------------------------------------------------ a failing configure
def test_a_failing_configure_stays_unconfigured_with_its_reason_until_the_parameter_is_fixed(harness):
    h = harness
    node = h.add(PlannerNode(context=h.context, parameter_overrides=_params(
        model_file="no/such/model.yaml", autostart=False)))
    rec = h.recorder()
    lc = _client(h, "/planner")
    h.start()
    assert lc.wait_for_services()
    assert not lc.change("configure")  # the service's answer: no success ...
    assert lc.state() == "unconfigured"  # ... and the node is where it was, alive
    assert node.configure_error.startswith("model_file: 'no/such/model.yaml' not found")
    assert h.wait_until(lambda: (d := _diag_in(rec, "planner", "unconfigured"))
                        and d["_level"] == DiagnosticStatus.ERROR, timeout=10)
    d = _diag_in(rec, "planner", "unconfigured")
    assert d["_message"] == f"unconfigured: configure failed: {node.configure_error}"
    assert d["configure_error"] == node.configure_error and "\n" not in d["_message"]

    # model_file is read at configure: settable while unconfigured, then configure succeeds
    (res,) = _set(h, "planner", model_file=S3)
    assert res.successful
    assert lc.change("configure") and lc.state() == "inactive"
    assert h.wait_until(lambda: (d := _diag_in(rec, "planner", "inactive")) and d["_level"] == DiagnosticStatus.OK,
                        timeout=10)
    assert "configure_error" not in _diag_in(rec, "planner", "inactive")
    (res,) = _set(h, "planner", model_file=PERIMETER)  # configured: refused, with the way out
    assert not res.successful
    assert res.reason == ("model_file: read-only while the node is inactive (read at configure: settable only "
                          "while the node is unconfigured; 'ros2 lifecycle set /planner cleanup' first)")
    assert node.get_parameter("model_file").value == S3
    (res,) = _set(h, "planner", time_budget=0.5)  # a run-time parameter is not affected
    assert res.successful


def test_a_value_refused_as_it_is_declared_fails_configure_until_the_parameter_is_set(harness):
    """Without autostart a refused parameter value does not stop the node: the parameter holds its
    default, and configure fails with the refusal's one line (in declaration order) until a valid
    value is set; with autostart the same line is the node's start-up error."""
    h = harness
    node = h.add(PlannerNode(context=h.context, parameter_overrides=_params(
        model_file=S3, autostart=False, time_budget=100.0, chunk_kib=5)))
    lc = _client(h, "/planner")
    h.start()
    assert lc.wait_for_services() and lc.state() == "unconfigured"
    assert node.get_parameter("time_budget").value == 0.1  # the default while refused
    assert not lc.change("configure") and lc.state() == "unconfigured"
    assert node.configure_error == f"time_budget: must be a number in {TB}, got 100.0"
    assert not _set(h, "planner", time_budget=200.0)[0].successful  # still out of range: still refused
    assert all(r.successful for r in _set(h, "planner", time_budget=0.5))
    assert not lc.change("configure")
    assert node.configure_error == "chunk_kib: must be an integer in 16..1048576, got 5"
    assert all(r.successful for r in _set(h, "planner", chunk_kib=64))
    assert lc.change("configure") and lc.change("activate") and lc.state() == "active"
    assert node.loop.params["time_budget"] == 0.5
    with pytest.raises(NodeConfigError, match=r"^chunk_kib: must be an integer in 16\.\.1048576, got 5$") as err:
        PlannerNode(node_name="planner_autostart", context=h.context,
                    parameter_overrides=_params(model_file=S3, chunk_kib=5))
    assert err.value.node == "planner_autostart"


def test_every_configure_time_error_is_one_line_and_leaves_the_node_configurable(harness):
    h = harness
    flt = h.add(BeliefFilter(context=h.context, parameter_overrides=_params(
        model_file=S3, autostart=False, stall_warn_after=5.0, stall_error_after=1.0,
        observation_topics=["cam", "cam"])))
    lc = _client(h, "/belief_filter")
    h.start()
    assert lc.wait_for_services()
    assert not lc.change("configure") and lc.state() == "unconfigured"
    assert flt.configure_error.startswith("stall_warn_after, stall_error_after: stall limits: need 0 < warn_after")
    assert all(r.successful for r in _set(h, "belief_filter", stall_error_after=10.0))
    assert not lc.change("configure")
    assert flt.configure_error == ("observation_topics, likelihood_topics: need distinct topics, at least one, got "
                                   "['cam', 'cam'] and []")
    assert all(r.successful for r in _set(h, "belief_filter", observation_topics=["cam", "radar"],
                                          observation_model_files=["", "nope.yaml"]))
    assert not lc.change("configure")
    assert flt.configure_error.startswith("observation_model_files[1]: 'nope.yaml' not found")
    assert flt.count_subscribers("cam") == 0 and not list(flt.subscriptions)  # nothing left behind
    assert all(r.successful for r in _set(h, "belief_filter", observation_model_files=["", ""]))
    assert lc.change("configure") and lc.change("activate") and lc.state() == "active"
    assert flt.loop.topics == ["cam", "radar"]


# ------------------------------------------------------------------ a running loop
def _loop(h, *, sim_params=None, planner_params=None):
    """Simulator (plain node), filter and planner (managed, autostart) on the perimeter S = 3 model,
    a recorder, spinning; depth-1 decisions (the same for a belief every time)."""
    sim = TargetSimulator(context=h.context, parameter_overrides=_params(model_file=PERIMETER, seed=4,
                                                                         **(sim_params or {})))
    flt = BeliefFilter(context=h.context, parameter_overrides=_params(model_file=PERIMETER))
    planner = PlannerNode(context=h.context, parameter_overrides=_params(
        model_file=PERIMETER, time_budget=5.0, max_depth=1, **(planner_params or {})))
    rec = h.recorder()
    clients = {"planner": _client(h, "/planner"), "belief_filter": _client(h, "/belief_filter")}
    h.start()
    for pub, n in ((flt.belief_pub, 2), (planner.action_pub, 3), (sim.obs_pubs[0], 2)):
        assert h.wait_matched(pub, n), f"{pub.topic_name}: subscribers not matched"
    assert all(c.wait_for_services() for c in clients.values())
    for node in (sim, flt, planner):
        h.add(node)
    return sim, flt, planner, rec, clients


def _newest(rec, kind: str) -> int:
    """The newest epoch received of ``kind`` (``belief``, ``action`` or ``observation``), -1 if none."""
    if kind == "belief":
        return max(rec.belief_epochs(3), default=-1)
    with rec.cond:
        msgs = list(rec.actions) if kind == "action" else list(rec.observations["observation"])
    return max((m[0] for m in msgs), default=-1)


def _copies(rec, kind: str, epoch: int) -> int:
    if kind == "belief":
        return sum(b.epoch == epoch for b in rec.decoded_beliefs(3))
    with rec.cond:
        return sum(m[0] == epoch for m in rec.observations["observation"])


def _check_no_epoch_mispaired(rec, model, first_epochs: int) -> None:
    """Every action ``[t + 1, p]``: ``p`` is the core's depth-1 decision on the recorded belief of
    epoch ``t``; every recorded belief is Bayes' rule replayed from the prior on the observations
    the simulator sent (each with the action it carries)."""
    planner = build_planner(model).planner
    beliefs = rec.beliefs_by_epoch(model.S)
    with rec.cond:
        actions = list(rec.actions)
        obs = {t: (p, z) for t, p, z in rec.observations["observation"]}
    assert len(set(actions)) == len(dict(actions))  # no epoch answered twice differently
    for t, p in set(actions):
        assert t - 1 in beliefs, f"action of epoch {t}: the belief of epoch {t - 1} was never published"
        assert p == planner.plan(beliefs[t - 1], max_depth=1, time_budget=5.0).priority, f"action of epoch {t}"
    assert len({p for _, p in actions}) >= 2  # varied decisions: a mis-pairing would show
    b = np.full(model.S, 1.0 / model.S)
    for t in range(1, max(beliefs) + 1):
        a, z = obs[t][0] - 1, obs[t][1]
        b = (b @ model.P[a]) * model.O[a, :, z]
        b = b / b.sum()
        if t in beliefs:
            np.testing.assert_allclose(beliefs[t], b, rtol=1e-9, atol=1e-12, err_msg=f"belief of epoch {t}")
    assert max(beliefs) >= first_epochs


def test_deactivate_and_activate_each_node_of_a_free_running_loop_mispairs_no_epoch(harness):
    h = harness
    model = load_model(PERIMETER)
    _sim, flt, planner, rec, lc = _loop(h)
    assert h.wait_until(lambda: _newest(rec, "belief") >= 20, timeout=60)

    # the planner: the loop pauses on the belief whose action it does not publish; nothing is re-sent
    # meanwhile. Belief `paused` waits in the mailbox, or its search was running at the deactivation
    # and its action is kept, unpublished, for the activation.
    assert lc["planner"].change("deactivate") and lc["planner"].state() == "inactive"
    resent = planner.loop.health.counts["resent_actions"]
    assert h.wait_until(lambda: _copies(rec, "belief", _newest(rec, "belief")) >= 3, timeout=30)  # 2 re-sends
    paused = _newest(rec, "belief")
    assert _newest(rec, "action") == paused  # the last action published answered belief `paused - 1`
    with planner.lock:
        waiting, kept = planner.loop.mailbox, planner.loop.last_action
    assert planner.loop.health.counts["resent_actions"] == resent
    assert (waiting is not None and waiting.epoch == paused) or (
        waiting is None and kept is not None and kept.epoch == paused + 1), (waiting, kept)
    assert lc["planner"].change("activate")
    assert h.wait_until(lambda: _newest(rec, "belief") >= paused + 20, timeout=60)

    # the filter: it applies the reading it gets while inactive and publishes the belief when activated
    assert lc["belief_filter"].change("deactivate") and lc["belief_filter"].state() == "inactive"
    assert h.wait_until(lambda: _copies(rec, "observation", _newest(rec, "observation")) >= 3, timeout=30)
    held = _newest(rec, "observation")
    assert _newest(rec, "belief") == held - 1 and flt.loop.epoch == held  # applied, withheld
    assert lc["belief_filter"].change("activate")
    assert h.wait_until(lambda: _newest(rec, "belief") >= held + 20, timeout=60)
    _check_no_epoch_mispaired(rec, model, held + 20)


def test_deactivate_and_activate_beside_a_sensor_that_keeps_stepping_mispairs_no_epoch(harness):
    """Timer-driven simulator (the sensor is the clock): an inactive filter still applies every
    reading and publishes its newest belief when activated; an inactive planner skips the epochs it
    did not plan and plans the newest belief when activated."""
    h = harness
    model = load_model(PERIMETER)
    _sim, flt, planner, rec, lc = _loop(h, sim_params={"step_period": 0.02})
    assert h.wait_until(lambda: _newest(rec, "belief") >= 10, timeout=60)

    assert lc["belief_filter"].change("deactivate")
    with flt.lock:
        last_published = flt.loop.epoch  # no belief published after this one until activation
    assert h.wait_until(lambda: _newest(rec, "observation") >= last_published + 15, timeout=60)
    assert _newest(rec, "belief") <= last_published
    with flt.lock:
        applied = flt.loop.epoch  # the filter's newest reading before the activation (the recorder's may be newer)
    assert applied > last_published + 1  # readings applied while inactive: epochs to skip
    assert lc["belief_filter"].change("activate")
    assert h.wait_until(lambda: _newest(rec, "belief") >= last_published + 15, timeout=30)
    first_after = min(e for e in rec.belief_epochs(3) if e > last_published)
    assert first_after >= applied  # the newest at once, no belief for the epochs in between
    with planner.lock:  # a documented transition: no "stray, forged or replayed" warning at the planner
        assert planner.loop.health.counts["unexplained_epochs"] == 0

    assert lc["planner"].change("deactivate")
    with planner.lock:
        last_planned = max(planner.loop.line.position, planner.loop.planning or 0)
    assert h.wait_until(lambda: _newest(rec, "belief") >= last_planned + 15, timeout=60)
    assert _newest(rec, "action") <= last_planned + 1
    assert lc["planner"].change("activate")
    assert h.wait_until(lambda: _newest(rec, "action") >= last_planned + 15, timeout=30)
    assert planner.loop.health.counts["resyncs"] == flt.loop.health.counts["resyncs"] == 0
    _check_no_epoch_mispaired(rec, model, last_planned + 15)


@pytest.mark.parametrize("name", sorted(MANAGED))
def test_an_inactive_node_still_drops_an_oversized_sample_and_refuses_use_sim_time(harness, name):
    """The stray-message rules hold in every state with a loop: an inactive node drops an oversized
    sample on its input unread (counted) and refuses ``use_sim_time``; after cleanup it has no input."""
    from std_msgs.msg import Float64MultiArray, Int64MultiArray

    from pomdp_planner.nodes.qos import STREAM_QOS

    h = harness
    node = h.add(MANAGED[name](context=h.context, parameter_overrides=_params(model_file=S3, autostart=False)))
    rec = h.recorder()
    lc = _client(h, f"/{name}")
    sender = h.add(Node(f"oversized_sender_{name}", context=h.context))
    topic, msg = {"planner": ("belief", Float64MultiArray(data=[0.0] * 4096)),
                  "belief_filter": ("observation", Int64MultiArray(data=[0] * 4096))}[name]
    pub = sender.create_publisher(type(msg), topic, STREAM_QOS)
    h.start()
    assert lc.wait_for_services()
    assert not _set(h, f"/{name}", use_sim_time=True)[0].successful  # unconfigured: refused too
    others = sender.count_subscribers(topic)  # the recorder's
    assert lc.change("configure") and lc.state() == "inactive"
    assert h.wait_until(lambda: pub.get_subscription_count() > others, timeout=10)
    pub.publish(msg)
    assert h.wait_until(lambda: int((_diag_in(rec, name, "inactive") or {}).get("oversized_samples", 0)) >= 1,
                        timeout=10)
    result = _set(h, f"/{name}", use_sim_time=True)[0]
    assert not result.successful and "use_sim_time" in result.reason
    assert lc.change("cleanup") and node.inputs == {}
    assert h.wait_until(lambda: sender.count_subscribers(topic) == others, timeout=10)
