"""What the package refuses, in three kinds, each one line that names the field and the problem.

* :class:`ModelError`: a model is malformed (a model file, a matrix, a generator field); the
  loaders start the message with the file name.
* :class:`OptionError`: an option, argument or parameter value (a depth, a seed, a time budget,
  a bound variant, a policy option) or a request the planners refuse (a search too deep or too
  large for its memory budget).
* :class:`BeliefError`: a belief, action or observation given to the filter.

All three are :class:`InputError` (a ``ValueError``): an entry point catches that one class and
prints the message as it is (the command line's exit code 2, a node's ``[FATAL]`` line). A
message is always one line: line breaks in it become spaces. Input accepted with a change
(a renormalised row of a peer model file) is an :class:`InputWarning`, one line as well.

:func:`short_repr` and :func:`kind_of` quote the offending value in a message, bounded in length
whatever the value is.
"""

from __future__ import annotations

import math
import numbers
import re
import reprlib
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

#: Longest text of a value quoted in an error message (:func:`short_repr`).
MESSAGE_VALUE_CHARS = 80


class InputError(ValueError):
    """Bad input of any kind (module docstring): one line naming the field and the problem."""

    def __init__(self, message: object = "") -> None:
        super().__init__(" ".join(str(message).splitlines()))


class ModelError(InputError):
    """A model is malformed: the message names the field and the problem (one line)."""


class OptionError(InputError):
    """An option, argument or parameter value is refused: the message names it (one line)."""


class BeliefError(InputError):
    """A belief, action or observation given to the filter is invalid (message says which)."""


class InputWarning(UserWarning):
    """Input accepted with a change the user should know of (one line), e.g. a peer model file
    whose rows were renormalised; the command line prints it as one line, as it does errors."""


@contextmanager
def prefixed(prefix: str) -> Iterator[None]:
    """Re-raise an :class:`InputError` of the block with ``prefix: `` in front of its message,
    keeping its class (used once per file: the loaders name the file this way)."""
    try:
        yield
    except InputError as exc:
        raise _with_message(exc, f"{prefix}: {exc}") from None


def _with_message(exc: InputError, message: str) -> InputError:
    try:
        new = type(exc)(message)
    except TypeError:  # a subclass with another constructor: keep the kind at least
        new = next(k for k in (ModelError, OptionError, BeliefError, InputError) if isinstance(exc, k))(message)
    return new


class _ShortRepr(reprlib.Repr):
    """``reprlib`` limits, plus integers too long to print (Python refuses > 4300 digits)."""

    def __init__(self) -> None:
        super().__init__()
        self.maxlevel, self.maxlist, self.maxtuple, self.maxdict = 3, 6, 6, 4
        self.maxstring, self.maxlong, self.maxother = MESSAGE_VALUE_CHARS, 40, MESSAGE_VALUE_CHARS

    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() > 128:
            return f"<integer of about {int(x.bit_length() * math.log10(2)) + 1} digits>"
        return repr(x)


_SHORT = _ShortRepr()


def short_repr(value: object, limit: int = MESSAGE_VALUE_CHARS) -> str:
    """``repr(value)`` cut to at most ``limit`` characters, on one line, whatever ``value`` is.

    Containers show their first few items only (:mod:`reprlib`), so quoting a value never costs
    more than a few hundred operations, and an error message never embeds an unbounded value.
    """
    try:
        text = _SHORT.repr(value)
    except Exception:
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split("\n"))
    return text if len(text) <= limit else text[:limit - 3] + "..."


#: Strings that YAML 1.1 reads as numbers and model files do not (they read plain decimal digits
#: only): binary, octal (a leading zero), hexadecimal, sexagesimal (``1:30``), digits with underscores.
_YAML11_NUMBER = re.compile(r"[-+]?(?:0b[01_]+|0o?[0-7_]+|0x[0-9a-fA-F_]+|[0-9][0-9_]*(?::[0-5]?[0-9])+(?:\.[0-9_]*)?"
                            r"|[0-9][0-9_]*_[0-9_]*(?:\.[0-9_]*)?(?:[eE][-+]?[0-9]+)?|[0-9][0-9_]*\.[0-9_]*_[0-9_]*)")


def kind_of(value: object) -> str:
    """What a parsed value is, in words, for messages ("a string '0.5'", "a list", "null"); a
    string that only YAML 1.1 reads as a number (``0b11``, ``017``, ``1:00``, ``1_000``) says so."""
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return f"a boolean ({value})"
    if isinstance(value, str):
        if len(value) <= 64 and _YAML11_NUMBER.fullmatch(value.strip()):
            return (f"a string {short_repr(value)} (a YAML 1.1 number form, not a number in model files: write "
                    "plain decimal digits)")
        return f"a string {short_repr(value)}"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    if isinstance(value, numbers.Integral):
        return f"the integer {short_repr(value)}"
    if isinstance(value, numbers.Real):
        return f"the number {short_repr(value)}"
    return f"{type(value).__name__} {short_repr(value)}"

