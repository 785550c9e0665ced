"""A 500 Hz flood on every input of a running free loop, 30 s in all: the three executables as
processes (the S = 3 parameter files, free running: ``step_period 0``), observed from the test's
process, flooded from a process of its own on localhost, in a domain of its own.

The flood process publishes plausible samples (the next epoch the planner's ``plan_info`` names,
random priorities and observations, random beliefs) at 500 Hz on each of ``action``,
``observation`` and ``belief``, as a node named ``flood``, in three windows of 10 s. Before each
window and after the last it publishes the same samples at the same rate for 5 s on topics
nobody reads: the baseline. On a machine of two cores, shared with other work, the flood
process's own work slows every process down and the load drifts; what is measured is what the
flood does through the nodes' inputs, against baselines interleaved with it. Asserted: every
input of every node follows the writer it followed before the flood (``input.<name>.writer``
unchanged, ``writer_changes`` 0), the flood reached it (``foreign_samples``), and the loop ran
at at least half its baseline rate (decisions per second, counted from ``plan_info``; the first
second of each window left out). Run time about 70 s.
"""

from __future__ import annotations

import itertools
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnostic_msgs.msg import DiagnosticArray
from nodes_support import die_with_test, rclpy, remove_dead_shm, shm_entries
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from pomdp_planner.nodes.processes import ros_env, start_nodes, stop_nodes
from pomdp_planner.nodes.qos import RECORDER_QOS

RATE, BASELINE, FLOOD, WINDOWS = 500.0, 5.0, 10.0, 3
#: Each node's inputs (diagnostics status name -> input names).
INPUTS = {"target_simulator: simulation": ("action",), "belief_filter: belief": ("observation", "action"),
          "planner: planning": ("belief",)}

FLOODER = '''
import random, sys, threading, time
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, Int64MultiArray
from pomdp_planner.nodes.messages import encode_action, encode_belief, encode_observation
from pomdp_planner.nodes.qos import RECORDER_QOS, STREAM_QOS

rate, baseline, flood, windows = (float(x) for x in sys.argv[1:5])
rclpy.init()
node = Node("flood")
epoch = [0]
node.create_subscription(Float64MultiArray, "plan_info", lambda m: epoch.__setitem__(0, int(m.data[0])), RECORDER_QOS)
kinds = {"action": Int64MultiArray, "observation": Int64MultiArray, "belief": Float64MultiArray}
pubs = {(t, decoy): node.create_publisher(kind, t + ("_unread" if decoy else ""), STREAM_QOS)
        for t, kind in kinds.items() for decoy in (True, False)}
executor = SingleThreadedExecutor()
executor.add_node(node)
def run():
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
spin = threading.Thread(target=run, daemon=True)
spin.start()
rng = random.Random(3)
sent = 0
for decoy, seconds in [(True, baseline), (False, flood)] * int(windows) + [(True, baseline)]:
    print(f"{'decoy' if decoy else 'flood'} {time.monotonic()!r}", flush=True)
    t0, n = time.monotonic(), 0
    while time.monotonic() - t0 < seconds:
        e = epoch[0]
        b = [rng.random() + 1e-3 for _ in range(3)]
        pubs[("action", decoy)].publish(encode_action(e + 1, rng.randint(1, 3)))
        pubs[("observation", decoy)].publish(encode_observation(e + 1, rng.randint(1, 3), rng.randrange(3)))
        pubs[("belief", decoy)].publish(encode_belief(e, [x / sum(b) for x in b]))
        n += 1
        time.sleep(max(0.0, t0 + n / rate - time.monotonic()))
    sent += 0 if decoy else n
print(f"end {time.monotonic()!r} sent {sent}", flush=True)
rclpy.try_shutdown()  # wakes the spin, which then ends
spin.join(timeout=5.0)
node.destroy_node()
'''


