"""Run records as rosbag2 MCAP files: what ``simulate --record``, the demo's ``--record`` and the
``run_recorder`` node write when the output's name ends in ``.mcap``, and what ``plot`` and
``replay`` read (docs/cli.md, "Bags").

A bag written here is one MCAP file with the ``ros2`` profile and ROS 2 message definitions
(``ros2msg``, Jazzy's, from the ``rosbags`` type store), as ``ros2 bag record -s mcap`` writes
them: ``ros2 bag info`` / ``ros2 bag play`` and Foxglove read it. Its topics, under the
``namespace`` the run had (``""``: the root):

============== ============================ ===================================================
topic          type                         messages
============== ============================ ===================================================
run_record     ``std_msgs/msg/String``      the run record itself (:mod:`.run_record`): first its
                                            first line and header, then one message per row
belief         ``std_msgs/msg/Float64MultiArray``  row ``t``'s belief, layout ``[("state", S), ("epoch=t", 1)]``
action         ``std_msgs/msg/Int64MultiArray``    ``[t + 1, priority]``, label ``epoch,action_priority``
true_state     ``std_msgs/msg/Int64MultiArray``    ``[t, state]`` where known
observation    ``std_msgs/msg/Int64MultiArray``    ``[t, priority, z]``: the reading that made belief ``t`` (a
                                            simulation: with its row; a node: as it came)
plan_info      ``std_msgs/msg/Float64MultiArray``  the planner's record of the decision, where the writer has it
============== ============================ ===================================================

The loop's topics carry the nodes' layouts (docs/ros.md, "Topics"), each offered with the loop's
QoS (reliable, transient local, depth 100), so ``ros2 bag play`` feeds nodes that subscribe as the
loop's do. Each row's messages are stamped with the row's time (its ``stamp_ns``: the writer's
clock, or a run's epoch times), the action and ``plan_info`` after the row's latency.

:func:`read_run_bag` reads such a file, and also a bag of a running loop recorded with
``ros2 bag record`` (a directory or an ``.mcap``/``.db3`` file): without ``run_record`` the rows
are paired from the loop's topics by the run recorder's rule (:class:`~..loop.recorder_loop.RecorderLoop`).
Errors are one :class:`RunBagError` line naming the file.
"""

from __future__ import annotations

import io
import math
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import short_repr
from ..loop.health import Log
from ..loop.planner_loop import PlanInfo
from ..loop.recorder_loop import RecorderLoop
from ..loop.samples import ActionSample, BeliefSample
from .run_record import RunRecord, RunRecordError, RunRecordWriter, read_run_record

#: A run record's output is a bag when its name ends with this (case-insensitive).
BAG_SUFFIX = ".mcap"
#: The bag's topics (relative to its namespace) and their ROS 2 types.
TOPIC_TYPES = {"run_record": "std_msgs/msg/String", "belief": "std_msgs/msg/Float64MultiArray",
               "action": "std_msgs/msg/Int64MultiArray", "true_state": "std_msgs/msg/Int64MultiArray",
               "observation": "std_msgs/msg/Int64MultiArray", "plan_info": "std_msgs/msg/Float64MultiArray"}
#: The nodes' layouts (nodes/messages.py; a test checks the bytes against rclpy's).
ACTION_LABEL = "epoch,action_priority"
OBSERVATION_LABEL = "epoch,action_priority,observation"
TRUE_STATE_LABEL = "epoch,state"
PLAN_INFO_FIELDS = ("epoch", "action_priority", "depth", "nodes_expanded", "pruned_percent", "certified",
                    "time_used", "latency", "deadline_hit", "deadline_miss", "bound_lower", "bound_upper")
#: The loop's QoS (nodes/qos.py STREAM_QOS), offered by every topic of the bag.
LOOP_DEPTH = 100
#: Seconds between the epochs of a run that has no clock (a simulation).
SIMULATED_PERIOD = 0.1


class RunBagError(RunRecordError):
    """A bag that cannot be written or read: one line naming the file."""


def is_bag(path: str | os.PathLike) -> bool:
    """Whether a run record's output ``path`` is a bag (its name ends with :data:`BAG_SUFFIX`)."""
    return str(path).lower().endswith(BAG_SUFFIX)


