"""Benchmarks of the ROS 2 nodes (they import rclpy and ``pomdp_planner.nodes``), run as modules:

* ``python -m pomdp_planner.bench.ros.latency``: observation-to-action latency of the node loop.
"""
