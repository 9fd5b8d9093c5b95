"""Transports: send one command, receive decoded messages with a timeout, close.

A transport hides the link from :class:`northfinder.driver.device.Device`: both deliver the same items,
whole protocol messages (:class:`~northfinder.driver.protocol.messages.Reply`, ``Status``, ``Identify``,
``Sample``) and :class:`~northfinder.driver.protocol.can.TickLoss` reports for sample ticks that did not
arrive whole. On CAN the codec's :class:`~northfinder.driver.protocol.can.CanReceiver` joins frames into
messages; on serial a :class:`~northfinder.driver.protocol.serial.Deframer` checks frames and this module
compares consecutive sample counters. Neither opens anything: the bus or port is passed in (the
device's classmethods open them), and ``close`` releases it only when the transport owns it.

One thread (the device's reader) calls :meth:`recv`; :meth:`send` and :meth:`restart_stream` may
be called from any thread (python-can buses and pyserial ports allow one reader and one writer).
"""

from __future__ import annotations

import errno
import logging
import queue
import socket
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import can
import serial
from can.interfaces.slcan import slcanBus
from can.interfaces.virtual import VirtualBus

try:  # python-can's SocketCAN backend: importable on Linux only
    from can.interfaces.socketcan.socketcan import SocketcanBus, capture_message
except ImportError:  # pragma: no cover - not Linux
    SocketcanBus = None  # type: ignore[assignment,misc]
    capture_message = None  # type: ignore[assignment]

from northfinder.driver.errors import LinkError, LinkLost, ProtocolError
from northfinder.driver.protocol.can import CanReceiver, TickLoss, encode_can, sample_ids
from northfinder.driver.protocol.constants import UINT32_MAX
from northfinder.driver.protocol.counters import counter_diff
from northfinder.driver.protocol.messages import Command, Identify, Reply, Sample, Status
from northfinder.driver.protocol.serial import Deframer, SerialEncoder, decode_payload

log = logging.getLogger("northfinder.driver")

__all__ = [
    "CanTransport",
    "Received",
    "SerialTransport",
    "Transport",
    "bus_open_hint",
    "frame_batch",
    "frame_drain",
    "open_serial_port",
]

Received = Reply | Status | Identify | Sample | TickLoss
"""What a transport delivers."""

#: Longest a read blocks before the reader looks at its stop flag, s.
READ_POLL_S = 0.05
#: Most CAN frames one :meth:`CanTransport.recv` call drains, so the caller keeps control.
MAX_FRAMES_PER_RECV = 512


class Transport(Protocol):
    """What :class:`~northfinder.driver.device.Device` needs from a link."""

    kind: str
    """``"can"`` or ``"serial"``."""

    def send(self, command: Command) -> None: ...
    def recv(self, timeout: float) -> list[Received]: ...
    def restart_stream(self) -> list[TickLoss]: ...
    def counters(self) -> dict[str, int]: ...
    def close(self) -> None: ...


#: Receive buffer asked for on kernel CAN sockets: about 5 s of a saturated 1 Mbit/s bus, so a
#: host that is briefly busy (a loaded machine, a virtual machine) loses no frame.
SOCKET_RCVBUF = 8 * 1024 * 1024


def bus_open_hint(exc: BaseException) -> str:
    """A hint for a python-can bus that would not open, by its cause ("" when there is none):
    ``EAFNOSUPPORT`` (errno 97: "Address family not supported by protocol") is a kernel without
    SocketCAN (a container, WSL, a kernel built without the can modules)."""
    seen: BaseException | None = exc
    for _ in range(8):  # the cause chain: python-can wraps its errors
        if seen is None:
            break
        if isinstance(seen, OSError) and seen.errno == errno.EAFNOSUPPORT:
            return (
                "; this kernel has no SocketCAN: use vcan in a VM (scripts/hil), or the "
                "simulator's SLCAN or serial pseudo-terminal (sim --slcan-pty, sim --pty), or "
                "-i virtual"
            )
        seen = seen.__cause__ or seen.__context__
    return ""


