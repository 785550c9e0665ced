"""Benchmarks that ship with the package (so ``pomdp-planner bench ...`` works when installed).

``bench/`` at the repository root holds the documented entry scripts, e.g.
``python bench/search_bench.py``.
"""
