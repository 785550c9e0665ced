"""The one check for each kind of value a user gives: integers, numbers, yes/no flags, choices.

Every check is strict about types: an integer is an ``int`` or a numpy integer, never a bool, a
float (``3.0``) or a string; a number is an int or a float, never a bool or a string. A failed
check raises the given error class (:class:`~.errors.OptionError` unless the caller says
otherwise) with one line: ``"<field>: must be <what>, got <value>"``.

Text from a command line (``--option KEY=VALUE``) is turned into a value by :func:`option_value`:
only plain ASCII decimal digits make an integer (``1_0``, ``٣`` or ``0x10`` stay text, which the
integer check then refuses). :func:`integer` and :func:`number` read a count or a number typed as
an option's value the same way (an argparse ``type``: ``ValueError`` for other text), so
``--depth 1_0`` is refused although Python's ``int`` reads it as 10.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import InputError, OptionError, short_repr

#: Words :func:`parse_flag` reads as yes and as no (any case).
FLAG_WORDS = {"1": True, "true": True, "yes": True, "on": True, "0": False, "false": False, "no": False, "off": False}

_DECIMAL_INT = re.compile(r"[-+]?[0-9]+")
_DECIMAL_FLOAT = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


def is_integer(value: Any) -> bool:
    """``value`` is an integer: an ``int`` or a numpy integer, not a bool."""
    return isinstance(value, (numbers.Integral, np.integer)) and not isinstance(value, (bool, np.bool_))


def number_text(x: float) -> str:
    """A bound as a message shows it: integral values without a decimal point (``50``, ``0.001``)."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def span_text(lo: float, hi: float) -> str:
    """``lo..hi`` as a message shows it (:func:`number_text`)."""
    return f"{number_text(lo)}..{number_text(hi)}"


def _want(what: str, lo: float | None, hi: float | None) -> str:
    if lo is not None and hi is not None:
        return f"{what} in {span_text(lo, hi)}"
    if lo is not None:
        return f"{what} >= {number_text(lo)}"
    if hi is not None:
        return f"{what} <= {number_text(hi)}"
    return what


def check_int(value: Any, field: str, lo: int | None = None, hi: int | None = None, *,
              error: type[InputError] = OptionError, note: str = "") -> int:
    """``value`` as an ``int`` after checking it is an integer (:func:`is_integer`) in ``lo..hi``
    (inclusive; ``None``: no limit on that side); else ``error`` naming ``field`` (``note`` is
    appended to the message, e.g. what the values mean)."""
    if not is_integer(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
        raise error(f"{field}: must be {_want('an integer', lo, hi)}, got {short_repr(value)}"
                    + (f" {note}" if note else ""))
    return int(value)


def check_number(value: Any, field: str, lo: float | None = None, hi: float | None = None, *,
                 error: type[InputError] = OptionError, what: str = "a number") -> float:
    """``value`` as a finite ``float`` after checking it is a number (int or float, not a bool or a
    string) in ``lo..hi`` (inclusive; ``None``: open); else ``error`` naming ``field``."""
    ok = isinstance(value, (numbers.Real, np.floating, np.integer)) and not isinstance(value, (bool, np.bool_))
    try:
        x = float(value) if ok else math.nan
    except OverflowError:
        x = math.nan
    if not math.isfinite(x) or (lo is not None and x < lo) or (hi is not None and x > hi):
        raise error(f"{field}: must be {_want(what, lo, hi)}, got {short_repr(value)}")
    return x


def parse_flag(value: Any, field: str, *, error: type[InputError] = OptionError) -> bool:
    """A yes/no value: a bool, the integers 1 and 0, or one of :data:`FLAG_WORDS` (any case)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if is_integer(value) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in FLAG_WORDS:
        return FLAG_WORDS[value.strip().lower()]
    raise error(f"{field}: must be 1/0 (true/false, yes/no, on/off), got {short_repr(value)}")


def check_choice(value: Any, choices: Sequence[str], field: str, *, error: type[InputError] = OptionError) -> str:
    """``value`` if it is one of ``choices`` (strings), else ``error`` naming ``field`` and the choices."""
    if not isinstance(value, str) or value not in choices:
        raise error(f"{field}: expected one of {', '.join(choices)}, got {short_repr(value)}")
    return value


def option_value(text: str) -> int | float | str:
    """The value of a ``KEY=VALUE`` option typed on a command line: an ``int`` for plain ASCII
    decimal digits (optional sign), a ``float`` for a plain ASCII decimal number, else ``text``."""
    t = text.strip()
    if len(t) <= 64 and _DECIMAL_INT.fullmatch(t):
        return int(t)
    if len(t) <= 64 and _DECIMAL_FLOAT.fullmatch(t):
        return float(t)
    return text


def integer(text: str) -> int:
    """An integer typed on a command line, read by :func:`option_value` (plain ASCII decimal digits,
    an optional sign); ``ValueError`` for any other text (an argparse ``type``)."""
    value = option_value(text)
    if not isinstance(value, int):
        raise ValueError(f"not an integer: {short_repr(text)}")
    return value


def number(text: str) -> float:
    """A number typed on a command line, read by :func:`option_value` (a plain ASCII decimal number);
    ``ValueError`` for any other text, NaN and infinity included (an argparse ``type``)."""
    value = option_value(text)
    if isinstance(value, str) or not math.isfinite(value):
        raise ValueError(f"not a number: {short_repr(text)}")
    return float(value)