def _rosbags():
    """The ``rosbags`` modules (a dependency: README, "Dependencies")."""
    try:
        from rosbags import interfaces, rosbag2
        from rosbags.typesys import Stores, get_typestore
    except ImportError:  # pragma: no cover - installed with the package's requirements
        raise RunBagError("a .mcap run record needs the rosbags package: pip install rosbags") from None
    return rosbag2, interfaces, get_typestore(Stores.ROS2_JAZZY)


def _loop_qos(interfaces):
    q = interfaces
    never = q.QosTime(0x7FFFFFFF, 0xFFFFFFFF)  # rmw's "infinite" duration
    return [q.Qos(q.QosHistory.KEEP_LAST, LOOP_DEPTH, q.QosReliability.RELIABLE, q.QosDurability.TRANSIENT_LOCAL,
                  never, never, q.QosLiveliness.AUTOMATIC, never, False)]


class Messages:
    """The loop's messages as ``rosbags`` objects in the nodes' layouts (module docstring)."""

    def __init__(self, typestore):
        self.ts = typestore
        t = typestore.types
        self.F64, self.I64 = t["std_msgs/msg/Float64MultiArray"], t["std_msgs/msg/Int64MultiArray"]
        self.Layout, self.Dim, self.String = (t["std_msgs/msg/MultiArrayLayout"], t["std_msgs/msg/MultiArrayDimension"],
                                              t["std_msgs/msg/String"])

    def _layout(self, dims: Sequence[tuple[str, int]]):
        return self.Layout(dim=[self.Dim(label=label, size=n, stride=n) for label, n in dims], data_offset=0)

    def record(self, label: str, values: Sequence[int]):
        return self.I64(layout=self._layout([(label, len(values))]), data=np.asarray(values, dtype=np.int64))

    def belief(self, epoch: int, b: np.ndarray):
        b = np.asarray(b, dtype=np.float64)
        return self.F64(layout=self._layout([("state", b.size), (f"epoch={int(epoch)}", 1)]), data=b)

    def plan_info(self, info: PlanInfo):
        values = info.as_dict()
        return self.F64(layout=self._layout([(",".join(PLAN_INFO_FIELDS), len(PLAN_INFO_FIELDS))]),
                        data=np.array([float(values[k]) for k in PLAN_INFO_FIELDS]))

    def text(self, data: str):
        return self.String(data=data)

    def serialize(self, msg) -> bytes:
        return bytes(self.ts.serialize_cdr(msg, msg.__msgtype__))


def _topic(namespace: str, name: str) -> str:
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{name}"


