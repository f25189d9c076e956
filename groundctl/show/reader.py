"""Typed, checked access to one table of a show file.

Every problem becomes a :class:`ShowFileError` naming the file, the place in
it (``[limits]``, ``formation 3 'star'``) and the key in quotes, with the
value that was found: ``'size' must be a number, got string 'big'``.
"""

from __future__ import annotations

import difflib
import math
import reprlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from groundctl.errors import ShowFileError
from groundctl.show.ranges import MAX_COORD, MAX_SLOTS, Range


class _Missing:
    def __repr__(self) -> str:
        return "MISSING"


#: Marks a required key (no default).
MISSING: Final = _Missing()


def describe(value: object) -> str:
    """A TOML-flavoured description of a value for messages: ``string 'big'``, ``array``.

    Bounded whatever the value: long strings and integers are cut short, and
    arrays are shown only when short (a 900-deep nested array would overflow
    ``repr``'s recursion).
    """
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, int):
        return f"integer {value}" if abs(value) < 10**30 else _int_text(value)
    if isinstance(value, float):
        return f"number {value:g}"
    if isinstance(value, str):
        return f"string {value!r}" if len(value) <= 60 else f"string {value[:57]!r}..."
    if isinstance(value, list):
        text = _SHORT.repr(value)
        return f"array {text}" if len(text) <= 40 and "..." not in text else "array"
    if isinstance(value, dict):
        return "table"
    return f"{type(value).__name__} {_SHORT.repr(value)}"


def _short_repr() -> reprlib.Repr:
    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxstring, r.maxother = 3, 8, 40, 40
    return r


_SHORT = _short_repr()


def _int_text(value: int) -> str:
    return str(value) if abs(value) < 10**30 else f"an integer of {len(str(abs(value)))} digits"


def finite(value: object) -> bool:
    """True for a TOML integer or float that is a finite double (not NaN, inf, 10**400)."""
    if not is_number(value):
        return False
    try:
        return math.isfinite(value)  # type: ignore[arg-type]
    except OverflowError:  # an integer beyond any double
        return False


def closest(word: str, options: Iterable[str]) -> str | None:
    """The option that looks most like ``word``, or None if nothing is close."""
    found = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return found[0] if found else None


