"""What was done as a run ended, remembered on the exception that ended it.

A run that ends by an error still leaves the unit at rest and keeps the windows it has; the one
line that reports the error says so (``sent STOP; the unit reads SETTLING; kept 3 of 4 windows
in run.csv``). The session layer notes each clause on the exception as it happens; the command
line's error report reads them back.
"""

from __future__ import annotations

import contextlib
from typing import Any

__all__ = ["ending_of", "note_at_rest", "note_ending"]


def note_ending(exc: BaseException, clause: str) -> None:
    """Remember on ``exc`` a clause of what was done as the command ended (the device left at
    rest, the windows kept), for the one line that reports ``exc``."""
    with contextlib.suppress(AttributeError, TypeError):
        clauses = exc.__dict__.setdefault("northfinder_ending", [])
        clauses.append(clause)


def note_at_rest(exc: BaseException, rest: Any) -> None:
    """:func:`note_ending` with what was done to leave the device at rest (an
    :class:`~northfinder.driver.device_link.AtRest`), if there was anything to undo."""
    if rest.needed:
        note_ending(exc, rest.summary())


def ending_of(exc: BaseException) -> str | None:
    """The clauses :func:`note_ending` remembered on ``exc`` and the errors in its chain, joined
    (``sent STOP; the unit reads SETTLING; kept 3 of 4 windows in run.csv``); None if none."""
    clauses: list[str] = []
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        clauses += getattr(current, "northfinder_ending", [])
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return "; ".join(clauses) if clauses else None
