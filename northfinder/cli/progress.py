"""Progress of a long command on stderr: a tqdm bar on a terminal, plain lines elsewhere.

A terminal that reports its width gets a bar (tqdm) that redraws itself in place. Where a bar
cannot work, on a pipe, a log file, a CI runner, or a terminal that reports no width (a serial
console, a container without a size), the same progress is written as plain lines: one line per
step (a phase of ``find``, a file read by ``calibrate``), and for a count of equal parts (the
chunks of a ``study``) a line at each tenth. ``--json`` turns it off.
"""

from __future__ import annotations

import math
import os
import sys
from typing import TYPE_CHECKING, Any, Literal, TextIO

if TYPE_CHECKING:
    from northfinder.host.procedure import FindProgress

Mode = Literal["bar", "lines", "off"]


def progress_mode(stream: Any, enabled: bool = True) -> Mode:
    """``bar`` on a terminal that reports its size, ``lines`` on anything else (a terminal of no
    width or no height too: tqdm draws nothing on one of no height), ``off`` when not
    ``enabled``."""
    if not enabled:
        return "off"
    isatty = getattr(stream, "isatty", None)
    if isatty is None or not isatty():
        return "lines"
    try:
        size = os.get_terminal_size(stream.fileno())
    except (OSError, ValueError, AttributeError):
        return "lines"
    return "bar" if size.columns > 0 and size.lines > 0 else "lines"


class Progress:
    """Progress of ``label`` (the command's name) over ``total`` equal parts or named steps.

    :meth:`step` names what is being done now (a bar's description; a line of its own), and
    :meth:`advance` counts parts done (a bar's position; a line at each tenth of ``total``).
    """

    def __init__(
        self,
        label: str,
        total: int | None = None,
        *,
        unit: str = "",
        enabled: bool = True,
        stream: TextIO | None = None,
    ) -> None:
        self.label = label
        self.total = total
        self.unit = unit
        self.stream: Any = sys.stderr if stream is None else stream
        self.mode: Mode = progress_mode(self.stream, enabled)
        self.done = 0
        self._bar: Any = None
        self._tenth = -1
        self._step = ""

    #: tqdm's layout of the bar; None for tqdm's own.
    bar_format: str | None = None

    def _ensure_bar(self) -> Any:
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=self.total, desc=self.label, unit=self.unit or "it", file=self.stream,
                leave=False, dynamic_ncols=True, bar_format=self.bar_format,
            )  # fmt: skip
        return self._bar

    def _line(self, text: str) -> None:
        print(f"{self.label}: {text}", file=self.stream, flush=True)

    def step(self, text: str) -> None:
        """What is being done now."""
        if self.mode == "off" or text == self._step:
            return
        self._step = text
        if self.mode == "bar":
            self._ensure_bar().set_description_str(f"{self.label}: {text}")
        else:
            self._line(text)

    def advance(self, n: int = 1) -> None:
        """``n`` more parts done."""
        self.done += n
        if self.mode == "bar":
            self._ensure_bar().update(n)
        elif self.mode == "lines" and self.total:
            tenth = min(10, 10 * self.done // self.total)
            if tenth > self._tenth:
                self._tenth = tenth
                unit = f" {self.unit}" if self.unit else ""
                self._line(f"{self.done}/{self.total}{unit} ({100 * self.done // self.total}%)")

    def count(self, done: int, total: int) -> None:
        """``done`` of ``total`` parts done (a callback of the Monte Carlo engine); a count that
        starts again (fewer done than before) is a new part of the work."""
        if done < self.done or self.total != total:
            self.total, self.done, self._tenth = total, 0, -1
            if self._bar is not None:
                self._bar.reset(total=total)
        self.advance(done - self.done)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PlanProgress(Progress):
    """Progress of a plan (``find``, ``record``), fed the procedure's
    :class:`~northfinder.host.procedure.FindProgress` reports. On a terminal the bar counts the
    plan's device seconds done in wall-clock time, so elapsed and remaining are what the user
    waits (an embedded simulator at ``--speed 100`` finishes 100 times sooner than the plan's
    device time); elsewhere one line per step: ``find: rotate position 2/4``. Off when
    ``enabled`` is False (``--json``, ``--nmea -``).
    """

    bar_format = "{desc} {percentage:3.0f}%|{bar}| {elapsed} elapsed, ~{remaining} left"

    def __init__(
        self, *, enabled: bool = True, stream: TextIO | None = None, label: str = "find"
    ) -> None:
        super().__init__(label, None, enabled=enabled, stream=stream)
        self.enabled = self.mode != "off"

    def __call__(self, p: FindProgress) -> None:
        if self.mode == "lines":
            where = f" position {p.position}/{p.positions}" if p.position else ""
            self.step(f"{p.phase}{where}")
            return
        if self.mode != "bar":
            return
        bar = self._ensure_bar()
        from northfinder.host.heading import heading_text

        angle = "---" if p.table_deg is None else heading_text(p.table_deg, 3)
        bar.set_description_str(
            f"{p.phase:<8} position {p.position}/{p.positions} table {angle} deg"
        )
        if p.seconds_left is not None and math.isfinite(p.seconds_left):
            if bar.total is None:
                bar.total = max(p.seconds_left, 1e-9)
            bar.n = max(0.0, min(bar.total, bar.total - p.seconds_left))
        bar.refresh()
        if p.phase == "done":
            self.close()
