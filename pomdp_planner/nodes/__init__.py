"""The thin ROS 2 nodes (the only place rclpy is imported): messages and parameters in, core calls out.

Executables: ``target_simulator``, ``belief_filter``, ``planner`` and ``closed_loop`` (all three in
one process); ``demo`` (``make demo``) runs the three as processes and prints a live table.
Message layouts: :mod:`.messages`; epochs and the filter's rules: ``core/epoch_buffer.py`` and
``core/filter.py``; README ``## ROS 2 nodes``.
"""
