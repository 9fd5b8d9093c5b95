"""Sessions read back from CAN logs: the windows a host measured, rebuilt from the frame stream.

A CAN log in any format python-can reads (``.log`` candump, ``.asc``, ``.blf``, ``.csv``, ``.db``,
``.trc``, ``.mf4`` with asammdf; ``.gz`` after a text format) written by ``northfinder sim --log``,
``northfinder find/record --can-log``, python-can's logger or candump, holds everything a session
sent and received. :func:`read_can_log` decodes it with the protocol's own receiver
(:class:`~northfinder.driver.protocol.can.CanReceiver`) and rebuilds the windows:

- IDENTIFY gives the count scales and the device's identity; a SAMPLE_RATE_HZ configuration
  reply (GET_CONFIG or SET_CONFIG) the sample rate (default the protocol's 200 Hz).
- A window begins at each STREAM_START command and ends at the next ROTATE_TO, ROTATE_BY, HOME,
  RESET or STREAM_START (samples still arriving after a STREAM_STOP belong to it). Its commanded
  angle is that of the last ROTATE_TO (ROTATE_BY adds, HOME is 0). With ``window_s`` a window
  keeps its first ``round(window_s * rate)`` ticks, as ``find``'s acquisition did.
- A log without commands (a bus monitor that started late, say) is cut where the table moves:
  each run of samples without the moving or settling bits is a window, its commanded angle the
  encoder's.
- Missing ticks are never papered over: a window keeps its counters (the gaps show in
  :attr:`~northfinder.host.recording.RecordedWindow.gaps`) and :attr:`CanLogSession.notes` names
  every gap, every window shorter than asked and every frame that did not decode.
- A log cut short (a copy cut mid-file: a partial last line, a truncated BLF container) is read
  up to its break, and the notes say so ("cut short"); so does a last window whose STREAM_STOP
  is not in the log (the host stops every stream it starts). ``solve`` refuses such a log
  (exit 1), as it refuses one with a gap: the missing part could change the heading.
"""

from __future__ import annotations

import math
import sqlite3
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from northfinder.driver.framelog import LOG_SUFFIXES
from northfinder.driver.protocol.can import CanReceiver, TickLoss, split_can_id
from northfinder.driver.protocol.constants import (
    SAMPLE_RATE_DEFAULT_HZ,
    ConfigKey,
    Opcode,
    Validity,
)
from northfinder.driver.protocol.errors import ProtocolError
from northfinder.driver.protocol.messages import (
    Command,
    Home,
    Identify,
    Reply,
    Reset,
    RotateBy,
    RotateTo,
    Sample,
    StreamStart,
    StreamStop,
)
from northfinder.driver.window import CountScales, WindowCollector
from northfinder.host.errors import RecordingError
from northfinder.host.recording import RecordedWindow, Recording
from northfinder.host.results import SIMULATOR_MODEL, device_identity

__all__ = ["LOG_SUFFIXES", "CanLogSession", "is_can_log", "read_can_log"]

#: Ticks a whole-segment collector may span (far beyond any session: 2**40 ticks at 400 Hz is
#: 87 years).
_UNBOUNDED = 1 << 40
_MOVING = int(Validity.TABLE_MOVING | Validity.TABLE_SETTLING)
_CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"


#: python-can's own errors for a file that is not of the format its ending names.
_FORMAT_ERRORS: tuple[type[Exception], ...] = (can.io.blf.BLFParseError,)
_OPEN_ERRORS: tuple[type[Exception], ...] = (
    OSError, ValueError, ImportError, NotImplementedError, *_FORMAT_ERRORS,
)  # fmt: skip
_READ_ERRORS: tuple[type[Exception], ...] = (
    OSError, ValueError, EOFError, IndexError, KeyError, zlib.error, struct.error, sqlite3.Error,
    *_FORMAT_ERRORS,
)  # fmt: skip