class RunBagWriter:
    """A run record streamed into a bag (module docstring): :meth:`write` takes the rows of
    :meth:`~.run_record.RunRecordWriter.write` (checked as the CSV writer checks them), and
    optionally the row's ``plan_info`` (``info``) and the reading that made its belief
    (``observation``: ``(priority, z)``). The file appears at ``path`` when :meth:`close` ends the
    bag (it is written beside it until then, in ``<path>.partial/``). ``clock``: the row time in
    nanoseconds when a row gives none (default: the wall clock)."""

    def __init__(self, path: str | os.PathLike, field_name: str, model_name: str, S: int, A: int,
                 time_budget: float | None = None, *, namespace: str = "",
                 clock: Callable[[], int] = time.time_ns):
        rosbag2, interfaces, ts = _rosbags()
        self.path, self.field, self.clock = Path(path), field_name, clock
        self.where = f"{field_name}: cannot write {path}"
        self.msgs = Messages(ts)
        self._text = io.StringIO()
        self.record = RunRecordWriter(self._text, model_name, S, A, time_budget)  # the CSV rule of every row
        self._partial = self.path.with_name(self.path.name + ".partial")
        try:
            if self._partial.exists():
                shutil.rmtree(self._partial)
            self.bag = rosbag2.Writer(self._partial, version=9, storage_plugin=rosbag2.StoragePlugin.MCAP)
            self.bag.set_custom_data("pomdp_planner.model", str(model_name))
            self.bag.set_custom_data("pomdp_planner.time_budget", "none" if time_budget is None else repr(time_budget))
            self.bag.open()
            qos = _loop_qos(interfaces)
            self.conns = {name: self.bag.add_connection(_topic(namespace, name), msgtype, typestore=ts,
                                                        offered_qos_profiles=qos)
                          for name, msgtype in TOPIC_TYPES.items()}
        except (OSError, rosbag2.WriterError) as exc:
            raise RunBagError(f"{self.where}: {getattr(exc, 'strerror', None) or exc}") from None
        self._head = self._take_text()  # the record's first line and header: written with the first row's time
        self.rows = 0

    def _take_text(self) -> str:
        text = self._text.getvalue()
        self._text.seek(0)
        self._text.truncate()
        return text

    def _write(self, topic: str, stamp_ns: int, msg) -> None:
        try:
            self.bag.write(self.conns[topic], int(stamp_ns), self.msgs.serialize(msg))
        except OSError as exc:
            raise RunBagError(f"{self.where}: {exc.strerror or type(exc).__name__}") from None

    def write(self, epoch: int, belief: Sequence[float] | np.ndarray, priority: int, *, true_state: int | None = None,
              bounds: tuple[int, int] | None = None, guaranteed: bool = False, depth: int | None = None,
              certified: bool = False, latency: float | None = None, info: PlanInfo | None = None,
              observation: tuple[int, int] | None = None, stamp_ns: int | None = None) -> None:
        """One row (module docstring); the arguments after ``priority`` up to ``latency`` are
        :meth:`~.run_record.RunRecordWriter.write`'s."""
        self.record.write(epoch, belief, priority, true_state=true_state, bounds=bounds, guaranteed=guaranteed,
                          depth=depth, certified=certified, latency=latency)
        t = self.clock() if stamp_ns is None else int(stamp_ns)
        later = t + (0 if latency is None or not math.isfinite(latency) else int(latency * 1e9))
        m = self.msgs
        if self._head:
            self._write("run_record", t, m.text(self._head))
            self._head = ""
        self._write("run_record", t, m.text(self._take_text()))
        if true_state is not None:
            self._write("true_state", t, m.record(TRUE_STATE_LABEL, (epoch, true_state)))
        if observation is not None:
            self._write("observation", t, m.record(OBSERVATION_LABEL, (epoch, *observation)))
        self._write("belief", t, m.belief(epoch, belief))
        self._write("action", later, m.record(ACTION_LABEL, (epoch + 1, priority)))
        if info is not None:
            self._write("plan_info", later, m.plan_info(info))
        self.rows += 1

    def observation(self, epoch: int, priority: int, z: int, stamp_ns: int | None = None) -> None:
        """A reading of the loop (``[epoch, priority, z]``) as it comes, apart from the rows (a node
        that records the loop's topics as they arrive)."""
        self._write("observation", self.clock() if stamp_ns is None else int(stamp_ns),
                    self.msgs.record(OBSERVATION_LABEL, (epoch, priority, z)))

    def close(self) -> None:
        """End the bag: its index and metadata, then the file at ``path``."""
        try:
            if self._head:  # a record without rows
                self._write("run_record", self.clock(), self.msgs.text(self._head))
            self.bag.close()
            inner = self._partial / f"{self._partial.name}.mcap"
            os.replace(inner, self.path)
            shutil.rmtree(self._partial, ignore_errors=True)
        except OSError as exc:
            raise RunBagError(f"{self.where}: {exc.strerror or type(exc).__name__}") from None


def simulated_clock(start_ns: int | None = None, period: float = SIMULATED_PERIOD) -> Callable[[int], int]:
    """Row times of a run without a clock: epoch ``t`` at ``start + t * period`` (nanoseconds;
    ``start``: now)."""
    start = time.time_ns() if start_ns is None else start_ns
    return lambda epoch: start + round(epoch * period * 1e9)


# ------------------------------------------------------------------------------------- reading
@dataclass
class RunBag:
    """A bag read back: ``record`` (the rows, as a run record), the readings that made each
    belief (``observations``: epoch -> ``(priority, z)``), every belief and action of the loop's
    topics (by epoch), the topics found, and ``notes`` (one line each: what was left out)."""

    path: str
    record: RunRecord
    observations: dict[int, tuple[int, int]] = field(default_factory=dict)
    beliefs: dict[int, np.ndarray] = field(default_factory=dict)
    actions: dict[int, int] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _open_reader(path: Path):
    rosbag2, _, ts = _rosbags()
    if not path.exists():
        raise RunBagError(f"{path}: no such file or directory")
    try:
        reader = rosbag2.Reader(path)
        reader.open()
    except Exception as exc:  # rosbags raises its own errors and struct/OS errors for a damaged file
        raise RunBagError(f"{path}: not a readable rosbag2 bag ({short_repr(str(exc), 120)}; a bag is complete "
                          "once its writer has closed it)") from None
    return reader, ts


