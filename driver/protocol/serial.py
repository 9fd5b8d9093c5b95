"""Serial link framing: frame layout, CRC-16/CCITT-FALSE and a resynchronising de-framer.

Frame (little-endian)::

    offset  size  field
    0       2     sync A5 5A
    2       1     payload length n, 0..64
    3       1     message type (SerialType)
    4       1     sequence counter, per sender, +1 per frame mod 256
    5       n     payload
    5+n     2     CRC-16/CCITT-FALSE over bytes 2 .. 4+n (length, type, seq, payload), low byte first
"""

from __future__ import annotations

import binascii
from collections.abc import Callable
from dataclasses import dataclass

from northfinder.driver.protocol.constants import SerialType
from northfinder.driver.protocol.errors import (
    CrcError,
    EncodeError,
    FrameError,
    ProtocolError,
    UnknownMessageError,
)
from northfinder.driver.protocol.messages import Command, Identify, Message, Reply, Sample, Status

__all__ = [
    "CRC_INIT",
    "HEADER_SIZE",
    "MAX_FRAME_SIZE",
    "MAX_PAYLOAD",
    "SYNC",
    "Deframer",
    "SerialEncoder",
    "SerialFrame",
    "crc16_ccitt",
    "decode_frame",
    "decode_payload",
    "encode_serial",
    "message_type",
    "parse_frame",
]

SYNC = b"\xa5\x5a"
"""The two sync bytes that start every frame, in wire order."""
HEADER_SIZE = 5
"""Sync (2), length, type, sequence counter."""
CRC_SIZE = 2
MAX_PAYLOAD = 64
"""Largest payload length; a length byte above it marks a false sync."""
MAX_FRAME_SIZE = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE
CRC_INIT = 0xFFFF

_SYNC0 = SYNC[0]