class Observer(Node):
    def __init__(self, context: Context):
        super().__init__("flood_observer", context=context)
        self.lock = threading.Lock()
        self.decisions: list[float] = []
        self.status: dict[str, dict[str, str]] = {}
        self.create_subscription(Float64MultiArray, "plan_info", self._info, RECORDER_QOS)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 100)

    def _info(self, msg) -> None:
        with self.lock:
            self.decisions.append(time.monotonic())

    def _diag(self, msg) -> None:
        with self.lock:
            for st in msg.status:
                self.status[st.name] = {kv.key: kv.value for kv in st.values}

    def rate(self, a: float, b: float) -> float:
        with self.lock:
            return sum(a <= t < b for t in self.decisions) / (b - a)

    def writers(self) -> dict[str, tuple[str, str, str]]:
        """Per node and input: (followed writer, writer_changes, foreign_samples)."""
        with self.lock:
            return {f"{n}/{i}": (self.status[n][f"input.{i}.writer"], self.status[n][f"input.{i}.writer_changes"],
                                 self.status[n][f"input.{i}.foreign_samples"])
                    for n, inputs in INPUTS.items() if n in self.status for i in inputs}


def _wait(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out: {what}"
        time.sleep(0.05)


def test_a_500_hz_flood_on_every_input_takes_over_nothing_and_the_loop_keeps_half_its_rate(tmp_path):
    domain = random.Random(os.getpid() + time.time_ns()).randint(1, 101)
    env = ros_env(domain)
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env, ROS_PYTHON_CHECK_FIELDS="1")
    shm_before = shm_entries()
    ctx = Context()
    rclpy.init(context=ctx)
    observer = Observer(ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(observer)
    threading.Thread(target=executor.spin, daemon=True).start()
    procs = start_nodes("s3", domain, tmp_path, {"target_simulator": ["-p", "step_period:=0.0"]},
                        preexec_fn=die_with_test)
    flooder = None
    try:
        _wait(lambda: len(observer.decisions) > 50 and len(observer.writers()) == 4, 90, "the loop did not come up")
        script = tmp_path / "flooder.py"
        script.write_text(FLOODER)
        flooder = subprocess.Popen([sys.executable, str(script), str(RATE), str(BASELINE), str(FLOOD), str(WINDOWS)],
                                   env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   preexec_fn=die_with_test)
        lines: list[str] = []

        def read() -> None:
            for ln in flooder.stdout:
                lines.append(ln.strip())

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        _wait(lambda: any(ln.startswith("flood") for ln in lines), 60 + BASELINE, "the flood did not start")
        before = observer.writers()
        assert flooder.wait(timeout=WINDOWS * (FLOOD + BASELINE) + BASELINE + 60) == 0, "\n".join(lines)
        reader.join(timeout=5)
        time.sleep(2.5)  # the diagnostics of the flood's end
        after = observer.writers()
        marks = [(ln.split()[0], float(ln.split()[1])) for ln in lines if ln.split()[0] in ("decoy", "flood", "end")]
        spans = {"decoy": [0.0, 0], "flood": [0.0, 0]}  # seconds, decisions
        for (kind, t0), (_, t1) in itertools.pairwise(marks):
            spans[kind][0] += t1 - (t0 + 1.0)
            spans[kind][1] += round(observer.rate(t0 + 1.0, t1) * (t1 - (t0 + 1.0)))
        baseline, flooded = (spans[k][1] / spans[k][0] for k in ("decoy", "flood"))
        sent = int(lines[-1].split()[-1])
    finally:
        if flooder is not None and flooder.poll() is None:
            flooder.kill()
        codes = stop_nodes(procs, timeout=15.0)
        executor.shutdown(timeout_sec=1.0)
        observer.destroy_node()
        ctx.try_shutdown()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        remove_dead_shm(shm_before)
    foreign = ", ".join(f"{k} {v[2]}" for k, v in after.items())
    print(f"decisions/s: {baseline:.1f} beside the unread flood, {flooded:.1f} under the flood ({sent} samples "
          f"per input); foreign samples {foreign}")
    for key, (writer, changes, foreign) in after.items():
        assert writer == before[key][0] and changes == "0", (key, before[key], after[key])
        assert not writer.startswith("/flood"), key
        assert int(foreign) >= sent // 2, (key, foreign, sent)  # the flood reached it
    assert flooded >= 0.5 * baseline, f"{flooded:.1f} decisions/s under the flood, {baseline:.1f} beside it"
    for name, code in codes.items():
        text = procs[name][1].read_text(errors="replace")
        assert code == 0 and "Traceback" not in text, f"{name}: exit code {code}\n{text[-2000:]}"

