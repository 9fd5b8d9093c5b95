"""Wire adapters of the simulated device: CAN on a python-can bus, serial and SLCAN on byte streams.

An adapter receives frames, decodes them with the shared codec and hands commands to the
firmware; it encodes what the firmware sends. It also applies the frame-level faults ordered
through the control channel (drop or corrupt the next N frames). Malformed input is counted in
the firmware's ``rx_malformed`` and never stops the device.

Every adapter takes a ``tap``: a callable given each frame received and each frame sent (as it
went out, after fault injection), for a CAN log. The serial adapter gives the CAN frames that
carry the same messages on the CAN link (a frame the fault injection corrupted has no such
frame and is not given), so a serial session logs like a CAN one. Frames are handed over with
``timestamp`` 0 unless the bus stamped them: the tap stamps them (this package reads no clock).
A tap with a ``flush`` method (a :class:`~northfinder.driver.framelog.FrameLog`) is flushed as
the device answers a command, before the answer goes out and again after it, so a log read
after a host's last reply holds all the host's session.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import tty
from collections.abc import Callable, Iterable
from typing import Any, Protocol

import can
import serial
from can import Message

from northfinder.driver.protocol.can import encode_can, sample_ids, split_can_id
from northfinder.driver.protocol.constants import CanFunction
from northfinder.driver.protocol.errors import BadCommandError, ProtocolError
from northfinder.driver.protocol.messages import Command, Identify, Reply, Sample
from northfinder.driver.protocol.serial import Deframer, SerialEncoder, decode_payload
from northfinder.firmware_sim.firmware import Firmware, Outgoing

#: Most frames one poll handles before letting time advance, so a flood cannot starve the stream.
MAX_FRAMES_PER_POLL = 256


class ByteStream(Protocol):
    """A bidirectional byte link: a pseudo-terminal master or an opened serial port."""

    def read(self, timeout: float) -> bytes: ...
    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...


class FdStream:
    """A byte stream on a file descriptor (the master side of a pseudo-terminal)."""

    def __init__(self, fd: int, write_timeout: float = 0.05) -> None:
        self.fd = fd
        self.write_timeout = write_timeout
        os.set_blocking(fd, False)

    def read(self, timeout: float) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], max(timeout, 0.0))
        if not ready:
            return b""
        try:
            return os.read(self.fd, 65536)
        except OSError:  # the other side is not open (EIO on a pty): nothing to read
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            _, ready, _ = select.select([], [self.fd], [], self.write_timeout)
            if not ready:
                raise BlockingIOError("pseudo-terminal output is full: nobody is reading it")
            try:
                n = os.write(self.fd, view)
            except BlockingIOError:
                continue
            view = view[n:]

    def close(self) -> None:
        os.close(self.fd)


class SerialStream:
    """A byte stream on a pyserial port."""

    def __init__(self, port: serial.Serial) -> None:
        self.port = port

    def read(self, timeout: float) -> bytes:
        self.port.timeout = max(timeout, 0.0)
        first = self.port.read(1)
        if not first:
            return b""
        return first + self.port.read(self.port.in_waiting)

    def write(self, data: bytes) -> None:
        self.port.write(data)

    def close(self) -> None:
        self.port.close()


class PseudoTerminal:
    """A pseudo-terminal in raw mode; the device keeps both ends open so hosts may come and go.

    Attributes
    ----------
    path : str
        The slave path a host opens (``/dev/pts/N``).
    stream : FdStream
        The device's end.
    """

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self.stream = FdStream(self.master)

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


#: The lines an SLCAN adapter sends that do not parse, as the ``garble`` fault puts them on the
#: wire in turn: a data frame shorter than its header (python-can 4.6.1 raises IndexError), a
#: length or data that is not hex, bytes that are not ASCII, a bare command letter, an FD frame
#: cut short, a line far too long.
GARBLED_SLCAN_LINES: tuple[bytes, ...] = (
    b"T1234\r",
    b"t12\r",
    b"t12Z8\r",
    b"t1238ZZ\r",
    b"t1\xff38\r",
    b"T\r",
    b"t\r",
    b"r\r",
    b"R12\r",
    b"d1\r",
    b"D123\r",
    b"b\r",
    b"B1234567\r",
    b"x12\r",
    b"t7FFA" + b"0" * 20 + b"\r",
    b"\xfe\xff\x00\r",
    b"t" + b"9" * 90 + b"\r",
)


class _FrameFaults:
    """Drop or corrupt outgoing frames as the firmware's fault injection says."""

    def __init__(self, firmware: Firmware) -> None:
        self.firmware = firmware
        self.garbled = 0  # pieces of junk put on the wire (``garble``)

    def filter(self, data: bytes, corrupt: Callable[[bytes], bytes]) -> bytes | None:
        faults = self.firmware.faults
        if faults.drop_frames > 0:
            faults.drop_frames -= 1
            return None
        if faults.corrupt_frames > 0:
            faults.corrupt_frames -= 1
            return corrupt(data)
        return data

    def junk(self) -> range:
        """The indices of the pieces of junk to put before the next frame (``garble``)."""
        faults = self.firmware.faults
        n = min(max(faults.garble, 0), max(faults.garble_per_frame, 1))
        faults.garble -= n
        self.garbled += n
        return range(self.garbled - n, self.garbled)


