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