def _find_topics(reader, where: str, namespace: str | None) -> dict[str, object]:
    """The connection of each of the bag's topics (:data:`TOPIC_TYPES`) by its last name, within
    ``namespace`` (``None``: the one namespace the bag has them in)."""
    found: dict[str, list] = {}
    for conn in reader.connections:
        head, _, name = conn.topic.rpartition("/")
        if name in TOPIC_TYPES and conn.msgtype == TOPIC_TYPES[name] and (namespace is None or
                                                                           head.strip("/") == namespace.strip("/")):
            found.setdefault(name, []).append(conn)
    out = {}
    for name, conns in found.items():
        topics = sorted({c.topic for c in conns})
        if len(topics) > 1:
            raise RunBagError(f"{where}: {len(topics)} {name} topics ({', '.join(topics)}): give the namespace of the "
                              "run (--namespace)")
        out[name] = conns
    return out


def _values(msg) -> list:
    return [x.item() if hasattr(x, "item") else x for x in np.asarray(msg.data).tolist()]


def read_run_bag(path: str | os.PathLike, *, namespace: str | None = None, num_actions: int | None = None) -> RunBag:
    """Read a bag (module docstring); ``num_actions``: ``A`` of the run when the bag has no
    ``run_record`` (default: the largest priority in it)."""
    path = Path(path)
    where = str(path)
    reader, ts = _open_reader(path)
    try:
        conns = _find_topics(reader, where, namespace)
        if "belief" not in conns and "run_record" not in conns:
            names = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
            raise RunBagError(f"{where}: no run_record or belief topic of this package "
                              f"(topics: {short_repr(names, 200)})")
        wanted = [c for cs in conns.values() for c in cs]
        by_id = {c.id: name for name, cs in conns.items() for c in cs}
        text: list[str] = []
        bag = RunBag(where, record=None, topics={name: cs[0].topic for name, cs in conns.items()})  # type: ignore[arg-type]
        stream: list[tuple[int, str, object]] = []
        for conn, stamp, raw in reader.messages(connections=wanted):
            name = by_id[conn.id]
            try:
                msg = ts.deserialize_cdr(raw, conn.msgtype)
            except Exception:
                bag.notes.append(f"{where}: a {name} message at {stamp} ns does not deserialize: left out")
                continue
            if name == "run_record":
                text.append(msg.data)
            else:
                stream.append((stamp, name, msg))
    finally:
        reader.close()
    _loop_samples(bag, stream)
    if text:  # the first line and header, then the rows in epoch order (messages of one time may come in any order)
        head = [x for x in text if x.startswith("#")]
        rows = sorted((x for x in text if not x.startswith("#")), key=lambda x: int(x.split(",", 1)[0] or -1)
                      if x.split(",", 1)[0].isdigit() else -1)
        bag.record = read_run_record(where, text="".join(head + rows))
    else:
        bag.record = _paired_record(where, stream, bag, num_actions)
    return bag


def _epoch_label(msg) -> int | None:
    dims = list(msg.layout.dim)
    if len(dims) == 2 and dims[0].label == "state" and dims[1].label.startswith("epoch="):
        rest = dims[1].label[len("epoch="):]
        return int(rest) if rest.isdigit() else None
    return None


def _loop_samples(bag: RunBag, stream: list) -> None:
    """The observations, beliefs and actions of the loop's topics, by epoch (malformed ones noted)."""
    bad: dict[str, int] = {}
    for _, name, msg in stream:
        v = _values(msg)
        if name == "observation" and len(v) == 3:
            bag.observations[int(v[0])] = (int(v[1]), int(v[2]))
        elif name == "action" and len(v) == 2:
            bag.actions[int(v[0])] = int(v[1])
        elif name == "belief" and _epoch_label(msg) is not None:
            bag.beliefs[_epoch_label(msg)] = np.asarray(v, dtype=float)
        elif name in ("observation", "action", "belief"):
            bad[name] = bad.get(name, 0) + 1
    for name, n in bad.items():
        bag.notes.append(f"{bag.path}: {n} {name} message(s) not in the loop's layout: left out")


