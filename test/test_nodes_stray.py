"""Stray, forged and replayed messages against the running loop: the three executables as
processes with the shipped 10 Hz parameter files on the S = 3 model and the opt-in Fast DDS profile
(one bring-up for the whole module), observed and attacked from the test's own process on
localhost, in a domain of its own.

Scenarios (docs/ros.md, "The loop's rules"): forged actions, beliefs and observations
inside the epoch window; an oversized sample on every input; a ``ros2 bag play``-like replay of
the loop's own earlier epochs, renumbered as a longer earlier run would be; a second writer (a
second "planner" answering every belief at once, and a flood of plausible observations);
``use_sim_time`` set at run time, and a node started with it and no ``/clock``. Each asserts, in
epochs (10 epochs = 1 s at 10 Hz), that at most one epoch is applied from the stray messages and
none after the first 10, that every belief is the filter's rule applied to the simulator's own
readings, that the planner answers only the filter's beliefs, and that the diagnostics name the
cause. The test attributes samples by content: what it injected itself is known, the rest is the
loop's own (an injected sample identical to a real one is harmless either way).
"""

from __future__ import annotations

import array
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticArray
from nodes_support import REPO, die_with_test, rclpy, remove_dead_shm, shm_entries
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, Int64MultiArray

from pomdp_planner.bench.ros.soak import rss_mib
from pomdp_planner.core.filter import EpochFilter
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.nodes.messages import decode_belief, encode_action, encode_belief, encode_observation
from pomdp_planner.nodes.processes import node_command, ros_env, start_nodes, stop_nodes
from pomdp_planner.nodes.qos import RECORDER_QOS, STREAM_QOS

MODEL = load_model(REPO / "config" / "models" / "tracking_s3_info.yaml")
#: Epochs watched after the stray messages; the loop must follow the planner again after RECOVERY.
WATCH, RECOVERY = 40, 10
#: A lagging planner's decision may reach the simulator this many epochs late (a loaded machine).
LAG = 8
NODES = ("target_simulator", "belief_filter", "planner")


class Observer(Node):
    """Records the loop's topics and ``/diagnostics`` (with arrival times), telling the loop's own
    samples from those the test injected (:meth:`Loop.inject` counts each before it is sent)."""

    def __init__(self, context: Context):
        super().__init__("stray_observer", context=context)
        self.lock = threading.Lock()
        self.obs: dict[int, tuple[int, int]] = {}            # the simulator's readings: epoch -> (p, z)
        self.beliefs: dict[int, tuple[float, ...]] = {}      # the filter's beliefs
        self.decisions: dict[int, int] = {}  # plan_info: only the real planner publishes it
        self.diags: list[tuple[float, str, int, str, dict]] = []
        self.injected: Counter = Counter()  # (topic, content) injected and not received back yet
        self.create_subscription(Int64MultiArray, "observation", self._obs, RECORDER_QOS)
        self.create_subscription(Float64MultiArray, "belief", self._bel, RECORDER_QOS)
        self.create_subscription(Float64MultiArray, "plan_info", self._info, RECORDER_QOS)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 100)

    def _own(self, key) -> bool:
        """Whether a sample received is the loop's own (not one the test injected)."""
        if self.injected[key] > 0:
            self.injected[key] -= 1
            return False
        return True

    def _obs(self, msg):
        if len(msg.data) != 3:
            return  # the oversized one
        t, p, z = (int(x) for x in msg.data)
        with self.lock:
            if self._own(("observation", (t, p, z))):
                self.obs[t] = (p, z)

    def _bel(self, msg):
        try:
            b = decode_belief(msg, MODEL.S)
        except Exception:
            return
        content = tuple(float(x) for x in b.belief)
        with self.lock:
            if self._own(("belief", (b.epoch, content))):
                self.beliefs[b.epoch] = content

    def _info(self, msg):
        with self.lock:
            self.decisions[int(msg.data[0])] = int(msg.data[1])

    def _diag(self, msg):
        now = time.monotonic()
        with self.lock:
            for st in msg.status:
                self.diags.append((now, st.name, st.level[0] if isinstance(st.level, bytes) else st.level,
                                   st.message, {kv.key: kv.value for kv in st.values}))

    # ----------------------------------------------------------- what the loop did
    def real_obs(self) -> dict[int, tuple[int, int]]:
        with self.lock:
            return dict(self.obs)

    def real_beliefs(self) -> dict[int, tuple[float, ...]]:
        with self.lock:
            return dict(self.beliefs)

    def newest(self) -> int:
        with self.lock:
            return max(self.obs, default=-1)

    def unlikely_priority(self) -> int:
        """A priority the planner has not decided lately (or its least frequent one)."""
        with self.lock:
            recent = [p for _, p in sorted(self.decisions.items())[-20:]]
        counts = Counter({p: 0 for p in range(1, MODEL.A + 1)}) + Counter(recent)
        return min(range(1, MODEL.A + 1), key=lambda p: (counts.get(p, 0), p))

    def diag(self, node: str, since: float) -> list[tuple[int, str, dict]]:
        with self.lock:
            return [(lv, m, v) for t, n, lv, m, v in self.diags if t >= since and n.startswith(node + ":")]


