"""Who writes a loop's input streams: one writer per stream (rule "One writer" of docs/ros.md,
"The loop's rules").

ROS topics are unauthenticated and any process on the domain may publish on them. A node follows
*one* writer per input stream, the *established* one: the first writer whose sample it admits.
While that writer is alive, samples of any other writer are *foreign*: dropped before they are
decoded, counted and reported with the writer's node name. The established writer is alive while
it has delivered a sample within ``alive_after`` seconds (the nodes pass ``stall_warn_after``: a
writer silent that long is a stall anyway) and, once the graph has been looked at, while it is
still in the graph. A writer that is not alive any more is *replaced*: the next writer whose sample
comes (a restarted node: a new writer id, the same node name) becomes the established one, and the
change is reported with both names. A killed process (``kill -9``) stays in the graph until its
DDS lease ends (20 s with Fast DDS), so silence, not the graph, is what lets a restart take over.

Writer ids are opaque strings (the nodes pass the publisher GID in hex) or ``None`` when the
middleware does not say who wrote a sample (*unattributed*: admitted, the preference cannot apply).
Node names come from the graph (:meth:`WriterWatch.graph`), which the nodes look at once a second
and whenever a writer id they have not seen in it appears. Times are passed in (``now``, seconds
on a monotonic clock). Memory is bounded: at most :data:`MAX_WRITERS` writers are remembered.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

#: Writers remembered per stream (the least recently heard ones are forgotten first).
MAX_WRITERS = 32

Admission = Literal["admitted", "foreign", "replaced"]


@dataclass
class _Writer:
    id: str
    last_sample: float
    samples: int = 0
    announced: bool = False  # its first foreign sample has been logged


class WriterWatch:
    """The writers of the input stream ``name`` (see the module docstring)."""

    def __init__(self, name: str, alive_after: float):
        if alive_after <= 0:
            raise ValueError(f"alive_after: must be > 0, got {alive_after}")
        self.name = name
        self.alive_after = alive_after
        self.established: str | None = None
        self.unattributed = 0           # samples without a writer id
        self.changes = 0                # replaced established writers
        self.foreign = 0                # foreign samples dropped
        self._writers: OrderedDict[str, _Writer] = OrderedDict()
        self._graph: dict[str, str] | None = None  # id -> node name, as last seen in the graph
        self._names: dict[str, str] = {}            # every name the graph gave (bounded with the writers)
        self.candidate: str | None = None           # the newest foreign writer (a successor, should the
                                                    # established one go)

    # ----------------------------------------------------------- facts
    def graph(self, writers: Mapping[str, str]) -> None:
        """The writers the graph lists on this stream now: ``{writer id: node name}``."""
        self._graph = dict(writers)
        self._names.update(writers)
        if len(self._names) > 4 * MAX_WRITERS:
            keep = set(self._writers) | set(self._graph)
            self._names = {k: v for k, v in self._names.items() if k in keep}

    def known(self, writer: str) -> bool:
        """Whether the graph has named ``writer`` (else the node looks at the graph again)."""
        return writer in self._names

    def label(self, writer: str | None) -> str:
        """``writer`` as messages name it: its node name and its id (the GID ``ros2 topic info -v`` shows)."""
        if writer is None:
            return "an unattributed writer"
        return f"{self._names.get(writer, '(node not in the graph)')} [{writer}]"

    # ----------------------------------------------------------- the rule
    def alive(self, now: float) -> bool:
        """Whether the established writer is alive (module docstring)."""
        if self.established is None:
            return False
        if self._graph is not None and self.established not in self._graph:
            return False
        return now - self._writers[self.established].last_sample < self.alive_after

    def silence(self, now: float) -> float:
        """Seconds since the established writer's last sample (0 if there is none)."""
        w = self._writers.get(self.established or "")
        return 0.0 if w is None else now - w.last_sample

    def admit(self, writer: str | None, now: float) -> tuple[Admission, str]:
        """Whether a sample of ``writer`` is acted on: ``("admitted", "")``, ``("foreign", text)``
        (dropped; ``text`` is the warning, ``""`` after the writer's first one) or ``("replaced",
        text)`` (admitted: ``writer`` replaced the established writer, which was not alive)."""
        if writer is None:
            self.unattributed += 1
            return "admitted", ""
        old_alive = self.alive(now)  # before this sample refreshes anything
        silent = self.silence(now)
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
        if old_alive:
            self.foreign += 1
            self.candidate = writer
            text = ""
            if not w.announced:
                w.announced = True
                text = (f"{self.name}: samples of a second writer, {self.label(writer)}, dropped while "
                        f"{self.label(self.established)} writes (one writer per stream)")
            return "foreign", text
        old, self.established, self.candidate = self.established, writer, None
        self.changes += 1
        gone = self._graph is not None and old not in self._graph
        why = "it left the graph" if gone else f"silent for {silent:.1f} s"
        return "replaced", (f"{self.name}: writer changed from {self.label(old)} ({why}) to {self.label(writer)} "
                            "(a restart?)")

    def takeover_due(self, now: float) -> bool:
        """A foreign writer's sample waits (:attr:`candidate`) and the established writer is not
        alive any more: the node hands that sample in again, and it is admitted (``"replaced"``)."""
        return self.candidate is not None and not self.alive(now)

    # ----------------------------------------------------------- report
    def status(self) -> str:
        """What the report says while the graph lists more than one writer of the stream (a
        warning), naming them; ``""`` otherwise."""
        if self._graph is None or len(self._graph) <= 1:
            return ""
        names = ", ".join(self.label(k) + (" (followed)" if k == self.established else "")
                          for k in sorted(self._graph, key=lambda k: (k != self.established, self._graph[k], k)))
        return f"{self.name} has {len(self._graph)} writers: {names}"

    def values(self) -> dict[str, object]:
        """Diagnostic values of this stream (``input.<name>.writer*``)."""
        p = f"input.{self.name}"
        return {f"{p}.writer": "none" if self.established is None else self.label(self.established),
                f"{p}.writers": "unknown" if self._graph is None else len(self._graph),
                f"{p}.foreign_samples": self.foreign, f"{p}.writer_changes": self.changes}
