"""Measurement code users run, shipped with the package (so ``pomdp-planner bench ...`` works installed).

What it is for: reproducing the paper's experiments and measuring your own models
(docs/benchmarks.md). Outputs go to a file or folder the user names, or the current directory.

* :mod:`.search`: the search benchmark (paper Table II, timings, throughput):
  ``pomdp-planner bench search`` or ``python -m pomdp_planner.bench.search``.
* :mod:`.experiments`: every experiment of the paper and the peer comparison, writing
  ``RESULTS.md`` and plots (``pomdp-planner bench all``; ``make experiments`` refreshes docs/).
* :mod:`.lp`: the bound LPs of Theorem 2 (``core/bounds.py``), the structured solver against
  Clarabel: ``python -m pomdp_planner.bench.lp``.
* :mod:`.mcts`: the belief-space MCTS (simulations/s, tuning, closed loop): ``python -m pomdp_planner.bench.mcts``.
* :mod:`.references`: the reference policies regrets are measured against.
* :mod:`.paper`: the paper's published numbers, shown beside ours.
* ``ros/``: benchmarks of the ROS 2 nodes (they import rclpy; the only part of ``bench`` that may
  import ``pomdp_planner.nodes``).

Development tooling (the model search, the model-file fuzzer) lives in ``tools/`` of the source
tree and is not installed. Everything here imports the core (and ``.paper``); nothing in the
core, the CLI's other commands or the nodes imports it.
"""