def enlarge_receive_buffer(bus: can.BusABC, size: int = SOCKET_RCVBUF) -> int | None:
    """Ask the kernel for a larger receive buffer on a SocketCAN bus; return what it granted.

    Best effort: buses without a kernel socket (``virtual``, ``slcan``, ...) are left alone
    (None), and the kernel caps the size at ``net.core.rmem_max`` unless the process may
    override it.
    """
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return None
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, size)
            break
        except OSError:
            continue
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def frame_drain(bus: can.BusABC) -> Callable[[], can.Message | None]:
    """A function that returns the next frame already received on ``bus``, or None, at once
    (one frame at a time of :func:`frame_batch`)."""
    take = frame_batch(bus)

    def next_frame() -> can.Message | None:
        frames = take(1)
        return frames[0] if frames else None

    return next_frame


#: What python-can's ``slcan`` reader raises for a line it cannot parse. It indexes and converts
#: the line's fields without checking its length first (4.6.1, ``slcanBus._recv_internal``):
#: ``T1234\r``, a data frame shorter than its header, raises IndexError; a field that is not hex
#: raises ValueError (hardbyte/python-can#1821). Either is one damaged line, never a dead link.
SLCAN_PARSE_ERRORS: tuple[type[Exception], ...] = (ValueError, IndexError)


def garbled_slcan_line(bus: can.BusABC, exc: BaseException) -> bool:
    """Whether ``exc``, raised by ``bus.recv``, is one SLCAN line that did not parse (a flipped
    bit, a dropped byte): a frame error, not a lost link. python-can's ``slcan`` reader raises
    ValueError or IndexError for a line it cannot parse (:data:`SLCAN_PARSE_ERRORS`) and
    CanOperationError (from UnicodeDecodeError) for a byte that is not ASCII; in the latter case
    the line stays in its buffer and would fail every later read, so it is dropped here, up to
    its terminator."""
    if not isinstance(bus, slcanBus):
        return False
    cause = getattr(exc, "__cause__", None) if isinstance(exc, can.CanOperationError) else exc
    if not isinstance(cause, SLCAN_PARSE_ERRORS):  # UnicodeDecodeError is a ValueError
        return False
    held = getattr(bus, "_buffer", None)
    if isinstance(cause, UnicodeDecodeError) and isinstance(held, bytearray):
        ends = [i for i in (held.find(b"\r"), held.find(b"\a")) if i >= 0]
        del held[: min(ends) + 1 if ends else len(held)]
    return True


def frame_batch(
    bus: can.BusABC, on_garbled: Callable[[], None] | None = None
) -> Callable[[int], list[can.Message]]:
    """A function ``take(n)`` that returns up to ``n`` frames already received on ``bus``, in
    the order they arrived, at once (an empty list if none is waiting).

    On python-can's SocketCAN bus it reads the kernel socket directly (non-blocking, with
    python-can's own frame parser): one system call a frame, where ``bus.recv(0)`` makes three
    (a clock read, ``select`` and ``recvmsg``). Where system calls are dear (a virtual machine,
    user-mode Linux: 60 to 100 us each) this halves a reader's cost per frame. On python-can's
    ``virtual`` bus it takes the frames after the first from the bus's queue (``recv`` reads
    two clocks and logs for each frame). Every other bus, and a SocketCAN or
    virtual bus with filters set in python-can, gets ``bus.recv(0.0)`` for each frame; on
    python-can's ``slcan`` bus only while bytes are waiting (there ``recv(0.0)`` on an empty
    port waits for the port's read timeout, 1 ms by default, before it says there is nothing:
    every batch would end 1 ms after its last frame, on a timer's wake-up).

    The socket is switched to non-blocking mode, which python-can's own ``recv`` and ``send``
    allow (both wait with ``select`` before they read or write).
    """
    if isinstance(bus, VirtualBus) and not bus.filters:
        return _virtual_batch(bus)
    if isinstance(bus, slcanBus):
        return _slcan_batch(bus, on_garbled)
    sock = getattr(bus, "socket", None)
    if (
        SocketcanBus is None
        or not isinstance(bus, SocketcanBus)
        or bus.filters
        or not isinstance(sock, socket.socket)
    ):

        def take_each(n: int) -> list[can.Message]:
            out: list[can.Message] = []
            while len(out) < n and (msg := bus.recv(0.0)) is not None:
                out.append(msg)
            return out

        return take_each
    sock.setblocking(False)
    channel = bus.channel

    def take_socket(n: int) -> list[can.Message]:
        out: list[can.Message] = []
        while len(out) < n:
            try:
                msg = capture_message(sock)
            except can.CanOperationError as exc:
                if exc.error_code in (errno.EAGAIN, errno.EWOULDBLOCK):
                    break
                raise
            if msg is None:
                break
            if not msg.channel:
                msg.channel = channel
            out.append(msg)
        return out

    return take_socket


