"""Raw links of the conformance suite: a python-can bus or a serial port, spoken at the wire level.

The suite must be able to send what a well-behaved host never sends (a command payload of the wrong
length, an unknown identifier, a frame with a bad CRC), so it does not use the driver: each link
sends command payloads and raw frames, and returns what the unit sends as :class:`Arrival` items
stamped with the host's monotonic clock on receipt. Decoding uses the shared codec only.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, TypeVar

import can
import serial

from northfinder.driver.protocol.can import IdentifyAssembler, can_id, decode_can
from northfinder.driver.protocol.constants import CanFunction, SerialType
from northfinder.driver.protocol.errors import ProtocolError, UnknownMessageError
from northfinder.driver.protocol.messages import (
    IdentifyPage,
    Reply,
    SampleAux,
    SampleAxis,
    SampleX,
    SampleY,
    SampleZ,
    Status,
    StatusCounters,
    StatusMain,
)
from northfinder.driver.protocol.serial import SYNC, Deframer, SerialFrame, decode_payload
from northfinder.driver.transport import enlarge_receive_buffer, frame_drain

__all__ = ["Arrival", "CanRawLink", "RawLink", "SerialRawLink", "TickParts"]

SLCAN_LINE_BYTES = len("t1018") + 2 * 8 + len("\r")
"""An SLCAN line of a standard frame with 8 data bytes: ``tIIIL``, the data in hex, CR."""
SAMPLE_PAYLOAD_BYTES = 35
"""The serial SAMPLE payload (protocol.md 3)."""


@dataclass(frozen=True, slots=True)
class TickParts:
    """The frames of one CAN sample tick as received (complete when all four are present)."""

    tick: int
    x: SampleX | None
    y: SampleY | None
    z: SampleZ | None
    aux: SampleAux | None

    @property
    def complete(self) -> bool:
        return None not in (self.x, self.y, self.z, self.aux)


@dataclass(frozen=True, slots=True)
class Arrival:
    """One thing the unit sent, as the host saw it.

    Attributes
    ----------
    t : float
        Host monotonic time of receipt, s (wall clock).
    message : object
        A decoded :class:`Reply`, :class:`Status`, :class:`Identify`, :class:`Sample` (serial),
        :class:`TickParts` (CAN), or a ``str`` describing something the unit sent that does not
        decode (counted as a link error).
    seq : int or None
        Serial frame sequence counter; None on CAN.
    """

    t: float
    message: object
    seq: int | None = None


_P = TypeVar("_P", SampleX, SampleY, SampleZ, SampleAux)


def _part(parts: dict[type, SampleAxis | SampleAux], kind: type[_P]) -> _P | None:
    part = parts.get(kind)
    return part if isinstance(part, kind) else None


class RawLink(Protocol):
    """What the suite needs from a link."""

    kind: str
    """``"can"`` or ``"serial"``."""
    tick_bytes: int
    """Bytes one sample tick takes on the link as a tty carries it (what a full buffer holds)."""
    after_send: Callable[[], None] | None
    """Called after every send (a virtual clock's ``notify``), or None."""

    def send_command(self, payload: bytes) -> None:
        """Send a COMMAND carrying ``payload`` (any bytes, also malformed)."""

    def receive(self, timeout: float) -> list[Arrival]:
        """Whatever arrives within ``timeout`` wall seconds (returns early once something came)."""

    def close(self) -> None: ...


class CanRawLink:
    """The suite's end of a python-can bus.

    Sample frames are grouped into :class:`TickParts` (a tick closes when a frame of another tick
    or a non-sample frame of the unit arrives); STATUS and STATUS_COUNTERS are merged; identify
    pages are joined. Nothing else is interpreted: judging is the checks' business.

    Parameters
    ----------
    bus : can.BusABC
        Opened and closed by the caller.
    node_id : int
        The unit's node id.
    """

    kind = "can"
    tick_bytes = 4 * SLCAN_LINE_BYTES
    """Four frames of 8 bytes a tick, as an SLCAN adapter writes them on its tty."""

    def __init__(self, bus: can.BusABC, node_id: int = 1) -> None:
        self.bus = bus
        self.node_id = node_id
        self.rcvbuf = enlarge_receive_buffer(bus)
        self._next_frame = frame_drain(bus)
        self.command_id = can_id(CanFunction.COMMAND, node_id)
        self._identify = IdentifyAssembler()
        self._status: StatusMain | None = None
        self._tick: int | None = None
        self._parts: dict[type, SampleAxis | SampleAux] = {}
        self.frames = 0
        self.other = 0
        self.after_send: Callable[[], None] | None = None

    def send_command(self, payload: bytes) -> None:
        self.send_frame(self.command_id, payload)

    def send_frame(self, arbitration_id: int, data: bytes, *, extended: bool = False) -> None:
        """Send any classic data frame (the suite's bad-input checks use other identifiers)."""
        self.bus.send(
            can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=extended)
        )
        if self.after_send is not None:
            self.after_send()

    def receive(self, timeout: float) -> list[Arrival]:
        out: list[Arrival] = []
        msg = self.bus.recv(timeout)
        # Frames drained at once arrived together: one clock read for the batch.
        t = time.monotonic()
        while msg is not None:
            self._on_frame(msg, t, out)
            if len(out) > 64:
                break
            msg = self._next_frame()
        return out

    def _on_frame(self, msg: can.Message, t: float, out: list[Arrival]) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            return
        self.frames += 1
        try:
            node, part = decode_can(msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id)
        except UnknownMessageError:
            self.other += 1  # other equipment on the bus
            return
        except ProtocolError as exc:
            fn = msg.arbitration_id & 0x7F0
            if (msg.arbitration_id & 0x0F) == self.node_id and fn != CanFunction.COMMAND:
                out.append(Arrival(t, f"undecodable frame 0x{msg.arbitration_id:03X}: {exc}"))
            return
        if node != self.node_id:
            self.other += 1
            return
        if isinstance(part, SampleAxis | SampleAux):
            if self._tick is not None and part.tick != self._tick:
                self._close_tick(t, out)
            if type(part) in self._parts:
                out.append(Arrival(t, f"tick {part.tick}: {type(part).__name__} repeated"))
            self._tick = part.tick
            self._parts[type(part)] = part
            if len(self._parts) == 4:
                self._close_tick(t, out)
            return
        if self._tick is not None:
            self._close_tick(t, out)
        if isinstance(part, StatusMain):
            if self._status is not None:
                out.append(Arrival(t, "STATUS not followed by STATUS_COUNTERS"))
            self._status = part
        elif isinstance(part, StatusCounters):
            main, self._status = self._status, None
            if main is None:
                out.append(Arrival(t, "STATUS_COUNTERS without a preceding STATUS"))
            else:
                out.append(Arrival(t, Status.from_parts(main, part)))
        elif isinstance(part, IdentifyPage):
            errors = self._identify.errors
            ident = self._identify.add(part)
            if self._identify.errors != errors:
                out.append(Arrival(t, f"identify pages: {self._identify.last_error}"))
            if ident is not None:
                out.append(Arrival(t, ident))
        elif isinstance(part, Reply):
            out.append(Arrival(t, part))
        # A COMMAND frame of our node is another host's (or our own echo): not the unit's.

    def _close_tick(self, t: float, out: list[Arrival]) -> None:
        p = self._parts
        tick = TickParts(
            self._tick or 0,
            _part(p, SampleX),
            _part(p, SampleY),
            _part(p, SampleZ),
            _part(p, SampleAux),
        )
        out.append(Arrival(t, tick))
        self._tick = None
        self._parts = {}

    def close(self) -> None:
        """The bus belongs to the caller; nothing to release here."""


