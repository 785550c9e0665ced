#!/usr/bin/env python3
"""Search benchmark (paper Table II, timings, throughput): ``python bench/search_bench.py [--quick] [--json FILE]``.

The same as ``pomdp-planner bench search``; the code is ``pomdp_planner/bench/search_bench.py``.
Runs from a source checkout without installing (the repository root is put on ``sys.path``).
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pomdp_planner.bench.search_bench import main

if __name__ == "__main__":
    sys.exit(main())
