"""Measurement code, all of it, shipped with the package (so ``pomdp-planner bench ...`` works installed).

* :mod:`.search`: the search benchmark (paper Table II, timings, throughput):
  ``pomdp-planner bench search`` or ``python -m pomdp_planner.bench.search``.
* :mod:`.experiments`: every experiment of the paper and the peer comparison, writing
  docs/RESULTS.md (``pomdp-planner bench all``, ``make experiments``).
* :mod:`.lp`: the bound LPs of Theorem 2 (``core/bounds.py``), the default solver against the
  previous Clarabel path: ``python -m pomdp_planner.bench.lp``.
* :mod:`.mcts`: the belief-space MCTS (simulations/s, tuning, closed loop): ``python -m pomdp_planner.bench.mcts``.
* :mod:`.lookahead_models`: the search for models where lookahead pays (issue 12):
  ``python -m pomdp_planner.bench.lookahead_models``.
* :mod:`.fuzz_models`: the mutation corpus of malformed model files and its runner.
* :mod:`.paper`: the paper's published numbers, shown beside ours.
* ``ros/``: benchmarks of the ROS 2 nodes (they import rclpy; the only part of ``bench`` that may
  import ``pomdp_planner.nodes``).

Everything here imports the core (and ``.paper``); nothing in the core, the CLI's other commands
or the nodes imports it.
"""
