"""A node's ROS time (rule "Time" of docs/ros.md, "The loop's rules").

The loops run on a monotonic clock the node passes in (``now``); ROS time (``/clock`` when
``use_sim_time`` is true) only paces what is meant to follow a simulation: the simulator's steps
in timer mode. ``use_sim_time`` is chosen at start-up and refused at run time (a peer could
otherwise stop every ROS-time timer of a running node by setting it, through the standard
parameter service, with no ``/clock`` on the domain). With sim time on, a ``/clock`` that has not
advanced for the stall interval (``stall_warn_after``) makes the report ERROR, saying so.
"""

from __future__ import annotations


class ClockWatch:
    """Progress of a node's ROS time: ``sim_time`` is the node's ``use_sim_time`` at start-up;
    :meth:`tick` gets the ROS clock's reading (nanoseconds) with ``now``, at every report."""

    def __init__(self, sim_time: bool, stall_after: float, now: float):
        self.sim_time = sim_time
        self.stall_after = stall_after
        self._ros_ns: int | None = None
        self._advanced = now  # when ROS time last moved (or the watch started)

    def tick(self, ros_ns: int, now: float) -> None:
        if self._ros_ns is None or ros_ns != self._ros_ns:
            if self._ros_ns is not None or ros_ns != 0:  # 0: sim time before the first /clock
                self._advanced = now
            self._ros_ns = ros_ns

    def stalled_for(self, now: float) -> float:
        return now - self._advanced

    def status(self, now: float) -> str:
        """The ERROR of the report (``""`` while ROS time moves, or runs on the system clock)."""
        if not self.sim_time or self.stalled_for(now) < self.stall_after:
            return ""
        never = self._ros_ns in (None, 0)
        return (f"use_sim_time is true and /clock has {'never advanced' if never else 'not advanced'} for "
                f"{self.stalled_for(now):.1f} s{' (no /clock publisher?)' if never else ''}: what runs on ROS "
                "time waits for it")

    def refuse(self, wanted: object) -> str:
        """The reason a run-time change of ``use_sim_time`` to ``wanted`` is refused."""
        return (f"use_sim_time: set at start-up only (it is {str(self.sim_time).lower()}; asked for "
                f"{wanted!r} at run time): restart the node with -p use_sim_time:=<true|false>")

    def values(self, now: float) -> dict[str, object]:
        out: dict[str, object] = {"use_sim_time": self.sim_time}
        if self.sim_time:
            out["clock.ros_time_ns"] = "none" if self._ros_ns is None else self._ros_ns
            out["clock.seconds_since_advance"] = round(self.stalled_for(now), 3)
        return out