def _slcan_batch(
    bus: slcanBus, on_garbled: Callable[[], None] | None = None
) -> Callable[[int], list[can.Message]]:
    """:func:`frame_batch` of a python-can ``slcan`` bus: ``recv(0.0)`` while the port has bytes
    waiting or the bus holds a whole line it has read. python-can's next ``slcan`` reader
    (merged after 4.6.1) reads all the waiting bytes at once and keeps the lines after the first;
    it reads at least one byte before it looks at them, so for those the port's read timeout is
    set to 0 (that read returns at once)."""
    port = bus.serialPortOrig

    def line_held() -> bool:
        # Noted 2026-12-04: python-can has no public way to ask whether its slcan bus holds a
        # whole line it has already read. Its reader of hardbyte/python-can#2028 (for issue
        # #2027, after 4.6.1) reads every waiting byte and keeps the lines after the first in
        # the private ``_buffer``; 4.6.1 reads byte by byte and never holds a whole line, so
        # there this is always False. Without the look, a held line would wait for the next
        # batch (a read that waits for the port's timeout).
        held = getattr(bus, "_buffer", b"")
        return b"\r" in held or b"\a" in held

    def waiting() -> int:
        if not port.is_open:
            raise can.CanOperationError("the SLCAN adapter's serial port is closed")
        try:
            return port.in_waiting
        except TypeError as exc:  # pyserial, on a port closed meanwhile
            raise can.CanOperationError(f"the SLCAN adapter's serial port: {exc}") from exc

    def take(n: int) -> list[can.Message]:
        out: list[can.Message] = []
        timeout = port.timeout  # pyserial reconfigures the port at each change: at most two
        try:
            for _ in range(n):  # at most n reads, whatever keeps arriving
                if not waiting():
                    if not line_held():
                        break
                    if port.timeout:
                        port.timeout = 0
                try:
                    msg = bus.recv(0.0)
                except (can.CanError, ValueError, IndexError) as exc:  # SLCAN_PARSE_ERRORS
                    if on_garbled is None or not garbled_slcan_line(bus, exc):
                        raise
                    on_garbled()
                    continue
                if msg is not None:  # None: a line not complete yet, or an answer to a command
                    out.append(msg)
        finally:
            if port.timeout != timeout and port.is_open:
                port.timeout = timeout
        return out

    return take


def _virtual_batch(bus: VirtualBus) -> Callable[[int], list[can.Message]]:
    """:func:`frame_batch` of a python-can ``virtual`` bus: the frames from the bus's receive
    queue (``bus.queue``, a :class:`queue.Queue`) by ``get_nowait``, without ``recv``'s clock
    reads and logging for each frame. A closed bus is refused as python-can's ``recv`` refuses
    it: python-can takes the queue off the bus's channel (``bus.channel``, the receivers'
    queues) when it shuts the bus down."""
    q, channel = bus.queue, bus.channel

    def take(n: int) -> list[can.Message]:
        waiting = min(n, q.qsize())
        if waiting < 1:
            return []
        if q not in channel:
            raise can.CanOperationError("Cannot operate on a closed bus")
        out: list[can.Message] = []
        try:
            for _ in range(waiting):
                out.append(q.get_nowait())
        except queue.Empty:  # taken by another reader meanwhile
            pass
        return out

    return take


