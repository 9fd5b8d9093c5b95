"""``northfinder dump LOG [LOG ...] | -i INTERFACE -c CHANNEL``: decode CAN frames with protocol.dbc.

Reads a CAN log in any format python-can reads (candump .log, .asc, .blf, .csv, .db, .trc), the
parts of a rotated log in order (several files or a quoted glob), or a live python-can bus, one
frame at a time (a log of any size in constant memory; ``--count`` reads no further than it
needs), and prints one line per frame decoded by cantools with the protocol's DBC, as
``candump -L | cantools decode --single-line protocol.dbc`` would: the candump line with its
direction (``T`` sent, ``R`` received), then the decoded message (``--raw``: the candump line
alone). Filters: ``--id``, ``--time-from``/``--time-to`` (seconds from the first frame),
``--session N`` (a host session of a ``sim --log``).
"""

from __future__ import annotations

import argparse
import os
import stat
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from northfinder.cli.argtypes import bounded_float, bounded_int
from northfinder.cli.links import add_bus_arguments, bus_given, open_can_bus
from northfinder.cli.logprogress import LogProgress
from northfinder.cli.options import add_duration_argument, add_session_argument
from northfinder.cli.output import warn
from northfinder.host.errors import HostConfigError, RecordingError


def _dbc_path(given: str | None) -> Path:
    """The DBC: ``--dbc``, else the protocol's own, installed with the package."""
    if given:
        return Path(given)
    from northfinder.driver.protocol import dbc_path

    installed = dbc_path()
    if not installed.is_file():  # pragma: no cover - a broken installation
        raise HostConfigError(
            "--dbc: protocol.dbc is missing from this installation; reinstall northfinder or "
            "give --dbc PATH"
        )
    return Path(str(installed))


def _frame_id(text: str) -> int:
    try:
        value = int(text, 16)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not a hexadecimal CAN id or message name: {text!r}"
        ) from None
    if not 0 <= value <= 0x7FF:
        raise argparse.ArgumentTypeError(f"a CAN id is 000 to 7FF, got {text!r}")
    return value


def _id_list(text: str) -> list[str]:
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError("give CAN ids in hex (101) or message names (SAMPLE_X)")
    return parts


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "log", nargs="*", default=None, metavar="LOG",
        help="CAN log to decode, or the parts of a rotated log (or give a bus with -i/-c)",
    )  # fmt: skip
    g = p.add_argument_group("filters")
    g.add_argument(
        "--id", dest="ids", type=_id_list, action="extend", default=None, metavar="ID,...",
        help="only these frames: hex CAN ids (101) or DBC message names (SAMPLE_X), any node",
    )  # fmt: skip
    g.add_argument(
        "--time-from", type=bounded_float(0.0, 1e9, "s"), default=None, metavar="SECONDS",
        help="only frames at least this long after the first frame",
    )  # fmt: skip
    g.add_argument(
        "--time-to", type=bounded_float(0.0, 1e9, "s"), default=None, metavar="SECONDS",
        help="only frames at most this long after the first frame",
    )  # fmt: skip
    add_session_argument(
        g, "only the frames of host session N (1-based; each host's IDENTIFY begins one)"
    )
    g = p.add_argument_group("output")
    g.add_argument("--dbc", metavar="FILE", help="the DBC (default: the protocol's own)")
    g.add_argument(
        "--count", type=bounded_int(1, 10**12), default=None, metavar="N",
        help="stop after N frames printed",
    )  # fmt: skip
    add_duration_argument(g, "a live bus: stop after this many wall seconds")
    g.add_argument(
        "--raw", action="store_true",
        help="print the frames as candump -L lines, not decoded (for canplayer, cantools decode)",
    )  # fmt: skip
    g.add_argument(
        "--strict", action="store_true",
        help="a damaged line of a log is an error (default: skipped with a warning)",
    )  # fmt: skip
    add_bus_arguments(p)


def _wanted_ids(db: Any, names: list[str] | None) -> set[int] | None:
    """The functions (ids without their node bits) of ``--id``: hex ids or DBC names."""
    if names is None:
        return None
    out: set[int] = set()
    for name in names:
        try:
            out.add(db.get_message_by_name(name).frame_id & ~0x0F)
            continue
        except KeyError:
            pass
        try:
            out.add(_frame_id(name) & ~0x0F)
        except argparse.ArgumentTypeError as exc:
            known = ", ".join(m.name for m in db.messages)
            raise HostConfigError(f"--id {name}: {exc}; the DBC's messages: {known}") from None
    return out


