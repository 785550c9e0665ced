"""Every ``lifecycle_msgs/srv/ChangeState`` request gets an answer and the node lives: the planner,
the belief filter and the sensor manager, in process and (the planner) as a process.

* The rule (``core/loop/managed.transition_request``) against the standard lifecycle graph written
  out here: a request is carried out exactly when it names a transition of the current state.
* Every transition id 0..99 and a set of labels (valid, of another state, unknown, an id and a
  label that disagree) from every primary state (unconfigured, inactive, active, finalized): the
  answer is ``success`` exactly for the transitions of that state, the node is then in that
  transition's goal state, or still where it was; its services keep answering; activated again,
  the node answers its input (the loop resumes).
* Two clients racing 200 requests (by id and by label, valid or not) on one node: every request
  answered, the node alive, and then driven to active it answers its input.
* A planner process (as ``ros2 run`` starts it) asked for transitions its state does not have
  (``activate`` and ``configure`` by id while active, id 99) answers ``false``, lives, and ends
  with exit code 0 at SIGINT without a traceback.
"""

from __future__ import annotations

import random
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from nodes_support import S3, LifecycleClient, make_harness, node_process_and_client
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, Int64MultiArray
from test_nodes_multiprocess import domain  # noqa: F401 (a fixture)

from pomdp_planner.core.loop import transition_request
from pomdp_planner.nodes.belief_filter import BeliefFilter
from pomdp_planner.nodes.messages import decode_belief, encode_belief
from pomdp_planner.nodes.planner import PlannerNode
from pomdp_planner.nodes.qos import RECORDER_QOS, STREAM_QOS
from pomdp_planner.nodes.sensor_manager import SensorManager

harness = pytest.fixture(make_harness)

#: The standard lifecycle graph (design.ros2.org, node lifecycle): from each primary state, the
#: transitions a client may ask for, id -> (label, goal state).
GRAPH = {
    "unconfigured": {1: ("configure", "inactive"), 5: ("shutdown", "finalized")},
    "inactive": {2: ("cleanup", "unconfigured"), 3: ("activate", "active"), 6: ("shutdown", "finalized")},
    "active": {4: ("deactivate", "inactive"), 7: ("shutdown", "finalized")},
    "finalized": {},
}
#: The way back from a transition's goal state to its start (labels).
BACK = {("unconfigured", 1): "cleanup", ("inactive", 2): "configure", ("inactive", 3): "deactivate",
        ("active", 4): "activate"}
LABELS = ("configure", "cleanup", "activate", "deactivate", "shutdown", "destroy", "create", "transition_success",
          "unconfigured", "Configure", " activate", "bogus")
SHUTDOWN = {"unconfigured": 5, "inactive": 6, "active": 7}


# ------------------------------------------------------------------ the rule
@pytest.mark.parametrize("state", sorted(GRAPH))
def test_the_rule_carries_out_exactly_the_transitions_of_the_state(state):
    available = [(tid, label) for tid, (label, _) in GRAPH[state].items()]
    for tid in range(100):
        label, reason = transition_request(tid, "", state, available)
        if tid in GRAPH[state]:
            assert (label, reason) == (GRAPH[state][tid][0], "")
        else:
            assert label is None and reason.startswith(f"change_state: no transition id {tid} from the state {state}; "
                                                       f"refused, still {state} (available: ")
            assert "\n" not in reason
    for text in LABELS:
        ids = [tid for tid, (lab, _) in GRAPH[state].items() if lab == text]
        assert transition_request(0, text, state, available)[0] == (text if ids else None)
        if ids:  # an id beside the label: the same transition's, or refused
            assert transition_request(ids[0], text, state, available)[0] == text
            other = 1 if ids[0] != 1 else 2
            label, reason = transition_request(other, text, state, available)
            assert label is None and "the id and the label name different transitions" in reason
    if state == "inactive":
        assert transition_request(99, "", state, available)[1] == (
            "change_state: no transition id 99 from the state inactive; refused, still inactive (available: "
            "cleanup (2), activate (3), shutdown (6))")


