"""QoS profiles of the node topics (docs/ros.md, "Topics")."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Two profiles, chosen by what a topic means (docs/ros.md, "Topics"). Both are reliable and
# transient-local: reliable because every node acts on every sample it gets; transient-local so
# that the start order of the nodes does not matter (the prior belief, published before a planner
# exists, and the first action reach nodes that match later) and so that transient-local readers
# (recorders, `ros2 topic echo --qos-durability transient_local`) are compatible at all: a
# volatile writer does not match a transient-local reader. Neither durability nor history depth
# costs measurable latency (docs/benchmarks.md, "Latency of the node loop").

#: Per-epoch streams where every sample matters (``action``, ``observation``, ``true_state``,
#: ``belief`` as published, ``plan_info``), for their writers and for the readers that must see
#: every epoch (the simulator's and the filter's subscriptions) or must not lose the real sample
#: to a stray one (the planner's ``belief`` subscription, which plans only the newest valid one:
#: with depth 1, one stale belief arriving between the real one and the take would replace it,
#: and the loop would stop for good). KEEP_LAST with a depth far beyond
#: how many epochs a reader can fall behind: a reliable writer keeps a sample until every reader
#: has it unless ``depth`` newer ones replace it first (then it is lost for good; with depth 1 a
#: single transport loss of an action could not be repaired once the next one was out). Not
#: KEEP_ALL: a stuck recorder must not block the loop's publishers. A late joiner gets at most the
#: last ``depth`` epochs, which the nodes' epoch checks handle (stale epochs are dropped; a
#: restarted node joins at the newest, ``core/loop``).
STREAM_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: "Latest value" (latched), depth 1: readers for which only the newest sample is useful (a
#: timer-driven simulator's ``belief`` subscription, only to learn the loop's epoch when it
#: joins) and gauges (``belief_entropy``).
LATCHED_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: For observers that record every sample of the loop (the demo's monitor, the latency probe, the
#: tests' recorder): transient-local like the writers, so they match, with a history deep enough
#: that nothing is lost while they catch up.
RECORDER_QOS = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: A real sensor's output (the measurement adapter's input): best effort and volatile, so that it
#: matches every writer (a best-effort reader matches reliable and best-effort writers, a volatile
#: reader volatile and transient-local ones; drivers usually publish with ROS's sensor-data profile,
#: best effort), and KEEP_LAST with a small depth: the adapter answers each action with one fresh
#: reading, so a backlog is worth nothing and a burst from a fast sensor replaces older samples
#: instead of queueing them.
SENSOR_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
