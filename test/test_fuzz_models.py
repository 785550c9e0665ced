"""Property test: mutated model files load or fail cleanly, never anything else; and a model that
loads is one the entry points handle.

The mutations are those of the corpus generator ``tools/fuzz_models.py`` (byte
flips, truncation, binary junk, re-encoding, huge and non-finite numbers, blown-up sizes, type
swaps on the parsed YAML tree, alias bombs, deep nesting, ``.POMDP`` header bombs, long tokens),
applied to the shipped models, their explicit matrix form and their ``.POMDP`` exports. Every
case must end in a valid model or in a ``ModelError`` of one line that names the file.

Bounded resources without timing asserts: the address space of the process is limited to its
size plus :data:`HEADROOM` while the cases run, so a case that tried to allocate more fails with
``MemoryError`` (not a clean outcome); ``MAX_MODEL_BYTES`` is lowered to 16 MiB so that blown-up
sizes exercise the refusals rather than build big models (each case then stays fast).
"""

from __future__ import annotations

import random
import resource
import tempfile
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pomdp_planner.core import model as model_module
from pomdp_planner.core.errors import InputError, InputWarning
from pomdp_planner.core.io import cassandra
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import ModelError
from tools.fuzz_models import (
    MUTATIONS,
    VALUE_MUTATIONS,
    classify,
    exercise,
    mutate,
    mutations_for,
    seeds,
)

SEEDS = seeds()
CASES = [(i, name) for i, s in enumerate(SEEDS) for name in mutations_for(s[1])]
VALUE_CASES = [(i, name) for i, name in CASES if name in VALUE_MUTATIONS]
#: Address space allowed on top of the process's size while the cases run.
HEADROOM = 1 << 30
#: Model budget while fuzzing (the refusal path is the same at any budget).
FUZZ_MODEL_BYTES = 16 * 2**20
TMP = Path(tempfile.mkdtemp(prefix="pomdp_planner_fuzz_"))


def _vm_size() -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))


@pytest.fixture(scope="module")
def bounded_process():
    """Lower ``MAX_MODEL_BYTES`` and cap the address space for the duration of the module."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(model_module, "MAX_MODEL_BYTES", FUZZ_MODEL_BYTES)
        mp.setattr(cassandra, "MAX_MODEL_BYTES", FUZZ_MODEL_BYTES)
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        limit = _vm_size() + HEADROOM
        if hard != resource.RLIM_INFINITY:
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
        try:
            yield
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def test_every_mutation_applies_to_some_seed():
    assert {name for _, name in CASES} == set(MUTATIONS)
    assert {s[1] for s in SEEDS} == {"yaml", "pomdp"} and len(SEEDS) >= 6


@settings(max_examples=3000, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(case=st.sampled_from(CASES), seed=st.integers(0, 2**32 - 1))
def test_mutated_model_files_load_or_fail_cleanly(bounded_process, case, seed):
    index, name = case
    s = SEEDS[index]
    data = mutate(s, name, random.Random(seed))
    path = TMP / f"case.{'yaml' if s[1] == 'yaml' else 'POMDP'}"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # a numpy warning would reach the user
        warnings.simplefilter("ignore", InputWarning)  # a renormalised peer row: said on purpose
        outcome, detail = classify(path, load_model, ModelError)
    assert outcome in ("valid", "clean error"), f"{name} on {s[0]} ({s[1]}), seed {seed}: {outcome}: {detail}"


def _write(case: tuple[int, str], seed: int) -> Path:
    index, name = case
    s = SEEDS[index]
    path = TMP / f"case.{'yaml' if s[1] == 'yaml' else 'POMDP'}"
    path.write_bytes(mutate(s, name, random.Random(seed)))
    return path


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=st.sampled_from(VALUE_CASES), seed=st.integers(0, 2**32 - 1))
def test_every_model_that_loads_is_one_the_entry_points_handle(bounded_process, case, seed):
    """Value mutations (huge weights and rewards, subnormal epsilon, discount 1, YAML 1.1 numbers,
    duplicate keys, rows off 1 by about pomdp-solve's tolerance): a model that loads goes through the
    gate, a depth-2 search, the bound LP and a simulation with finite values or a one-line refusal,
    and no numpy warning."""
    path = _write(case, seed)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", InputWarning)
        outcome, detail = classify(path, load_model, ModelError, exercise, InputError)
    assert outcome in ("valid", "clean error"), f"{case[1]} on {SEEDS[case[0]][0]}, seed {seed}: {outcome}: {detail}"


def test_the_value_mutations_reach_every_kind_of_seed():
    assert {SEEDS[i][1] for i, _ in VALUE_CASES} == {"yaml", "pomdp"}
    assert {"hostile_value", "yaml11_number", "duplicate_key", "row_drift"} <= {name for _, name in VALUE_CASES}
