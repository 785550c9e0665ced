"""Development tooling of pomdp_planner, run from a checkout (``python -m tools.<name>``); not installed.

* :mod:`.lookahead_models`: the search for models on which lookahead pays (docs/MODEL_SEARCH.md).
* :mod:`.fuzz_models`: the mutation fuzzer of the model-file loader.
"""
