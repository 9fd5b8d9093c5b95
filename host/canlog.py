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
- A rotated log (``sim --log-max-bytes``, python-can's rotating loggers) is read as one log from
  its parts in order (:func:`~northfinder.driver.framelog.order_log_parts`). Where frames are
  missing between two parts (a part left out, the device's sample counter in STATUS_COUNTERS
  jumping by more than :data:`PART_GAP_HEARTBEATS` heartbeats), the notes say so and the window
  measured across or just after the gap counts as incomplete (its commanded angle or samples
  may be among the missing frames).
- A log cut short (a copy cut mid-file: a partial last line, a truncated BLF container) is read
  up to its break, and the notes say so ("cut short"); so does a last window whose STREAM_STOP
  is not in the log (the host stops every stream it starts). ``solve`` refuses such a log
  (exit 1), as it refuses one with a gap: the missing part could change the heading.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import logging
import math
import os
import re
import sqlite3
import stat
import struct
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import can
import numpy as np

from northfinder.driver.framelog import LOG_SUFFIXES, order_log_parts
from northfinder.driver.protocol.can import CanReceiver, TickLoss, split_can_id
from northfinder.driver.protocol.constants import (
    SAMPLE_RATE_DEFAULT_HZ,
    CanFunction,
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
    RequestIdentify,
    Reset,
    RotateBy,
    RotateTo,
    Sample,
    StreamStart,
    StreamStop,
)
from northfinder.driver.window import CountScales, SampleColumns, WindowCollector
from northfinder.host.errors import RecordingError
from northfinder.host.recording import RecordedWindow, Recording
from northfinder.host.results import SIMULATOR_MODEL, device_identity

__all__ = [
    "LOG_SUFFIXES",
    "CanLogSession",
    "LogSet",
    "ReadProgress",
    "SessionCounter",
    "check_log_file",
    "decode_signals",
    "is_can_log",
    "read_can_log",
    "read_frames",
]

LogPaths = str | Path | Sequence[str | Path]
"""One log file, or the parts of a log in order (a rotated log)."""
ReadProgress = Callable[[int, int], None]
"""Told how far a reading is: ``progress(done, total)`` in bytes of the log's files."""


def decode_signals(db: Any, arbitration_id: int, data: bytes) -> tuple[str, int, list[str]]:
    """A protocol frame decoded by cantools with the protocol's DBC ``db`` (as
    ``cantools decode`` would): the message's name, the frame's node id and each signal as
    ``"Name: value unit"``. The DBC describes node 1 (``DBC_NODE``); a frame of another node is
    decoded by the same message. The message and its units are looked up once per DBC and id.

    Raises
    ------
    Exception
        What cantools raises for a frame it does not know or cannot decode (its own errors,
        KeyError, ValueError).
    """
    _, node = split_can_id(arbitration_id)
    message, units = _dbc_message(db, arbitration_id & ~0x0F)
    signals = message.decode(bytes(data), decode_choices=True, allow_truncated=True)
    fields = [
        f"{name}: {value:g}{units[name]}"
        if isinstance(value, float)
        else f"{name}: {value}{units[name]}"
        for name, value in signals.items()
    ]
    return message.name, node, fields


@functools.lru_cache(maxsize=256)
def _dbc_message(db: Any, base_id: int) -> tuple[Any, dict[str, str]]:
    """The DBC's message of a function's base id and its signals' units (``" deg"`` or ``""``)."""
    from northfinder.driver.protocol import DBC_NODE

    message = db.get_message_by_frame_id(base_id | DBC_NODE)
    return message, {sig.name: f" {sig.unit}" if sig.unit else "" for sig in message.signals}


#: A jump of the device's sample counter between two parts of a log of more than this many
#: heartbeats (the typical step between two STATUS_COUNTERS) means frames are missing.
PART_GAP_HEARTBEATS = 2.5

#: Ticks a whole-segment collector may span (far beyond any session: 2**40 ticks at 400 Hz is
#: 87 years).
_UNBOUNDED = 1 << 40
_MOVING = int(Validity.TABLE_MOVING | Validity.TABLE_SETTLING)
_CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"


#: python-can's own errors for a file that is not of the format its ending names.
_FORMAT_ERRORS: tuple[type[Exception], ...] = (can.io.blf.BLFParseError,)
_OPEN_ERRORS: tuple[type[Exception], ...] = (
    OSError, ValueError, ImportError, NotImplementedError, EOFError, struct.error, zlib.error,
    *_FORMAT_ERRORS,
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
    if not p.is_file():  # a FIFO would block the read of its header line
        return False
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
    #: Indices into :attr:`windows` (0-based) of the windows with samples missing.
    incomplete_windows: tuple[int, ...] = ()
    #: Damaged lines skipped (``skip_damaged``).
    skipped_lines: int = 0
    #: (session, windows) of every host session with windows in the log.
    sessions: tuple[tuple[int, int], ...] = ()
    #: The session read (None: the log's only one).
    session: int | None = None
    #: The number (1-based, in its session) of each window of :attr:`windows`.
    window_numbers: tuple[int, ...] = ()
    #: The parts of the log in reading order (one file: just it).
    parts: tuple[str, ...] = ()
    #: Frames missing between two parts (a part left out, a jump of the device's counter).
    part_gaps: tuple[str, ...] = ()
    #: Indices into :attr:`windows` of the windows whose only flaw is ticks missing inside them
    #: (bounded by their STREAM_START and STREAM_STOP, no cut, no part gap): the mean of the
    #: samples received stands for them (``solve --on-gap report``).
    gap_windows: tuple[int, ...] = ()
    #: The first damaged line skipped, ``run.log:801: garbage here (ValueError: ...)``.
    first_damaged: str | None = None
    #: With ``read_can_log(..., summarise=f)``: ``f`` of each window, in the order of
    #: :attr:`window_numbers`; :attr:`windows` is then empty (the samples were dropped).
    summaries: tuple[Any, ...] = ()

    def complete(self, *, keep_gaps: bool = False) -> CanLogSession:
        """The session without its windows that have samples missing (a gap, a cut);
        ``keep_gaps`` keeps those whose only flaw is ticks missing (:attr:`gap_windows`)."""
        keep = [
            i for i in range(len(self.windows) or len(self.summaries))
            if i not in self.incomplete_windows or (keep_gaps and i in self.gap_windows)
        ]  # fmt: skip
        return dataclasses.replace(
            self,
            windows=tuple(self.windows[i] for i in keep) if self.windows else (),
            summaries=tuple(self.summaries[i] for i in keep) if self.summaries else (),
            window_numbers=tuple(self.window_numbers[i] for i in keep)
            if self.window_numbers
            else (),
            incomplete_windows=(),
            gap_windows=(),
        )

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


class SessionCounter:
    """Host sessions in a frame stream. Each host that connects asks IDENTIFY first; an IDENTIFY
    command after a STREAM_START of the session before begins a new session (the retries of a
    host's first IDENTIFY do not). Feed it every command in order; :attr:`number` is the
    session (1-based) the command belongs to."""

    def __init__(self) -> None:
        self.number = 1
        self._streamed = False

    def command(self, command: Command) -> int:
        """The session of ``command`` (a new one when it begins one)."""
        if isinstance(command, RequestIdentify) and self._streamed:
            self.number += 1
            self._streamed = False
        if isinstance(command, StreamStart):
            self._streamed = True
        return self.number


class _Segment:
    def __init__(self, commanded_deg: float, requested: int, t: float, session: int = 1) -> None:
        self.session = session
        self.commanded_deg = commanded_deg
        self.collector = WindowCollector(requested, on_gap="report")
        self.requested = requested
        self.t = t
        self.stopped = False
        #: Frames missing between two parts of the log in or just before this window.
        self.suspect: str | None = None
        #: What ``summarise`` made of the window as it ended, and the rate and scales its
        #: samples were converted with (:meth:`summarise`).
        self.summary: tuple[Any, float, CountScales] | None = None

    def summarise(
        self, summarise: Callable[[RecordedWindow, float], Any], rate_hz: float, scales: CountScales
    ) -> None:
        """Reduce the window (ended) with ``summarise`` and drop its samples: the collector is
        replaced by what :meth:`_Scan.window_flaws` and :meth:`_Scan.choose` read of it."""
        self.summary = (summarise(self.recorded(rate_hz, scales), rate_hz), rate_hz, scales)
        c = self.collector
        self.collector = _Collected(c.gaps, c.received, c.missing, c.done)  # type: ignore[assignment]

    def recorded(self, sample_rate_hz: float, scales: CountScales) -> RecordedWindow:
        """The window's samples in physical units; the collector's raw counts are released as
        they are converted (call once)."""
        window = self.collector.take_window(sample_rate_hz, scales)
        return RecordedWindow.from_window(window, self.commanded_deg)


@dataclass(frozen=True)
class _Collected:
    """What is known of a window's collector once its samples are summarised and dropped."""

    gaps: list[tuple[int, int]]
    received: int
    missing: int
    done: bool


class _Restart(Exception):
    """The rate or scales changed after windows were summarised: read the log again whole."""


#: python-can's readers of text logs whose lines each hold one frame after a header: a damaged
#: line among them can be skipped and the rest read on.
_TEXT_READERS: dict[str, type[Any]] = {
    ".log": can.CanutilsLogReader,
    ".asc": can.ASCReader,
    ".csv": can.CSVReader,
    ".trc": can.TRCReader,
}
#: Most damaged lines skipped before a log counts as unreadable.
MAX_SKIPPED_LINES = 10_000


#: Longest line of a text log taken at once: a longer one (a binary file has few line ends) is
#: read in pieces of this many characters, each a damaged line, so memory stays bounded.
MAX_LINE_CHARS = 1 << 16
#: Lines before a log's first frame kept to hand again to the reader that goes on after a
#: damaged line (python-can's text readers learn the format from them: ASC's base and times,
#: TRC's version and columns). Beyond this many it is no header.
MAX_HEADER_LINES = 200
#: ASC lines that hold no frame and are not junk: the header, the trigger blocks, comments and
#: events (every event line begins with its time).
_ASC_OTHER = re.compile(
    r"\s*($|//|date\s|base\s|(no\s+)?internal\s+events\s+logged|begin\s+triggerblock"
    r"|end\s+triggerblock|[-+]?\d+(\.\d*)?(\s|$))",
    re.IGNORECASE,
)


class _FileBroken(Exception):
    """The file itself could not be read on (a truncated ``.gz``, an I/O error)."""


def _printable(text: str, limit: int = 60) -> str:
    """Text of a damaged line fit for one line of a terminal: other than printable ASCII
    escaped, cut at ``limit`` characters."""
    shown = text.encode("ascii", "backslashreplace").decode("ascii")
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in shown)
    return shown[:limit] + ("..." if len(shown) > limit else "")


def _excerpt(line: str) -> str:
    return f"'{_printable(line.rstrip(chr(13) + chr(10)), 40)}'"


class _Feed:
    """The lines of a text log handed to a python-can reader one at a time, streamed from the
    file (the readers take a line and parse it before the next), so that the line a reader fails
    on and the lines it passes over without a frame are known. After a damaged line a new reader
    goes on from the next, given the header lines again.

    A line the reader passes over that its format cannot hold (``junk``: a line of a binary
    file, say) is a damaged line too: python-can's ASC reader passes such lines over in silence
    and its TRC reader logs a warning for each; here they are counted."""

    def __init__(self, fh: Any, suffix: str) -> None:
        self.fh = fh
        self.suffix = suffix
        self.number = 0  # lines of the file taken so far
        self._line_open = False  # the last piece read ended inside a line
        self.header: list[str] | None = []  # lines taken while no frame came yet
        self._first_lines: list[str] = []  # the header: lines before the first frame or damage
        self.replay: list[str] = []  # header lines to hand to the next reader
        self.pending: str | None = None  # the last line of the file handed out, no frame yet
        self.junk: tuple[int, str] | None = None  # a line passed over that holds no frame
        self.eof = False

    def read(self, *_: Any) -> str:  # pragma: no cover - the readers iterate
        raise io.UnsupportedOperation("a CAN log is read line by line")

    def readline(self) -> str:
        return next(self, "")

    def __iter__(self) -> _Feed:
        return self

    def _passed_over(self, line: str) -> None:
        if self.suffix == ".asc" and not _ASC_OTHER.match(line):
            self.junk = (self.number, f"not a frame of an ASC log: {_excerpt(line)}")

    def __next__(self) -> str:
        if self.pending is not None:
            self._passed_over(self.pending)
            self.pending = None
        if self.junk is not None:
            raise ValueError(self.junk[1])
        if self.replay:
            return self.replay.pop(0)
        try:
            line = self.fh.readline(MAX_LINE_CHARS)
        except (OSError, EOFError, zlib.error, UnicodeError) as exc:
            raise _FileBroken(f"{type(exc).__name__}: {exc}") from exc
        if not line:
            self.eof = True
            raise StopIteration
        if not self._line_open:
            self.number += 1
        self._line_open = not line.endswith("\n")
        if self.header is not None and len(self.header) < MAX_HEADER_LINES:
            self.header.append(line)
        self.pending = line
        return line

    def frame(self) -> None:
        """The reader made a frame of the last line."""
        self.pending = None
        if self.header is not None:
            self._first_lines = self.header[: max(0, self.number - 1)]
            self.header = None

    def end(self) -> None:
        """The reader is through the file: the last line, if it gave no frame, was passed over."""
        if self.pending is not None:
            self._passed_over(self.pending)
            self.pending = None
        if self.junk is not None:
            raise ValueError(self.junk[1])

    def damaged(self) -> tuple[int, str | None, str | None]:
        """A reader failed on the last line taken: its number, the message of junk found (None:
        the reader's own error) and the line (None if unknown). The next reader is handed the
        header again."""
        line = self.pending
        number, text = self.junk if self.junk is not None else (self.number, None)
        self.junk = None
        self.pending = None
        if self.header is not None:  # no frame yet: the header is what came before this line
            self._first_lines = self.header[: max(0, self.number - 1)]
            self.header = None
        self.replay = list(self._first_lines)
        return number, text, line

    def close(self) -> None:
        pass


class _TrcWarnings(logging.Filter):
    """python-can's TRC reader logs a warning for every line it cannot parse: each becomes a
    damaged line of the feed instead of a line on stderr."""

    def __init__(self, feed: _Feed) -> None:
        super().__init__()
        self.feed = feed

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        if self.feed.pending is not None and self.feed.junk is None:
            self.feed.junk = (
                self.feed.number,
                f"not a frame of a TRC log: {_excerpt(self.feed.pending)}",
            )
        return False


def _text_suffix(path: Path) -> tuple[str, bool] | None:
    """The ending of a text log whose reader can skip a damaged line, and whether it is
    gzipped (None for other formats)."""
    suffixes = [s.lower() for s in path.suffixes]
    gz = bool(suffixes) and suffixes[-1] == ".gz"
    if gz:
        suffixes = suffixes[:-1]
    if not suffixes or suffixes[-1] not in _TEXT_READERS:
        return None
    return suffixes[-1], gz


def _text_messages(
    path: Path,
    suffix: str,
    gz: bool,
    skipped: list[tuple[int, str]] | None,
    cut: list[str] | None,
    opened: list[Any] | None = None,
    **options: Any,
) -> Iterator[can.Message]:
    """The frames of a text log, streamed line by line (the file object read goes to
    ``opened``). With ``skipped`` each damaged line is
    skipped and noted there as (line number, error), and a new reader goes on after it, given
    the header again; without, the log ends at the first (noted in ``cut``; before any frame an
    error)."""
    reader_class = _TEXT_READERS[suffix]
    try:
        if gz:
            import gzip

            fh: Any = gzip.open(path, "rt", errors="replace", newline="")
        else:
            fh = path.open(errors="replace", newline="")
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read as a CAN log ({exc})") from exc
    if opened is not None:
        opened.append(fh)
    feed = _Feed(fh, suffix)
    trc_log = logging.getLogger("can.io.trc")
    quiet = _TrcWarnings(feed)
    trc_log.addFilter(quiet)
    n = 0
    try:
        while True:
            try:
                for msg in reader_class(feed, **options):
                    feed.frame()
                    n += 1
                    yield msg
                feed.end()
                return
            except _FileBroken as exc:
                if cut is None or n == 0:
                    raise RecordingError(f"{path}: cannot read as a CAN log ({exc})") from exc
                cut.append(f"the log breaks off after frame {n} ({exc}): it is cut short")
                return
            except _READ_ERRORS as exc:
                number, junk, line = feed.damaged()
                what = junk or (
                    (f"{_excerpt(line)} " if line else "")
                    + f"({type(exc).__name__}: {_printable(str(exc))})"
                )
                if skipped is None:
                    if cut is None or n == 0:
                        raise RecordingError(
                            f"{path}: unreadable CAN log (line {number}: {what})"
                        ) from exc
                    cut.append(f"the log breaks off after frame {n} ({what}): it is cut short")
                    return
                skipped.append((number, what))
                if len(skipped) > MAX_SKIPPED_LINES:
                    raise RecordingError(
                        f"{path}: more than {MAX_SKIPPED_LINES} damaged lines (line "
                        f"{skipped[0][0]}: {skipped[0][1]}): not a CAN log python-can reads"
                    ) from exc
                if feed.eof:
                    return
    finally:
        trc_log.removeFilter(quiet)
        fh.close()


def check_log_file(path: str | Path) -> None:
    """A CAN log is a regular file: anything else is named for what it is (reading a FIFO would
    wait for a writer that may never come).

    Raises
    ------
    RecordingError
        No such file, a folder, a FIFO, a device or a socket.
    """
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise RecordingError(f"{p}: no such file") from None
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read ({exc.strerror or exc})") from exc
    if stat.S_ISDIR(mode):
        raise RecordingError(f"{p}: a folder, not a CAN log (give the log files in it)")
    if not stat.S_ISREG(mode):
        kind = (
            "a FIFO" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode)
            else "not a file"
        )  # fmt: skip
        raise RecordingError(f"{p}: {kind}, not a regular file: a CAN log is read from a file")