class FrameBus(Protocol):
    """What :class:`CanLink` needs of a bus: a python-can bus, or an :class:`SlcanAdapter`."""

    def send(self, msg: can.Message) -> None: ...
    def recv(self, timeout: float | None = None) -> can.Message | None: ...


class CanLink:
    """The device on a python-can bus (``virtual``, ``socketcan``, an SLCAN pty bus, ...).

    Parameters
    ----------
    bus : can.BusABC or FrameBus
        Opened by the caller and closed by the caller.
    firmware : Firmware
    node_id : int
        The device answers COMMAND frames of this node only.
    tap : callable, optional
        Given every frame received and sent (see the module docstring).
    """

    def __init__(
        self,
        bus: FrameBus,
        firmware: Firmware,
        node_id: int = 1,
        *,
        tap: Callable[[can.Message], None] | None = None,
    ) -> None:
        self.bus = bus
        self.firmware = firmware
        self.node_id = node_id
        self.tap = tap
        self._faults = _FrameFaults(firmware)
        self._send = _frame_sender(bus)

    def poll(self, timeout: float) -> int:
        """Receive and handle frames for up to ``timeout`` seconds; return how many were read."""
        n = 0
        msg = self.bus.recv(timeout)
        while msg is not None:
            self._on_frame(msg)
            n += 1
            if n >= MAX_FRAMES_PER_POLL:
                break
            msg = self.bus.recv(0.0)
        return n

    def _on_frame(self, msg: can.Message) -> None:
        if self.tap is not None:
            self.tap(msg)
        if msg.is_error_frame or msg.is_extended_id:
            return
        try:
            function, node = split_can_id(msg.arbitration_id)
        except ProtocolError:
            return  # not a protocol id: another device's traffic
        if function != CanFunction.COMMAND or node != self.node_id:
            return
        if msg.is_remote_frame or msg.is_fd:
            self.firmware.note_malformed()
            return
        try:
            command = Command.decode(bytes(msg.data))
        except BadCommandError as exc:
            self.firmware.refuse(exc.seq, exc.opcode, exc.result)
        except ProtocolError:
            self.firmware.note_malformed()
        else:
            self.firmware.handle(command)

    def send(self, outgoing: list[Outgoing]) -> None:
        faults = self.firmware.faults
        if faults.drop_frames or faults.corrupt_frames or faults.garble:
            msgs = self._frames_with_faults(outgoing)
        else:
            msgs = _frames(outgoing, self.node_id)
        if msgs:
            flush = None if self.tap is None else _flush_at_reply(self.tap, outgoing)
            if flush is not None:
                flush()  # the command answered, and all before it
            self._put(msgs)
            if flush is not None:
                flush()  # the answer

    def _frames_with_faults(self, outgoing: list[Outgoing]) -> list[can.Message]:
        """The frames of ``outgoing`` as the firmware's fault injection leaves them (dropped,
        corrupted, junk before them); junk on an SLCAN adapter goes out at once."""
        msgs = []
        faults = self.firmware.faults
        node = self.node_id
        for item in outgoing:
            for arbitration_id, data in encode_can(item.message, node):
                if faults.drop_frames or faults.corrupt_frames:
                    # A corrupted CAN frame that still reaches the host has a wrong length: the
                    # bus's own CRC would have stopped any other corruption.
                    kept = self._faults.filter(data, _drop_last_byte)
                    if kept is None:
                        continue
                    data = kept
                for k in self._faults.junk() if faults.garble else ():
                    send_line = getattr(self.bus, "send_line", None)
                    if send_line is not None:  # an SLCAN adapter: a line that does not parse
                        send_line(GARBLED_SLCAN_LINES[k % len(GARBLED_SLCAN_LINES)])
                    else:
                        bad = data[:-1] if len(data) > 1 else data + b"\0"  # a wrong length
                        msgs.append(
                            Message(arbitration_id=arbitration_id, data=bad, is_extended_id=False)
                        )
                msgs.append(Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
        return msgs

    def _put(self, msgs: list[can.Message]) -> None:
        """Send the frames on the bus (those it refuses counted as dropped), then to the tap."""
        send_many = getattr(self.bus, "send_many", None)
        if send_many is not None:
            # A bus that takes frames in batches (the embedded simulator's virtual bus): one
            # hand-over for all, the frames it could not deliver counted as dropped.
            dropped = send_many(msgs)
            self.firmware.tx_dropped += len(dropped)
            sent = [m for m in msgs if m not in dropped] if dropped else msgs
        else:
            sent = []
            for msg in msgs:
                try:
                    self._send(msg)
                except can.CanError:
                    self.firmware.tx_dropped += 1
                    continue
                sent.append(msg)
        if self.tap is not None:
            for msg in sent:
                self.tap(can.Message(
                    arbitration_id=msg.arbitration_id, data=msg.data, is_extended_id=False,
                    is_rx=False,
                ))  # fmt: skip


#: What the device sends in answer to a command (IDENTIFY's pages follow its reply).
_ANSWERS = (Reply, Identify)


def _flush_at_reply(
    tap: Callable[[can.Message], None] | None, outgoing: list[Outgoing]
) -> Callable[[], None] | None:
    """The ``flush`` of ``tap`` if ``outgoing`` answers a command (heartbeats and samples go
    unflushed: the tap flushes on its own, :class:`~northfinder.driver.framelog.FrameLog` once
    a second)."""
    flush = getattr(tap, "flush", None)
    if flush is not None and any(type(item.message) in _ANSWERS for item in outgoing):
        return flush
    return None


def _frames(outgoing: list[Outgoing], node: int) -> list[can.Message]:
    """The CAN frames of ``outgoing`` from ``node``, in sending order: a sample's four from the
    data the firmware packed with its chunk (``item.frames``), anything else by
    :func:`_frame_data`."""
    msgs: list[can.Message] = []
    for item in outgoing:
        data = item.frames
        if data is None:
            msgs += [
                Message(arbitration_id=arbitration_id, data=payload, is_extended_id=False)
                for arbitration_id, payload in _frame_data(item, node)
            ]
            continue
        x, y, z, aux = sample_ids(node)
        msgs += (
            Message(arbitration_id=x, data=data[:8], is_extended_id=False),
            Message(arbitration_id=y, data=data[8:16], is_extended_id=False),
            Message(arbitration_id=z, data=data[16:24], is_extended_id=False),
            Message(arbitration_id=aux, data=data[24:], is_extended_id=False),
        )
    return msgs


def _frame_data(item: Outgoing, node: int) -> Iterable[tuple[int, bytes]]:
    """``(arbitration_id, data)`` of each CAN frame of ``item`` from ``node``, in sending
    order, for an item the firmware did not pack with its chunk (``item.frames`` None): a
    sample's four packed straight from its fields (as :func:`encode_can` does, without a frame
    object each)."""
    if type(item.message) is Sample:
        return zip(sample_ids(node), item.message.can_payloads(), strict=True)
    return encode_can(item.message, node)


def _drop_last_byte(data: bytes) -> bytes:
    return data[:-1]


def _frame_sender(bus: FrameBus) -> Callable[[can.Message], None]:
    """How :class:`CanLink` puts a frame on ``bus``.

    On python-can's SocketCAN bus: straight onto the kernel socket with python-can's own frame
    builder, one system call a frame; python-can's ``send`` makes three (a clock read, ``select``
    for writability, ``send``), which where system calls are dear (user-mode Linux: 60 to 100 us
    each) costs the 200 Hz stream a fifth of a CPU. A full transmit queue is an error either way
    (python-can raises, the socket reports ENOBUFS), counted as a dropped frame. Every other bus
    gets ``bus.send``.
    """
    try:
        from can.interfaces.socketcan.socketcan import SocketcanBus, build_can_frame
    except ImportError:  # pragma: no cover - not Linux
        return bus.send
    sock = getattr(bus, "socket", None)
    if not isinstance(bus, SocketcanBus) or not isinstance(sock, socket.socket):
        return bus.send

    def send(msg: can.Message) -> None:
        try:
            sock.send(build_can_frame(msg))
        except BlockingIOError:
            bus.send(msg, timeout=0.01)  # a non-blocking socket with a full buffer: wait briefly
        except OSError as exc:
            raise can.CanOperationError(f"Failed to transmit: {exc.strerror}", exc.errno) from exc

    return send


class SerialLink:
    """The device on a serial byte stream with the protocol's binary frames.

    ``tap`` (optional) is given every message received and sent as the CAN frames of node
    ``node_id`` that carry it (see the module docstring).
    """

    def __init__(
        self,
        stream: ByteStream,
        firmware: Firmware,
        *,
        tap: Callable[[can.Message], None] | None = None,
        node_id: int = 1,
    ) -> None:
        self.stream = stream
        self.firmware = firmware
        self.tap = tap
        self.node_id = node_id
        self.deframer = Deframer()
        self.encoder = SerialEncoder()
        self._faults = _FrameFaults(firmware)
        self._bad = 0
        self._boot = firmware.boot_count

    def poll(self, timeout: float) -> int:
        data = self.stream.read(timeout)
        if not data:
            return 0
        frames = self.deframer.feed(data)
        bad = self.deframer.crc_errors + self.deframer.length_errors
        for _ in range(bad - self._bad):
            self.firmware.note_malformed()
        self._bad = bad
        for frame in frames:
            try:
                message = decode_payload(frame.msg_type, frame.payload)
            except BadCommandError as exc:
                self.firmware.refuse(exc.seq, exc.opcode, exc.result)
                continue
            except ProtocolError:
                self.firmware.note_malformed()
                continue
            if isinstance(message, Command):
                self._tap(message, is_rx=True)
                self.firmware.handle(message)
            else:
                self.firmware.note_malformed()  # a device receives only commands
        return len(frames)

    def _tap(self, message: Any, *, is_rx: bool) -> None:
        if self.tap is None:
            return
        for frame in encode_can(message, self.node_id):
            self.tap(
                can.Message(
                    arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False,
                    is_rx=is_rx,
                )
            )  # fmt: skip

    def send(self, outgoing: list[Outgoing]) -> None:
        if self.firmware.boot_count != self._boot:
            # protocol.md 6: after RESET the serial sequence counter restarts.
            self._boot = self.firmware.boot_count
            self.encoder = SerialEncoder()
        chunks = []
        intact = []
        for item in outgoing:
            encoded = self.encoder.encode(item.message)
            data = self._faults.filter(encoded, _flip_payload_bit)
            for k in self._faults.junk() if self.firmware.faults.garble else ():
                chunks.append(GARBLED_SLCAN_LINES[k % len(GARBLED_SLCAN_LINES)])  # no sync word
            if data is not None:
                chunks.append(data)
                if data == encoded:
                    intact.append(item.message)
        if chunks:
            flush = _flush_at_reply(self.tap, outgoing)
            if flush is not None:
                flush()  # the command answered, and all before it
            try:
                self.stream.write(b"".join(chunks))
            except (BlockingIOError, OSError):
                self.firmware.tx_dropped += len(chunks)
                return
            for message in intact:
                self._tap(message, is_rx=False)
            if flush is not None:
                flush()  # the answer


def _flip_payload_bit(frame: bytes) -> bytes:
    b = bytearray(frame)
    b[min(5, len(b) - 3)] ^= 0x01
    return bytes(b)


def slcan_line(msg: can.Message) -> bytes:
    """The SLCAN (Lawicel) line an adapter sends for a received data frame: ``tIIILDD..\\r``
    (standard identifier) or ``TIIIIIIIILDD..\\r`` (extended)."""
    ident = f"T{msg.arbitration_id:08X}" if msg.is_extended_id else f"t{msg.arbitration_id:03X}"
    return f"{ident}{msg.dlc}{bytes(msg.data).hex().upper()}\r".encode("ascii")


class SlcanAdapter:
    """The device side of an SLCAN (Lawicel) adapter on a byte stream, usable as a CAN bus.

    A host in another process opens the pseudo-terminal with python-can's ``slcan`` interface and
    sees the simulated node on "its" CAN bus. Only what the device needs is implemented: standard
    and extended data frames, open/close/bitrate commands (acknowledged), version and serial.
    """

    def __init__(self, stream: ByteStream) -> None:
        self.stream = stream
        self._buf = bytearray()
        self._frames: list[can.Message] = []
        self.open = False
        self.errors = 0
        self.dropped_acks = 0

    def send(self, msg: can.Message) -> None:
        if not self.open:
            return  # a closed adapter puts nothing on the wire
        try:
            self.stream.write(slcan_line(msg))
        except OSError as exc:  # BlockingIOError included: the host does not read
            # Like a real adapter's full transmit queue: the caller counts the frame as dropped.
            raise can.CanOperationError(f"SLCAN adapter: {exc}") from exc

    def send_line(self, line: bytes) -> None:
        """Put ``line`` on the wire as it is (the ``garble`` fault: a line that does not parse);
        dropped, as a frame would be, when the host does not read."""
        if not self.open:
            return
        with contextlib.suppress(OSError):
            self.stream.write(line)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._frames:
            return self._frames.pop(0)
        data = self.stream.read(0.0 if timeout is None else timeout)
        if data:
            self._feed(data)
        return self._frames.pop(0) if self._frames else None

    def _feed(self, data: bytes) -> None:
        self._buf += data
        while True:
            i = self._buf.find(b"\r")
            if i < 0:
                if len(self._buf) > 64:  # no SLCAN line is this long: garbage
                    self.errors += 1
                    self._buf.clear()
                return
            line = bytes(self._buf[:i])
            del self._buf[: i + 1]
            self._answer(line)

    def _ack(self, data: bytes) -> None:
        """The adapter's answer to a line from the host. When the host has not read the link for
        so long that it is full, the answer is dropped, as a real adapter's transmit queue would
        drop it: the adapter goes on (the host's command was taken all the same)."""
        try:
            self.stream.write(data)
        except OSError:  # BlockingIOError included
            self.dropped_acks += 1

    def _answer(self, line: bytes) -> None:
        ok, bell = b"\r", b"\x07"
        if not line:
            return
        cmd = chr(line[0])
        try:
            if cmd in "tT":
                n = 3 if cmd == "t" else 8
                arb = int(line[1 : 1 + n], 16)
                dlc = int(line[1 + n : 2 + n])
                payload = bytes.fromhex(line[2 + n :].decode("ascii"))
                if dlc > 8 or len(payload) != dlc:
                    raise ValueError("length")
                if self.open:
                    self._frames.append(
                        can.Message(arbitration_id=arb, data=payload, is_extended_id=cmd == "T")
                    )
                self._ack(b"z\r" if cmd == "t" else b"Z\r")
            elif cmd in "rR":
                self._ack(ok)
            elif cmd in "OL":
                self.open = True
                self._ack(ok)
            elif cmd == "C":
                self.open = False
                self._ack(ok)
            elif cmd in "SsMmXWZQ":
                self._ack(ok)
            elif cmd == "F":
                self._ack(b"F00\r")
            elif cmd in "Vv":
                self._ack(cmd.encode() + b"0101\r")
            elif cmd == "N":
                self._ack(b"NSIM1\r")
            else:
                raise ValueError("command")
        except (ValueError, UnicodeDecodeError):
            self.errors += 1
            self._ack(bell)

    def shutdown(self) -> None:
        self.open = False
