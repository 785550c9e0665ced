"""Numbers a user types (core/io/numbers.py): exactly the plain ASCII forms, never Python's extras."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pomdp_planner.core.io.numbers import integer, number, parse_float, parse_int


@given(st.integers(min_value=-(10**30) + 1, max_value=10**30 - 1))
def test_every_plain_integer_reads_as_itself(n: int) -> None:
    assert parse_int(str(n)) == n and parse_int(f"+{n}" if n >= 0 else str(n)) == n
    assert parse_float(str(n)) == float(n)


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_every_float_python_prints_reads_back(x: float) -> None:
    assert parse_float(repr(x)) == x and parse_float(f"{x:e}") == float(f"{x:e}")


@pytest.mark.parametrize("text", ["1_0", "1_000", "\u0661\u0660", "\uff11", "\u00b2", " 3", "3 ", "", "+", "0x1f",
                                  "1e3", "3.0", "1" * 31, "٣", "𝟑"])
def test_python_accepts_these_as_ints_or_they_are_not_integers(text: str) -> None:
    assert parse_int(text) is None
    with pytest.raises(ValueError, match="not an integer"):
        integer(text)


@pytest.mark.parametrize("text", ["1_0", "0_1", "1e1_0", "\u0661.5", "\uff11", "1..2", ".", "e3", "1e", "0x1p3",
                                  "infinit", " 1", ""])
def test_python_accepts_some_of_these_as_floats_but_they_are_not_numbers(text: str) -> None:
    assert parse_float(text) is None
    with pytest.raises(ValueError, match="not a number"):
        number(text)


@pytest.mark.parametrize(("text", "value"), [("1.", 1.0), (".5", 0.5), ("-2.5E-3", -2.5e-3), ("1e400", math.inf),
                                             ("INF", math.inf), ("-Infinity", -math.inf)])
def test_the_plain_forms(text: str, value: float) -> None:
    assert parse_float(text) == value
    assert math.isnan(parse_float("nan")) and math.isnan(number("NaN"))