class SerialRawLink:
    """The suite's end of a serial line carrying the protocol's binary frames.

    Parameters
    ----------
    port : serial.Serial
        Opened and closed by the caller.
    """

    kind = "serial"
    tick_bytes = len(SYNC) + 3 + SAMPLE_PAYLOAD_BYTES + 2
    """One SAMPLE frame a tick: sync, length, type, seq, payload, CRC."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port
        self.deframer = Deframer()
        self.seq = 0
        self.after_send: Callable[[], None] | None = None

    def send_command(self, payload: bytes) -> None:
        self.send_frame(SerialType.COMMAND, payload)

    def send_frame(self, msg_type: int, payload: bytes) -> None:
        """Send a well-formed frame of any type with this host's sequence counter."""
        self.send_bytes(SerialFrame(msg_type, self.seq, payload).encode())

    def send_bytes(self, data: bytes) -> None:
        """Send raw bytes (garbage, broken frames); the sequence counter still advances."""
        self.seq = (self.seq + 1) & 0xFF
        self.port.write(data)
        self.port.flush()
        if self.after_send is not None:
            self.after_send()

    def receive(self, timeout: float) -> list[Arrival]:
        self.port.timeout = max(timeout, 0.0)
        data = self.port.read(1)
        if not data:
            return []
        data += self.port.read(self.port.in_waiting)
        t = time.monotonic()
        out: list[Arrival] = []
        crc, length = self.deframer.crc_errors, self.deframer.length_errors
        for frame in self.deframer.feed(data):
            try:
                msg: object = decode_payload(frame.msg_type, frame.payload)
            except ProtocolError as exc:
                msg = f"undecodable frame of type 0x{frame.msg_type:02X}: {exc}"
            out.append(Arrival(t, msg, frame.seq))
        bad = self.deframer.crc_errors - crc + self.deframer.length_errors - length
        if bad:
            out.append(Arrival(t, f"{bad} serial frame(s) with a bad CRC or length"))
        return out

    def close(self) -> None:
        """The port belongs to the caller; nothing to release here."""
