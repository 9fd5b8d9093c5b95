"""The command lines of the documentation pages and the output they show, for tests/test_readme.py.

A page's commands are the ``northfinder ...`` lines of its ``sh`` and ``console`` blocks (also
after ``&&``, and joined over a line ending in ``\\``). In a ``console`` block a command is a
``$ `` line and the lines after it, to the next command, are the output the page shows for it
(a console block without any ``$ `` line is commands only, as an ``sh`` block).

Shown output is compared in substance: each line is cut into tokens, words (labels) and numbers
(any token with a digit, hexadecimal data included); a printed line has the shape of a shown line
when its words are the same in the same places and it has as many numbers. A line ``...`` elides
any number of lines; a line that ends in ``...`` shows only the start of its line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_BLOCK = re.compile(r"^```(sh|console)\n(.*?)^```", re.M | re.S)
_TOKEN = re.compile(r"[A-Za-z0-9_.+\-]+")
_NORTHFINDER = re.compile(r"^(\S*/)?(\.venv/bin/)?northfinder\b")
ELISION = "..."


def pages() -> list[str]:
    """README.md and every page of docs/, as paths from the repository's root."""
    return ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]


@dataclass(frozen=True)
class Command:
    """One command of a page: its text (without the comment), the comment, and the output shown."""

    page: str
    index: int
    text: str
    comment: str = ""
    shown: tuple[str, ...] = field(default=())

    def __str__(self) -> str:
        return f"{self.page}, command {self.index}: {self.text}"


def _joined(lines: list[str]) -> list[str]:
    out: list[str] = []
    pending = ""
    for line in lines:
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1].rstrip() + " "
            continue
        out.append(pending + line.strip() if pending else line)
        pending = ""
    if pending:
        out.append(pending.rstrip())
    return out


def _northfinder_parts(line: str) -> tuple[list[str], str]:
    line, _, comment = line.partition(" #")
    parts = []
    for part in line.split("&&"):
        part = _NORTHFINDER.sub("northfinder", part.strip())
        if part.startswith("northfinder ") or part == "northfinder":
            parts.append(part)
    return parts, comment.strip().lstrip("#").strip()


def commands(page: str) -> list[Command]:
    """The northfinder commands of a page's ``sh`` and ``console`` blocks, in order."""
    text = (ROOT / page).read_text(encoding="utf-8")
    found: list[tuple[str, str, list[str]]] = []
    for kind, body in _BLOCK.findall(text):
        lines = _joined(body.splitlines())
        prompted = kind == "console" and any(line.startswith("$ ") for line in lines)
        current: list[str] | None = None
        for line in lines:
            if prompted and not line.startswith("$ "):
                if current is not None:
                    current.append(line.rstrip())
                continue
            current = None
            parts, comment = _northfinder_parts(line[2:] if prompted else line.strip())
            for part in parts:
                current = []
                found.append((part, comment, current))
    return [
        Command(page, i, text, comment, tuple(shown))
        for i, (text, comment, shown) in enumerate(found)
    ]


# -- comparing output ---------------------------------------------------------------------------


def _tokens(line: str) -> list[str]:
    return _TOKEN.findall(line)


def _is_number(token: str) -> bool:
    return any(c.isdigit() for c in token)


def _same_number(shown: str, printed: str) -> bool:
    """The printed number, as the page rounds it, is the shown one."""
    if shown == printed:
        return True
    try:
        a, b = float(shown.rstrip("%")), float(printed.rstrip("%"))
    except ValueError:
        return False
    if not (math.isfinite(a) and math.isfinite(b)):
        return False
    mantissa = re.split(r"[eE]", shown.rstrip("%"))[0]
    decimals = len(mantissa.partition(".")[2])
    exponent = int(re.split(r"[eE]", shown)[1]) if re.search(r"[eE]", shown) else 0
    return abs(a - b) <= 0.5 * 10.0 ** (exponent - decimals) * (1 + 1e-9)


def line_matches(shown: str, printed: str, numbers: bool) -> bool:
    """``printed`` has the shape of ``shown`` (and its numbers, if ``numbers``)."""
    prefix = shown.rstrip().endswith(ELISION)
    want = _tokens(shown.rstrip().removesuffix(ELISION))
    got = _tokens(printed)
    if prefix:
        got = got[: len(want)]
    if len(want) != len(got):
        return False
    for w, g in zip(want, got, strict=True):
        if _is_number(w) != _is_number(g):
            return False
        if not _is_number(w) and w != g:
            return False
        if _is_number(w) and numbers and not _same_number(w, g):
            return False
    return True


def _segments(shown: tuple[str, ...]) -> tuple[list[list[str]], bool, bool]:
    """The shown lines cut at the elisions; whether it is elided at its start, at its end."""
    lines = [line for line in shown if line.strip()]
    segments: list[list[str]] = [[]]
    for line in lines:
        if line.strip() == ELISION:
            segments.append([])
        else:
            segments[-1].append(line)
    head = bool(lines) and lines[0].strip() == ELISION
    tail = bool(lines) and lines[-1].strip() == ELISION
    return [s for s in segments if s], head, tail


def output_mismatch(shown: tuple[str, ...], printed: str, numbers: bool) -> str | None:
    """Why the printed output is not what the page shows (None: it is).

    Each run of shown lines between elisions matches consecutive printed lines, in order; without
    an elision at the start (end) the first (last) shown line is the first (last) printed line.
    """
    segments, head, tail = _segments(shown)
    if not segments:
        return None
    got = [line for line in printed.splitlines() if line.strip()]
    at = 0
    for n, segment in enumerate(segments):
        first = n == 0 and not head
        last = n == len(segments) - 1 and not tail
        starts = [at] if first else range(at, len(got) - len(segment) + 1)
        for start in starts:
            window = got[start : start + len(segment)]
            if len(window) == len(segment) and all(
                line_matches(s, p, numbers) for s, p in zip(segment, window, strict=True)
            ):
                if last and start + len(segment) != len(got):
                    continue
                at = start + len(segment)
                break
        else:
            return (
                f"no printed lines have the shape{' and numbers' if numbers else ''} of\n  "
                + "\n  ".join(segment)
                + "\nprinted:\n  "
                + "\n  ".join(got)
            )
    return None
