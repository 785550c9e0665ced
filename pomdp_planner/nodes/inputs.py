"""What every input sample of a node passes before it is decoded: its size, then its writer
(rules "Bounded samples" and "One writer" of docs/ros.md, "The loop's rules"), with the graph's
facts about the writers of each input.

:class:`CheckedInputs` subscribes raw (:func:`.take.subscribe`: the sample's size and its
publisher's GID come before any copy into Python), counts an oversized sample in the loop's
health and drops it unread, asks the loop's health (:meth:`~pomdp_planner.core.loop.health.LoopHealth.admit`)
whether the writer is the one the loop follows, keeps the newest foreign sample for a takeover,
and only then deserializes the sample and hands it on. These checks are the subscription's
*screen*: the project's executor runs it as it takes each sample (:mod:`.take`), so a flood of
foreign samples is dropped without a callback each. Each input has the expected writers of its
kind (``core/loop/writers.expected_writers``, with the node's ``expected_writers`` parameter). The
loop nodes (:mod:`.loop_node`) and the run recorder's inputs (:mod:`.run_recorder`) use it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from rclpy.node import Node
from rclpy.serialization import deserialize_message

from ..core.loop import Log
from ..core.loop.health import LoopHealth
from ..core.loop.writers import expected_writers
from .messages import WireBound, oversized
from .runtime import callback
from .take import subscribe

#: Writers per input for which the node looked at the graph on their first sample (the oldest forgotten).
GRAPH_ASKED = 64
#: A writer the graph did not name yet (its node's discovery can arrive after its first samples) is
#: looked up again on a later sample, at most this often (s).
GRAPH_RETRY = 0.1


@dataclass
class Input:
    """An input stream (:meth:`CheckedInputs.subscribe`)."""

    name: str
    msg_type: type
    bound: WireBound
    on_msg: Callable[[object], None]
    on_bad: Callable[[str], None]
    expected: frozenset[str] = frozenset()  # the expected writers' node names (core/loop/writers.py)

    @property
    def type_name(self) -> str:
        """The message type as the graph names it, e.g. ``sensor_msgs/msg/Range``."""
        return f"{self.msg_type.__module__.split('.')[0]}/msg/{self.msg_type.__name__}"
    topic: str = ""
    sub: object = None                      # the subscription
    held: tuple[bytes, dict] | None = None  # the newest foreign sample: handed in again at a takeover
    asked: dict[str, float] = field(default_factory=dict)  # writers the graph was looked at for, and when


class CheckedInputs:
    """The checked input streams of ``node`` (module docstring). ``health()`` is the health of the
    loop the samples go to (``None``: no loop now, a sample is ignored), read and changed with
    ``lock`` held; ``log`` gets the health's log lines; ``now`` is the loop's clock."""

    def __init__(self, node: Node, lock: threading.Lock, health: Callable[[], LoopHealth | None],
                 log: Callable[[Iterable[Log]], None], now: Callable[[], float] = time.monotonic):
        self.node = node
        self.context = node.context  # for @callback
        self.lock, self.health, self.log, self.now = lock, health, log, now
        self.streams: dict[str, Input] = {}
        #: Node names added to every input's expected writers (the node's ``expected_writers``).
        self.extra_writers: tuple[str, ...] = ()

    def subscribe(self, name: str, msg_type: type, topic: str, qos, on_msg: Callable[[object], None], *,
                  bound: WireBound, on_bad: Callable[[str], None], kind: str, **kwargs) -> Input:
        """Subscribe to ``topic`` as the input ``name`` of ``kind`` (a key of
        ``core.loop.writers.EXPECTED_WRITERS``): a sample larger than ``bound`` is dropped unread,
        one of a writer other than the one the loop follows is dropped before it is decoded, the
        rest is deserialized and handed to ``on_msg`` (one that does not deserialize to ``on_bad``)."""
        spec = Input(name, msg_type, bound, on_msg, on_bad, expected_writers(kind, self.extra_writers))
        sub = subscribe(self.node, msg_type, topic, lambda raw, info: self.on_sample(spec, raw, info), qos,
                        bound.max_bytes, screen=lambda raw, info: self.screen(spec, raw, info), **kwargs)
        spec.topic, spec.sub = sub.topic_name, sub
        self.streams[name] = spec
        return spec

    def clear(self) -> None:
        """Forget every stream (their subscriptions are destroyed by the node)."""
        self.streams = {}

    def followed(self, name: str, writer: str | None) -> bool:
        """Whether a sample of ``writer`` on input ``name`` comes from the writer the loop follows
        (or from no known writer yet): a read-only look, for a second reader of the same topic."""
        with self.lock:
            health = self.health()
            if health is None or writer is None:
                return health is not None
            established = health.writers[name].established
        return established is None or established == writer

    def screen(self, spec: Input, raw: bytes | None, info: dict) -> bool:
        """The size and writer rules for one sample (module docstring): whether it is to be decoded."""
        try:
            return self._screen(spec, raw, info)
        except Exception:  # e.g. the graph asked during a shutdown
            if self.context.ok():
                raise
            return False

    def _screen(self, spec: Input, raw: bytes | None, info: dict) -> bool:
        health = self.health()
        if health is None:  # taken before a cleanup released the subscription
            return False
        now = self.now()
        size = info.get("size", 0 if raw is None else len(raw))
        if raw is None or size > spec.bound.max_bytes:
            with self.lock:
                health.oversized(spec.name, oversized(spec.name, size, spec.bound), now)
                logs = health.drain_logs()
            self.log(logs)
            return False
        writer = info.get("publisher_gid")
        ww = health.writers[spec.name]
        if ww.expected is not spec.expected:
            ww.expected = spec.expected
        if writer is not None and not ww.known(writer) and now - spec.asked.get(writer, -math.inf) >= GRAPH_RETRY:
            spec.asked.pop(writer, None)  # who is it? On its first sample, again while the graph has no name
            spec.asked[writer] = now
            while len(spec.asked) > GRAPH_ASKED:
                del spec.asked[next(iter(spec.asked))]
            self.look_at_graph(spec)
        with self.lock:
            admitted = health.admit(spec.name, writer, now)
            if not admitted:
                spec.held = (raw, info)
            logs = health.drain_logs() if health.logs else ()
        if logs:
            self.log(logs)
        return admitted

    @callback
    def on_sample(self, spec: Input, raw: bytes | None, info: dict) -> None:
        if not info.get("screened") and not self.screen(spec, raw, info):
            return
        try:
            msg = deserialize_message(raw, spec.msg_type)
        except Exception as exc:  # not a sample of the topic's type (a raw publisher's bytes)
            spec.on_bad(f"{spec.name}: not a {spec.msg_type.__name__} ({type(exc).__name__})")
            return
        spec.on_msg(msg)

    def look_at_graph(self, spec: Input) -> None:
        """The graph's facts about the writers of ``spec``'s topic: ``{GID (hex): node name}``, and
        the publishers of it with another message type (named once, and in the report)."""
        writers, wrong = {}, {}
        for i in self.node.get_publishers_info_by_topic(spec.topic):
            gid, name = bytes(i.endpoint_gid).hex(), i.node_namespace.rstrip("/") + "/" + i.node_name
            if i.topic_type == spec.type_name:
                writers[gid] = name
            else:
                wrong[gid] = (name, i.topic_type)
        with self.lock:
            health = self.health()
            if health is not None:  # None: released by a cleanup meanwhile
                health.writers[spec.name].type_name = spec.type_name
                health.graph(spec.name, writers, wrong, self.now())
                logs = health.drain_logs() if health.logs else ()
            else:
                logs = ()
        if logs:
            self.log(logs)

    def look_at_graphs(self) -> None:
        """The graph's writers of every input (before a report)."""
        for spec in list(self.streams.values()):
            self.look_at_graph(spec)

    def takeovers(self) -> None:
        """Hand in again the waiting sample of a writer whose predecessor is gone (rule "One writer")."""
        now = self.now()
        for spec in list(self.streams.values()):
            with self.lock:
                health = self.health()
                held = spec.held if health is not None and health.writers[spec.name].takeover_due(now) else None
                if held is not None:
                    spec.held = None
            if held is not None:
                info = dict(held[1])
                info.pop("screened", None)
                self.on_sample(spec, held[0], info)
