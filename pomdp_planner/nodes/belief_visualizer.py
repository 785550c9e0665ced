"""``belief_visualizer``: the loop's belief as pictures for RViz and Foxglove.

Topics (relative names, remappable; layouts: :mod:`.messages`):

* subscribes ``belief``, ``plan_info`` and ``true_state`` (``STREAM_QOS``, as the loop's writers),
  each sample checked for its size and its writer before it is decoded, as the loop nodes' inputs;
* publishes ``belief_markers`` (``visualization_msgs/MarkerArray``: one bar per state, its height
  the state's probability; a sphere over the true state when a simulator publishes it; a text
  with the newest decision: its action, root bounds and certificate), for a grid model
  ``belief_grid`` (``nav_msgs/OccupancyGrid``: the belief over the cells, the most probable 100),
  both latched (``LATCHED_QOS``) with headers stamped now in ``frame_id``, at most once per
  ``publish_period`` and only when something changed; and ``/diagnostics``
  (``belief_visualizer: visualisation``).

What is shown is the core's :class:`~pomdp_planner.core.loop.visual_loop.VisualLoop`; this node
decodes, calls it and encodes its :class:`~pomdp_planner.core.loop.visual_loop.Scene`
(:func:`markers`, :func:`occupancy_grid`). It keeps the filter's and the planner's hot paths free
of drawing. RViz: ``rviz2 -d <share>/config/belief.rviz``. Parameters: docs/ros.md.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from nav_msgs.msg import MapMetaData, OccupancyGrid
from rclpy.clock import Clock, ClockType
from std_msgs.msg import ColorRGBA, Float64MultiArray, Header, Int64MultiArray
from visualization_msgs.msg import Marker, MarkerArray

from ..core.io.sensors import load_model_file
from ..core.loop import Log
from ..core.loop.visual_loop import TRUE_RGBA, GridError, Scene, VisualLoop, grid_shape
from .diagnostics import array, log_line, status
from .inputs import CheckedInputs
from .messages import MessageError, decode_belief, decode_plan_info, decode_true_state, wire_bounds
from .params import (
    NodeConfigError,
    ParameterNode,
    accept_integers_for_doubles,
    declare_double,
    declare_model_file,
    declare_optional_array,
    descriptor,
    optional_array,
)
from .qos import LATCHED_QOS, STREAM_QOS
from .runtime import callback, config_errors, main_for

#: Marker namespaces (``Marker.ns``) of the bars, the true state and the text.
BARS_NS, TRUE_NS, TEXT_NS = "belief", "true_state", "decision"
#: The bars' footprint as a share of the spacing between them.
BAR_WIDTH = 0.8


def _rgba(c) -> ColorRGBA:
    return ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))


def markers(scene: Scene, header: Header, spacing: float) -> MarkerArray:
    """``scene`` as a MarkerArray (module docstring): a CUBE per state (id = state, ns ``belief``)
    standing on z = 0 with its height the bar's (at least 1 mm, so a zero stays visible as a
    plate), a SPHERE over the true state's bar (ns ``true_state``; DELETE when it is not known)
    and a TEXT_VIEW_FACING with the scene's text (ns ``decision``)."""
    out = MarkerArray()
    width = BAR_WIDTH * spacing
    for bar in scene.bars:
        h = max(bar.height, 0.001)
        out.markers.append(Marker(
            header=header, ns=BARS_NS, id=bar.state, type=Marker.CUBE, action=Marker.ADD,
            pose=Pose(position=Point(x=bar.x, y=bar.y, z=h / 2), orientation=Quaternion(w=1.0)),
            scale=Vector3(x=width, y=width, z=h), color=_rgba(bar.rgba), frame_locked=False,
            text=f"state {bar.state}: {bar.probability:.4f}"))
    true = Marker(header=header, ns=TRUE_NS, id=0, type=Marker.SPHERE)
    if scene.true_state is None:
        true.action = Marker.DELETE
    else:
        bar = scene.bars[scene.true_state]
        true.action = Marker.ADD
        true.pose = Pose(position=Point(x=bar.x, y=bar.y, z=bar.height + 0.4 * spacing), orientation=Quaternion(w=1.0))
        true.scale = Vector3(x=0.5 * spacing, y=0.5 * spacing, z=0.5 * spacing)
        true.color = _rgba(TRUE_RGBA)
        true.text = f"true state {scene.true_state}"
    out.markers.append(true)
    x, y, z = scene.text_xyz
    out.markers.append(Marker(
        header=header, ns=TEXT_NS, id=0, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
        pose=Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(w=1.0)),
        scale=Vector3(z=0.35 * spacing), color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0), text=scene.text))
    return out


