"""Run records as rosbag2 MCAP bags (``core/io/run_bag.py``), ``plot`` on bags and windows, and
``pomdp-planner replay`` (``core/loop/replay.py``), with bags the tests write.

* A bag is checked with two readers: ``rosbags`` (which wrote it) and the ``mcap`` library with
  ``mcap_ros2`` (Foxglove's MCAP reader and ROS 2 decoder, independent of the writer): the profile,
  the schemas (ROS 2 ``.msg`` definitions), the channels' QoS, each message's content; the bytes
  of each loop message are rclpy's own serialization of the nodes' encoding of it.
* ``simulate --record x.mcap`` gives the same rows as ``--record x.csv`` with the same seed, and
  the readings of the simulation.
* A bag without ``run_record`` (as ``ros2 bag record`` writes one of a running loop: a directory)
  is paired into rows by the recorder's rule.
* ``replay``: the same model and policy reproduce every belief and decision; the beliefs are
  Bayes' rule written out here; another model or policy is reported where it differs, with the
  returns computed here from the rows.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.cli.plot import block_size, blocks, parse_epochs, select_epochs
from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.run_bag import RunBagError, RunBagWriter, read_run_bag, read_run_output
from pomdp_planner.core.io.run_record import read_run_record
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop.planner_loop import PlanInfo
from pomdp_planner.core.loop.replay import replay
from pomdp_planner.core.uncertainty import SHANNON

rosbags = pytest.importorskip("rosbags")
REPO = Path(__file__).resolve().parents[1]
INFO = PlanInfo(epoch=1, action_priority=2, depth=2, nodes_expanded=12, pruned_percent=25.0, certified=False,
                time_used=0.004, latency=0.005, deadline_hit=False, deadline_miss=False, bound_lower=1.0,
                bound_upper=3.0)


def small_bag(path: Path, namespace: str = "") -> None:
    w = RunBagWriter(path, "--record", "tracking_s3_info", 3, 3, 0.05, namespace=namespace, clock=lambda: 7 * 10**9)
    w.write(0, [0.2, 0.3, 0.5], 2, true_state=1, bounds=(1, 3), guaranteed=True, depth=2, latency=0.005, info=INFO,
            stamp_ns=10**9)
    w.write(1, [0.1, 0.3, 0.6], 1, true_state=2, observation=(2, 1), stamp_ns=2 * 10**9)
    w.close()


def test_a_bag_reads_back_with_rosbags_and_with_the_mcap_library(tmp_path):
    path = tmp_path / "run.mcap"
    small_bag(path, namespace="robot1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]  # one file, nothing left beside it
    bag = read_run_bag(path)
    rec = bag.record
    assert (rec.model, rec.S, rec.A, rec.time_budget) == ("tracking_s3_info", 3, 3, 0.05)
    assert rec.epoch.tolist() == [0, 1] and rec.action.tolist() == [2, 1] and rec.true_state.tolist() == [1, 2]
    assert rec.lower.tolist() == [1, 0] and rec.upper.tolist() == [3, 0] and rec.depth.tolist() == [2, -1]
    assert bag.observations == {1: (2, 1)} and bag.actions == {1: 2, 2: 1}
    assert bag.topics["belief"] == "/robot1/belief"
    csv = tmp_path / "run.csv"  # the same rows written as CSV read back the same
    from pomdp_planner.core.io.run_record import open_run_record
    w = open_run_record(csv, "--record", "tracking_s3_info", 3, 3, 0.05)
    w.write(0, [0.2, 0.3, 0.5], 2, true_state=1, bounds=(1, 3), guaranteed=True, depth=2, latency=0.005)
    w.write(1, [0.1, 0.3, 0.6], 1, true_state=2)
    w.close()
    same = read_run_record(csv)
    for name in ("epoch", "true_state", "beliefs", "action", "lower", "upper", "guaranteed", "depth", "certified"):
        np.testing.assert_array_equal(getattr(rec, name), getattr(same, name))

    mcap_reader = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert {t: s.name for t, s in schemas.items()} == {
            "/robot1/run_record": "std_msgs/msg/String", "/robot1/belief": "std_msgs/msg/Float64MultiArray",
            "/robot1/action": "std_msgs/msg/Int64MultiArray", "/robot1/true_state": "std_msgs/msg/Int64MultiArray",
            "/robot1/observation": "std_msgs/msg/Int64MultiArray",
            "/robot1/plan_info": "std_msgs/msg/Float64MultiArray"}
        assert all(s.encoding == "ros2msg" for s in schemas.values())
        for c in summary.channels.values():  # the loop's QoS, so that ros2 bag play feeds the nodes
            assert c.message_encoding == "cdr"
            assert "reliability: reliable" in c.metadata["offered_qos_profiles"]
            assert "durability: transient_local" in c.metadata["offered_qos_profiles"]
        got = [(ch.topic, m.log_time, msg) for _, ch, m, msg in reader.iter_decoded_messages()]
    by_topic: dict = {}
    for topic, stamp, msg in got:
        by_topic.setdefault(topic.rsplit("/", 1)[1], []).append((stamp, msg))
    assert [list(m.data) for _, m in by_topic["belief"]] == [[0.2, 0.3, 0.5], [0.1, 0.3, 0.6]]
    assert [(d.label, d.size) for d in by_topic["belief"][0][1].layout.dim] == [("state", 3), ("epoch=0", 1)]
    assert [(s, list(m.data)) for s, m in by_topic["action"]] == [(10**9 + 5 * 10**6, [1, 2]), (2 * 10**9, [2, 1])]
    assert [list(m.data) for _, m in by_topic["observation"]] == [[1, 2, 1]]
    assert by_topic["observation"][0][1].layout.dim[0].label == "epoch,action_priority,observation"
    assert [list(m.data) for _, m in by_topic["true_state"]] == [[0, 1], [1, 2]]
    assert list(by_topic["plan_info"][0][1].data) == [1, 2, 2, 12, 25.0, 0, 0.004, 0.005, 0, 0, 1, 3]
    text = "".join(m.data for _, m in by_topic["run_record"])
    assert text == csv.read_text()  # the record itself, line for line


def test_the_loop_messages_are_the_nodes_own_messages(tmp_path):
    """Each loop message of a bag is what the nodes publish: as long as rclpy's serialization of the
    nodes' encoding of it (CDR's alignment padding is not data: rclpy leaves it unset), and rclpy
    reads it back as that very message."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64MultiArray, Int64MultiArray

    from pomdp_planner.nodes.messages import (
        encode_action,
        encode_belief,
        encode_observation,
        encode_plan_info,
        encode_true_state,
    )

    path = tmp_path / "run.mcap"
    small_bag(path)
    from rosbags.rosbag2 import Reader
    with Reader(path) as reader:
        raw = {}
        for conn, _, data in reader.messages():
            raw.setdefault(conn.topic, []).append(bytes(data))
    for ours, msg in ((raw["/belief"][0], encode_belief(0, np.array([0.2, 0.3, 0.5]))),
                      (raw["/action"][0], encode_action(1, 2)), (raw["/observation"][0], encode_observation(1, 2, 1)),
                      (raw["/true_state"][1], encode_true_state(1, 2)),
                      (raw["/plan_info"][0], encode_plan_info(**INFO.as_dict()))):
        assert len(ours) == len(serialize_message(msg))
        assert deserialize_message(ours, type(msg)) == msg
    assert type(encode_belief(0, np.ones(1))) is Float64MultiArray and type(encode_action(1, 1)) is Int64MultiArray