def crc16_ccitt(data: bytes | bytearray | memoryview, crc: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE: polynomial 0x1021, MSB first, no reflection, no final XOR.

    Parameters
    ----------
    data : bytes-like
        Bytes to cover.
    crc : int
        Initial value (0xFFFF), or the CRC so far to continue it.

    Returns
    -------
    int
        CRC, 0..0xFFFF (``crc16_ccitt(b"123456789") == 0x29B1``).
    """
    # binascii.crc_hqx is exactly this CRC with a caller-supplied initial value.
    return binascii.crc_hqx(data, crc)


_TYPE_OF: dict[type, SerialType] = {
    Reply: SerialType.REPLY,
    Status: SerialType.STATUS,
    Identify: SerialType.IDENTIFY,
    Sample: SerialType.SAMPLE,
}

_DECODER: dict[int, Callable[[bytes], Message]] = {
    SerialType.COMMAND: Command.decode,
    SerialType.REPLY: Reply.decode,
    SerialType.STATUS: Status.decode,
    SerialType.IDENTIFY: Identify.decode,
    SerialType.SAMPLE: Sample.decode,
}


def message_type(message: Message) -> SerialType:
    """Serial message type of a message.

    Raises
    ------
    EncodeError
        The object is not a message carried on the serial link.
    """
    if isinstance(message, Command):
        return SerialType.COMMAND
    try:
        return _TYPE_OF[type(message)]
    except KeyError:
        raise EncodeError(f"{type(message).__name__} is not a serial message") from None


@dataclass(frozen=True, slots=True)
class SerialFrame:
    """One serial frame whose CRC has been checked.

    Attributes
    ----------
    msg_type : int
        Message type byte (a :class:`SerialType` value, or an undefined one).
    seq : int
        Sender's sequence counter.
    payload : bytes
        Payload, at most 64 bytes.
    """

    msg_type: int
    seq: int
    payload: bytes

    def encode(self) -> bytes:
        """Whole frame bytes, sync to CRC."""
        n = len(self.payload)
        if n > MAX_PAYLOAD:
            raise EncodeError(f"payload of {n} bytes exceeds {MAX_PAYLOAD}")
        if not (0 <= self.msg_type <= 0xFF and 0 <= self.seq <= 0xFF):
            raise EncodeError("msg_type and seq must be u8")
        body = bytes((n, self.msg_type, self.seq)) + self.payload
        crc = crc16_ccitt(body)
        return SYNC + body + bytes((crc & 0xFF, crc >> 8))


def encode_serial(message: Message, seq: int) -> bytes:
    """Whole serial frame carrying ``message`` with sequence counter ``seq``."""
    return SerialFrame(message_type(message), seq, message.encode()).encode()


def decode_payload(msg_type: int, payload: bytes) -> Message:
    """Decode the payload of a serial frame of type ``msg_type``.

    Raises
    ------
    UnknownMessageError
        Undefined message type.
    PayloadError
        Wrong length or undefined field value (:class:`~northfinder.driver.protocol.errors.BadCommandError` for a
        command the device must refuse).
    """
    decoder = _DECODER.get(msg_type)
    if decoder is None:
        raise UnknownMessageError(f"undefined serial message type 0x{msg_type:02X}")
    return decoder(payload)


def decode_frame(frame: SerialFrame) -> Message:
    """Decode the message in a CRC-checked frame (see :func:`decode_payload`)."""
    return decode_payload(frame.msg_type, frame.payload)


def parse_frame(data: bytes) -> SerialFrame:
    """Parse bytes holding exactly one frame.

    Raises
    ------
    FrameError
        Missing sync, length field above 64 or not matching ``len(data)``.
    CrcError
        The CRC does not match.
    """
    data = bytes(data)
    if len(data) < HEADER_SIZE + CRC_SIZE or data[:2] != SYNC:
        raise FrameError("frame must start with sync A5 5A and hold at least 7 bytes")
    n = data[2]
    if n > MAX_PAYLOAD or len(data) != HEADER_SIZE + n + CRC_SIZE:
        raise FrameError(f"length field {n} does not match a frame of {len(data)} bytes")
    expected = crc16_ccitt(data[2:-2])
    received = data[-2] | (data[-1] << 8)
    if expected != received:
        raise CrcError(
            f"CRC mismatch: computed 0x{expected:04X}, frame has 0x{received:04X}",
            expected,
            received,
        )
    return SerialFrame(data[3], data[4], data[5:-2])


class SerialEncoder:
    """Frames messages with this sender's sequence counter (+1 per frame, mod 256).

    Parameters
    ----------
    seq : int
        Sequence counter of the first frame (0 after boot).
    """

    def __init__(self, seq: int = 0) -> None:
        self.seq = seq & 0xFF

    def encode(self, message: Message) -> bytes:
        """Whole frame for ``message``; advances the counter."""
        frame = encode_serial(message, self.seq)
        self.seq = (self.seq + 1) & 0xFF
        return frame


class Deframer:
    """Turns a byte stream in any chunking into CRC-checked frames, resynchronising after garbage.

    It searches for the sync, rejects a length above 64 and a bad CRC by moving one byte past
    that sync (so a real frame hidden behind a false sync is still found), and never holds more
    than one maximum frame of bytes. It compares each frame's sequence counter with the previous
    one to count lost frames.

    Attributes
    ----------
    frames : int
        Frames delivered.
    crc_errors : int
        Candidate frames rejected for a bad CRC.
    length_errors : int
        Sync found with a length byte above 64.
    discarded_bytes : int
        Bytes not part of any delivered frame.
    lost_frames : int
        Sum of the gaps in the sequence counter (a repeated counter counts as 255 lost).
    malformed : int
        Frames whose payload :meth:`feed_messages` could not decode.
    last_error : ProtocolError or None
        The most recent decode error in :meth:`feed_messages`.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._tail = 0  # leading bytes of _buf that end the last delivered frame
        self._last_seq: int | None = None
        self.frames = 0
        self.crc_errors = 0
        self.length_errors = 0
        self.discarded_bytes = 0
        self.lost_frames = 0
        self.malformed = 0
        self.last_error: ProtocolError | None = None

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame (below 71; besides them up to two final
        bytes of the last frame delivered are kept while a next frame may begin in them)."""
        return len(self._buf) - self._tail

    def reset(self) -> None:
        """Drop buffered bytes and forget the sequence counter (keep the statistics)."""
        self._buf.clear()
        self._tail = 0
        self._last_seq = None

    def feed(self, data: bytes | bytearray | memoryview) -> list[SerialFrame]:
        """Add received bytes; return the frames completed by them, in order.

        A frame may begin in the last two bytes of the frame delivered before it (protocol.md
        2.2): when a frame lost its last byte and the next frame's first sync byte completed it
        with a valid CRC (the lost byte was 0xA5), the next frame still starts there. A candidate
        found there that fails is not counted as an error: those bytes were a good frame's.
        """
        buf = self._buf
        buf += data
        n = len(buf)
        out: list[SerialFrame] = []
        pos = self._tail  # bytes before pos are accounted for (delivered or discarded)
        scan = 0
        last_end = self._tail if self._tail else None
        cut = None
        crc = binascii.crc_hqx
        while True:
            i = buf.find(SYNC, scan)
            if i < 0:
                # A trailing first sync byte may be completed by the next chunk.
                keep = n - 1 if n > pos and buf[n - 1] == _SYNC0 else max(n, pos)
                self.discarded_bytes += max(keep - pos, 0)
                pos = max(pos, keep)
                cut = keep
                break
            in_tail = i < pos  # inside the last two bytes of the frame just delivered
            if not in_tail:
                self.discarded_bytes += i - pos
                pos = i
            if n - i < 3:
                cut = i
                break
            length = buf[i + 2]
            end = i + HEADER_SIZE + length + CRC_SIZE
            too_long = length > MAX_PAYLOAD
            if not too_long and end > n:
                cut = i
                break
            if too_long or crc(buf[i + 2 : end - 2], CRC_INIT) != buf[end - 2] | buf[end - 1] << 8:
                # No frame starts here: skip the sync byte (counted unless a good frame's own).
                if not in_tail:
                    if too_long:
                        self.length_errors += 1
                    else:
                        self.crc_errors += 1
                    self.discarded_bytes += 1
                    pos = i + 1
                scan = i + 1
                continue
            seq = buf[i + 4]
            if self._last_seq is not None:
                self.lost_frames += (seq - self._last_seq - 1) & 0xFF
            self._last_seq = seq
            out.append(SerialFrame(buf[i + 3], seq, bytes(buf[i + 5 : end - 2])))
            pos = last_end = end
            scan = end - 2
        # While nothing after the last delivered frame has come, keep its final bytes if the
        # next frame may begin there (they end in A5, or are A5 5A).
        if last_end is not None and n <= last_end:
            final = bytes(buf[max(0, last_end - 2) : last_end])
            if final == SYNC:
                cut = min(cut, last_end - 2)
            elif final.endswith(SYNC[:1]):
                cut = min(cut, last_end - 1)
        cut = max(0, min(cut, n))
        self._tail = max(0, pos - cut) if last_end is not None and cut < pos else 0
        del buf[:cut]
        self.frames += len(out)
        return out

    def feed_messages(self, data: bytes | bytearray | memoryview) -> list[Message]:
        """Like :meth:`feed`, but decode each frame; undecodable ones are counted and dropped."""
        out: list[Message] = []
        for frame in self.feed(data):
            try:
                out.append(decode_payload(frame.msg_type, frame.payload))
            except ProtocolError as exc:
                self.malformed += 1
                self.last_error = exc
        return out
