"""Benchmarks that ship with the package (so ``pomdp-planner bench ...`` works when installed).

``bench/`` at the repository root holds the documented entry scripts, e.g.
``python bench/search_bench.py``. ``python -m pomdp_planner.bench.lp`` times the bound LPs
(``core/bounds.py``: the default solver against the previous Clarabel path).
"""
