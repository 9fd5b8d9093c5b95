"""Checks of the values a caller hands to :class:`~northfinder.driver.device.Device`.

Every public call checks its numbers here before anything is sent, so a bad value is an
:class:`~northfinder.driver.errors.ArgumentError` naming the argument and what it must be, never
a ``TypeError`` from string formatting, an ``OverflowError`` or a silently rounded value.

Configuration values are whole numbers in their key's unit (protocol.md 4.4: Hz, ms, 1e-3 deg/s,
...). A value with a fraction is refused rather than rounded: the device would carry out a
value other than the one asked for (``199.7`` Hz is no sample rate; ``1999.5`` ms is not a
settle time the device can report back), and the caller is the one who knows which way to
round. Whole floats (``200.0``) and numpy integers are taken.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

from northfinder.driver.protocol.errors import ArgumentError

__all__ = ["MAX_WAIT_S", "finite_number", "seconds", "whole_number"]

#: Longest wait or window a call may ask for, s (a day; a window of it is 17 million samples at
#: 200 Hz).
MAX_WAIT_S = 86_400.0


def _show(value: Any) -> str:
    """``repr`` of a value, shortened (a 400-digit integer is named, not printed)."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"


def finite_number(name: str, value: Any, unit: str = "") -> float:
    """``value`` as a finite float; bools, strings and non-numbers are refused."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ArgumentError(
            f"{name}={_show(value)}: must be a number{' of ' + unit if unit else ''}"
        )
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise ArgumentError(
            f"{name}={_show(value)}: must be a finite number{' of ' + unit if unit else ''}"
        )
    return x


def whole_number(name: str, value: Any) -> int:
    """``value`` as an int: integers and whole floats; a fraction is refused (not rounded)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ArgumentError(f"{name}={_show(value)}: must be a whole number")
    if isinstance(value, numbers.Integral):
        return int(value)
    x = finite_number(name, value)
    if x != math.floor(x):
        raise ArgumentError(
            f"{name}={_show(value)}: configuration values are whole numbers in the key's unit; "
            "round it yourself (the device would run another value than asked)"
        )
    return int(x)


def seconds(
    name: str, value: Any, *, allow_none: bool = True, hi: float = MAX_WAIT_S
) -> float | None:
    """A duration in s: positive, finite, at most ``hi`` (None allowed when ``allow_none``)."""
    if value is None and allow_none:
        return None
    x = finite_number(name, value, "seconds")
    if not 0.0 < x <= hi:
        raise ArgumentError(
            f"{name}={_show(value)}: must be more than 0 and at most {hi:g} seconds"
        )
    return x
