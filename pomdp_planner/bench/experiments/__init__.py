"""The paper's experiments: ``run_all`` writes ``RESULTS.md`` and ``img/*.png`` into a folder.

No rclpy: it imports the core and ``bench/search.py``, ``bench/paper.py`` only. Plots need
matplotlib (optional extra ``experiments``), POUCT needs pomdp-py (optional extra ``bench``);
both are imported lazily. Entry points: ``make experiments`` and
``pomdp-planner bench all [--output DIR] [--quick]``.
"""

from .runner import FULL, QUICK, SECTIONS, ExperimentConfig, run_all

__all__ = ["FULL", "QUICK", "SECTIONS", "ExperimentConfig", "run_all"]
