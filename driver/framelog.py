"""CAN frame logs in python-can's formats: a tap that writes every frame a link carries.

:class:`FrameLog` wraps python-can's :class:`can.Logger`, which picks the format by the file
name's ending (``.log`` candump, ``.asc`` Vector ASCII, ``.blf`` Vector binary, ``.csv``, ``.db``
SQLite, ``.trc`` PEAK, ``.mf4`` with asammdf installed; ``.gz`` after a text format compresses
it). A :class:`FrameLog` is a callable taking one :class:`can.Message`, so it is what the driver's
transports (``Device.from_bus(bus, tap=log)``, ``Device.open_serial(port, tap=log)``) and the
simulator's links take as ``tap``. It may be called from several threads at once.

Frames keep their own timestamp when they have one (a bus's receive time); frames without one
(``timestamp == 0``, as a sender builds them) are stamped with the wall clock when logged. A log
of a run in virtual time (:meth:`FrameLog.use_clock`, as ``find --sim --can-log`` and
``SimulatedInstrument(log=...)`` do) stamps every frame with the virtual clock instead, counted
from the wall-clock time at which the clock was attached, so that the log's times are the
instrument's (a 10 s window spans 10 s of the log, however fast the CPU ran it). A
frame the host or device sent is logged with ``is_rx=False`` (``Tx`` in ASC and BLF). Every
frame is logged on one channel: ``channel`` (default ``can0`` for candump, whose lines name an
interface; the writer's own default, channel 1, for the formats that number channels).

A log may be rotated as python-can's :class:`can.SizedRotatingLogger` rotates one: with
``max_bytes`` a new part begins once the current one has grown to that size, with ``max_seconds``
once a frame is that many seconds (by the log's own timestamps) after the part's first frame;
either or both. The part being written keeps the name given; each finished part is closed (a
complete log on its own) and renamed ``STEM_#NNN.EXT``, NNN counting 000, 001, ... in order
(:func:`part_name`). Rotation takes the formats python-can rotates: ``.asc``, ``.blf``,
``.csv``, ``.log``. :func:`log_parts` lists a set in order, the part with the given name last.

A log is readable while it is written: the file is flushed with the first frame logged
``flush_s`` wall seconds (default 1) after the last flush, and at :meth:`FrameLog.flush`, which
the simulator's links call as they answer a command, before the answer goes out and after (so
a log read after a host's last reply holds that host's session whole). BLF's containers are
written out then too; ``.mf4`` and SQLite write as their libraries do.

A write that fails (disk full, say) does not stop the link: the first error is kept in
:attr:`FrameLog.error`, later frames are counted in :attr:`FrameLog.lost`, and :meth:`close`
raises :class:`~northfinder.driver.errors.LinkError` naming both, so a log is never silently
incomplete.
"""

from __future__ import annotations

import copy
import glob
import itertools
import os
import re
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Self

import can

from northfinder.driver.errors import ArgumentError, LinkError
from northfinder.driver.protocol.can import CanFrame

__all__ = [
    "LOG_SUFFIXES",
    "ROTATING_SUFFIXES",
    "FrameLog",
    "FrameTap",
    "RotatingLog",
    "frame_message",
    "log_parts",
    "log_suffix",
    "order_log_parts",
    "part_name",
]

LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc")
"""File endings python-can reads and writes as CAN logs (``.mf4`` needs ``asammdf``)."""

ROTATING_SUFFIXES = (".asc", ".blf", ".csv", ".log")
"""File endings a rotated log may have (those python-can's :class:`can.SizedRotatingLogger` takes)."""

#: Smallest and largest ``max_bytes`` and ``max_seconds`` of a rotated log: a smaller part would
#: hold a handful of frames (a part per frame is no log), a larger one is no rotation at all.
MAX_BYTES_RANGE = (4096, 1 << 40)
MAX_SECONDS_RANGE = (1.0, 366 * 86_400.0)

FrameTap = Callable[[can.Message], None]
"""What a link calls with every frame it sends or receives (a :class:`FrameLog`, or your own)."""


