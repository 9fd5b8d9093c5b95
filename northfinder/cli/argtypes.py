"""argparse value types: each parses one kind of value and its error quotes the bad text
and states the bounds.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from northfinder.driver.protocol.constants import (
    NODE_ID_MAX,
    NODE_ID_MIN,
)


def whole_number(text: str) -> int:
    """argparse type: a whole number, with an error that quotes the bad text."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None


def finite_float(text: str) -> float:
    """argparse type: a finite float, with an error that quotes the bad text."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite: {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive: {text!r}")
    return value


def bounded_float(lo: float, hi: float, unit: str = "", *, open_lo: bool = False) -> Any:
    """argparse type: a finite float in [lo, hi] (``(lo, hi]`` with ``open_lo``); the error
    states the bounds."""
    span = f"more than {lo:g} and at most {hi:g}" if open_lo else f"{lo:g} to {hi:g}"

    def parse(text: str) -> float:
        value = finite_float(text)
        if value > hi or value < lo or (open_lo and value == lo):
            raise argparse.ArgumentTypeError(
                f"must be {span}{' ' + unit if unit else ''}, got {text!r}"
            )
        return value

    parse.__name__ = "number"
    return parse


def bounded_int(lo: int, hi: int) -> Any:
    """argparse type: a whole number in [lo, hi]; the error states the bounds."""

    def parse(text: str) -> int:
        value = whole_number(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be {lo} to {hi}, got {value}")
        return value

    parse.__name__ = "whole number"
    return parse


#: Largest random seed accepted (numpy takes any non-negative integer; 2**63 - 1 is plenty).
MAX_SEED = 2**63 - 1
seed_value = bounded_int(0, MAX_SEED)
"""argparse type: a random seed, a whole number 0 .. 2**63 - 1."""


def node_id(text: str) -> int:
    """argparse type: a CAN node id, 1..15 (protocol.md 2.1)."""
    value = whole_number(text)
    if not NODE_ID_MIN <= value <= NODE_ID_MAX:
        raise argparse.ArgumentTypeError(f"must be {NODE_ID_MIN}..{NODE_ID_MAX}, got {value}")
    return value


#: Highest serial baud rate accepted, bit/s (fast USB UARTs reach about 12 Mbaud).
MAX_BAUD = 100_000_000


def baud_rate(text: str) -> int:
    """argparse type: a serial baud rate, a whole number of bit/s from 1 to :data:`MAX_BAUD`."""
    value = whole_number(text)
    if not 1 <= value <= MAX_BAUD:
        raise argparse.ArgumentTypeError(f"must be 1..{MAX_BAUD} bit/s, got {value}")
    return value


#: Largest magnitude of an angle given in degrees (an azimuth, a table position): one turn either
#: way. Beyond it a value is a typo, and 1e20 deg has no meaningful remainder modulo 360.
MAX_ANGLE_DEG = 360.0
#: Largest magnitude of a table angle, deg: two turns either way (a plan may count on past 360).
MAX_TABLE_ANGLE_DEG = 720.0
_table_angle = bounded_float(-MAX_TABLE_ANGLE_DEG, MAX_TABLE_ANGLE_DEG, "deg")

#: Most table positions a plan may hold (and angles a list may hold).
MAX_POSITIONS = 64


def angle_list(text: str) -> list[float]:
    """argparse type: comma-separated angles in degrees, e.g. ``0,60`` or ``0,90,180,270``
    (at most :data:`MAX_POSITIONS`)."""
    parts = [p.strip() for p in text.split(",")]
    if not any(parts):
        raise argparse.ArgumentTypeError("expected comma-separated angles in degrees, e.g. 0,180")
    if not all(parts):
        raise argparse.ArgumentTypeError(
            f"an empty angle in {text!r}: give comma-separated angles in degrees, e.g. 0,180"
        )
    if len(parts) > MAX_POSITIONS:
        raise argparse.ArgumentTypeError(
            f"{len(parts)} angles: at most {MAX_POSITIONS} positions are allowed"
        )
    return [_table_angle(p) for p in parts]


def key_value(text: str) -> tuple[str, Any]:
    """argparse type: ``KEY=VALUE``, the value read as JSON when it parses, else as a string."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return key.strip(), value