def _load_dbc(path: Path) -> Any:
    """The DBC as cantools loads it; a file it cannot load is a usage error naming the file."""
    import cantools

    if path.is_dir():
        raise HostConfigError(f"--dbc {path}: a folder, not a DBC file")
    try:
        return cantools.database.load_file(str(path))
    except FileNotFoundError:
        raise HostConfigError(f"--dbc {path}: no such file") from None
    except Exception as exc:  # cantools' parsers raise their own, ValueError, UnicodeError...
        text = " ".join(str(exc).split())
        raise HostConfigError(
            f"--dbc {path}: not a DBC cantools reads ({type(exc).__name__}: {text[:200]})"
        ) from exc


class _Count:
    """The frames of a stream, counted as they pass."""

    def __init__(self, frames: Iterable[Any]) -> None:
        self.frames = frames
        self.n = 0

    def __iter__(self) -> Iterator[Any]:
        for msg in self.frames:
            self.n += 1
            yield msg


def _frames_of_bus(args: argparse.Namespace) -> Iterator[Any]:
    bus = open_can_bus(args)
    end = None if args.duration is None else time.monotonic() + args.duration
    try:
        while end is None or time.monotonic() < end:
            wait = 0.5 if end is None else max(0.0, min(0.5, end - time.monotonic()))
            msg = bus.recv(wait)
            if msg is not None:
                yield msg
    finally:
        bus.shutdown()


#: The channel of a frame from a log that names none (python-can's candump writer's default).
UNNAMED_CHANNEL = "vcan0"
_CAN_ERR_FLAG = 0x20000000
_CAN_ERR_BUSERROR = 0x00000080


def candump_line(msg: Any, channel: str = UNNAMED_CHANNEL) -> str:
    """One frame as ``candump -L`` logs it with its direction, as python-can's candump writer
    does: ``(t) CHANNEL ID#DATA R`` (received) or ``T`` (sent); an error frame without one.
    ``channel`` names a frame whose own channel is None; a number ``n`` is ``can<n>``."""
    name = msg.channel if msg.channel is not None else channel
    if isinstance(name, int) or (isinstance(name, str) and name.isdigit()):
        name = f"can{name}"
    head = f"({msg.timestamp:.6f}) {name} "
    if msg.is_error_frame:
        return f"{head}{_CAN_ERR_FLAG | _CAN_ERR_BUSERROR:08X}#"
    head += f"{msg.arbitration_id:08X}#" if msg.is_extended_id else f"{msg.arbitration_id:03X}#"
    if msg.is_remote_frame:
        body = "R"
    else:
        flags = ""
        if msg.is_fd:
            flags = (
                f"#{(1 if msg.bitrate_switch else 0) | (2 if msg.error_state_indicator else 0):X}"
            )
        body = flags + bytes(msg.data).hex().upper()
    return f"{head}{body} {'R' if msg.is_rx else 'T'}"


class FrameDecoder:
    """Frames decoded with a DBC into dump's lines (:func:`~northfinder.host.canlog.decode_signals`,
    the decoder the monitor's frame view uses too)."""

    def __init__(self, db: Any) -> None:
        from northfinder.driver.protocol import DBC_NODE

        self.db = db
        self._dbc_node = DBC_NODE

    def __call__(self, msg: Any, channel: str = UNNAMED_CHANNEL) -> str:
        """One frame as ``(t) CHANNEL ID#DATA DIR :: NAME(Signal: value unit, ...)``: the
        :func:`candump_line` and what the DBC decodes of it, as ``cantools decode
        --single-line`` prints a ``candump -L`` line."""
        from northfinder.host.canlog import decode_signals

        head = candump_line(msg, channel)
        if msg.is_error_frame:
            return f"{head} :: error frame"
        if msg.is_extended_id or msg.is_remote_frame:
            return f"{head} :: not a protocol frame"
        try:
            name, node, fields = decode_signals(self.db, msg.arbitration_id, bytes(msg.data))
        except (
            Exception
        ) as exc:  # cantools raises its own and KeyError, ValueError, ours ProtocolError
            return f"{head} :: undecodable ({type(exc).__name__}: {exc})"
        node_text = f" node {node}" if node != self._dbc_node else ""
        return f"{head} :: {name}{node_text}({', '.join(fields)})"