def frame_message(frame: CanFrame, *, is_rx: bool = True, timestamp: float = 0.0) -> can.Message:
    """A python-can message for one protocol frame (11-bit identifier, classic CAN)."""
    return can.Message(
        arbitration_id=frame.arbitration_id,
        data=frame.data,
        is_extended_id=False,
        is_rx=is_rx,
        timestamp=timestamp,
    )


def log_suffix(path: str | Path) -> str:
    """The format-defining ending of a log file name (``.log`` for ``run.log.gz``).

    Raises
    ------
    ArgumentError
        The ending is not a CAN log format python-can knows.
    """
    suffixes = [s.lower() for s in Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    suffix = suffixes[-1] if suffixes else ""
    if suffix not in LOG_SUFFIXES:
        raise ArgumentError(
            f"{path}: not a CAN log name; the ending chooses the format: "
            f"{', '.join(LOG_SUFFIXES)} (a text format may add .gz)"
        )
    return suffix


def part_name(path: str | Path, index: int) -> Path:
    """The name of part ``index`` (0-based) of a rotated log: ``run.log`` -> ``run_#000.log``
    (``run.log`` itself is the part written last)."""
    p = Path(path)
    suffix = p.suffix
    return p.with_name(f"{p.name[: len(p.name) - len(suffix)]}_#{index:03d}{suffix}")


def _part_index(path: Path) -> tuple[str, int] | None:
    """(the base name, the index) of a finished part's name, None for any other name."""
    m = re.fullmatch(r"(.*)_#(\d{3,})(\.[^.]+)", path.name)
    if m is None:
        return None
    return str(path.with_name(m.group(1) + m.group(3))), int(m.group(2))


def log_parts(path: str | Path) -> list[Path]:
    """The finished parts of the rotated log ``path`` on disk, in order (``path`` itself, the
    part written last, not included)."""
    p = Path(path)
    stem = p.name[: len(p.name) - len(p.suffix)]
    found = [Path(f) for f in glob.glob(glob.escape(str(p.with_name(stem))) + "_#*" + p.suffix)]
    parts = [(_part_index(f), f) for f in found]
    return [f for key, f in sorted((k, f) for k, f in parts if k is not None and k[0] == str(p))]


def order_log_parts(paths: Iterable[str | Path]) -> tuple[list[Path], list[str]]:
    """Files of a log in reading order, and notes on parts missing from the set.

    Files that are all parts of one rotated log (``run_#000.log``, ``run_#001.log`` and maybe
    ``run.log``) are put in the order they were written, whatever the order given (a shell's
    ``run*.log`` lists ``run.log`` first); any other list keeps the order given. A part number
    skipped between two given parts is noted (frames of that time are missing).
    """
    files = [Path(f) for f in paths]
    keys = [_part_index(f) for f in files]
    bases = {k[0] for k in keys if k is not None}
    others = [f for f, k in zip(files, keys, strict=True) if k is None]
    if len(bases) != 1 or any(str(f) not in bases for f in others) or len(others) > 1:
        return files, []
    base = next(iter(bases))
    numbered = sorted((k[1], f) for f, k in zip(files, keys, strict=True) if k is not None)
    notes = [
        f"part #{n:03d} of {base} is missing between {a} and {b}"
        for (i, a), (j, b) in itertools.pairwise(numbered)
        for n in range(i + 1, j)
    ][:10]
    return [f for _, f in numbered] + others, notes


def expand_log_names(names: Iterable[str]) -> list[str]:
    """Log names as given, a name with ``*``, ``?`` or ``[`` that is no file expanded as a glob
    (sorted; :func:`order_log_parts` orders a rotated set)."""
    out: list[str] = []
    for name in names:
        if glob.has_magic(name) and not os.path.exists(name):
            matches = sorted(glob.glob(name))
            if not matches:
                raise ArgumentError(f"{name}: no file matches")
            out += matches
        else:
            out.append(name)
    return out


class RotatingLog(can.SizedRotatingLogger):
    """python-can's size-rotating logger, rotating by time as well, its parts named
    predictably (:func:`part_name`).

    Parameters
    ----------
    path : str or Path
        The log (the part written last keeps this name).
    max_bytes : int
        Begin a new part once the current one holds this many bytes (0: never by size).
    max_seconds : float
        Begin a new part with the first frame this many seconds, by the frames' timestamps,
        after the first frame of the current part (0: never by time).
    **options
        Passed to python-can's writer of each part.
    """

    def __init__(
        self, path: str | Path, *, max_bytes: int = 0, max_seconds: float = 0.0, **options: Any
    ) -> None:
        self.max_seconds = float(max_seconds)
        self._part_start: float | None = None
        self._next_index = 0
        super().__init__(str(path), max_bytes=max_bytes, **options)
        self.namer = self._name_part

    def _name_part(self, _default: Any) -> str:
        name = str(part_name(self.base_filename, self._next_index))
        self._next_index += 1
        return name

    def should_rollover(self, msg: can.Message) -> bool:
        if self._part_start is None:
            self._part_start = msg.timestamp
            return False
        due = super().should_rollover(msg) or (
            self.max_seconds > 0 and msg.timestamp - self._part_start >= self.max_seconds
        )
        if due:
            self._part_start = msg.timestamp
        return due


def check_rotation(path: str | Path, max_bytes: int = 0, max_seconds: float = 0.0) -> None:
    """Refuse a rotation a log cannot have (a format python-can does not rotate, a size or a
    time out of range) before anything is written.

    Raises
    ------
    ArgumentError
    """
    if not (max_bytes or max_seconds):
        return
    lo, hi = MAX_BYTES_RANGE
    if max_bytes and not lo <= max_bytes <= hi:
        raise ArgumentError(f"a rotated log's size must be {lo} to {hi} bytes, got {max_bytes}")
    lo_s, hi_s = MAX_SECONDS_RANGE
    if max_seconds and not lo_s <= max_seconds <= hi_s:
        raise ArgumentError(
            f"a rotated log's time must be {lo_s:g} to {hi_s:g} s, got {max_seconds:g}"
        )
    name = Path(path).name.lower()
    if not name.endswith(ROTATING_SUFFIXES):
        raise ArgumentError(
            f"{path}: a rotated log must end in {', '.join(ROTATING_SUFFIXES)} "
            "(the formats python-can rotates)"
        )


class FrameLog:
    """Writes CAN frames to a log file in the format its name ends with.

    Parameters
    ----------
    path : str or Path
        The log file (created or replaced).
    channel : str or int, optional
        The channel of every logged frame (see the module docstring).
    max_bytes : int, optional
        Rotate the log by size (see the module docstring; 0: never).
    max_seconds : float, optional
        Rotate the log by time (see the module docstring; 0: never).
    flush_s : float, optional
        Flush the file with the first frame this many wall seconds after the last flush (0:
        with every frame).
    **options
        Passed to python-can's writer (for example ``channel=`` of the ASC writer).

    Attributes
    ----------
    path : Path
    channel : str, int or None
        The channel every frame is logged on.
    frames : int
        Frames written.
    lost : int
        Frames not written after a write failed.
    error : Exception or None
        The first write error.

    Raises
    ------
    ArgumentError
        The file name has no CAN log ending; rotation of a format it does not take, or
        ``max_bytes`` or ``max_seconds`` out of range.
    LinkError
        The file cannot be created, or the format's library is missing (``.mf4``).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        channel: str | int | None = None,
        max_bytes: int = 0,
        max_seconds: float = 0.0,
        flush_s: float = 1.0,
        **options: Any,
    ) -> None:
        if not flush_s >= 0:
            raise ArgumentError(f"a log's flush interval must be 0 s or more, got {flush_s}")
        self.path = Path(path)
        suffix = log_suffix(self.path)
        check_rotation(self.path, max_bytes, max_seconds)
        self.channel = "can0" if channel is None and suffix == ".log" else channel
        self._writer: can.io.generic.MessageWriter
        try:
            if max_bytes or max_seconds:
                self._writer = RotatingLog(
                    self.path, max_bytes=max_bytes, max_seconds=max_seconds, **options
                )
            else:
                self._writer = can.Logger(str(self.path), **options)
        except (OSError, ValueError, ImportError) as exc:
            raise LinkError(f"cannot write the CAN log {self.path}: {exc}") from exc
        self._lock = threading.Lock()
        self._clock: Any = None
        self._epoch = 0.0
        self._closed = False
        self.flush_s = float(flush_s)
        self._flushed_at = time.monotonic()
        self.frames = 0
        self.lost = 0
        self.error: Exception | None = None

    def use_clock(self, clock: Any) -> None:
        """Stamp every frame from now on with ``clock.now()`` (a virtual clock), offset so that
        the clock's present reads as the wall-clock time of this call.

        The offset is a whole number of milliseconds: instants of the device's tick grid then
        fall on whole microseconds, as the text formats print them, instead of rounding half
        of them up and half down (a 5 ms tick would read 4.999 and 5.001 ms alternately)."""
        self._epoch = round(time.time() - clock.now(), 3)
        self._clock = clock

    def __call__(self, msg: can.Message) -> None:
        """Log one frame (thread-safe; after :meth:`close` frames are counted as lost)."""
        clock = self._clock
        if clock is not None:
            stamp = self._epoch + clock.now()
        else:
            stamp = msg.timestamp or time.time()
        msg = copy.copy(msg)  # the caller's frame keeps its own stamp and channel
        msg.timestamp, msg.channel = stamp, self.channel
        with self._lock:
            if self._closed or self.error is not None:
                self.lost += 1
                return
            try:
                self._writer.on_message_received(msg)
            except (OSError, ValueError) as exc:
                self.error = exc
                self.lost += 1
                return
            self.frames += 1
            if time.monotonic() - self._flushed_at >= self.flush_s:
                self._flush_writer()

    on_message_received = __call__
    """The :class:`can.Listener` spelling, so a :class:`can.Notifier` can feed the log too."""

    def flush(self) -> None:
        """Write the frames logged so far to the file, so that a reader of the file sees them
        (thread-safe; nothing after :meth:`close`)."""
        with self._lock:
            if not self._closed and self.error is None:
                self._flush_writer()

    def _flush_writer(self) -> None:
        # Called with the lock held. A rotating log's writer is its current part's.
        writer = getattr(self._writer, "writer", self._writer)
        self._flushed_at = time.monotonic()
        try:
            # BLF: the frames buffered for the next compressed container (python-can's own
            # method, private; without it the container waits for its size or the close).
            blf_flush = (
                getattr(writer, "_flush", None) if isinstance(writer, can.BLFWriter) else None
            )
            if callable(blf_flush):
                blf_flush()
            file = getattr(writer, "file", None)
            if file is not None and not file.closed:
                file.flush()
        except (OSError, ValueError) as exc:
            self.error = exc

    def close(self) -> None:
        """Flush and close the file (idempotent).

        Raises
        ------
        LinkError
            A write failed: the log misses :attr:`lost` frames.
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._drain_sqlite()
                self._writer.stop()
            except (OSError, ValueError) as exc:
                self.error = self.error or exc
            written = getattr(self._writer, "num_frames", None)
            if self.error is None and isinstance(written, int) and written < self.frames:
                self.lost += self.frames - written
                self.error = OSError(f"the writer stored {written} of {self.frames} frames")
        if self.error is not None:
            raise LinkError(
                f"the CAN log {self.path} is incomplete: {self.error} "
                f"({self.lost} frame(s) not written)"
            ) from self.error

    def _drain_sqlite(self, limit_s: float = 30.0) -> None:
        # python-can's SQLite writer stores frames from a queue in a thread and, once stopped,
        # ends after its current batch: frames still queued would be lost. Wait until it has
        # taken them all (the stored count is checked in close()).
        buffer = getattr(self._writer, "buffer", None)
        if not isinstance(self._writer, can.SqliteWriter) or buffer is None:
            return
        deadline = time.monotonic() + limit_s
        while not buffer.empty() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(2 * self._writer.GET_MESSAGE_TIMEOUT)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
