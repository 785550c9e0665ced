"""Budgeted multi-target sensor management: K independent targets, one effort budget per epoch.

* :mod:`.problem`: the problem (models, efforts, budget; exact rational efforts).
* :mod:`.knapsack`: the exact multiple-choice knapsack over targets.
* :mod:`.dual`: the dual bound and the search for the price ``lambda``.
* :mod:`.planner`: the planner (per-target branch-and-bound at a price, knapsack, dual bound, gap).
* :mod:`.joint_exact`: the exact joint expectimax, written independently of the decomposition.
* :mod:`.policies`: the joint policies (the planner and the baselines) by name.
* :mod:`.simulate`: closed-loop runs of a joint policy with common random numbers.

docs/multitarget.md is the user guide, docs/THEORY.md ("Several targets") the proofs.
"""