def _messages(
    path: Path,
    cut: list[str] | None = None,
    skipped: list[tuple[int, str]] | None = None,
    opened: list[Any] | None = None,
    **options: Any,
) -> Iterator[can.Message]:
    """The log's frames, streamed (the file object read goes to ``opened``: its position is how
    far the reading is). A file that breaks off after some frames (a copy cut short: a
    partial last line, a truncated BLF container) ends the frames there and says so in ``cut``
    when it is given; without ``cut``, or before any frame, it is an error. With ``skipped`` a
    damaged line of a text log is skipped and noted there (line number, error), and the lines
    after it are read."""
    check_log_file(path)
    text = _text_suffix(path)
    if text is not None:
        yield from _text_messages(path, *text, skipped, cut, opened, **options)
        return
    try:
        reader = can.LogReader(str(path), **options)
    except _OPEN_ERRORS as exc:
        # NotImplementedError: python-can's reader for the format needs a package not installed
        # (asammdf for .mf4); its message names it.
        raise RecordingError(f"{path}: cannot read as a CAN log ({exc})") from exc
    file = getattr(reader, "file", None)
    if opened is not None and file is not None:
        opened.append(file)
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


class LogSet:
    """A CAN log of one file or of several parts read in order, as one stream of frames.

    Parameters
    ----------
    paths : str, Path or sequence of them
        The file, or the parts (a rotated log's parts are put in the order they were written,
        :func:`~northfinder.driver.framelog.order_log_parts`).

    Attributes
    ----------
    files : list of Path
        The parts in reading order.
    gaps : list of str
        Frames missing between two parts (a part number skipped; the device's sample counter
        jumping at a boundary), as found while reading.
    """

    def __init__(self, paths: LogPaths) -> None:
        given = [paths] if isinstance(paths, str | Path) else list(paths)
        if not given:
            raise RecordingError("no CAN log given")
        self.files, self.gaps = order_log_parts(given)
        self._gaps_named = len(self.gaps)
        #: (file, line, what) of every damaged line skipped in the last reading.
        self.damaged: list[tuple[str, int, str]] = []
        #: ASC stores times from each file's start: parts are read by their absolute times.
        self._reader_options = {"relative_timestamp": False} if len(self.files) > 1 else {}
        self._sizes = [_size(f) for f in self.files]
        self._before = 0  # bytes of the parts read before the current one
        self._opened: list[Any] = []  # the current part's file object

    def position(self) -> tuple[int, int]:
        """How far the reading is: bytes of the files read so far (of a compressed file, its
        compressed bytes), and of them all."""
        total = sum(self._sizes)
        at = 0
        if self._opened:
            try:
                at = os.lseek(self._opened[-1].fileno(), 0, os.SEEK_CUR)
            except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
                at = 0
        return min(self._before + at, total), total

    @property
    def name(self) -> str:
        """The log as named in messages: its file, or ``FIRST .. LAST (N parts)``."""
        if len(self.files) == 1:
            return str(self.files[0])
        return f"{self.files[0]} .. {self.files[-1]} ({len(self.files)} parts)"

    def messages(
        self, cut: list[str] | None = None, skipped: list[tuple[int, str]] | None = None
    ) -> Iterator[can.Message]:
        """The frames of every part in order (``cut`` and ``skipped`` as :func:`read_frames`:
        a part that breaks off is noted and the next part read). Frames missing at a boundary
        between parts are added to :attr:`gaps` when the first status after it shows them."""
        del self.gaps[self._gaps_named :]  # a second reading finds them again
        self.damaged = []
        return self._messages(cut, skipped)

    def _messages(
        self, cut: list[str] | None, skipped: list[tuple[int, str]] | None
    ) -> Iterator[can.Message]:
        last: dict[int, int] = {}  # node -> sample counter of its last STATUS_COUNTERS
        steps: dict[int, list[int]] = {}  # node -> recent counter steps between heartbeats
        pending: dict[int, str] = {}  # node -> the boundary its next status crosses
        previous: Path | None = None
        for path in self.files:
            if previous is not None:
                pending = {node: f"{previous} and {path}" for node in last}
            part_skipped: list[tuple[int, str]] | None = None if skipped is None else []
            options = self._reader_options if path.name.lower().endswith(".asc") else {}
            self._before = sum(self._sizes[: self.files.index(path)])
            self._opened = []
            for msg in _messages(path, cut, part_skipped, self._opened, **options):
                if (
                    msg.arbitration_id & 0x7F0 == CanFunction.STATUS_COUNTERS
                    and len(msg.data) == 8
                    and not (msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame)
                ):
                    self._watch(msg, last, steps, pending)
                yield msg
            if skipped is not None and part_skipped:
                prefix = f"{path} " if len(self.files) > 1 else ""
                skipped += [(n, f"{prefix}{e}") for n, e in part_skipped]
                self.damaged += [(str(path), n, e) for n, e in part_skipped]
            previous = path

    def _watch(
        self,
        msg: can.Message,
        last: dict[int, int],
        steps: dict[int, list[int]],
        pending: dict[int, str],
    ) -> None:
        node = msg.arbitration_id & 0x0F
        counter = int.from_bytes(bytes(msg.data[:4]), "little")
        before = last.get(node)
        last[node] = counter
        if before is None:
            return
        step = (counter - before) % (1 << 32)
        boundary = pending.pop(node, None)
        recent = steps.setdefault(node, [])
        if boundary is None:
            recent.append(step)
            del recent[:-16]
            return
        typical = sorted(recent)[len(recent) // 2] if recent else 0
        if typical > 0 and step > PART_GAP_HEARTBEATS * typical:
            self.gaps.append(
                f"frames missing between {boundary}: the device's sample counter jumps from "
                f"{before} to {counter} (about {step / typical:.0f} heartbeats)"
            )


def read_frames(
    path: LogPaths,
    *,
    skip_damaged: bool = True,
    skipped: list[tuple[int, str]] | None = None,
    cut: list[str] | None = None,
    gaps: list[str] | None = None,
    progress: ReadProgress | None = None,
) -> Iterator[can.Message]:
    """The frames of a CAN log in any format python-can reads, or of the parts of a rotated log
    in order; with ``skip_damaged`` a damaged line of a text log is skipped and noted in
    ``skipped`` (line number, error), and a log that breaks off ends there (noted in ``cut``).
    ``gaps`` receives a note for frames missing between two parts as they are found;
    ``progress(done, total)`` is told the bytes read every 65536 frames and at the end."""
    logs = LogSet(path)
    if gaps is not None:
        gaps += logs.gaps
    frames = logs.messages(
        [] if cut is None else cut,
        (skipped if skipped is not None else []) if skip_damaged else None,
    )
    if progress is not None:
        frames = _telling(logs, frames, progress)
    if gaps is None:
        return frames
    return _noting_gaps(logs, frames, gaps)


def _telling(
    logs: LogSet, frames: Iterator[can.Message], progress: ReadProgress
) -> Iterator[can.Message]:
    for n, msg in enumerate(frames, 1):
        yield msg
        if not n & 0xFFFF:
            progress(*logs.position())
    total = logs.position()[1]
    progress(total, total)


def _noting_gaps(
    logs: LogSet, frames: Iterator[can.Message], gaps: list[str]
) -> Iterator[can.Message]:
    seen = len(logs.gaps)
    for msg in frames:
        if len(logs.gaps) > seen:
            gaps += logs.gaps[seen:]
            seen = len(logs.gaps)
        yield msg


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0  # the reader names what is wrong with it


#: The function part (``id & 0x7F0``) of every protocol identifier.
_FUNCTION_IDS = frozenset(int(f) for f in CanFunction)
#: The sample frames' functions and their slots in a tick: x, y, z, aux.
_SAMPLE_SLOTS = {
    int(CanFunction.SAMPLE_X): 0,
    int(CanFunction.SAMPLE_Y): 1,
    int(CanFunction.SAMPLE_Z): 2,
    int(CanFunction.SAMPLE_AUX): 3,
}
_SLOT_FUNCTIONS = tuple(sorted(_SAMPLE_SLOTS, key=_SAMPLE_SLOTS.__getitem__))
#: A SAMPLE_X/_Y/_Z frame's 8 bytes (tick, gyro i32, accel i24 as its low 16 bits and high byte)
#: and a SAMPLE_AUX frame's (tick, angle u32, temperature i16, validity u8), as numpy reads them.
_AXIS_FRAME = np.dtype([("tick", "u1"), ("gyro", "<i4"), ("lo", "<u2"), ("hi", "i1")])
_AUX_FRAME = np.dtype(
    [("tick", "u1"), ("angle", "<u4"), ("temperature", "<i2"), ("validity", "u1")]
)
#: Sample frames of a streaming window buffered before they are decoded together (64 KiB of
#: frame data); 0 decodes every frame one by one.
RUN_FRAMES = 8192
#: The slots of a tick's frames in the order a device sends them (x, y, z, aux), repeated.
_TICK_ORDER = bytes(range(4)) * (RUN_FRAMES // 4)
_U32 = 0xFFFF_FFFF


def _tick_columns(frames: np.ndarray, first_raw: int) -> SampleColumns:
    """The samples of whole ticks from their frames (shape (ticks, 4, 8): slots x, y, z, aux),
    the first of counter ``first_raw`` and each after it the next (wrapping at 2**32)."""
    n = len(frames)
    axis = np.ascontiguousarray(frames[:, :3]).view(_AXIS_FRAME)[..., 0]
    aux = np.ascontiguousarray(frames[:, 3]).view(_AUX_FRAME)[:, 0]
    accel = axis["lo"].astype(np.int32) | (axis["hi"].astype(np.int32) << 16)
    return SampleColumns(
        (np.arange(n, dtype=np.int64) + first_raw) & _U32,
        np.ascontiguousarray(axis["gyro"], dtype=np.int32),
        accel,
        np.ascontiguousarray(aux["angle"], dtype=np.uint32),
        np.ascontiguousarray(aux["temperature"], dtype=np.int16),
        np.ascontiguousarray(aux["validity"], dtype=np.uint8),
        np.zeros(n, np.float64),  # a recorded window keeps no arrival times
    )


class _Run:
    """Sample frames of the receiver's node, buffered while a window streams (nothing but them
    came between them), then added to the window: the same as giving each to the receiver and
    its samples and losses to the collector, with whole ticks of consecutive counters in a
    device's frame order decoded together with numpy."""

    def __init__(self) -> None:
        self.slots = bytearray()
        self.data = bytearray()

    def add(self, slot: int, data: bytes | bytearray) -> bool:
        """Buffer a frame; True when the run is full (to be fed)."""
        self.slots.append(slot)
        self.data += data
        return len(self.slots) >= RUN_FRAMES

    def feed(self, receiver: CanReceiver, collector: WindowCollector) -> None:
        slots, data = self.slots, self.data
        n = len(slots)
        ticks = n // 4
        start = 0
        if n % 4 == 0 and ticks >= 3 and slots == _TICK_ORDER[:n]:
            frames = np.frombuffer(bytes(data), dtype=np.uint8).reshape(ticks, 4, 8)
            tick = frames[:, :, 0]
            if (tick == tick[:, :1]).all() and (np.diff(tick[:, 0]) == 1).all():  # u8: wraps
                # The first tick one by one: it places the tick counter (and reports what was
                # lost before it); each tick after it then is the next counter, whole.
                repeated = receiver.ticks.duplicates
                last = self._frames(receiver, collector, 0, 4)
                start = 4
                if (
                    isinstance(last, Sample)
                    and last.counter & 0xFF == int(tick[0, 0])
                    and receiver.ticks.duplicates == repeated  # it began a tick of its own
                ):
                    self._place(receiver, tick[:, 0], last.counter)
                    if not collector.done:
                        collector.add_samples(_tick_columns(frames[1:], (last.counter + 1) & _U32))
                    start = n
        self._frames(receiver, collector, start, n)
        del slots[:], data[:]

    @staticmethod
    def _place(receiver: CanReceiver, ticks: np.ndarray, first: int) -> None:
        """Advance the receiver over ticks ``1 ..`` of ``ticks`` as one by one would: the
        counter placed at most 255 ticks a step, each tick counted complete."""
        counter = receiver.ticks.counter
        placed = 0
        last = len(ticks) - 1
        for k in [*range(255, last, 255), last]:
            c, step = counter.place(int(ticks[k]))
            assert step == k - placed and c == (first + k) & _U32
            placed = k
        receiver.ticks.complete += last
        receiver.frames += 4 * last

    def _frames(
        self, receiver: CanReceiver, collector: WindowCollector, start: int, end: int
    ) -> Sample | TickLoss | None:
        """Frames ``start .. end`` of the run one by one; the last item they gave."""
        last: Sample | TickLoss | None = None
        node = receiver.node_id or 0
        for i in range(start, end):
            arbitration_id = _SLOT_FUNCTIONS[self.slots[i]] + node
            for item in receiver.feed(arbitration_id, self.data[8 * i : 8 * i + 8]):
                last = item if isinstance(item, Sample | TickLoss) else None
                if collector.done:
                    continue
                if isinstance(item, Sample):
                    collector.add_sample(item, 0.0)
                elif isinstance(item, TickLoss):
                    collector.add_loss(item)
        return last


class _Scan:
    """One pass over a log's frames: the windows of one node, its identity, scales and rate,
    the commands and the host sessions (see the module docstring)."""

    def __init__(
        self,
        logs: LogSet,
        node_id: int | None,
        window_s: float | None,
        summarise: Callable[[RecordedWindow, float], Any] | None = None,
    ) -> None:
        self.logs = logs
        self.summarise = summarise
        self.node_id = node_id
        self.window_s = window_s
        # Without node_id the first node with a protocol frame is decoded and every node seen
        # counted (several are an error, as no choice was made).
        self.node: int | None = node_id
        self.receiver: CanReceiver | None = None if node_id is None else CanReceiver(node_id)
        self.nodes: dict[int, int] = {}
        self.scales = CountScales()
        self.identity: Identify | None = None
        self.rate = float(SAMPLE_RATE_DEFAULT_HZ)
        self.commanded = 0.0
        self.commands: list[tuple[float, str]] = []
        self.segments: list[_Segment] = []
        self.current: _Segment | None = None
        self.free: _Segment | None = None  # a window cut by the encoder, for logs without commands
        self.free_segments: list[_Segment] = []
        self.saw_stream_start = False
        self.frames = 0
        self.t0: float | None = None
        self.sessions = SessionCounter()
        self.after_gap: str | None = None
        self.run = _Run()

    def requested(self) -> int:
        return _UNBOUNDED if self.window_s is None else max(1, round(self.window_s * self.rate))

    def read(self, stream: Iterator[can.Message], progress: ReadProgress | None) -> None:
        """Every frame of ``stream`` in order."""
        logs, run = self.logs, self.run
        gaps_seen = len(logs.gaps)
        for msg in stream:
            if len(logs.gaps) > gaps_seen:
                # Frames missing at a boundary between parts: the window in progress lost
                # samples, and the next may have lost its command (its angle).
                gaps_seen = len(logs.gaps)
                self.after_gap = logs.gaps[-1]
                if self.current is not None:
                    self.current.suspect = self.current.suspect or self.after_gap
            self.frames += 1
            if progress is not None and not self.frames & 0xFFFF:
                progress(*logs.position())
            if self.t0 is None:
                self.t0 = msg.timestamp
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            arbitration_id = msg.arbitration_id
            if self.node_id is None and not self._count_node(arbitration_id, msg.is_extended_id):
                continue
            current = self.current
            if current is not None and RUN_FRAMES:
                slot = _SAMPLE_SLOTS.get(arbitration_id & 0x7F0)
                if (
                    slot is not None
                    and arbitration_id & 0x0F == self.node
                    and arbitration_id <= 0x7FF
                    and not msg.is_extended_id
                    and len(msg.data) == 8
                ):
                    if run.add(slot, msg.data):
                        run.feed(cast(CanReceiver, self.receiver), current.collector)
                    continue
                if run.slots:
                    run.feed(cast(CanReceiver, self.receiver), current.collector)
            assert self.receiver is not None
            data = bytes(msg.data)
            for item in self.receiver.feed(arbitration_id, data, is_extended_id=msg.is_extended_id):
                self._item(item, msg.timestamp)
        if run.slots:
            assert self.current is not None and self.receiver is not None
            run.feed(self.receiver, self.current.collector)
        if progress is not None:
            total = logs.position()[1]
            progress(total, total)

    def _count_node(self, arbitration_id: int, extended: bool) -> bool:
        """Count the node of a protocol frame; whether to decode the frame (the first node
        seen is decoded; once there are several nothing is)."""
        seen = arbitration_id & 0x0F
        if seen and not extended and arbitration_id & ~0x0F in _FUNCTION_IDS:
            self.nodes[seen] = self.nodes.get(seen, 0) + 1
            if self.receiver is None:
                self.node, self.receiver = seen, CanReceiver(node_id=seen)
        return self.receiver is not None and len(self.nodes) <= 1

    def _item(self, item: Any, t: float) -> None:
        """What the receiver decoded from a frame at time ``t``."""
        if isinstance(item, Sample):
            self._sample(item, t)
        elif isinstance(item, TickLoss):
            for seg in (self.current, self.free):
                if seg is not None and not seg.collector.done:
                    seg.collector.add_loss(item)
        elif isinstance(item, Identify):
            self.identity, self.scales = item, CountScales.of(item)
        elif isinstance(item, Reply):
            if item.ok and item.opcode in (Opcode.GET_CONFIG, Opcode.SET_CONFIG):
                try:
                    key, value = item.config_value()
                except ProtocolError:
                    return
                if key == ConfigKey.SAMPLE_RATE_HZ and value > 0:
                    self.rate = float(value)
        elif isinstance(item, Command):
            self._command(item, t)

    def _sample(self, item: Sample, t: float) -> None:
        current = self.current
        if current is not None:
            if not current.collector.done:
                current.collector.add_sample(item, t)
        elif not self.saw_stream_start:
            at_rest = not (int(item.validity) & _MOVING)
            if at_rest and self.free is None:
                angle = item.angle * self.scales.angle_deg
                self.free = _Segment(angle, self.requested(), t)
                self._ended(self.free_segments)
                self.free_segments.append(self.free)
            elif not at_rest:
                self.free = None
            if self.free is not None and not self.free.collector.done:
                self.free.collector.add_sample(item, t)

    def _command(self, item: Command, t: float) -> None:
        self.commands.append((t - (self.t0 or 0.0), repr(item)))
        before = self.sessions.number
        if self.sessions.command(item) != before:
            self.current = None  # a new host: the last window of the one before is over
        angle_deg = self.scales.angle_deg
        if isinstance(item, RotateTo):
            self.commanded = item.angle * angle_deg
        elif isinstance(item, RotateBy):
            self.commanded = (self.commanded + item.delta * angle_deg) % 360.0
        elif isinstance(item, Home):
            self.commanded = 0.0
        if isinstance(item, StreamStop) and self.current is not None:
            self.current.stopped = True
        if isinstance(item, RotateTo | RotateBy | Home | Reset | StreamStart):
            self.current = None
        if isinstance(item, StreamStart):
            self.saw_stream_start = True
            self.free = None
            assert self.receiver is not None
            self.receiver.ticks.restart()  # as the driver does: a new stream
            current = _Segment(self.commanded, self.requested(), t, self.sessions.number)
            current.suspect, self.after_gap = self.after_gap, None
            self._ended(self.segments)
            self.segments.append(current)
            self.current = current

    def _ended(self, segments: list[_Segment]) -> None:
        """Summarise the windows of ``segments`` (all ended: a new one begins) not yet
        summarised, so that only the window being read holds its samples."""
        if self.summarise is None:
            return
        for seg in reversed(segments):
            if seg.summary is not None:
                break
            if seg.collector.received > 0 and seg is not self.current:
                seg.summarise(self.summarise, self.rate, self.scales)

    def check_nodes(self) -> int:
        """The node read.

        Raises
        ------
        RecordingError
            No node chosen and none, or several, in the log.
        """
        p = self.logs.name
        if self.node_id is None:
            if not self.nodes:
                raise RecordingError(f"{p}: no frame of the north finder protocol in this CAN log")
            if len(self.nodes) > 1:
                listed = ", ".join(map(str, sorted(self.nodes)))
                raise RecordingError(f"{p}: frames of nodes {listed}; choose one (--node-id)")
        assert self.node is not None
        return self.node

    def choose(
        self, session: int | None, windows: Sequence[int] | None
    ) -> tuple[list[tuple[int, _Segment]], dict[int, int], list[_Segment]]:
        """The windows asked for, numbered (1-based, in their session), the windows of each
        session, and those of the session read.

        Raises
        ------
        RecordingError
            Windows of several sessions and none chosen; a session or window not in the log.
        """
        p = self.logs.name
        chosen = self.segments if self.saw_stream_start else self.free_segments
        chosen = [seg for seg in chosen if seg.collector.received > 0]
        counts: dict[int, int] = {}
        for seg in chosen:
            counts[seg.session] = counts.get(seg.session, 0) + 1
        listing = ", ".join(f"{k}: {v} window(s)" for k, v in sorted(counts.items()))
        if session is None and len(counts) > 1:
            raise RecordingError(
                f"{p}: windows of {len(counts)} host sessions ({listing}); choose one (--session N)"
            )
        if session is not None:
            if session not in counts:
                raise RecordingError(
                    f"{p}: no session {session} with windows in the log (sessions: "
                    f"{listing or 'none'})"
                )
            chosen = [seg for seg in chosen if seg.session == session]
        numbered = list(enumerate(chosen, start=1))
        if windows is not None:
            wanted = list(windows)
            missing = [i for i in wanted if not 1 <= i <= len(chosen)]
            if missing:
                raise RecordingError(
                    f"{p}: no window {missing[0]}: the session holds windows 1..{len(chosen)}"
                )
            numbered = [(i, chosen[i - 1]) for i in wanted]
        return numbered, counts, chosen

    def window_flaws(self, i: int, seg: _Segment) -> tuple[list[str], int]:
        """What is missing from window ``i``: the notes, and how many of them (the first) are
        ticks missing inside it."""
        where = f"window {i} ({seg.commanded_deg:g} deg)"
        flaws = [
            f"{where}: {count} tick(s) missing from counter {first}"
            for first, count in seg.collector.gaps
        ]
        gap_notes = len(flaws)
        ticks = seg.collector.received + seg.collector.missing
        if self.window_s is not None and not seg.collector.done:
            flaws.append(f"{where}: the log ends the window after {ticks} of {seg.requested} ticks")
        if seg is self.current and not seg.stopped and not seg.collector.done:
            # The host stops every stream it starts: a last window without its STREAM_STOP
            # is a log cut inside the window, whose samples fall short of what was measured.
            flaws.append(
                f"{where}: the log ends inside the window after {ticks} ticks, before its "
                "STREAM_STOP: the log is cut short"
            )
        if seg.suspect is not None:
            flaws.append(f"{where}: {seg.suspect}")
        return flaws, gap_notes


def read_can_log(
    path: LogPaths,
    *,
    node_id: int | None = None,
    window_s: float | None = None,
    min_windows: int = 2,
    skip_damaged: bool = False,
    session: int | None = None,
    windows: Sequence[int] | None = None,
    progress: ReadProgress | None = None,
    summarise: Callable[[RecordedWindow, float], Any] | None = None,
) -> CanLogSession:
    """Rebuild a session's windows from a CAN log (see the module docstring), reading it once.

    Memory: a constant for the reading, plus each window's samples as numpy arrays (raw counts
    while the window is collected, about 43 bytes a sample; 81 bytes a sample in physical units
    in the result, the raw counts of one window released as it is converted).

    Parameters
    ----------
    path : str, Path or sequence of them
        The log; python-can's reader for its ending reads it. Several files are the parts of
        one log (a rotated log), read in order.
    node_id : int, optional
        The device whose session to read (default: the only node in the log).
    window_s : float, optional
        Keep the first ``round(window_s * rate)`` ticks of each window (default: all samples
        streamed at the position).
    min_windows : int
        Fewer windows is an error (north finding needs two).
    skip_damaged : bool
        Skip a damaged line of a text log (``.log``, ``.asc``, ``.csv``, ``.trc``) and read on;
        :attr:`CanLogSession.skipped_lines` counts them (default: the log ends there, as cut).
    session : int, optional
        The host session to read, 1-based (see :attr:`CanLogSession.sessions`); required when
        the log holds windows of several sessions.
    windows : sequence of int, optional
        Keep only these windows of the session, 1-based, in this order.
    progress : callable, optional
        Called as ``progress(done, total)`` with the bytes of the log's files read so far (of a
        compressed file its compressed bytes) and in all, every 65536 frames and at the end.
    summarise : callable, optional
        Reduce each window as it ends (``summarise(window, sample_rate_hz)``, which should
        not raise: keep an error in what it returns) and drop its samples: memory is then one
        window's samples and the summaries, whatever the log's length. The results go to
        :attr:`CanLogSession.summaries`, :attr:`~CanLogSession.windows` is empty. A window is
        converted with the rate and scales known when it ends; should they change later in the
        log (never in a log of one session), the log is read a second time.

    Raises
    ------
    RecordingError
        Not a readable CAN log, no protocol frame, several nodes and none chosen, windows of
        several sessions and none chosen, a session or window that is not in the log, fewer
        windows than ``min_windows``.
    """
    logs = LogSet(path)
    if window_s is not None and not (math.isfinite(window_s) and window_s > 0):
        raise RecordingError(f"window: must be a positive number of seconds, got {window_s!r}")
    for streamed in (True, False) if summarise is not None else (False,):
        scan = _Scan(logs, node_id, window_s, summarise if streamed else None)
        cut: list[str] = []
        skipped: list[tuple[int, str]] = []
        scan.read(logs.messages(cut, skipped if skip_damaged else None), progress)
        try:
            return _session(scan, cut, skipped, session, windows, min_windows, summarise)
        except _Restart:
            logs = LogSet(path)
    raise AssertionError("unreachable: the second reading summarises at the end")


def _session(
    scan: _Scan,
    cut: list[str],
    skipped: list[tuple[int, str]],
    session: int | None,
    windows: Sequence[int] | None,
    min_windows: int,
    summarise: Callable[[RecordedWindow, float], Any] | None = None,
) -> CanLogSession:
    """The session a scan read: the windows asked for in physical units (or their summaries),
    and the notes.

    Raises
    ------
    _Restart
        A window was summarised with a rate or scales the log changed afterwards.
    """
    logs = scan.logs
    node = scan.check_nodes()
    numbered, counts, chosen = scan.choose(session, windows)
    incomplete: list[str] = list(cut)
    notes: list[str] = [g for g in logs.gaps if not any(g == s.suspect for s in chosen)]
    if skipped:
        first_line, first_error = skipped[0]
        notes.append(
            f"skipped {len(skipped)} damaged line(s) of the log (first: line {first_line}, "
            f"{first_error})"
        )
    receiver = scan.receiver
    assert receiver is not None
    if receiver.malformed:
        notes.append(
            f"{receiver.malformed} frame(s) of node {node} did not decode "
            f"(last: {receiver.last_error})"
        )
    out: list[Any] = []
    short: list[int] = []
    gap_only: list[int] = []
    for i, seg in numbered:
        flaws, gap_notes = scan.window_flaws(i, seg)
        incomplete += flaws
        if flaws:
            short.append(len(out))
            if len(flaws) == gap_notes:
                gap_only.append(len(out))
        if summarise is None:
            out.append(seg.recorded(scan.rate, scan.scales))
            continue
        if seg.summary is None:
            seg.summarise(summarise, scan.rate, scan.scales)
        elif seg.summary[1:] != (scan.rate, scan.scales):
            raise _Restart
        assert seg.summary is not None
        out.append(seg.summary[0])
    damaged = None
    if logs.damaged:
        file, line, error = logs.damaged[0]
        damaged = f"{file}:{line}: damaged line {error}"
    if len(out) < min_windows:
        raise RecordingError(
            f"{logs.name}: {len(out)} window(s) of node {node} in the log; need at least "
            f"{min_windows} (a window is the samples streamed at one position)"
            + (f"; the first damaged line: {damaged}" if damaged else "")
        )
    return CanLogSession(
        str(logs.name), node, scan.rate, () if summarise else tuple(out), scan.identity,
        tuple(scan.commands),
        tuple(incomplete + notes), scan.frames, scan.t0, incomplete=tuple(incomplete),
        incomplete_windows=tuple(short), skipped_lines=len(skipped),
        sessions=tuple(sorted(counts.items())), session=session,
        window_numbers=tuple(i for i, _ in numbered),
        parts=tuple(str(f) for f in logs.files), part_gaps=tuple(logs.gaps),
        gap_windows=tuple(gap_only), first_damaged=damaged,
        summaries=tuple(out) if summarise else (),
    )  # fmt: skip
