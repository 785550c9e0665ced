"""Test-suite configuration shared by every test module.

Hypothesis: no per-example deadline (CI runs on 2 shared cores, where timing varies by 10x),
and in CI (``CI`` set) a derandomized profile, so a CI run is reproducible and a failure is
reproduced by running the same command again.
"""

import os

from hypothesis import HealthCheck, settings

settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("ci", parent=settings.get_profile("dev"), derandomize=True, print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "dev")


import pytest  # noqa: E402

from pomdp_planner.core import search_kernel  # noqa: E402


@pytest.fixture(params=["c", "numpy"])
def engine(request) -> str:
    """The planner's two search engines (``Planner(kernel=...)``): the compiled kernel (skipped where
    it is not installed; test_search_kernel.py fails then under ``make test``) and the numpy reference."""
    if request.param == "c" and not search_kernel.available():
        pytest.skip(search_kernel.load()[1])
    return request.param