def test_a_cut_bag_and_a_foreign_file_are_one_line(tmp_path):
    path = tmp_path / "run.mcap"
    small_bag(path)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:-100])  # a writer killed before its index
    with pytest.raises(RunBagError, match=r"cut.mcap: not a readable rosbag2 bag .*once its writer has closed it"):
        read_run_bag(cut)
    text = tmp_path / "run.txt.mcap"
    text.write_text("epoch,b0\n")
    with pytest.raises(RunBagError, match="not a readable rosbag2 bag"):
        read_run_bag(text)
    with pytest.raises(RunBagError, match="no such file"):
        read_run_bag(tmp_path / "none.mcap")


def test_a_bag_of_a_running_loop_without_its_record_is_paired_by_epoch(tmp_path):
    """Topics as ``ros2 bag record`` keeps them (a directory, receive times, history first): rows by
    the recorder's rule, the row's plan_info where it came."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from pomdp_planner.core.io.run_bag import Messages

    ts = get_typestore(Stores.ROS2_JAZZY)
    m = Messages(ts)
    bag_dir = tmp_path / "rosbag2_run"
    beliefs = {0: [1 / 3, 1 / 3, 1 / 3], 1: [0.6, 0.2, 0.2], 2: [0.1, 0.8, 0.1]}
    with Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = {n: w.add_connection(f"/site/{n}", t, typestore=ts) for n, t in
             (("belief", "std_msgs/msg/Float64MultiArray"), ("action", "std_msgs/msg/Int64MultiArray"),
              ("observation", "std_msgs/msg/Int64MultiArray"), ("plan_info", "std_msgs/msg/Float64MultiArray"))}
        t = 0
        for e, b in beliefs.items():
            if e:
                w.write(c["observation"], t, m.serialize(m.record("epoch,action_priority,observation", (e, 2, e))))
            w.write(c["belief"], t + 1, m.serialize(m.belief(e, b)))
            info = PlanInfo(e + 1, 1 + e % 3, 1, 3, 0.0, False, 0.001, 0.002, False, False)
            w.write(c["action"], t + 2, m.serialize(m.record("epoch,action_priority", (e + 1, 1 + e % 3))))
            w.write(c["plan_info"], t + 3, m.serialize(m.plan_info(info)))
            t += 10**8
    bag = read_run_bag(bag_dir, num_actions=3)
    rec = bag.record
    assert rec.model == "unknown" and rec.epoch.tolist() == [0, 1, 2] and rec.action.tolist() == [1, 2, 3]
    np.testing.assert_allclose(rec.beliefs, np.array(list(beliefs.values())))
    assert rec.depth.tolist() == [1, 1, 1] and rec.latency.tolist() == [0.002] * 3
    assert bag.observations == {1: (2, 1), 2: (2, 2)}
    assert read_run_output(bag_dir).epoch.tolist() == [0, 1, 2]  # plot's reader: a directory is a bag


def test_simulate_records_the_same_rows_in_a_bag_with_the_readings(tmp_path, capsys):
    csv, bag_path = tmp_path / "run.csv", tmp_path / "run.mcap"
    args = ["simulate", "perimeter_s3", "--steps", "25", "--seed", "3", "--policy", "bnb", "--option", "max_depth=2",
            "--option", "time_budget=5"]
    assert main([*args, "--record", str(csv)]) == 0
    assert main([*args, "--record", str(bag_path)]) == 0
    a, bag = read_run_record(csv), read_run_bag(bag_path)
    b = bag.record
    for name in ("epoch", "true_state", "beliefs", "action", "lower", "upper", "guaranteed", "depth", "certified"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    from pomdp_planner.core.simulate import simulate
    model = load_model_file("perimeter_s3")
    from pomdp_planner.core.policies import make_policy
    run = simulate(model, make_policy("bnb", model, seed=4, max_depth=2, time_budget=5), 25, seed=3)
    assert bag.observations == {t + 1: (int(run.actions[t]) + 1, int(run.observations[t])) for t in range(24)}


def bayes(model, b, a, z):
    """Bayes' rule written out (paper Eqs. 1-2)."""
    pred = np.array([sum(b[i] * model.P[a][i, j] for i in range(model.S)) for j in range(model.S)])
    post = np.array([pred[j] * model.O[a][j, z] for j in range(model.S)])
    return post / post.sum()


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("bags") / "sim.mcap"
    assert main(["simulate", "perimeter_s3", "--steps", "30", "--seed", "5", "--policy", "bnb", "--option",
                 "max_depth=2", "--option", "time_budget=5", "--record", str(path)]) == 0
    return path


