"""The thin ROS 2 nodes (the only place rclpy is imported): messages and parameters in, core calls out.

Executables: ``target_simulator``, ``belief_filter``, ``planner`` and ``closed_loop`` (all three in
one process); ``demo`` (``make demo``) runs the three as processes and prints a live table.
Message layouts: :mod:`.messages`; the loop's rules: ``core/loop/`` (each node is a shell around
one of its loops, :mod:`.loop_node`) and ``core/filter.py``; docs/ros.md.
"""