def is_can_log(path: str | Path) -> bool:
    """Whether the file is a CAN log by its name (and, for ``.csv``, by python-can's header line:
    a northfinder recording is CSV too)."""
    p = Path(path)
    suffixes = [s.lower() for s in p.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    suffix = suffixes[-1] if suffixes else ""
    if suffix not in LOG_SUFFIXES:
        return False
    if suffix != ".csv" or p.name.lower().endswith(".gz"):
        return True
    try:
        with p.open(errors="replace") as fh:
            first = fh.readline().strip()
    except OSError:
        return False
    return first.replace(" ", "") == _CSV_HEADER


@dataclass(frozen=True)
class CanLogSession:
    """What a CAN log holds of one device's session.

    Attributes
    ----------
    source : str
        The file.
    node_id : int
        The device's node id.
    sample_rate_hz : float
    windows : tuple of RecordedWindow
        The windows, in time order (see the module docstring).
    identity : Identify or None
        The device's IDENTIFY, if the log holds one.
    commands : tuple of (float, str)
        Every command in the log: its timestamp and a readable form.
    notes : tuple of str
        Gaps, short windows, undecodable frames.
    frames : int
        Frames read.
    """

    source: str
    node_id: int
    sample_rate_hz: float
    windows: tuple[RecordedWindow, ...]
    identity: Identify | None = None
    commands: tuple[tuple[float, str], ...] = ()
    notes: tuple[str, ...] = ()
    frames: int = 0
    start_time: float | None = field(default=None, repr=False)
    #: The notes that say samples are missing (a gap, a window the log ends early, a log cut
    #: short): the data cannot vouch for a heading solved from it.
    incomplete: tuple[str, ...] = ()

    def recording(self, **meta: Any) -> Recording:
        """The windows as a :class:`~northfinder.host.recording.Recording` (with ``meta``)."""
        info: dict[str, Any] = {
            "sample_rate_hz": self.sample_rate_hz,
            "source": {"can_log": self.source, "node_id": self.node_id},
        }
        if self.identity is not None:
            info["device"] = device_identity(
                self.identity, simulated=self.identity.model == SIMULATOR_MODEL
            )
        return Recording(self.windows, {**info, **meta})


class _Segment:
    def __init__(self, commanded_deg: float, requested: int, t: float) -> None:
        self.commanded_deg = commanded_deg
        self.collector = WindowCollector(requested, on_gap="report")
        self.requested = requested
        self.t = t
        self.stopped = False


def _messages(path: Path, cut: list[str] | None = None) -> Iterator[can.Message]:
    """The log's frames. A file that breaks off after some frames (a copy cut short: a partial
    last line, a truncated BLF container) ends the frames there and says so in ``cut`` when it
    is given; without ``cut``, or before any frame, it is an error."""
    try:
        reader = can.LogReader(str(path))
    except _OPEN_ERRORS as exc:
        # NotImplementedError: python-can's reader for the format needs a package not installed
        # (asammdf for .mf4); its message names it.
        raise RecordingError(f"{path}: cannot read as a CAN log ({exc})") from exc
    n = 0
    try:
        with reader:
            for msg in reader:
                n += 1
                yield msg
    except _READ_ERRORS as exc:
        what = f"{type(exc).__name__}: {exc}"
        if cut is None or n == 0:
            raise RecordingError(f"{path}: unreadable CAN log ({what})") from exc
        cut.append(f"the log breaks off after frame {n} ({what}): it is cut short")


def _pick_node(path: Path) -> int:
    nodes: dict[int, int] = {}
    for msg in _messages(path, []):  # a log cut short is read to its break (read_can_log says so)
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            continue
        try:
            _, node = split_can_id(msg.arbitration_id)
        except ProtocolError:
            continue
        nodes[node] = nodes.get(node, 0) + 1
    if not nodes:
        raise RecordingError(f"{path}: no frame of the north finder protocol in this CAN log")
    if len(nodes) > 1:
        raise RecordingError(
            f"{path}: frames of nodes {', '.join(map(str, sorted(nodes)))}; choose one (--node-id)"
        )
    return next(iter(nodes))


def read_can_log(
    path: str | Path,
    *,
    node_id: int | None = None,
    window_s: float | None = None,
    min_windows: int = 2,
) -> CanLogSession:
    """Rebuild a session's windows from a CAN log (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The log; python-can's reader for its ending reads it.
    node_id : int, optional
        The device whose session to read (default: the only node in the log).
    window_s : float, optional
        Keep the first ``round(window_s * rate)`` ticks of each window (default: all samples
        streamed at the position).
    min_windows : int
        Fewer windows is an error (north finding needs two).

    Raises
    ------
    RecordingError
        Not a readable CAN log, no protocol frame, several nodes and none chosen, fewer windows
        than ``min_windows``.
    """
    p = Path(path)
    if window_s is not None and not (math.isfinite(window_s) and window_s > 0):
        raise RecordingError(f"window: must be a positive number of seconds, got {window_s!r}")
    node = _pick_node(p) if node_id is None else node_id
    receiver = CanReceiver(node_id=node)
    scales = CountScales()
    identity: Identify | None = None
    rate = float(SAMPLE_RATE_DEFAULT_HZ)
    commanded = 0.0
    commands: list[tuple[float, str]] = []
    segments: list[_Segment] = []
    current: _Segment | None = None
    free: _Segment | None = None  # a window cut by the encoder, for logs without commands
    free_segments: list[_Segment] = []
    saw_stream_start = False
    frames = 0
    t0: float | None = None

    def requested() -> int:
        return _UNBOUNDED if window_s is None else max(1, round(window_s * rate))

    cut: list[str] = []
    for msg in _messages(p, cut):
        frames += 1
        if t0 is None:
            t0 = msg.timestamp
        if msg.is_error_frame or msg.is_remote_frame:
            continue
        data = bytes(msg.data)
        for item in receiver.feed(msg.arbitration_id, data, is_extended_id=msg.is_extended_id):
            if isinstance(item, Sample):
                if current is not None:
                    if not current.collector.done:
                        current.collector.add_sample(item, msg.timestamp)
                elif not saw_stream_start:
                    at_rest = not (int(item.validity) & _MOVING)
                    if at_rest and free is None:
                        free = _Segment(item.angle * scales.angle_deg, requested(), msg.timestamp)
                        free_segments.append(free)
                    elif not at_rest:
                        free = None
                    if free is not None and not free.collector.done:
                        free.collector.add_sample(item, msg.timestamp)
            elif isinstance(item, TickLoss):
                for seg in (current, free):
                    if seg is not None and not seg.collector.done:
                        seg.collector.add_loss(item)
            elif isinstance(item, Identify):
                identity, scales = item, CountScales.of(item)
            elif isinstance(item, Reply):
                if item.ok and item.opcode in (Opcode.GET_CONFIG, Opcode.SET_CONFIG):
                    try:
                        key, value = item.config_value()
                    except ProtocolError:
                        continue
                    if key == ConfigKey.SAMPLE_RATE_HZ and value > 0:
                        rate = float(value)
            elif isinstance(item, Command):
                commands.append((msg.timestamp - (t0 or 0.0), repr(item)))
                if isinstance(item, RotateTo):
                    commanded = item.angle * scales.angle_deg
                elif isinstance(item, RotateBy):
                    commanded = (commanded + item.delta * scales.angle_deg) % 360.0
                elif isinstance(item, Home):
                    commanded = 0.0
                if isinstance(item, StreamStop) and current is not None:
                    current.stopped = True
                if isinstance(item, RotateTo | RotateBy | Home | Reset | StreamStart):
                    current = None
                if isinstance(item, StreamStart):
                    saw_stream_start = True
                    free = None
                    receiver.ticks.restart()  # as the driver does: a new stream
                    current = _Segment(commanded, requested(), msg.timestamp)
                    segments.append(current)
    chosen = segments if saw_stream_start else free_segments
    incomplete: list[str] = list(cut)
    notes: list[str] = []
    if receiver.malformed:
        notes.append(
            f"{receiver.malformed} frame(s) of node {node} did not decode "
            f"(last: {receiver.last_error})"
        )
    windows: list[RecordedWindow] = []
    for seg in chosen:
        if seg.collector.received == 0:
            continue
        w = seg.collector.window(rate, scales)
        rec = RecordedWindow.from_window(w, seg.commanded_deg)
        i = len(windows) + 1
        for first, count in w.gaps:
            incomplete.append(
                f"window {i} ({seg.commanded_deg:g} deg): {count} tick(s) missing from counter {first}"
            )
        if window_s is not None and not seg.collector.done:
            incomplete.append(
                f"window {i} ({seg.commanded_deg:g} deg): the log ends the window after "
                f"{seg.collector.received + seg.collector.missing} of {seg.requested} ticks"
            )
        if seg is current and not seg.stopped and not seg.collector.done:
            # The host stops every stream it starts: a last window without its STREAM_STOP
            # is a log cut inside the window, whose samples fall short of what was measured.
            incomplete.append(
                f"window {i} ({seg.commanded_deg:g} deg): the log ends inside the window after "
                f"{seg.collector.received + seg.collector.missing} ticks, before its STREAM_STOP: "
                "the log is cut short"
            )
        windows.append(rec)
    if len(windows) < min_windows:
        raise RecordingError(
            f"{p}: {len(windows)} window(s) of node {node} in the log; need at least {min_windows} "
            "(a window is the samples streamed at one position)"
        )
    return CanLogSession(
        str(p), node, rate, tuple(windows), identity, tuple(commands),
        tuple(incomplete + notes), frames, t0, incomplete=tuple(incomplete),
    )  # fmt: skip
