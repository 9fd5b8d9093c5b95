"""A command's printed text and JSON: one warning line on stderr, no negative zero."""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Mapping
from typing import Any

#: A number that prints as a negative zero ("-0", "-0.000", "-0.0e+00"): a value that rounds to
#: zero is shown as zero, without a sign that says nothing.
_NEGATIVE_ZERO = re.compile(r"(?<![\w.])-(0(?:\.0*)?(?:[eE][-+]?\d+)?)(?![\d.])")


def plain_numbers(text: str) -> str:
    """``text`` with every printed negative zero written as zero (``-0.0000`` -> ``0.0000``,
    ``+-0.0`` stays a plus-minus sign before ``0.0``)."""
    return _NEGATIVE_ZERO.sub(r"\1", text)


def say(*parts: Any, **options: Any) -> None:
    """``print`` for a command's text: every negative zero written as zero (:func:`plain_numbers`)."""
    print(*(plain_numbers(str(p)) for p in parts), **options)


def warn(command: str, text: str) -> None:
    """``northfinder COMMAND: warning: TEXT`` on stderr: the work goes on, but the user should
    know (lines skipped, windows left out)."""
    print(plain_numbers(f"northfinder {command}: warning: {text}"), file=sys.stderr, flush=True)


def _no_negative_zero(value: Any) -> Any:
    if isinstance(value, float):
        return 0.0 if value == 0.0 else value
    if isinstance(value, str):
        return plain_numbers(value)
    if isinstance(value, Mapping):
        return {k: _no_negative_zero(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_no_negative_zero(v) for v in value]
    return value


def dumps(value: Any, **options: Any) -> str:
    """JSON of a command's result (indented by 2), with no negative zero (``-0.0`` is 0.0, in
    numbers and in the texts of notes)."""
    options.setdefault("indent", 2)
    return json.dumps(_no_negative_zero(value), **options)