# ------------------------------------------------------------------ in process
class Kind:
    """A managed node type, its parameters, and an input that it answers with an output once active."""

    def __init__(self, cls, params: dict, in_topic: str, in_type, out_topic: str, out_type):
        self.cls, self.params = cls, params
        self.in_topic, self.in_type, self.out_topic, self.out_type = in_topic, in_type, out_topic, out_type


KINDS = {
    # the planner answers a belief of epoch t with the action of epoch t + 1
    "planner": Kind(PlannerNode, {"model_file": S3, "time_budget": 0.02, "max_depth": 1}, "belief", Float64MultiArray,
                    "action", Int64MultiArray),
    # the filter answers the reading of epoch t with the belief of epoch t
    "belief_filter": Kind(BeliefFilter, {"model_file": S3}, "observation", Int64MultiArray, "belief",
                          Float64MultiArray),
    # the sensor manager answers target t1's belief of epoch t with t1's action of epoch t + 1
    "sensor_manager": Kind(SensorManager, {"model_file": S3, "targets": ["t1"], "time_budget": 0.02, "max_depth": 1},
                           "t1/belief", Float64MultiArray, "t1/action", Int64MultiArray),
}


class Probe:
    """A node in namespace ``ns`` that feeds ``kind``'s input and records the epochs of its output."""

    def __init__(self, h, kind: Kind, ns: str):
        self.h, self.kind = h, kind
        self.node = h.add(Node("probe", namespace=ns, context=h.context))
        self.pub = self.node.create_publisher(kind.in_type, kind.in_topic, STREAM_QOS)
        self.epochs: list[int] = []
        self.node.create_subscription(kind.out_type, kind.out_topic, self._on_output, RECORDER_QOS)
        self.next = 0

    def _on_output(self, msg) -> None:
        epoch = decode_belief(msg, len(msg.data)).epoch if self.kind.out_type is Float64MultiArray else msg.data[0]
        with self.h.cond:
            self.epochs.append(int(epoch))
            self.h.cond.notify_all()

    def answered(self, timeout: float = 20.0) -> bool:
        """Feed the next epochs (the loop was made anew or was waiting) until one is answered."""
        seen = len(self.epochs)
        for _ in range(int(timeout / 0.5)):
            self.next += 1
            if self.kind.in_type is Float64MultiArray:
                self.pub.publish(encode_belief(self.next, np.array([0.5, 0.3, 0.2])))
            else:  # a reading of epoch t taken under priority 1: observation 0
                self.pub.publish(Int64MultiArray(data=[self.next, 1, 0]))
            if self.h.wait_until(lambda: len(self.epochs) > seen, timeout=0.5):
                return True
        return False


def _make(h, name: str, ns: str):
    kind = KINDS[name]
    params = [Parameter(k, value=v) for k, v in {**kind.params, "autostart": False}.items()]
    node = h.add(kind.cls(context=h.context, namespace=ns, parameter_overrides=params))
    lc = LifecycleClient(h.add(Node("lifecycle_client", namespace=ns, context=h.context)), f"{ns}/{name}",
                         timeout=10.0)
    return node, lc


def _sweep(lc: LifecycleClient, state: str) -> None:
    """Every id 0..99 but the state's shutdown, then every label, from ``state``; back after each success."""
    requests = [(tid, "") for tid in range(100) if tid != SHUTDOWN.get(state)]
    requests += [(0, label) for label in LABELS if label != "shutdown"]
    requests += [(tid, label) for tid, (label, _) in GRAPH[state].items() if label != "shutdown"]  # id and label
    requests += [(tid + 1, label) for tid, (label, _) in GRAPH[state].items() if label != "shutdown"]  # disagreeing
    for tid, label in requests:
        by_label = {lab: t for t, (lab, _) in GRAPH[state].items()}
        key = by_label.get(label) if label else tid
        if label and key is not None and tid not in (0, key):
            key = None
        expected = GRAPH[state].get(key) if key is not None else None
        assert lc.request(tid, label) == (expected is not None), (state, tid, label)
        if expected is None:
            assert lc.state() == state, (state, tid, label)
            continue
        assert lc.state() == expected[1], (state, tid, label)
        assert lc.change(BACK[(state, key)]) and lc.state() == state