def test_replay_with_the_run_s_model_and_planner_reproduces_it(sim_bag):
    model = load_model_file("perimeter_s3")
    bag = read_run_bag(sim_bag)
    from pomdp_planner.core.policies import as_callable, make_policy
    report = replay(model, bag.record, bag.observations, as_callable(make_policy("bnb", model, max_depth=2,
                                                                                 time_budget=5)))
    assert len(report.steps) == 30 and report.readings == 29 and not report.gaps
    assert report.belief_differences == [] and report.decision_differences == []
    b = bag.record.beliefs[0]
    for s in report.steps[1:]:  # every replayed belief is Bayes' rule on the reading
        p, z = bag.observations[s.epoch]
        b = bayes(model, b, p - 1, z)
        np.testing.assert_allclose(s.replayed, b, atol=1e-12)
    sums = report.sums(model)
    rec = bag.record
    disc = model.gamma ** np.arange(30)
    rho = np.array([model.rho(rec.beliefs[k])[rec.action[k] - 1] for k in range(30)])
    assert sums["recorded"]["discounted_return"] == pytest.approx(float(disc @ rho))
    assert sums["recorded"] == sums["replayed"]
    assert sums["recorded"]["mean_entropy"] == pytest.approx(np.mean([SHANNON.value(x) for x in rec.beliefs]))
    state = sum(disc[k] * model.r[rec.true_state[k], rec.action[k] - 1] for k in range(30))
    assert sums["recorded"]["discounted_state_return"] == pytest.approx(state)