def is_number(value: object) -> bool:
    """True for TOML integers and floats (booleans are not numbers here)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def fmt(x: float) -> str:
    """A number for a message: shortest of 0-3 decimals that is exact enough."""
    for decimals in (1, 2, 3):
        if abs(round(x, decimals) - x) < 1e-9:
            return f"{x:.{decimals}f}"
    return f"{x:.2f}"


class Table:
    """One table of the show file, read key by key with types and ranges checked."""

    def __init__(self, data: Mapping[str, Any], path: str, where: str) -> None:
        self.data = data
        self.path = path
        self.where = where

    def error(self, message: str) -> ShowFileError:
        """A :class:`ShowFileError` at this table."""
        return ShowFileError(self.path, self.where, message)

    def has(self, key: str) -> bool:
        """True if the file gives ``key``."""
        return key in self.data

    def check_keys(self, allowed: Iterable[str],
                   elsewhere: Mapping[str, str] | None = None) -> None:
        """Reject keys not in ``allowed``, suggesting the closest valid one.

        ``elsewhere`` maps keys that are valid in another context to a note
        (``"a key of shape 'star'"``) so the message can say why it does not apply.
        """
        allowed = list(allowed)
        for key in self.data:
            if key in allowed:
                continue
            if elsewhere and key in elsewhere:
                raise self.error(f"'{key}' does not apply here: it is {elsewhere[key]}")
            near = closest(key, allowed)
            hint = f"; did you mean '{near}'?" if near else f"; valid keys: {', '.join(allowed)}"
            raise self.error(f"unknown key '{key}'{hint}")

    def get(self, key: str, default: object = MISSING) -> Any:
        """The raw value of ``key``; a missing required key is an error."""
        if key in self.data:
            return self.data[key]
        if default is MISSING:
            raise self.error(f"missing required key '{key}'")
        return default

    def number(self, key: str, default: float | _Missing = MISSING, *,
               minimum: float | None = None, positive: bool = False,
               maximum: float | None = None) -> float:
        """A finite number (integer or float), optionally bounded."""
        if key not in self.data:
            if isinstance(default, _Missing):
                raise self.error(f"missing required key '{key}'")
            return float(default)
        value = self.data[key]
        if not is_number(value):
            raise self.error(f"'{key}' must be a number, got {describe(value)}")
        if not finite(value):
            bound = "" if maximum is None else f" and at most {maximum:g}"
            got = value if isinstance(value, float) else describe(value)
            raise self.error(f"'{key}' must be finite{bound}, got {got}")
        x = float(value)
        if positive and x <= 0:
            raise self.error(f"'{key}' must be greater than 0, got {value:g}")
        if minimum is not None and x < minimum:
            raise self.error(f"'{key}' must be at least {minimum:g}, got {value:g}")
        if maximum is not None and x > maximum:
            raise self.error(f"'{key}' must be at most {maximum:g}, got {value:g}")
        return x

    def ranged(self, key: str, default: float | _Missing, allowed: Range) -> float:
        """A number in ``allowed`` (see :mod:`groundctl.show.ranges`)."""
        x = self.number(key, default, minimum=None if allowed.low_open else allowed.low,
                        positive=allowed.low_open and allowed.low == 0,
                        maximum=None if allowed.high_open else allowed.high)
        problem = allowed.problem(key, x)
        if problem:
            raise self.error(problem)
        return x

    def integer(self, key: str, default: int | _Missing = MISSING, *,
                minimum: int | None = None, maximum: int | None = None) -> int:
        """An integer, optionally bounded."""
        if key not in self.data:
            if isinstance(default, _Missing):
                raise self.error(f"missing required key '{key}'")
            return default
        value = self.data[key]
        if not isinstance(value, int) or isinstance(value, bool):
            raise self.error(f"'{key}' must be an integer, got {describe(value)}")
        if minimum is not None and value < minimum:
            raise self.error(f"'{key}' must be at least {minimum}, got {_int_text(value)}")
        if maximum is not None and value > maximum:
            raise self.error(f"'{key}' must be at most {maximum}, got {_int_text(value)}")
        return value

    def string(self, key: str, default: str | _Missing = MISSING, *,
               choices: Sequence[str] | None = None, max_length: int | None = None) -> str:
        """A string, optionally one of ``choices`` (suggesting the closest on a miss), or
        printable text of at most ``max_length`` characters (a name shown in messages)."""
        if key not in self.data:
            if isinstance(default, _Missing):
                raise self.error(f"missing required key '{key}'")
            return default
        value = self.data[key]
        if not isinstance(value, str):
            raise self.error(f"'{key}' must be a string, got {describe(value)}")
        if max_length is not None and len(value) > max_length:
            raise self.error(f"'{key}' must be at most {max_length} characters, got "
                             f"{len(value)}")
        if max_length is not None and not value.isprintable():
            raise self.error(f"'{key}' must be printable text (no line breaks or control "
                             f"characters), got {describe(value)}")
        if choices is not None and value not in choices:
            near = closest(value, choices)
            hint = f"; did you mean '{near}'?" if near else ""
            options = ", ".join(f"'{c}'" for c in choices)
            raise self.error(f"'{key}' must be one of {options}, got '{value}'{hint}")
        return value

    def vector(self, key: str, lengths: Sequence[int],
               default: Sequence[float] | _Missing = MISSING, *,
               bound: float = MAX_COORD) -> tuple[float, ...]:
        """An array of numbers whose length is one of ``lengths``, each within +-``bound``."""
        if key not in self.data:
            if isinstance(default, _Missing):
                raise self.error(f"missing required key '{key}'")
            return tuple(float(x) for x in default)
        value = self.data[key]
        want = " or ".join(str(n) for n in lengths)
        if (not isinstance(value, list) or len(value) not in lengths
                or not all(finite(x) for x in value)):
            raise self.error(f"'{key}' must be an array of {want} numbers, got {describe(value)}")
        if any(abs(x) > bound for x in value):
            raise self.error(f"'{key}' values must be within +-{bound:g}, got {describe(value)}")
        return tuple(float(x) for x in value)

    def point_list(self, key: str, dims: Sequence[int], *, min_count: int = 1,
                   max_count: int = MAX_SLOTS, bound: float = MAX_COORD
                   ) -> NDArray[np.float64]:
        """A required array of ``min_count..max_count`` points, each an array of ``dims``
        numbers within +-``bound``, all the same length."""
        value = self.get(key)
        want = " or ".join(str(n) for n in dims)
        if not isinstance(value, list) or len(value) < min_count:
            raise self.error(f"'{key}' must be an array of at least {min_count} points "
                             f"[{', '.join('xyz'[:dims[0]])}], got {describe(value)}")
        if len(value) > max_count:
            raise self.error(f"'{key}' must have at most {max_count} points, got {len(value)}")
        for i, p in enumerate(value):
            if (not isinstance(p, list) or len(p) not in dims
                    or not all(finite(x) for x in p)):
                raise self.error(f"'{key}' point {i + 1} must be an array of {want} numbers, "
                                 f"got {describe(p)}")
            if any(abs(x) > bound for x in p):
                raise self.error(f"'{key}' point {i + 1} must be within +-{bound:g} m, got "
                                 f"{describe(p)}")
            if len(p) != len(value[0]):
                raise self.error(f"'{key}' point {i + 1} has {len(p)} values but point 1 has "
                                 f"{len(value[0])}; give every point the same number")
        return np.array(value, dtype=float)