@pytest.mark.parametrize("name", sorted(KINDS))
def test_every_request_from_every_state_is_answered_and_the_node_lives(harness, name):
    h = harness
    first, lc1 = _make(h, name, "/first")  # unconfigured, then finalized by id 5
    second, lc2 = _make(h, name, "/second")  # inactive and active, then finalized by id 6
    third, lc3 = _make(h, name, "/third")  # active, finalized by id 7
    probe = Probe(h, KINDS[name], "/second")
    h.start()
    assert all(lc.wait_for_services() for lc in (lc1, lc2, lc3))

    assert lc1.state() == "unconfigured"
    _sweep(lc1, "unconfigured")
    assert lc1.request(5) and lc1.state() == "finalized"
    _sweep(lc1, "finalized")
    assert lc1.transitions() == []

    assert lc2.change("configure") and lc2.state() == "inactive"
    _sweep(lc2, "inactive")
    assert lc2.change("activate")
    _sweep(lc2, "active")
    assert probe.answered(), f"{name}: no {KINDS[name].out_topic} after the requests"  # the loop resumes
    assert lc2.change("deactivate") and lc2.request(6) and lc2.state() == "finalized"

    assert lc3.change("configure") and lc3.change("activate") and lc3.request(7) and lc3.state() == "finalized"
    assert h._thread.is_alive() and all(n.lifecycle_state == "finalized" for n in (first, second, third))


@pytest.mark.parametrize("name", sorted(KINDS))
def test_two_clients_racing_200_requests_are_all_answered_and_the_loop_resumes(harness, name):
    h = harness
    node, lc = _make(h, name, "/race")
    probe = Probe(h, KINDS[name], "/race")
    racer = LifecycleClient(h.add(Node("second_client", namespace="/race", context=h.context)), f"/race/{name}",
                            timeout=30.0)
    h.start()
    assert lc.wait_for_services() and racer.wait_for_services()
    lc.timeout = 30.0
    # by id: every transition but shutdown, and ids no state has; by label: the same, and unknown ones
    ids = [1, 2, 3, 4, 0, 8, 10, 31, 99]
    labels = ["configure", "cleanup", "activate", "deactivate", "destroy", "bogus"]
    answers: list[list[bool]] = [[], []]
    errors: list[BaseException] = []

    def race(client: LifecycleClient, seed: int, out: list[bool]) -> None:
        rng = random.Random(seed)
        try:
            for _ in range(100):
                if rng.random() < 0.5:
                    out.append(client.request(rng.choice(ids)))
                else:
                    out.append(client.request(0, rng.choice(labels)))
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=race, args=(c, k, answers[k])) for k, c in enumerate((lc, racer))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors and [len(a) for a in answers] == [100, 100], errors
    assert any(a for a in answers[0] + answers[1]) and not all(answers[0] + answers[1])  # both kinds of answer
    assert h._thread.is_alive()
    state = lc.state()
    assert state == node.lifecycle_state and state in ("unconfigured", "inactive", "active")
    for label in {"unconfigured": ("configure", "activate"), "inactive": ("activate",), "active": ()}[state]:
        assert lc.change(label)
    assert lc.state() == "active"
    assert probe.answered(), f"{name}: no {KINDS[name].out_topic} after the race"


# ------------------------------------------------------------------ a process
def test_a_planner_process_answers_transitions_its_state_has_not_and_lives(domain, tmp_path):  # noqa: F811
    log = tmp_path / "planner.log"
    with node_process_and_client("planner", ["--ros-args", "-p", f"model_file:={S3}"], log) as (proc, node, codes):
        lc = LifecycleClient(node, "/planner")
        assert lc.wait_for_services(timeout=30.0), "no lifecycle services"
        assert lc.state() == "active"
        for tid in (3, 1, 99, 3):  # activate and configure while active, an id no state has
            assert not lc.request(tid)
            assert proc.poll() is None and lc.state() == "active"
        assert lc.request(4) and lc.state() == "inactive" and not lc.request(4) and lc.request(3)
        assert lc.state() == "active" and proc.poll() is None
    text = log.read_text(errors="replace")
    assert codes["planner"] == 0 and "Traceback" not in text and "RCLError" not in text, text[-3000:]
    refused = [line for line in text.splitlines() if "change_state:" in line]
    assert len(refused) == 5 and all("[WARN]" in line and "refused, still" in line for line in refused), refused
