"""``closed_loop``: the three nodes in one process and one ``MultiThreadedExecutor``.

Equivalent to starting ``target_simulator``, ``belief_filter`` and ``planner`` separately (same
node names, topics and parameters; a ``--params-file`` applies to each node by name, or to all
with ``/**:``), for tests and for users without three terminals::

    ros2 run pomdp_planner closed_loop --ros-args --params-file config/closed_loop_s8.yaml
"""

from __future__ import annotations

from .belief_filter import BeliefFilter
from .planner import PlannerNode
from .runtime import main_for
from .target_simulator import TargetSimulator


def main(args=None) -> None:
    main_for([TargetSimulator, BeliefFilter, PlannerNode])


if __name__ == "__main__":
    main()
