"""Checking arguments and file fields: one error type and one message format for the project.

Every checked argument, configuration field and file entry fails the same way::

    <where>: <field> = <value>: <problem>; allowed: <what is allowed>

for example ``fittings[3].position = [0.0, nan, 1.0]: not finite; allowed: three finite numbers
(m)`` or ``NetworkConfig.roll_angle_step = 2.5: out of range; allowed: 0.0175 to 1.571 (rad)``.
``where`` (a file name, a class) is optional. The error is an :class:`ArgumentError`, a
``ValueError`` with the parts as attributes, so callers can catch ``ValueError`` as before and
tools can read ``field``.

The checks return the value converted (a float, an int, a numpy array), so a constructor reads
``self.length = check_number("length", length, low=0.0, unit="m")``.

This is the lowest layer (the detector uses it too); it imports nothing from the project.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ArgumentError",
    "check_bool",
    "check_choice",
    "check_int",
    "check_number",
    "check_vector",
    "describe",
    "fail",
]


def describe(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters (a huge list or string stays readable)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class ArgumentError(ValueError):
    """A checked argument or field is wrong. ``field`` is its path (``goals[0]``,
    ``start.forward``), ``value`` what was given, ``allowed`` what would be accepted,
    ``problem`` what is wrong and ``where`` (optional) the file or object it belongs to."""

    def __init__(
        self,
        field: str,
        value: Any,
        allowed: str,
        problem: str = "not allowed",
        where: str | None = None,
    ) -> None:
        self.field = field
        self.value = value
        self.allowed = allowed
        self.problem = problem
        self.where = where
        prefix = f"{where}: " if where else ""
        super().__init__(f"{prefix}{field} = {describe(value)}: {problem}; allowed: {allowed}")

    def within(self, where: str) -> ArgumentError:
        """The same error placed in ``where`` (a file, an object); an existing place is kept
        after it (``net.json: fittings[2]``)."""
        place = f"{where}: {self.where}" if self.where else where
        return ArgumentError(self.field, self.value, self.allowed, self.problem, place)

    def __reduce__(self) -> tuple[Any, ...]:  # picklable across worker processes
        return (type(self), (self.field, self.value, self.allowed, self.problem, self.where))


def fail(
    field: str, value: Any, allowed: str, problem: str = "not allowed", where: str | None = None
) -> ArgumentError:
    """The error to raise: ``raise fail("kind", kind, "bend, tee")``."""
    return ArgumentError(field, value, allowed, problem, where)


def _range_text(low: float | None, high: float | None, unit: str, open_low: bool) -> str:
    suffix = f" ({unit})" if unit else ""
    if low is not None and high is not None:
        return f"{'above ' if open_low else ''}{low:g} to {high:g}{suffix}"
    if low is not None:
        return f"{'above' if open_low else 'at least'} {low:g}{suffix}"
    if high is not None:
        return f"at most {high:g}{suffix}"
    return f"a finite number{suffix}"


def check_number(
    field: str,
    value: Any,
    low: float | None = None,
    high: float | None = None,
    unit: str = "",
    open_low: bool = False,
    where: str | None = None,
) -> float:
    """``value`` as a finite float in [low, high] (``open_low``: strictly above ``low``).

    Booleans and strings are refused (``True`` is not a length); numpy scalars are accepted.
    """
    allowed = _range_text(low, high, unit, open_low)
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise ArgumentError(field, value, allowed, "not a number", where)
    try:
        number = float(value)
    except (OverflowError, ValueError) as exc:  # an int too large for a float
        raise ArgumentError(field, value, allowed, "not a finite number", where) from exc
    if not math.isfinite(number):
        raise ArgumentError(field, value, allowed, "not finite", where)
    too_low = low is not None and (number <= low if open_low else number < low)
    if too_low or (high is not None and number > high):
        raise ArgumentError(field, value, allowed, "out of range", where)
    return number


def check_int(
    field: str,
    value: Any,
    low: int | None = None,
    high: int | None = None,
    where: str | None = None,
) -> int:
    """``value`` as an int in [low, high]; floats with a fraction, bools and strings refused."""
    allowed = _range_text(low, high, "", False).replace("a finite number", "an integer")
    if low is not None or high is not None:
        allowed = f"an integer {allowed}"
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Integral):
        raise ArgumentError(field, value, allowed, "not an integer", where)
    number = int(value)
    if (low is not None and number < low) or (high is not None and number > high):
        raise ArgumentError(field, value, allowed, "out of range", where)
    return number


def check_bool(field: str, value: Any, where: str | None = None) -> bool:
    """``value`` as a bool: ``True``/``False`` (or numpy's) only, not 0, 1 or strings."""
    if not isinstance(value, bool | np.bool_):
        raise ArgumentError(field, value, "true or false", "not a boolean", where)
    return bool(value)


def check_choice(field: str, value: Any, choices: Iterable[Any], where: str | None = None) -> Any:
    """``value`` if it is one of ``choices`` (compared with ``==``; a StrEnum member matches
    its string), else an error listing them."""
    options = list(choices)
    try:
        if value in options:
            return value
    except TypeError:  # an unhashable or uncomparable value
        pass
    allowed = ", ".join(str(getattr(c, "value", c)) for c in options)
    raise ArgumentError(field, value, allowed, "unknown", where)


def check_vector(
    field: str,
    value: Any,
    size: int,
    unit: str = "",
    unit_length: bool = False,
    bound: float | None = None,
    where: str | None = None,
) -> NDArray[np.float64]:
    """``value`` as a float array of ``size`` finite numbers, each within ±``bound`` if given;
    ``unit_length``: nonzero, returned normalised."""
    suffix = f" ({unit})" if unit else ""
    allowed = f"{size} finite numbers{suffix}"
    if bound is not None:
        allowed += f" within ±{bound:g}"
    if unit_length:
        allowed += ", not all zero"
    if isinstance(value, str | bytes | dict):
        raise ArgumentError(field, value, allowed, "not a list of numbers", where)
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ArgumentError(field, value, allowed, "not a list of numbers", where) from exc
    if array.shape != (size,):
        raise ArgumentError(field, value, allowed, f"shape {array.shape}", where)
    if not np.all(np.isfinite(array)):
        raise ArgumentError(field, value, allowed, "not finite", where)
    if bound is not None and np.any(np.abs(array) > bound):
        raise ArgumentError(field, value, allowed, "out of range", where)
    if unit_length:
        norm = float(np.linalg.norm(array))
        if norm < 1e-12:
            raise ArgumentError(field, value, allowed, "zero length", where)
        array = array / norm
    return array