def test_replay_reports_where_another_planner_or_model_differs(sim_bag, capsys, tmp_path):
    assert main(["replay", str(sim_bag), "--policy", "myopic", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    model = load_model_file("perimeter_s3")
    rec = read_run_bag(sim_bag).record
    greedy = [int(np.argmax(model.rho(b))) + 1 for b in rec.beliefs]
    assert out["decision_differences"] == [int(e) for e, g, a in zip(rec.epoch, greedy, rec.action, strict=True)
                                           if g != a]
    assert out["belief_differences"] == [] and out["epochs"] == 30 and out["readings"] == 29
    assert [s["replayed_priority"] for s in out["steps"]] == greedy
    # another model with as many states: its filter gives other beliefs from the second epoch on
    assert main(["replay", str(sim_bag), "--model", "tracking_s3_info", "--option", "max_depth=1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"replay of {sim_bag}: model tracking_s3_info (the run's: perimeter_s3), 30 epochs "
                               "(0..29), 29 readings; policy bnb (max_depth 1, time_budget")
    assert lines[1].startswith("beliefs: 1 of 30 epochs equal to the recorded ones within 1e-09 (L1)")
    assert "first differing epoch 1" in lines[1]
    assert lines[2].startswith("decisions: ") and lines[3].startswith("entropy (Shannon, nats), mean: recorded ")


def test_replay_refuses_what_it_cannot_replay_in_one_line(sim_bag, tmp_path, capsys):
    assert main(["replay", str(sim_bag), "--model", "perimeter_s8"]) == 2
    assert "--model: perimeter_s8 has 8 states, the bag's beliefs 3" in capsys.readouterr().err
    no_readings = tmp_path / "demo.mcap"
    w = RunBagWriter(no_readings, "--record", "perimeter_s3", 3, 3, None)
    w.write(0, [0.2, 0.3, 0.5], 1)
    w.close()
    assert main(["replay", str(no_readings)]) == 2
    assert "no observation topic with the run's readings" in capsys.readouterr().err
    assert main(["replay", str(tmp_path / "none.mcap")]) == 2
    assert "none.mcap: no such file or directory" in capsys.readouterr().err


# ------------------------------------------------------------------ plot on bags and windows
def test_epoch_windows_and_blocks():
    assert parse_epochs("10:20") == (10, 20) and parse_epochs(":5") == (None, 5) and parse_epochs("7:") == (7, None)
    for bad in ("5", "a:b", "9:3", "4:4", "-1:3"):
        with pytest.raises(OptionError, match="--epochs: expected A:B"):
            parse_epochs(bad)
    assert block_size(200) == 1 and block_size(201) == 2 and block_size(900) == 5
    np.testing.assert_allclose(blocks([1, 2, 3, 4, 5], 2), [1.5, 3.5, 5.0])
    np.testing.assert_allclose(blocks([1, np.nan, 3, np.nan], 2, np.max), [1.0, 3.0])
    assert np.isnan(blocks([np.nan, np.nan], 2)).all()
    np.testing.assert_allclose(blocks(np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]]), 2), [[0.5, 0.5], [0.5, 0.5]])


def test_plot_draws_a_bag_and_a_window_of_it(sim_bag, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    png = tmp_path / "run.png"
    assert main(["plot", str(sim_bag), "-o", str(png), "--epochs", "10:20", "--dpi", "40"]) == 0
    assert "wrote" in capsys.readouterr().out and png.stat().st_size > 0
    rec = select_epochs(read_run_bag(sim_bag).record, "10:20")
    assert rec.epoch.tolist() == list(range(10, 20)) and rec.beliefs.shape == (10, 3)
    assert main(["plot", str(sim_bag), "-o", str(png), "--epochs", "100:200"]) == 2
    assert "--epochs: no row of the record in 100:200 (its epochs: 0..29)" in capsys.readouterr().err


def test_a_long_run_is_drawn_in_blocks(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    long = tmp_path / "long.mcap"
    assert main(["simulate", "perimeter_s3", "--steps", "450", "--policy", "myopic", "--record", str(long)]) == 0
    png = tmp_path / "long.png"
    assert main(["plot", str(long), "-o", str(png), "--dpi", "40"]) == 0
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pomdp_planner.cli.plot import draw
    fig = draw(plt, read_run_output(long), (10, 7), None)
    try:
        assert fig.axes[0].get_title() == "perimeter_s3: 450 decisions (S=3, A=3; epochs 0..449, 3 epochs per column)"
        assert fig.axes[0].collections[0].get_array().size == 150 * 3  # 150 columns of 3 states
    finally:
        plt.close(fig)


def test_read_run_output_reads_a_csv_too(tmp_path):
    csv = tmp_path / "r.csv"
    assert main(["simulate", "perimeter_s3", "--steps", "3", "--record", str(csv)]) == 0
    assert read_run_output(csv).epoch.tolist() == [0, 1, 2]


def test_a_bag_with_two_runs_needs_the_namespace(tmp_path):
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    small_bag(a, namespace="robot1")
    small_bag(b, namespace="robot2")
    merged = tmp_path / "both"
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(merged, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for src in (a, b):
            with Reader(src) as r:
                conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in r.connections}
                for c, t, data in r.messages():
                    w.write(conns[c.id], t, data)
    with pytest.raises(RunBagError, match=r"2 run_record topics \(/robot1/run_record, /robot2/run_record\): "
                                          r"give the namespace"):
        read_run_bag(merged)
    assert read_run_bag(merged, namespace="robot2").topics["belief"] == "/robot2/belief"
    shutil.rmtree(merged)


def test_the_command_line_help_names_replay():
    out = subprocess.run([sys.executable, "-m", "pomdp_planner", "--help"], capture_output=True, text=True,
                         cwd=REPO).stdout
    assert "replay" in out