class _TransportBase:
    """What every transport holds: its tap, a lock for sending and one for receiving, and its
    ``close``: the bus or port it was given is released once, and only if the transport owns it
    (``release``: None when it does not)."""

    _closed = False

    def __init__(
        self, tap: Callable[[can.Message], None] | None, release: Callable[[], object] | None
    ) -> None:
        self.tap = tap
        self._release = release
        self._send_lock = threading.Lock()
        self._rx_lock = threading.RLock()

    def close(self) -> None:
        """Release the bus (``shutdown``) or the port (``close``) if this transport owns it
        (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._release is not None:
            self._release()


class CanTransport(_TransportBase):
    """The protocol on a python-can bus, for one node.

    Parameters
    ----------
    bus : can.BusABC
        An opened bus (``virtual``, ``socketcan``, ``slcan``, ...).
    node_id : int
        The device's node id (1..15); frames of other nodes are counted and ignored.
    own_bus : bool
        Shut the bus down on :meth:`close` (True when the driver opened it).
    tap : callable, optional
        Called with every frame sent and received, in that order
        (a :class:`~northfinder.driver.framelog.FrameLog` writes them to a CAN log).
    """

    kind = "can"

    def __init__(
        self,
        bus: can.BusABC,
        node_id: int = 1,
        *,
        own_bus: bool = False,
        tap: Callable[[can.Message], None] | None = None,
    ) -> None:
        super().__init__(tap, bus.shutdown if own_bus else None)
        self.bus = bus
        self.node_id = node_id
        self.own_bus = own_bus
        self.receiver = CanReceiver(node_id=node_id)
        self.rcvbuf = enlarge_receive_buffer(bus)
        self.garbled = 0  # SLCAN lines that did not parse (frame errors)
        self._take = frame_batch(bus, self._garbled)
        self._tick_ids = sample_ids(node_id)

    def send(self, command: Command) -> None:
        """Send one command (one frame).

        Raises
        ------
        LinkLost
            The bus refused the frame (bus off, transmit buffer full, interface gone).
        """
        (frame,) = encode_can(command, self.node_id)
        msg = can.Message(
            arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
        )
        try:
            with self._send_lock:
                if self.tap is not None:
                    # Logged before it goes out, so that no answer can precede it in the log.
                    self.tap(
                        can.Message(
                            arbitration_id=frame.arbitration_id, data=frame.data,
                            is_extended_id=False, is_rx=False, timestamp=time.time(),
                        )
                    )  # fmt: skip
                self.bus.send(msg, timeout=0.1)
        except (can.CanError, OSError, ValueError) as exc:
            raise LinkLost(f"cannot send on the CAN bus {self._name()}: {exc}") from exc

    def recv(self, timeout: float) -> list[Received]:
        """Wait up to ``timeout`` s for frames; return the messages and tick losses they complete.

        Raises
        ------
        LinkLost
            The bus reported an error or was shut down under the driver.
        """
        try:
            if timeout > 0:
                # Block in the bus (one wake-up for the first frame), then take what came with it.
                try:
                    msg = self.bus.recv(timeout)
                except (can.CanError, ValueError, IndexError) as exc:  # SLCAN_PARSE_ERRORS
                    if not garbled_slcan_line(self.bus, exc):
                        raise
                    self._garbled()
                    return []
                frames = [] if msg is None else [msg, *self._take(MAX_FRAMES_PER_RECV - 1)]
            else:  # a poll (a virtual clock's, at every instant): nothing but what is waiting
                frames = self._take(MAX_FRAMES_PER_RECV)
        except (can.CanError, OSError, ValueError, IndexError, serial.SerialException) as exc:
            raise LinkLost(f"cannot receive from the CAN bus {self._name()}: {exc}") from exc
        if not frames:
            return []
        if self.tap is not None:
            for msg in frames:
                self.tap(msg)
        with self._rx_lock:
            return self._decode(frames)

    def _decode(self, frames: list[can.Message]) -> list[Received]:
        """The messages and tick losses ``frames`` complete (the receive lock held). A tick's
        four sample frames in sending order go to the receiver together
        (:meth:`~northfinder.driver.protocol.can.CanReceiver.feed_tick`), any other frame one at
        a time."""
        out: list[Any] = []
        receiver = self.receiver
        x_id = self._tick_ids[0]
        i, n = 0, len(frames)
        while i < n:
            msg = frames[i]
            if msg.arbitration_id == x_id and i + 4 <= n and self._whole_tick(frames, i):
                out += receiver.feed_tick(msg.data, frames[i + 1].data, frames[i + 2].data,
                                          frames[i + 3].data)  # fmt: skip
                i += 4
                continue
            i += 1
            if not (msg.is_error_frame or msg.is_remote_frame):
                got = receiver.feed(msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id)
                if not msg.is_rx:  # this host's own frame, echoed by the interface
                    got = [m for m in got if not isinstance(m, Command)]
                out += got
        # Commands on the bus are another host's (this host's own echoes were dropped above):
        # the link notes them.
        return out

    def _whole_tick(self, frames: list[can.Message], i: int) -> bool:
        """Whether ``frames[i:i + 4]`` (four frames: the caller has checked) are the four sample
        frames of one tick of this node, in sending order: standard data frames of 8 bytes."""
        x, y, z, aux = frames[i : i + 4]
        return (
            (x.arbitration_id, y.arbitration_id, z.arbitration_id, aux.arbitration_id)
            == self._tick_ids
            and len(x.data) == len(y.data) == len(z.data) == len(aux.data) == 8
            and not (
                x.is_extended_id or x.is_error_frame or x.is_remote_frame
                or y.is_extended_id or y.is_error_frame or y.is_remote_frame
                or z.is_extended_id or z.is_error_frame or z.is_remote_frame
                or aux.is_extended_id or aux.is_error_frame or aux.is_remote_frame
            )
        )  # fmt: skip

    def restart_stream(self) -> list[TickLoss]:
        """The stream was off: the next tick does not continue the previous one (any thread)."""
        with self._rx_lock:
            return self.receiver.ticks.restart()

    def _garbled(self) -> None:
        self.garbled += 1
        log.debug("an SLCAN line did not parse: counted as a rejected frame")

    def counters(self) -> dict[str, int]:
        """Frame statistics: received, rejected (could not be decoded, or an SLCAN line that did
        not parse), foreign, tick losses."""
        r = self.receiver
        return {
            "frames_received": r.frames,
            "frames_rejected": r.malformed + r.identify.errors + self.garbled,
            "frames_foreign": r.unknown_id + r.other_node,
            "frames_lost": 0,
            "ticks_lost": r.ticks.lost,
            "ticks_incomplete": r.ticks.incomplete,
            "duplicates": r.ticks.duplicates,
        }

    def _name(self) -> str:
        return str(getattr(self.bus, "channel_info", type(self.bus).__name__))


def open_serial_port(
    port_or_url: str, baudrate: int = 115_200, **options: Any
) -> serial.SerialBase:
    """Open a serial port as :class:`SerialTransport` wants it, input drained.

    Parameters
    ----------
    port_or_url : str
        A path such as ``/dev/ttyUSB0`` or ``/dev/pts/3``, or a pyserial URL.
    baudrate : int
        Baud rate (8N1).
    **options
        More pyserial options.

    Raises
    ------
    LinkError
        pyserial could not open the port.
    """
    try:
        port = serial.serial_for_url(
            port_or_url, baudrate=baudrate, timeout=READ_POLL_S, write_timeout=1.0, **options
        )
        port.reset_input_buffer()  # bytes from before this host opened the port
    except (serial.SerialException, OSError, ValueError) as exc:
        raise LinkError(f"cannot open the serial port {port_or_url!r}: {exc}") from exc
    return port


class SerialTransport(_TransportBase):
    """The protocol's binary frames on a serial port (pyserial ``Serial`` or URL handler).

    Lost frames show in the frame sequence counter (:class:`Deframer`), lost samples in the
    sample counter: a forward jump of the counter is reported as a :class:`TickLoss`.

    Parameters
    ----------
    port : serial.Serial
        An opened port; its ``timeout`` is set on every :meth:`recv`.
    own_port : bool
        Close the port on :meth:`close`.
    tap : callable, optional
        Called with every message sent and received as the CAN frames that carry it on the
        CAN link (protocol.md 2.1, node ``tap_node_id``), so a serial session logs as a CAN one.
    tap_node_id : int
        The node id of those frames (default 1).
    """

    kind = "serial"

    def __init__(
        self,
        port: serial.SerialBase,
        *,
        own_port: bool = True,
        tap: Callable[[can.Message], None] | None = None,
        tap_node_id: int = 1,
    ) -> None:
        super().__init__(tap, port.close if own_port else None)
        self.port = port
        self.tap_node_id = tap_node_id
        self.own_port = own_port
        self.deframer = Deframer()
        self.encoder = SerialEncoder()
        self._last_counter: int | None = None
        self.ticks_lost = 0
        self.counter_restarts = 0
        self.samples = 0
        #: Bytes read, and bytes read since the last frame that parsed: bytes that keep arriving
        #: while no frame parses are a line at another baud rate or another protocol.
        self.bytes_received = 0
        self.bytes_unparsed = 0

    def send(self, command: Command) -> None:
        """Send one command frame.

        Raises
        ------
        LinkLost
            The port failed or the write did not complete within its write timeout.
        """
        try:
            with self._send_lock:
                if self.tap is not None:
                    self._tap(command, is_rx=False)  # before it goes out: no answer precedes it
                self.port.write(self.encoder.encode(command))
                self.port.flush()
        except (serial.SerialException, OSError) as exc:
            raise LinkLost(f"cannot write to the serial port {self.port.name}: {exc}") from exc

    def _tap(self, message: Any, *, is_rx: bool) -> None:
        assert self.tap is not None
        now = time.time()
        for frame in encode_can(message, self.tap_node_id):
            self.tap(
                can.Message(
                    arbitration_id=frame.arbitration_id,
                    data=frame.data,
                    is_extended_id=False,
                    is_rx=is_rx,
                    timestamp=now,
                )
            )

    def recv(self, timeout: float) -> list[Received]:
        """Wait up to ``timeout`` s for bytes; return the messages and tick losses they complete.

        Raises
        ------
        LinkLost
            The port failed (for a pseudo-terminal: the other end closed).
        """
        try:
            self.port.timeout = timeout
            data = self.port.read(1)
            if data:
                waiting = self.port.in_waiting
                if waiting:
                    data += self.port.read(waiting)
        except (serial.SerialException, OSError, TypeError) as exc:
            # pyserial raises TypeError when the port is closed under a blocked read.
            raise LinkLost(f"cannot read from the serial port {self.port.name}: {exc}") from exc
        if not data:
            return []
        with self._rx_lock:
            return self._decode(data)

    def _decode(self, data: bytes) -> list[Received]:
        out: list[Received] = []
        self.bytes_received += len(data)
        parsed = self.deframer.frames
        frames = self.deframer.feed(data)
        if self.deframer.frames > parsed:
            self.bytes_unparsed = 0
        else:
            self.bytes_unparsed += len(data)
        for frame in frames:
            try:
                message = decode_payload(frame.msg_type, frame.payload)
            except ProtocolError as exc:
                self.deframer.malformed += 1
                self.deframer.last_error = exc
                continue
            if self.tap is not None:
                self._tap(message, is_rx=True)
            if isinstance(message, Sample):
                out += self._check_counter(message.counter)
                self.samples += 1
            if not isinstance(message, Command):
                out.append(message)
        return out

    def _check_counter(self, counter: int) -> list[TickLoss]:
        last, self._last_counter = self._last_counter, counter
        if last is None:
            return []
        step = counter_diff(counter, last)
        if step == 1:
            return []
        if step <= 0:
            # Repeated or earlier counter: the device restarted. The device decides what that
            # means; nothing is lost on this side.
            self.counter_restarts += 1
            return []
        self.ticks_lost += step - 1
        return [TickLoss((last + 1) & UINT32_MAX, step - 1, False)]

    def restart_stream(self) -> list[TickLoss]:
        """The stream was off: the next sample does not continue the previous one (any thread)."""
        with self._rx_lock:
            self._last_counter = None
        return []

    def counters(self) -> dict[str, int]:
        """Frame statistics: received, rejected (bad CRC or length, undecodable), lost (sequence
        counter gaps, including rejected frames), tick losses."""
        d = self.deframer
        return {
            "frames_received": d.frames,
            "frames_rejected": d.crc_errors + d.length_errors + d.malformed,
            "frames_foreign": 0,
            "frames_lost": d.lost_frames,
            "ticks_lost": self.ticks_lost,
            "ticks_incomplete": 0,
            "duplicates": 0,
            "bytes_received": self.bytes_received,
            "bytes_unparsed": self.bytes_unparsed,
        }
