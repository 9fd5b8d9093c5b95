"""The reading of a long CAN log shown as it goes: a bar of the megabytes read with the time
left on a terminal, a line at each tenth elsewhere (:class:`~northfinder.cli.progress.Progress`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from northfinder.cli.progress import Progress

#: A log at least this large (bytes, all its parts) shows the progress of its reading: about ten
#: minutes of stream in ASC, several seconds to read.
PROGRESS_BYTES = 32 * 1024 * 1024


class LogProgress:
    """``progress(done, total)`` for :func:`~northfinder.host.canlog.read_can_log`, shown under
    ``label`` (the command) when the files add up to :data:`PROGRESS_BYTES` or more."""

    def __init__(self, label: str, files: Sequence[Path], *, enabled: bool) -> None:
        self.total = sum(f.stat().st_size for f in files if f.is_file())
        self.enabled = enabled and self.total >= PROGRESS_BYTES
        megabytes = max(1, round(self.total / 1e6))
        self.bar = Progress(label, megabytes, unit="MB", enabled=self.enabled)

    def __call__(self, done: int, total: int) -> None:
        if self.enabled and total:
            self.bar.step("reading the log")
            whole = self.bar.total or 0
            self.bar.advance(
                (whole if done >= total else min(round(done / 1e6), whole)) - self.bar.done
            )
            if done >= total:
                self.bar.close()

    def __enter__(self) -> LogProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.close()
