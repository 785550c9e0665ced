"""``measurement_adapter``: a real sensor's output as the loop's observations.

Topics (relative names, remappable; layouts: :mod:`.messages`, QoS: :mod:`.qos`):

* subscribes ``measurement`` (``SENSOR_QOS``: best effort, so it matches any driver) of the type
  ``input_type`` names: ``std_msgs/Float64`` (``float64``), ``sensor_msgs/Range`` (``range``: its
  ``range``), ``geometry_msgs/PointStamped`` (``point``: the coordinate or norm ``point_field``
  names) or ``std_msgs/Float64MultiArray`` (``likelihood``: ``S`` values, one per state), and
  ``action`` (``Int64MultiArray [epoch, action_priority]``, ``STREAM_QOS``);
* publishes ``observation`` (``Int64MultiArray [epoch, action_priority, observation]``) for a
  scalar input, binned by ``bin_edges``, or ``likelihood`` (soft evidence, ``Float64MultiArray``
  with the epoch and priority in its layout) for a likelihood input, both ``STREAM_QOS``, and
  ``/diagnostics`` (``measurement_adapter: measurements``).

Every rule (values, limits, staleness, ordering, binning, which action a reading answers, joining,
re-sync, re-send) is the core's :class:`~pomdp_planner.core.loop.AdapterLoop`; its times are the
node's ROS clock, the clock of the stamps. Parameters, topics and diagnostics: docs/ros.md.
"""

from __future__ import annotations

from geometry_msgs.msg import PointStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import Range
from std_msgs.msg import Float64, Float64MultiArray, Int64MultiArray

from ..core.io.sensors import load_model_file, load_observation_model
from ..core.loop import INPUT_TYPES, POINT_FIELDS, AdapterLoop, AdapterOutput, point_value
from .loop_node import LoopNode, OneShot
from .messages import (
    MessageError,
    WireBound,
    encode_likelihood,
    encode_observation,
    max_wire_bytes,
    sensor_likelihood_values,
)
from .params import declare_double, declare_optional_array, descriptor, optional_array
from .qos import SENSOR_QOS, STREAM_QOS
from .runtime import callback, config_errors, main_for

#: The message type of each ``input_type``.
INPUT_MESSAGES = {"float64": Float64, "range": Range, "point": PointStamped, "likelihood": Float64MultiArray}
#: The largest scalar reading accepted (bytes, serialized): a ``Range`` or ``PointStamped`` with a
#: ``frame_id`` of up to 256 characters (rule "Bounded samples"); a likelihood: ``S`` values.
MAX_SENSOR_BYTES = 4 + 8 + 4 + 256 + 1 + 3 + 32


def _stamp(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


class MeasurementAdapter(LoopNode):
    """Measurement adapter node (see module docstring)."""

    task = "measurements"

    def __init__(self, node_name: str = "measurement_adapter", **kwargs):
        super().__init__(node_name, **kwargs)
        d = descriptor
        self.declare_parameter("input_type", "float64", d(
            "What the sensor publishes on 'measurement': float64 (std_msgs/Float64), range (sensor_msgs/Range), "
            "point (geometry_msgs/PointStamped) or likelihood (std_msgs/Float64MultiArray, one value per state)",
            read_only=True, constraints=f"one of {', '.join(INPUT_TYPES)}"))
        self.declare_parameter("point_field", "norm", d(
            "input_type point: the coordinate x, y or z of the point, or its Euclidean norm", read_only=True,
            constraints=f"one of {', '.join(POINT_FIELDS)}"))
        declare_optional_array(self, "bin_edges", "double",
                               "Scalar inputs: Z - 1 increasing edges; a reading x is observation #{k: edge_k <= x}")
        self.declare_parameter("observation_model_file", "", d(
            "Model file whose observation matrix the filter applies to this sensor's topic ('' = the model's own): "
            "its Z is what bin_edges must fit", read_only=True))
        declare_double(self, "max_age", 1.0, d(
            "Drop a stamped reading more than this many seconds older (or newer) than the node's clock (0 = no check)",
            float_range=(0.0, 3600.0)))
        declare_double(self, "settle_time", 0.0, d(
            "Seconds after an action is heard before a reading (by its stamp) may answer it", float_range=(0.0, 60.0)))
        self.add_post_set_parameters_callback(self._apply_parameters)

        value = self.get_parameter
        with config_errors():
            self.model = load_model_file(self.model_file)
            O = load_observation_model(self.model, value("observation_model_file").value, "observation_model_file")
            loop = AdapterLoop(self.model, self.live, now=self.now(), input_type=value("input_type").value,
                               bin_edges=optional_array(self, "bin_edges"), num_observations=O.shape[2],
                               point_field=value("point_field").value, max_age=value("max_age").value,
                               settle_time=value("settle_time").value, input_name="measurement")
        if loop.soft:
            self.out_pub = self.create_publisher(Float64MultiArray, "likelihood", STREAM_QOS)
        else:
            self.out_pub = self.create_publisher(Int64MultiArray, "observation", STREAM_QOS)
        limit = max_wire_bytes(self.model.S, 1) if loop.soft else MAX_SENSOR_BYTES
        self.input_sub = self.subscribe_input(
            "measurement", INPUT_MESSAGES[loop.input_type], "measurement", SENSOR_QOS, self._on_measurement,
            kind="measurement",
            bound=WireBound(limit, f"a {loop.input_type} reading"), on_bad=lambda problem: self.call(
                self.loop.rejected_measurement, problem)).sub
        self.subscribe_actions(STREAM_QOS)
        self._join = OneShot(self, self._on_join)
        self.run(loop)

    def now(self) -> float:
        """The node's ROS clock (seconds): the clock sensor stamps are on."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _apply_parameters(self, params: list[Parameter]) -> None:
        with self.lock:
            for p in params:
                if p.name in ("max_age", "settle_time"):
                    setattr(self.loop, p.name, p.value)

    @callback
    def _on_measurement(self, msg) -> None:
        kind = self.loop.input_type
        if kind == "float64":
            self.call(self.loop.measurement, msg.data)
        elif kind == "range":
            self.call(self.loop.measurement, msg.range, stamp=_stamp(msg.header), limits=(msg.min_range, msg.max_range))
        elif kind == "point":
            p = msg.point
            self.call(self.loop.measurement, point_value(p.x, p.y, p.z, self.loop.point_field),
                      stamp=_stamp(msg.header))
        else:
            try:
                values = sensor_likelihood_values(msg, self.model.S)
            except MessageError as exc:
                self.call(self.loop.rejected_measurement, str(exc))
                return
            self.call(self.loop.measurement, values)

    @callback
    def _on_join(self) -> None:
        self.call(self.loop.join_due)

    def emit(self, out: AdapterOutput) -> None:
        for s in out.samples:
            if self.loop.soft:
                self.out_pub.publish(encode_likelihood(s.epoch, s.priority, s.likelihood))
            else:
                self.out_pub.publish(encode_observation(s.epoch, s.priority, s.observation))
        self.log(out.logs)
        self._join.arm(out.join_at, self.now())


def main(args=None) -> None:
    main_for([MeasurementAdapter])


if __name__ == "__main__":
    main()