class Loop:
    def __init__(self, procs, observer: Observer, executor, log_dir: Path):
        self.procs, self.obs, self.executor, self.log_dir = procs, observer, executor, log_dir

    def wait(self, predicate, timeout: float, what: str = "") -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, f"timed out: {what}"
            time.sleep(0.05)

    def injector(self, name: str) -> Node:
        return Node(name, context=self.obs.context)

    def publisher(self, node: Node, msg_type, topic: str, readers: int):
        pub = node.create_publisher(msg_type, topic, STREAM_QOS)
        self.wait(lambda: pub.get_subscription_count() >= readers, 15, f"{node.get_name()} matched on {topic}")
        return pub

    def inject(self, pub, topic: str, msg) -> None:
        """Publish ``msg`` on ``topic``; a reading or a belief is counted as injected first (the
        observer tells them from the loop's own; actions it does not record: plan_info says what
        the planner decided)."""
        if topic in ("observation", "belief"):
            content = tuple(int(x) for x in msg.data) if topic == "observation" else \
                (decode_belief(msg, MODEL.S).epoch, tuple(float(x) for x in msg.data))
            with self.obs.lock:
                self.obs.injected[(topic, content)] += 1
        pub.publish(msg)

    def settle(self, start: int) -> int:
        """Wait until the simulator has stepped WATCH epochs past ``start`` and the filter has
        published the belief of that epoch (its reading comes first: the belief follows once the
        filter has applied it); returns that epoch."""
        end = start + WATCH
        self.wait(lambda: self.obs.newest() >= end and end in self.obs.real_beliefs(), 60,
                  f"the loop did not go on from epoch {start} to the belief of epoch {end}")
        return end

    # ----------------------------------------------------------- the invariants
    def stray_epochs(self, start: int, end: int) -> list[int]:
        """Epochs in ``start+1..end`` whose reading carries a priority none of the planner's decisions
        for the epochs just before it (LAG) chose: applied from a stray message."""
        obs = self.obs.real_obs()
        with self.obs.lock:
            decisions = dict(self.obs.decisions)
        out = []
        for t in range(start + 1, end + 1):
            recent = {decisions[e] for e in range(t - LAG, t + 1) if e in decisions}
            if t in obs and recent and obs[t][0] not in recent:
                out.append(t)
        return out

    def check_follows(self, start: int, end: int) -> None:
        strays = self.stray_epochs(start, end)
        assert len(strays) <= 1 and all(t <= start + RECOVERY for t in strays), (
            f"epochs {start + 1}..{end}: stray priorities applied at epochs {strays}")

    def check_beliefs(self, start: int, end: int) -> None:
        """Every belief of ``start..end`` is the filter's rule applied to the simulator's readings,
        every epoch has one, and the planner decided only for epochs after a real belief."""
        obs, beliefs = self.obs.real_obs(), self.obs.real_beliefs()
        epochs = list(range(start, end + 1))
        missing = [t for t in epochs if t not in beliefs or t not in obs]
        assert not missing, f"no belief or reading of epochs {missing[:10]}"
        flt = EpochFilter(MODEL, [MODEL.O])
        b = np.array(beliefs[start])
        for t in epochs[1:]:
            p, z = obs[t]
            b = flt.step(b, p - 1, {0: z}).belief
            np.testing.assert_allclose(beliefs[t], b, rtol=1e-9, atol=1e-12, err_msg=f"belief of epoch {t}")
        with self.obs.lock:
            decided = [e for e in self.obs.decisions if start < e <= end + 1]
        assert all(e - 1 in beliefs for e in decided), "the planner answered a belief the filter never published"

    def names(self, node: str, text: str, since: float, timeout: float = 15) -> None:
        """The node's diagnostics mention ``text`` (a writer's name, a cause) after ``since``."""
        self.wait(lambda: any(text in m for _, m, _ in self.obs.diag(node, since)), timeout,
                  f"{node}'s diagnostics never mentioned {text!r}: "
                  + repr([m for _, m, _ in self.obs.diag(node, since)][-3:]))

    def value(self, node: str, key: str, since: float = 0.0) -> str | None:
        values = [v for _, _, v in self.obs.diag(node, since) if key in v]
        return values[-1][key] if values else None


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    domain = random.Random(os.getpid() + time.time_ns()).randint(1, 101)
    # the opt-in Fast DDS profile (docs/ros.md, "Memory of an oversized sample"), for the
    # nodes and the test's own participant alike
    env = {**ros_env(domain), "FASTRTPS_DEFAULT_PROFILES_FILE": str(REPO / "config" / "fastdds_profile.xml"),
           "RMW_FASTRTPS_USE_QOS_FROM_XML": "1"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env, ROS_PYTHON_CHECK_FIELDS="1")
    log_dir = tmp_path_factory.mktemp("stray")
    shm_before = shm_entries()
    ctx = Context()
    rclpy.init(context=ctx)
    observer = Observer(ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(observer)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    procs = start_nodes("s3", domain, log_dir, preexec_fn=die_with_test)
    lp = Loop(procs, observer, executor, log_dir)
    try:
        lp.wait(lambda: observer.newest() > 30 and len(observer.decisions) > 20
                and all(observer.diag(n, 0) for n in NODES), 90, "the loop did not come up")
        yield lp
    finally:
        codes = stop_nodes(procs, timeout=15.0)
        executor.shutdown(timeout_sec=1.0)
        observer.destroy_node()
        ctx.try_shutdown()
        spin.join(timeout=2.0)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        remove_dead_shm(shm_before)  # only what no live process uses (other runs share /dev/shm)
    for name, code in codes.items():
        text = procs[name][1].read_text(errors="replace")
        assert code == 0 and "Traceback" not in text, f"{name}: exit code {code}\n{text[-2000:]}"


def _scenario(loop: Loop, name: str) -> Node:
    """An injecting node of the test's process, spun by an executor of its own (so that it can go
    again without touching the observer's)."""
    node = loop.injector(name)
    executor = SingleThreadedExecutor(context=loop.obs.context)
    executor.add_node(node)
    node.spin_thread = threading.Thread(target=executor.spin, daemon=True)
    node.spin_executor = executor
    node.spin_thread.start()
    return node


def _done(node: Node) -> None:
    """The injecting node leaves (and with it its writers leave the graph)."""
    node.spin_executor.shutdown(timeout_sec=2.0)
    node.spin_thread.join(timeout=2.0)
    node.destroy_node()


#: The 80 MB samples each node surely takes: the simulator's action (its belief reader keeps one
#: sample: the filter's next belief may replace the large one before it is taken), the filter's
#: observation and action, the planner's belief (its second, planning reader drops it uncounted).
OVERSIZED = {"target_simulator": 1, "belief_filter": 2, "planner": 1}


def test_an_oversized_sample_on_every_input_is_dropped_unread_and_leaves_no_memory(loop):
    """A 10^7-element belief, observation and action (80 MB each) at every node: dropped before
    they are decoded, the diagnostics say so, and with the opt-in Fast DDS profile every process
    is back to its size afterwards. "Afterwards" is once each node has reported every one of its
    80 MB samples dropped: an 80 MB sample takes a while to cross the middleware on a loaded
    machine, and the memory it occupies until it is taken is no leak."""
    def rss():
        samples = []
        for _ in range(5):
            samples.append({n: rss_mib(p.pid) for n, (p, _) in loop.procs.items()})
            time.sleep(0.2)
        return {n: float(np.median([s[n] for s in samples])) for n in NODES}

    before = rss()
    node = _scenario(loop, "forger_big")
    pubs = {t: loop.publisher(node, ty, t, k) for t, ty, k in (("belief", Float64MultiArray, 4),
                                                                ("observation", Int64MultiArray, 2),
                                                                ("action", Int64MultiArray, 2))}
    start, since = loop.obs.newest(), time.monotonic()
    base = {n: int(loop.value(n, "oversized_samples") or 0) for n in OVERSIZED}
    big_f, big_i = Float64MultiArray(), Int64MultiArray()
    big_f.data = array.array("d", bytes(8 * 10**7))
    big_i.data = array.array("q", bytes(8 * 10**7))
    for topic, pub in pubs.items():
        pub.publish(big_f if topic == "belief" else big_i)
    del big_f, big_i
    end = loop.settle(start)
    for n, count in OVERSIZED.items():  # every sample taken (and so freed): only then is the size compared
        loop.wait(lambda n=n, count=count: int(loop.value(n, "oversized_samples", since) or 0) >= base[n] + count,
                  60, f"{n} did not report its {count} oversized samples dropped: {loop.obs.diag(n, since)[-1:]}")
    # the planner's second (planning) reader drops its copy uncounted: it may still be crossing the
    # middleware, so the sizes are watched until they are back (or 60 s have passed)
    after: dict[str, float] = {}

    def back() -> bool:
        after.update(rss())
        return all(after[n] - before[n] < 10.0 for n in NODES)

    deadline = time.monotonic() + 60
    while not back() and time.monotonic() < deadline:
        pass
    _done(node)
    grown = {n: after[n] - before[n] for n in NODES}
    assert all(g < 10.0 for g in grown.values()), f"RSS grew (MiB): {grown}; before {before}"
    loop.check_follows(start, end)
    loop.check_beliefs(start, end)
    for n in NODES:  # said in each node's log (the diagnostics' message keeps only the newest warning)
        text = loop.procs[n][1].read_text(errors="replace")
        assert "a sample of 80000020 bytes" in text and "dropped unread" in text, text[-2000:]


def test_forged_actions_inside_the_window_are_not_applied(loop):
    """``[epoch + 900, p]``, ``[epoch + 1, p]`` and ``[epoch + 5, p]`` with a priority the planner
    has not chosen lately: the simulator keeps applying the planner's actions."""
    node = _scenario(loop, "forger_action")
    pub = loop.publisher(node, Int64MultiArray, "action", 2)
    q, start, since = loop.obs.unlikely_priority(), loop.obs.newest(), time.monotonic()
    for d in (900, 1, 5):
        loop.inject(pub, "action", encode_action(start + d, q))
    end = loop.settle(start)
    _done(node)
    loop.check_follows(start, end)
    loop.check_beliefs(start, end)
    loop.names("target_simulator", "/forger_action", since)


def test_forged_beliefs_inside_the_window_are_not_planned(loop):
    """A belief labelled ``epoch = b + 999`` and one labelled ``b + 1``: the planner answers the
    filter's beliefs only, and the simulator follows it."""
    node = _scenario(loop, "forger_belief")
    pub = loop.publisher(node, Float64MultiArray, "belief", 4)
    b = max(loop.obs.real_beliefs())
    start, since = loop.obs.newest(), time.monotonic()
    for d in (999, 1):
        loop.inject(pub, "belief", encode_belief(b + d, [0.98, 0.01, 0.01]))
    end = loop.settle(start)
    _done(node)
    with loop.obs.lock:
        assert max(loop.obs.decisions) < b + 999, "the planner answered the forged belief"
    loop.check_follows(start, end)
    loop.check_beliefs(start, end)
    loop.names("planner", "/forger_belief", since)


def test_forged_observations_inside_the_window_declare_nothing_lost(loop):
    """``[o + 50, 1, 0]`` and a contradicting ``[o + 1, p, z]``: no epoch is declared lost, every
    belief is the filter's rule applied to the simulator's own readings."""
    node = _scenario(loop, "forger_observation")
    pub = loop.publisher(node, Int64MultiArray, "observation", 2)
    start, since = loop.obs.newest(), time.monotonic()
    gaps = loop.value("belief_filter", "gaps")
    loop.inject(pub, "observation", encode_observation(start + 50, 1, 0))
    loop.inject(pub, "observation", encode_observation(start + 1, loop.obs.unlikely_priority(), 2))
    end = loop.settle(start)
    _done(node)
    assert loop.value("belief_filter", "gaps") == gaps, "the filter declared epochs lost"
    loop.check_follows(start, end)
    loop.check_beliefs(start + 1, end)
    loop.names("belief_filter", "/forger_observation", since)


def test_a_replay_of_an_earlier_run_steers_nothing(loop):
    """What ``ros2 bag play`` of an earlier, longer run publishes: the loop's own recorded actions,
    readings and beliefs of 30 epochs, renumbered 800 epochs ahead, at 10 Hz from a node named
    ``rosbag2_player``."""
    obs, beliefs = loop.obs.real_obs(), loop.obs.real_beliefs()
    with loop.obs.lock:
        decisions = dict(loop.obs.decisions)
    first = min(e for e in obs if e > 5)
    epochs = [e for e in range(first, first + 30) if e in obs and e in beliefs and e in decisions]
    node = _scenario(loop, "rosbag2_player")
    pubs = {"action": loop.publisher(node, Int64MultiArray, "action", 2),
            "observation": loop.publisher(node, Int64MultiArray, "observation", 2),
            "belief": loop.publisher(node, Float64MultiArray, "belief", 4)}
    start, since = loop.obs.newest(), time.monotonic()
    for e in epochs:
        loop.inject(pubs["action"], "action", encode_action(e + 800, decisions[e]))
        loop.inject(pubs["observation"], "observation", encode_observation(e + 800, *obs[e]))
        loop.inject(pubs["belief"], "belief", encode_belief(e + 800, list(beliefs[e])))
        time.sleep(0.1)
    end = loop.settle(start)
    _done(node)
    loop.check_follows(start, end)
    loop.check_beliefs(start, end)
    for n in NODES:
        loop.names(n, "/rosbag2_player", since)


def test_a_second_writer_is_named_and_not_followed(loop):
    """A second "planner" answering every belief at once with another priority, and a flood of
    plausible readings (the next epoch, the planner's last priority, a random observation) at
    about 500 Hz: the simulator follows the real planner, the filter the real simulator."""
    node = _scenario(loop, "planner_b")
    act = loop.publisher(node, Int64MultiArray, "action", 2)
    flood = _scenario(loop, "flood")
    obs_pub = loop.publisher(flood, Int64MultiArray, "observation", 2)
    q = loop.obs.unlikely_priority()
    node.create_subscription(Float64MultiArray, "belief", lambda msg: loop.inject(
        act, "action", encode_action(decode_belief(msg, MODEL.S).epoch + 1, q)), STREAM_QOS)
    rng = random.Random(7)

    def reading():
        with loop.obs.lock:
            p = loop.obs.decisions[max(loop.obs.decisions)]
            t = max(loop.obs.obs) + 1
        loop.inject(obs_pub, "observation", encode_observation(t, p, rng.randrange(MODEL.Z)))

    start, since = loop.obs.newest(), time.monotonic()
    timer = flood.create_timer(0.002, reading)
    end = loop.settle(start)
    timer.cancel()
    _done(node)
    _done(flood)
    loop.check_follows(start, end)
    loop.check_beliefs(start, end)
    loop.names("target_simulator", "/planner_b", since)
    loop.names("belief_filter", "/flood", since)


def test_use_sim_time_is_refused_at_run_time_and_the_loop_goes_on(loop):
    """``use_sim_time`` set to true through each node's parameter service (no ``/clock`` on the
    domain): refused with a reason, logged and counted in diagnostics; the 10 Hz loop goes on."""
    client_node = _scenario(loop, "param_setter")
    start, since = loop.obs.newest(), time.monotonic()
    for n in NODES:
        cli = client_node.create_client(SetParameters, f"/{n}/set_parameters")
        assert cli.wait_for_service(timeout_sec=15.0), n
        req = SetParameters.Request(parameters=[ParameterMsg(name="use_sim_time", value=ParameterValue(
            type=ParameterType.PARAMETER_BOOL, bool_value=True))])
        future = cli.call_async(req)
        loop.wait(future.done, 15, f"{n}: set_parameters")
        result = future.result().results[0]
        assert not result.successful and "use_sim_time" in result.reason, (n, result)
    end = loop.settle(start)
    _done(client_node)
    loop.check_follows(start, end)
    loop.check_beliefs(start, end)
    for n in NODES:
        loop.names(n, "use sim time refused", since)


def test_a_node_started_with_use_sim_time_and_no_clock_reports_error(loop, tmp_path):
    """A fourth node (a filter on topics of its own) started with ``use_sim_time:=true`` and no
    ``/clock`` anywhere: its diagnostics still come, ERROR, saying so."""
    since = time.monotonic()
    log = tmp_path / "clockless.log"
    remap = [a for t in ("observation", "belief", "action", "belief_entropy") for a in ("-r", f"{t}:=clockless_{t}")]
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*node_command("belief_filter"), "--ros-args", "-r", "__node:=clockless_filter",
                                 *remap, "-p", f"model_file:={REPO / 'config' / 'models' / 'tracking_s3_info.yaml'}",
                                 "-p", "use_sim_time:=true"], env=dict(os.environ), stdout=fh, stderr=subprocess.STDOUT)
    try:
        loop.wait(lambda: any(lv == 2 and "use_sim_time is true and /clock has never advanced" in m
                              for lv, m, _ in loop.obs.diag("clockless_filter", since)), 45,
                  "no ERROR from the node without /clock: " + repr(loop.obs.diag("clockless_filter", since)[-2:]))
    finally:
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=15)
    assert code == 0, log.read_text(errors="replace")[-2000:]
