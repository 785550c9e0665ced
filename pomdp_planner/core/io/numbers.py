"""Numbers a user types (command-line options, ``KEY=VALUE`` policy options): plain ASCII only.

Python's ``int`` and ``float`` accept more than a user means: digit-group underscores
(``int("1_0") == 10``), any Unicode decimal digit (``int("\\u0661\\u0660") == 10``, full-width
digits), surrounding whitespace. A count or a number given on a command line is therefore read
here, by two patterns:

* an integer: an optional sign and 1 to 30 ASCII digits (:data:`INTEGER`);
* a number: an optional sign, ASCII digits with at most one decimal point, an optional
  exponent, or ``inf``/``infinity``/``nan`` in any case (:data:`NUMBER`); whether a non-finite
  value is allowed is the caller's rule.

:func:`parse_int` and :func:`parse_float` return ``None`` for anything else; :func:`integer`
and :func:`number` raise ``ValueError`` instead (usable as an argparse ``type``: the error names
the option and quotes the text).
"""

from __future__ import annotations

import re

#: An integer as a user types it: optional sign, 1-30 ASCII digits (no underscores, no spaces).
INTEGER = re.compile(r"[+-]?[0-9]{1,30}")
#: A number as a user types it (ASCII; see the module docstring).
NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf|infinity|nan)", re.IGNORECASE)


def parse_int(text: str) -> int | None:
    """``text`` as an int if it is :data:`INTEGER`, else ``None``."""
    return int(text) if isinstance(text, str) and INTEGER.fullmatch(text) else None


def parse_float(text: str) -> float | None:
    """``text`` as a float if it is :data:`NUMBER` (an integer included), else ``None``."""
    return float(text) if isinstance(text, str) and NUMBER.fullmatch(text) else None


def integer(text: str) -> int:
    """:func:`parse_int`, raising ``ValueError`` for text that is not an integer."""
    value = parse_int(text)
    if value is None:
        raise ValueError(f"not an integer (ASCII digits): {text!r}")
    return value


def number(text: str) -> float:
    """:func:`parse_float`, raising ``ValueError`` for text that is not a number."""
    value = parse_float(text)
    if value is None:
        raise ValueError(f"not a number: {text!r}")
    return value
