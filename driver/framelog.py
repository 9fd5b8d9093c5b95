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

A write that fails (disk full, say) does not stop the link: the first error is kept in
:attr:`FrameLog.error`, later frames are counted in :attr:`FrameLog.lost`, and :meth:`close`
raises :class:`~northfinder.driver.errors.LinkError` naming both, so a log is never silently
incomplete.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from northfinder.driver.errors import ArgumentError, LinkError
from northfinder.driver.protocol.can import CanFrame

__all__ = ["LOG_SUFFIXES", "FrameLog", "FrameTap", "frame_message", "log_suffix"]

LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc")
"""File endings python-can reads and writes as CAN logs (``.mf4`` needs ``asammdf``)."""

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


class FrameLog:
    """Writes CAN frames to a log file in the format its name ends with.

    Parameters
    ----------
    path : str or Path
        The log file (created or replaced).
    channel : str or int, optional
        The channel of every logged frame (see the module docstring).
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
        The file name has no CAN log ending.
    LinkError
        The file cannot be created, or the format's library is missing (``.mf4``).
    """

    def __init__(
        self, path: str | Path, *, channel: str | int | None = None, **options: Any
    ) -> None:
        self.path = Path(path)
        suffix = log_suffix(self.path)
        self.channel = "can0" if channel is None and suffix == ".log" else channel
        try:
            self._writer = can.Logger(str(self.path), **options)
        except (OSError, ValueError, ImportError) as exc:
            raise LinkError(f"cannot write the CAN log {self.path}: {exc}") from exc
        self._lock = threading.Lock()
        self._clock: Any = None
        self._epoch = 0.0
        self._closed = False
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
        msg = can.Message(
            timestamp=stamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            is_error_frame=msg.is_error_frame,
            channel=self.channel,
            dlc=msg.dlc,
            data=msg.data,
            is_fd=msg.is_fd,
            is_rx=msg.is_rx,
            bitrate_switch=msg.bitrate_switch,
            error_state_indicator=msg.error_state_indicator,
            check=False,
        )
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

    on_message_received = __call__
    """The :class:`can.Listener` spelling, so a :class:`can.Notifier` can feed the log too."""

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

    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