def _paired_record(where: str, stream: list, bag: RunBag, num_actions: int | None) -> RunRecord:
    """The rows of a bag without ``run_record``: its loop topics paired by the run recorder's rule
    (row ``t``: belief ``t``, true state ``t``, action ``[t + 1, p]``, ``plan_info`` of ``t + 1``),
    fed in the bag's time order, as a run record."""
    if not bag.beliefs:
        raise RunBagError(f"{where}: no belief in the loop's layout")
    S = len(next(iter(bag.beliefs.values())))
    A = num_actions or max([p for p in bag.actions.values()] + [1])
    t0 = stream[0][0] if stream else 0
    loop = RecorderLoop(S, A, now=0.0, expect_true_state="true_state" in bag.topics)
    rows, logs = [], []

    def take(out) -> None:
        rows.extend(out.rows)
        logs.extend(out.logs)

    for stamp, name, msg in stream:
        now = (stamp - t0) / 1e9
        v = _values(msg)
        if name == "belief" and _epoch_label(msg) is not None and len(v) == S:
            take(loop.belief(BeliefSample(_epoch_label(msg), np.asarray(v, dtype=float)), now))
        elif name == "action" and len(v) == 2 and 1 <= v[1] <= A:
            take(loop.action(ActionSample(int(v[0]), int(v[1])), now))
        elif name == "plan_info" and len(v) == len(PLAN_INFO_FIELDS):
            take(loop.plan_info(dict(zip(PLAN_INFO_FIELDS, map(float, v), strict=True)), now))
        elif name == "true_state" and len(v) == 2:
            take(loop.true_state(int(v[0]), int(v[1]), now))
        take(loop.poll(now))
    take(loop.close(math.inf if not stream else (stream[-1][0] - t0) / 1e9))
    bag.notes += [f"{where}: {line.text}" for line in logs if isinstance(line, Log) and line.level == "warning"]
    if not rows:
        raise RunBagError(f"{where}: no row: no belief with the action chosen from it")
    text = io.StringIO()
    writer = RunRecordWriter(text, "unknown", S, A, None)
    for row in rows:
        writer.write(row.epoch, row.belief, row.priority, **row.record_fields())
    try:
        return read_run_record(where, text=text.getvalue())
    except RunRecordError as exc:  # pragma: no cover - the writer checked every row
        raise RunBagError(str(exc)) from None


def open_run_output(path: str | os.PathLike, field_name: str, model_name: str, S: int, A: int,
                    time_budget: float | None = None, *, namespace: str = "") -> RunBagWriter | object:
    """The writer of a run record at ``path``: a :class:`RunBagWriter` for a ``.mcap`` name, else
    the CSV writer of :func:`~.run_record.open_run_record`."""
    if is_bag(path):
        return RunBagWriter(path, field_name, model_name, S, A, time_budget, namespace=namespace)
    from .run_record import open_run_record

    return open_run_record(path, field_name, model_name, S, A, time_budget)


def read_run_output(path: str | os.PathLike, *, namespace: str | None = None) -> RunRecord:
    """A run record from a CSV file or a bag (a ``.mcap``/``.db3`` file or a rosbag2 directory)."""
    p = Path(path)
    if p.is_dir() or p.suffix.lower() in (BAG_SUFFIX, ".db3"):
        bag = read_run_bag(p, namespace=namespace)
        return bag.record
    return read_run_record(path)


def write_row(writer, epoch: int, belief, priority: int, *, info: PlanInfo | None = None,
              observation: tuple[int, int] | None = None, stamp_ns: int | None = None, **fields) -> None:
    """One row into ``writer`` (:func:`open_run_output`'s): a bag also gets the row's ``plan_info``,
    the reading that made its belief and its time; a CSV record only the row."""
    if isinstance(writer, RunBagWriter):
        writer.write(epoch, belief, priority, info=info, observation=observation, stamp_ns=stamp_ns, **fields)
    else:
        writer.write(epoch, belief, priority, **fields)