def occupancy_grid(scene: Scene, header: Header, spacing: float) -> OccupancyGrid:
    """A grid scene as an OccupancyGrid: ``cols`` wide, ``rows`` high, one cell per state
    (row-major from the origin, as the bars), resolution ``spacing``, the scene's occupancy values."""
    rows, cols = scene.grid
    info = MapMetaData(map_load_time=header.stamp, resolution=float(spacing), width=cols, height=rows,
                       origin=Pose(orientation=Quaternion(w=1.0)))
    return OccupancyGrid(header=header, info=info, data=list(scene.occupancy))


class BeliefVisualizer(ParameterNode):
    """The visualiser node (module docstring)."""

    def __init__(self, node_name: str = "belief_visualizer", **kwargs):
        super().__init__(node_name, **kwargs)
        accept_integers_for_doubles(self)
        d = descriptor
        self.model_file = declare_model_file(self)
        self.declare_parameter("frame_id", "map", d(
            "Frame of the markers and the grid (RViz's Fixed Frame, or a frame your TF tree has)", read_only=True))
        declare_double(self, "publish_period", 0.1, d(
            "At most one MarkerArray (and OccupancyGrid) per this many seconds, when something changed",
            read_only=True, float_range=(0.01, 60.0)))
        declare_double(self, "bar_height", 1.0, d("Height (m) of the bar of a state of probability 1",
                                                  read_only=True, float_range=(0.001, 1000.0)))
        declare_double(self, "spacing", 1.0, d("Distance (m) between neighbouring bars; a grid cell's size",
                                               read_only=True, float_range=(0.001, 1000.0)))
        declare_optional_array(self, "grid_shape", "integer",
                               "[rows, cols] of a grid model whose file does not say its grid (rows * cols = S); "
                               "unset: the model's own, or bars in a row")
        value = self.get_parameter
        self.frame_id = value("frame_id").value
        self.spacing = value("spacing").value
        with config_errors():
            self.model = load_model_file(self.model_file)
        try:
            grid = grid_shape(self.model, optional_array(self, "grid_shape"))
        except GridError as exc:
            raise NodeConfigError(str(exc)) from None
        self.lock = threading.Lock()
        self.loop = VisualLoop(self.model, grid, now=time.monotonic(), spacing=self.spacing,
                               bar_height=value("bar_height").value)
        self.checked = CheckedInputs(self, self.lock, lambda: self.loop.health, self.log)
        bounds = wire_bounds(self.model.S)
        S = self.model.S
        for topic, kind, decode, apply in (
                ("belief", Float64MultiArray, lambda m: decode_belief(m, S), self.loop.belief),
                ("plan_info", Float64MultiArray, decode_plan_info, self.loop.plan_info),
                ("true_state", Int64MultiArray, decode_true_state, lambda s, now: self.loop.true_state(*s, now))):
            self.checked.subscribe(topic, kind, topic, STREAM_QOS,
                                   lambda msg, t=topic, dec=decode, app=apply: self._on_message(t, dec, app, msg),
                                   bound=bounds[topic], on_bad=lambda problem, t=topic: self._call(
                                       self.loop.rejected, t, problem))
        self.markers_pub = self.create_publisher(MarkerArray, "belief_markers", LATCHED_QOS)
        self.grid_pub = self.create_publisher(OccupancyGrid, "belief_grid", LATCHED_QOS) if grid else None
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(value("publish_period").value, self._publish, clock=steady)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        shape = f"grid {grid[0]} x {grid[1]} on belief_grid" if grid else "no grid"
        self.get_logger().info(f"{self.model.describe()}; belief_markers in frame {self.frame_id!r}; {shape}")

    def log(self, logs: Iterable[Log]) -> None:
        logger = self.get_logger()
        for line in logs:
            log_line(logger, line)

    def _call(self, method, *args) -> None:
        with self.lock:
            method(*args, time.monotonic())
            logs = self.loop.health.drain_logs()
        self.log(logs)

    @callback
    def _on_message(self, topic: str, decode, apply, msg) -> None:
        try:
            sample = decode(msg)
        except MessageError as exc:
            self._call(self.loop.rejected, topic, str(exc))
            return
        self._call(apply, sample)

    def header(self) -> Header:
        stamp: Time = self.get_clock().now().to_msg()
        return Header(stamp=stamp, frame_id=self.frame_id)

    @callback
    def _publish(self) -> None:
        with self.lock:
            scene = self.loop.scene() if self.loop.changed else None
        if scene is None:
            return
        header = self.header()
        self.markers_pub.publish(markers(scene, header, self.spacing))
        if self.grid_pub is not None:
            self.grid_pub.publish(occupancy_grid(scene, header, self.spacing))

    @callback
    def _publish_diagnostics(self) -> None:
        self.checked.look_at_graphs()
        self.checked.takeovers()
        with self.lock:
            r = self.loop.report(time.monotonic())
        self.diag_pub.publish(array(self, status(f"{self.get_name()}: visualisation", self.model.name, r.level,
                                                 r.message, r.values)))


def main(args=None) -> None:
    main_for([BeliefVisualizer])


if __name__ == "__main__":
    main()
