"""Counts and numbers typed on a command line (core.checks.integer, number): the plain ASCII forms
only, never Python's extras (``int("1_0") == 10``, ``int("\\u0661\\u0660") == 10``)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pomdp_planner.core.checks import integer, number


@given(st.integers(min_value=-(10**30), max_value=10**30))
def test_every_plain_integer_reads_as_itself(n: int) -> None:
    assert integer(str(n)) == n and number(str(n)) == float(n)
    if n >= 0:
        assert integer(f"+{n}") == n


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_every_finite_float_python_prints_reads_back(x: float) -> None:
    assert number(repr(x)) == x and number(f"{x:e}") == float(f"{x:e}")


@pytest.mark.parametrize("text", ["1_0", "1_000", "\u0661\u0660", "\uff11", "\u00b2", "\U0001d7d1", "", "+", "0x1f",
                                  "1e3", "3.0", "three"])
def test_what_python_may_read_as_an_int_is_not_an_integer_here(text: str) -> None:
    with pytest.raises(ValueError, match="not an integer"):
        integer(text)


@pytest.mark.parametrize("text", ["1_0", "0_1", "1e1_0", "\u0661.5", "\uff11", "1..2", ".", "e3", "1e", "0x1p3",
                                  "nan", "inf", "-Infinity", "1e400", ""])
def test_what_python_may_read_as_a_float_is_not_a_number_here(text: str) -> None:
    with pytest.raises(ValueError, match="not a number"):
        number(text)


@pytest.mark.parametrize(("text", "value"), [("1.", 1.0), (".5", 0.5), ("-2.5E-3", -2.5e-3), ("7", 7.0)])
def test_the_plain_forms(text: str, value: float) -> None:
    assert number(text) == value
