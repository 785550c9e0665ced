"""Who writes a loop's input streams: one writer per stream (rule "One writer" of docs/ros.md,
"The loop's rules").

ROS topics are unauthenticated and any process on the domain may publish on them. A node follows
*one* writer per input stream, the *established* one: at first the first writer whose sample it
admits. Samples of any other writer are *foreign*: dropped before they are decoded, counted and
reported with the writer's node name. Each stream may know its *expected* writers: the node names
that write it in the package's loop (:data:`EXPECTED_WRITERS`: the planner writes ``action``, the
filter ``belief``, ...), and any the user adds; a name matches a writer's node name or its last
part (any namespace). The established writer is replaced by the writer ``W`` of a sample when:

1. it has left the graph (a clean exit): any ``W``;
2. it is not an expected writer and ``W`` is (a stray that spoke first, e.g. while the loop
   started): at once;
3. it has delivered no sample for ``alive_after`` seconds (the nodes pass ``stall_warn_after``)
   and ``W`` is its restart (the same node name), or an expected writer, or it is not expected
   itself. A killed process (``kill -9``) stays in the graph until its DDS lease ends (20 s with
   Fast DDS): this is how its restart takes over before then.

Nothing else replaces it: in particular a writer still in the graph is never replaced by a
writer of another, unexpected name because it fell silent, so a flood that crowds the
established writer's samples out of the reader's history (silence on the reader's side is no
proof that a writer has gone) cannot take over a stream. When an expected writer replaces one
that was not expected, the stray's numbering is dropped with it (``forget``: the loop joins the
new writer's stream afresh).

A publisher of the stream's topic with another message type never delivers a sample (the
middleware matches topics by type as well): the graph names it (:meth:`WriterWatch.graph`'s
``wrong_types``), and the report says so while it is there (a sensor driver publishing a
``LaserScan`` where the adapter reads a ``Range`` would otherwise be only "no new reading").

Writer ids are opaque strings (the nodes pass the publisher GID in hex) or ``None`` when the
middleware does not say who wrote a sample (*unattributed*: admitted, the preference cannot apply).
Node names come from the graph (:meth:`WriterWatch.graph`), which the nodes look at once a second
and whenever a writer id they have not seen in it appears; a writer the graph has not named yet
is no one's restart and not expected. Times are passed in (``now``, seconds on a monotonic clock).
Memory is bounded: at most :data:`MAX_WRITERS` writers are remembered.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Literal

#: Writers remembered per stream (the least recently heard ones are forgotten first).
MAX_WRITERS = 32
#: The package's node names that write each kind of input stream (module docstring).
EXPECTED_WRITERS: dict[str, tuple[str, ...]] = {
    "action": ("planner", "sensor_manager"),
    "belief": ("belief_filter",),
    "observation": ("target_simulator", "measurement_adapter"),
    "likelihood": ("measurement_adapter",),
    "plan_info": ("planner",),
    "true_state": ("target_simulator",),
    "measurement": (),  # a sensor driver: its name is the user's (expected_writers)
}


def check_writer_names(names: Iterable[str], field: str = "expected_writers") -> tuple[str, ...]:
    """Node names a user adds to the expected writers: each a ROS node name, optionally with its
    namespace (letters, digits, ``_``, ``/``); ``ValueError`` naming ``field`` otherwise."""
    out = []
    for k, name in enumerate(names):
        text = str(name).strip()
        ok = text and all(ch.isascii() and (ch.isalnum() or ch in "_/") for ch in text) and not text.endswith("/")
        if not ok or len(text) > 255:
            raise ValueError(f"{field}[{k}]: must be a node name such as sonar_driver or /robot1/sonar_driver, "
                             f"got {text[:60]!r}")
        out.append(text)
    return tuple(out)


def expected_writers(kind: str, extra: Iterable[str] = ()) -> frozenset[str]:
    """The expected writers of a stream of ``kind`` (a key of :data:`EXPECTED_WRITERS`), with the
    node names ``extra`` (the node's ``expected_writers`` parameter) added."""
    return frozenset((*EXPECTED_WRITERS[kind], *(e.strip() for e in extra if e.strip())))

Admission = Literal["admitted", "foreign", "replaced"]


@dataclass
class _Writer:
    id: str
    last_sample: float
    samples: int = 0
    announced: bool = False  # its first foreign sample has been logged


class WriterWatch:
    """The writers of the input stream ``name`` (see the module docstring); ``expected``: its
    expected writers' node names (``None``: not known, so rules 2 and 3 apply to restarts only)."""

    def __init__(self, name: str, alive_after: float, expected: frozenset[str] | None = None):
        if alive_after <= 0:
            raise ValueError(f"alive_after: must be > 0, got {alive_after}")
        self.name = name
        self.alive_after = alive_after
        self.expected = expected
        self.type_name = ""  # the stream's message type, as the graph names types (the node sets it)
        self.established: str | None = None
        self.unattributed = 0           # samples without a writer id
        self.changes = 0                # replaced established writers
        self.foreign = 0                # foreign samples dropped
        self._writers: OrderedDict[str, _Writer] = OrderedDict()
        self._graph: dict[str, str] | None = None  # id -> node name, as last seen in the graph
        self._names: dict[str, str] = {}            # every name the graph gave (bounded with the writers)
        self.wrong_types: dict[str, tuple[str, str]] = {}  # id -> (node name, message type): another type
        self.candidate: str | None = None           # the newest foreign writer (a successor, should the
                                                    # established one go)

    # ----------------------------------------------------------- facts
    def graph(self, writers: Mapping[str, str], wrong_types: Mapping[str, tuple[str, str]] | None = None) -> list[str]:
        """The writers the graph lists on this stream now: ``{writer id: node name}``, and the
        publishers of its topic with another message type: ``{id: (node name, type)}``. Returns a
        warning for each of those not seen before (the module docstring)."""
        new = {k: v for k, v in (wrong_types or {}).items() if k not in self.wrong_types}
        self.wrong_types = dict(wrong_types or {})
        warnings = [f"{self.name}: {node} [{k}] publishes {kind}, not the {self.type_name or 'expected type'} this "
                    "node reads: its samples never reach it" for k, (node, kind) in sorted(new.items())]
        self._graph = dict(writers)
        self._names.update(writers)
        if len(self._names) > 4 * MAX_WRITERS:
            keep = set(self._writers) | set(self._graph)
            self._names = {k: v for k, v in self._names.items() if k in keep}
        return warnings

    def known(self, writer: str) -> bool:
        """Whether the graph has named ``writer`` (else the node looks at the graph again)."""
        return writer in self._names

    def label(self, writer: str | None) -> str:
        """``writer`` as messages name it: its node name and its id (the GID ``ros2 topic info -v`` shows)."""
        if writer is None:
            return "an unattributed writer"
        return f"{self._names.get(writer, '(node not in the graph)')} [{writer}]"

    def is_expected(self, writer: str | None) -> bool:
        """Whether the graph names ``writer`` with one of the expected node names (module docstring)."""
        name = self._names.get(writer or "")
        if name is None or not self.expected:
            return False
        return name in self.expected or name.rsplit("/", 1)[-1] in self.expected

    # ----------------------------------------------------------- the rule
    def in_graph(self) -> bool:
        """Whether the established writer is still in the graph (``True`` until the graph is known)."""
        return self.established is not None and (self._graph is None or self.established in self._graph)

    def silence(self, now: float) -> float:
        """Seconds since the established writer's last sample (0 if there is none)."""
        w = self._writers.get(self.established or "")
        return 0.0 if w is None else now - w.last_sample

    def _successor(self, writer: str, now: float) -> str | None:
        """Why ``writer`` replaces the established writer now (rules 1-3 of the module docstring), or ``None``."""
        old = self.established
        if not self.in_graph():
            return "it left the graph"
        old_expected, new_expected = self.is_expected(old), self.is_expected(writer)
        if new_expected and not old_expected and self.expected:
            return "not an expected writer of this input"
        silent = self.silence(now)
        if silent >= self.alive_after:
            name = self._names.get(writer)
            restart = name is not None and name == self._names.get(old or "")
            if restart or new_expected or (self.expected and not old_expected):
                return f"silent for {silent:.1f} s"
        return None

    def admit(self, writer: str | None, now: float) -> tuple[Admission, str]:
        """Whether a sample of ``writer`` is acted on: ``("admitted", "")``, ``("foreign", text)``
        (dropped; ``text`` is the warning, ``""`` after the writer's first one) or ``("replaced",
        text)`` (admitted: ``writer`` replaced the established writer, module docstring); after a
        replacement :attr:`forget` says whether the old writer was a stray (not expected)."""
        if writer is None:
            self.unattributed += 1
            return "admitted", ""
        why = None if self.established in (None, writer) else self._successor(writer, now)
        w = self._writers.get(writer)
        if w is None:
            w = self._writers[writer] = _Writer(writer, now)
            while len(self._writers) > MAX_WRITERS:
                oldest = next(k for k in self._writers if k != self.established)
                del self._writers[oldest]
        self._writers.move_to_end(writer)
        w.last_sample = now
        w.samples += 1
        if self.established is None or writer == self.established:
            self.established = writer
            return "admitted", ""
        if why is None:
            self.foreign += 1
            self.candidate = writer
            text = ""
            if not w.announced:
                w.announced = True
                text = (f"{self.name}: samples of a second writer, {self.label(writer)}, dropped while "
                        f"{self.label(self.established)} writes (one writer per stream)")
            return "foreign", text
        old, self.established, self.candidate = self.established, writer, None
        self.forget = bool(self.expected) and not self.is_expected(old)
        self.changes += 1
        if why.startswith("not an expected"):
            text = (f"{self.name}: writer changed from {self.label(old)} ({why}) to {self.label(writer)} (expected: "
                    f"{', '.join(sorted(self.expected))})")
        else:
            text = f"{self.name}: writer changed from {self.label(old)} ({why}) to {self.label(writer)} (a restart?)"
        return "replaced", text

    #: After a replacement: the old writer was not an expected one (its numbering is dropped).
    forget = False

    def takeover_due(self, now: float) -> bool:
        """A foreign writer's sample waits (:attr:`candidate`) and that writer would now replace the
        established one: the node hands that sample in again, and it is admitted (``"replaced"``)."""
        return self.candidate is not None and self._successor(self.candidate, now) is not None

    # ----------------------------------------------------------- report
    def status(self) -> str:
        """What the report says while the graph lists more than one writer of the stream, or a
        publisher of its topic with another message type (a warning), naming them; ``""`` otherwise."""
        texts = []
        if self._graph is not None and len(self._graph) > 1:
            names = ", ".join(self.label(k) + (" (followed)" if k == self.established else "")
                              for k in sorted(self._graph, key=lambda k: (k != self.established, self._graph[k], k)))
            texts.append(f"{self.name} has {len(self._graph)} writers: {names}")
        if self.wrong_types:
            kinds = ", ".join(f"{node} publishes {kind}" for node, kind in sorted(self.wrong_types.values()))
            texts.append(f"{self.name}: {kinds}, not {self.type_name or 'the expected type'}")
        return "; ".join(texts)

    def values(self) -> dict[str, object]:
        """Diagnostic values of this stream (``input.<name>.writer*``)."""
        p = f"input.{self.name}"
        return {f"{p}.writer": "none" if self.established is None else self.label(self.established),
                f"{p}.writers": "unknown" if self._graph is None else len(self._graph),
                f"{p}.expected_writers": ",".join(sorted(self.expected or ())) or "any",
                f"{p}.wrong_type_publishers": len(self.wrong_types),
                f"{p}.foreign_samples": self.foreign, f"{p}.writer_changes": self.changes}