def decode_line(db: Any, msg: Any, channel: str = UNNAMED_CHANNEL) -> str:
    """One frame as :class:`FrameDecoder` prints it (a decoder made for this frame alone)."""
    return FrameDecoder(db)(msg, channel)


def _session_filter(frames: Iterable[Any], session: int | None) -> Iterator[Any]:
    """The frames of one host session (all frames when ``session`` is None)."""
    if session is None:
        yield from frames
        return
    from northfinder.driver.protocol.can import decode_can
    from northfinder.driver.protocol.errors import ProtocolError
    from northfinder.driver.protocol.messages import Command
    from northfinder.host.canlog import SessionCounter

    counter = SessionCounter()
    for msg in frames:
        if not (msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id):
            try:
                decoded = decode_can(msg.arbitration_id, bytes(msg.data))
            except ProtocolError:
                decoded = None
            if decoded is not None and isinstance(decoded.message, Command):
                counter.command(decoded.message)
        if counter.number == session:
            yield msg
        elif counter.number > session:
            return


def lines_go_to_a_file(stream: Any) -> bool:
    """Whether ``stream`` is a file (a regular file, or a buffer in memory with no descriptor,
    as a program embedding the command gives): not a terminal, where the lines themselves show
    how far the reading is, nor a pipe, whose reader (``less``, ``grep``) shares the terminal
    with stderr."""
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):
        return True
    try:
        return stat.S_ISREG(os.fstat(fd).st_mode)
    except OSError:
        return False


def run(args: argparse.Namespace) -> int:
    live = bus_given(args)
    if live == bool(args.log):
        raise HostConfigError("give a CAN log, or a bus with -i/-c (not both)")
    if live and args.session is not None:
        raise HostConfigError("--session applies to a CAN log")
    dbc = _dbc_path(args.dbc)
    db = _load_dbc(dbc)
    wanted = _wanted_ids(db, args.ids)
    skipped: list[tuple[int, str]] = []
    cut: list[str] = []
    gaps: list[str] = []
    name = "bus"
    shown: LogProgress | None = None
    if live:
        frames: Iterable[Any] = _frames_of_bus(args)
    else:
        from northfinder.driver.framelog import expand_log_names
        from northfinder.host.canlog import LogSet, check_log_file, read_frames

        logs = LogSet(expand_log_names(args.log))
        for path in logs.files:
            check_log_file(path)
        name = logs.name
        # A long log's reading shown on stderr when the lines go to a file.
        shown = LogProgress("dump", logs.files, enabled=lines_go_to_a_file(sys.stdout))
        frames = read_frames(
            logs.files, skip_damaged=not args.strict, skipped=skipped, cut=cut, gaps=gaps,
            progress=shown,
        )  # fmt: skip
    channel = str(args.channel) if live and args.channel is not None else UNNAMED_CHANNEL
    decode = FrameDecoder(db)
    read = _Count(frames)
    t0: float | None = None
    printed = 0
    out = sys.stdout
    try:
        for msg in _session_filter(read, args.session):
            if t0 is None:
                t0 = msg.timestamp
            t = msg.timestamp - t0
            if args.time_from is not None and t < args.time_from:
                continue
            if args.time_to is not None and t > args.time_to:
                if live:
                    continue
                break
            if wanted is not None and (msg.arbitration_id & ~0x0F) not in wanted:
                continue
            out.write((candump_line(msg, channel) if args.raw else decode(msg, channel)) + "\n")
            printed += 1
            if args.count is not None and printed >= args.count:
                break
    finally:
        out.flush()
        if shown is not None:
            shown.bar.close()
        for gap in gaps:
            warn("dump", f"{name}: {gap}")
        if skipped and read.n > 0:
            warn(
                "dump",
                f"{name}: skipped {len(skipped)} damaged line(s) (first: line "
                f"{skipped[0][0]}, {skipped[0][1]})",
            )
        if not args.strict:
            for note in cut:
                warn("dump", f"{name}: {note}")
    if args.strict and (cut or gaps):
        raise RecordingError(f"{name}: {(cut or gaps)[0]}")
    if skipped and read.n == 0:
        raise RecordingError(
            f"{name}: not a CAN log python-can reads: no frame, {len(skipped)} damaged line(s) "
            f"skipped (first: line {skipped[0][0]}, {skipped[0][1]})"
        )
    return 0
