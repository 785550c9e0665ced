"""pomdp_planner: online sensor management with myopic policy bounds (Lauri et al.).

``pomdp_planner.core`` is the pure numerical core (numpy, scipy, clarabel; never rclpy).
``pomdp_planner.nodes`` holds the thin ROS 2 nodes built on top of it.
"""

__version__ = "0.1.0"
