"""The host driver: one :class:`Device` object per instrument, on CAN or serial.

Units at this interface: angles in degrees (table angle counter-clockwise seen from above, as the
encoder reports it), gyro rates in deg/h (``Window.gyro_rps`` gives rad/s), specific force in
m/s^2, temperature in degC, times in seconds. Count scales come from the device's IDENTIFY, not
from constants.

Threads. A reader thread receives everything the device sends and sorts it: replies go to the
caller waiting for their sequence number, statuses update :attr:`Device.last_status` (and feed
link supervision), identify updates :attr:`Device.identity`, samples go to an :meth:`acquire`
in progress and are dropped otherwise. Every public method may be called from any thread;
:meth:`Device.acquire` calls run one at a time.

Timing. Every deadline, timeout and wait reads the device's clock (``clock=``: the wall clock by
default, or a :class:`~northfinder.driver.clock.VirtualClock` shared with an in-process simulator,
on which time jumps to the next event whenever every party waits). A command is sent with a fresh sequence number and waits
``reply_timeout`` (default 0.25 s; protocol.md 6 asks for at least 0.1 s) for its reply. Commands
that are safe to repeat (:data:`RETRYABLE`) are sent again with a new sequence number, up to
``retries`` more times (default 2), so a query fails with :class:`~northfinder.driver.errors.ReplyTimeout`
after at most ``(1 + retries) * reply_timeout`` = 0.75 s. Moves, HOME, RESET and SELF_TEST are
sent once: a lost reply leaves open whether they were carried out. The link counts as lost when
no status arrived for three heartbeat periods (0.3 s by default; ``min_supervision_s`` raises it),
counted once the reader has read everything that arrived (protocol.md 6), so a host that is busy
or an adapter that reads slowly does not take a late status for a lost link.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Concatenate, ParamSpec, TypeVar

import can
import serial

from northfinder.driver.arguments import finite_number, seconds, whole_number
from northfinder.driver.clock import Clock, WallClock
from northfinder.driver.errors import (
    ArgumentError,
    DeviceFault,
    DeviceRefused,
    DeviceReset,
    DriverError,
    DriverTimeout,
    LinkError,
    LinkLost,
    MoveTimeout,
    ProtocolError,
    ReplyTimeout,
    StreamTimeout,
)
from northfinder.driver.protocol.can import TickLoss
from northfinder.driver.protocol.constants import (
    HEARTBEAT_PERIOD_DEFAULT_MS,
    PROTOCOL_VERSION_MAJOR,
    ROTATE_BY_LIMIT,
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    Opcode,
    Result,
    result_meaning,
)
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    GetStatus,
    Home,
    Identify,
    Reply,
    RequestIdentify,
    Reset,
    RotateBy,
    RotateTo,
    Sample,
    SelfTest,
    SetConfig,
    Status,
    Stop,
    StreamStart,
    StreamStop,
)
from northfinder.driver.protocol.motion import TableLimits
from northfinder.driver.transport import (
    READ_POLL_S,
    CanTransport,
    Received,
    SerialTransport,
    Transport,
    open_serial_port,
)
from northfinder.driver.window import CountScales, OnGap, Window, WindowCollector

__all__ = [
    "RETRYABLE",
    "Device",
    "DeviceStatus",
    "LinkStats",
    "OnGap",
    "Window",
]

log = logging.getLogger("northfinder.driver")

RETRYABLE = frozenset(
    {
        Opcode.IDENTIFY,
        Opcode.GET_STATUS,
        Opcode.GET_CONFIG,
        Opcode.SET_CONFIG,
        Opcode.STREAM_START,
        Opcode.STREAM_STOP,
        Opcode.STOP,
    }
)
"""Commands sent again (with a new sequence number) when their reply does not come.

Queries change nothing; STREAM_START/STOP and STOP leave the same state however often they
arrive; SET_CONFIG writes an absolute value, so applying it twice equals applying it once (its
reply echoes the value in effect). ROTATE_TO/BY and HOME are not repeated (a second copy arriving
during the move is refused BUSY, and ROTATE_BY would add up), nor RESET and SELF_TEST.
"""

REPLY_TIMEOUT_S = 0.25
RETRIES = 2
HEARTBEATS_UNTIL_LOST = 3
"""protocol.md 6: the device counts as lost after three heartbeat periods without a status."""
_CONFIG_NAMES = ", ".join(k.name.lower() for k in ConfigKey)
# acquire()'s own argument is named ``seconds``: the checker under another name.
_window_seconds = _timeout_seconds = seconds
_DIRECTIONS = {"shortest": Direction.SHORTEST, "positive": Direction.POSITIVE}
_DIRECTIONS["negative"] = Direction.NEGATIVE
T = TypeVar("T")
P = ParamSpec("P")


def _on_clock(method: Callable[Concatenate[Device, P], T]) -> Callable[Concatenate[Device, P], T]:
    """A public call: its thread counts as a party of the device's clock while it runs (a
    virtual clock does not move on while the caller works between two waits)."""

    @functools.wraps(method)
    def call(self: Device, *args: P.args, **kwargs: P.kwargs) -> T:
        with self._clock.participant():
            return method(self, *args, **kwargs)

    return call


@dataclass(frozen=True, slots=True)
class DeviceStatus:
    """The device's status message in physical units.

    Attributes
    ----------
    state : DeviceState
    angle_deg : float
        Table angle from the encoder, deg in [0, 360).
    temperature_c : float
        Sensor temperature, degC (NaN: no reading).
    faults : Fault
        Fault flags (any set flag means state FAULT).
    sample_counter : int
        Counter of the device's most recent sample tick.
    rx_malformed, tx_dropped, cmd_rejected : int
        The device's wrapping counters (protocol.md 4.6).
    received_at : float
        The device clock's time (``time.monotonic()`` on the wall clock) when the status arrived.
    """

    state: DeviceState
    angle_deg: float
    temperature_c: float
    faults: Fault
    sample_counter: int
    rx_malformed: int
    tx_dropped: int
    cmd_rejected: int
    received_at: float


@dataclass(frozen=True, slots=True)
class LinkStats:
    """What the driver received and what it could not use, since the device object was created.

    Attributes
    ----------
    frames_received : int
        CAN frames, or serial frames that passed the CRC check.
    frames_rejected : int
        Frames dropped as corrupt: bad CRC or length (serial), or a protocol frame that did not
        decode (wrong length, undefined code).
    frames_foreign : int
        CAN frames of other nodes or other equipment (normal on a shared bus).
    frames_lost : int
        Serial only: frames missing from the device's sequence counter (dropped or rejected;
        a device restart also shows as a jump).
    ticks_lost, ticks_incomplete : int
        Sample ticks of which no frame / only some CAN frames arrived (while streaming).
    samples_received : int
        Whole samples delivered.
    stray_replies : int
        Replies nobody waited for (late replies to timed-out commands).
    retries : int
        Commands sent again after a reply timeout.
    reply_timeouts : int
        Commands that failed with :class:`~northfinder.driver.errors.ReplyTimeout`.
    resets_detected : int
        Device restarts noticed (BOOT status, unrequested IDENTIFY).
    """

    frames_received: int
    frames_rejected: int
    frames_foreign: int
    frames_lost: int
    ticks_lost: int
    ticks_incomplete: int
    samples_received: int
    stray_replies: int
    retries: int
    reply_timeouts: int
    resets_detected: int


@dataclass
class _Waiter:
    opcode: Opcode
    reply: Reply | None = None
    error: DriverError | None = None

    @property
    def done(self) -> bool:
        return self.reply is not None or self.error is not None

    def is_done(self) -> bool:
        return self.done


class Device:
    """A north finder on a CAN bus or a serial line.

    Open it with :meth:`open_can`, :meth:`from_bus` or :meth:`open_serial`, preferably as a
    context manager (``with Device.open_serial("/dev/ttyUSB0") as dev:``): :meth:`close` always
    stops the reader thread and releases the bus or port the device object opened. On opening the
    driver reads IDENTIFY (count scales, protocol version), the status and the configuration.

    Parameters
    ----------
    transport : Transport
        The link (:class:`~northfinder.driver.transport.CanTransport` or
        :class:`~northfinder.driver.transport.SerialTransport`); closed by :meth:`close`.
    reply_timeout : float
        Seconds to wait for each reply before declaring it lost (at least 0.1).
    retries : int
        Extra attempts for commands in :data:`RETRYABLE`.
    min_supervision_s : float
        Lower limit, in seconds, of the time without a status (or without samples while
        acquiring) before the link counts as lost. 0 keeps protocol.md's three heartbeat periods;
        a host that cannot read its link in time (a busy machine, a slow adapter) may need more.
    clock : Clock, optional
        What every timeout and wait reads (default: a :class:`~northfinder.driver.clock.WallClock`).
        With a :class:`~northfinder.driver.clock.VirtualClock` the device has no reader thread:
        the clock polls the link at every instant (in-process links only).

    Raises
    ------
    ReplyTimeout
        The device does not answer IDENTIFY.
    ProtocolError
        The device speaks another major protocol version.
    """

    def __init__(
        self,
        transport: Transport,
        *,
        reply_timeout: float = REPLY_TIMEOUT_S,
        retries: int = RETRIES,
        min_supervision_s: float = 0.0,
        clock: Clock | None = None,
    ) -> None:
        if not reply_timeout >= 0.1:
            raise ArgumentError(f"reply_timeout={reply_timeout!r}: must be at least 0.1 s")
        if retries < 0:
            raise ArgumentError(f"retries={retries!r}: must be >= 0")
        self._transport = transport
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        if not (math.isfinite(min_supervision_s) and min_supervision_s >= 0):
            raise ArgumentError(f"min_supervision_s={min_supervision_s!r}: must be >= 0 s")
        self.min_supervision_s = float(min_supervision_s)
        self._clock: Clock = WallClock() if clock is None else clock
        self._lock = threading.RLock()
        self._acquire_lock = threading.Lock()
        self._waiters: dict[int, _Waiter] = {}
        self._events = 0  # counts everything the reader delivered: waiters look again on a change
        # Whether the reader's latest read found nothing: supervision judges the time since the
        # last status only once the host has read everything that arrived (a busy host or a slow
        # adapter delivers statuses late behind the stream, while the link is plainly up).
        self._link_idle = True
        self._seq = 0
        self._opened_at = self._clock.now()
        self._status: DeviceStatus | None = None
        self._status_count = 0
        self._motion_count = 0  # _status_count of the latest ROTATING or SETTLING status
        self._identify: Identify | None = None
        self._identify_count = 0
        self._identify_expected_until = 0.0
        self._scales = CountScales()
        self._boot_epoch = 0
        self._reset_reason = ""
        # What the reader hands to an acquire() in progress: (kind, item, clock time, wall time)
        # for samples, losses, resets and a lost link.
        self._inbox: deque[tuple[str, Any, float, float]] | None = None
        self._inbox_since = 0.0  # clock time the inbox was registered
        self._config: dict[ConfigKey, int] = {}
        self._config_stale = True
        self._streaming = False
        self._dead: DriverError | None = None
        self._closed = False
        self._stop = threading.Event()
        self._counts = {"samples": 0, "stray": 0, "retries": 0, "timeouts": 0, "resets": 0}
        self._reader: threading.Thread | None = None
        if self._clock.virtual:
            self._clock.add_poller(self._pump)
        else:
            self._reader = threading.Thread(
                target=self._read_loop, name=f"northfinder-{transport.kind}-reader", daemon=True
            )
            self._reader.start()
        try:
            with self._clock.participant():
                self._connect()
        except BaseException:
            self.close()
            raise

    # -- constructors -------------------------------------------------------------------------
    @classmethod
    def from_bus(
        cls,
        bus: can.BusABC,
        node_id: int = 1,
        *,
        own_bus: bool = False,
        tap: Callable[[can.Message], None] | None = None,
        **options: Any,
    ) -> Device:
        """A device on an opened python-can bus.

        Parameters
        ----------
        bus : can.BusABC
            The bus; shut down by :meth:`close` only with ``own_bus=True``.
        node_id : int
            The device's CAN node id, 1..15.
        tap : callable, optional
            Called with every frame sent and received (a
            :class:`~northfinder.driver.framelog.FrameLog` writes them to a CAN log; the caller
            closes it).
        **options
            ``reply_timeout``, ``retries``, ``min_supervision_s``, ``clock`` (see :class:`Device`).
        """
        return cls(CanTransport(bus, node_id, own_bus=own_bus, tap=tap), **options)

    @classmethod
    def open_can(
        cls,
        interface: str | None = None,
        channel: str | int | None = None,
        bitrate: int | None = None,
        *,
        node_id: int = 1,
        reply_timeout: float = REPLY_TIMEOUT_S,
        retries: int = RETRIES,
        min_supervision_s: float = 0.0,
        clock: Clock | None = None,
        tap: Callable[[can.Message], None] | None = None,
        **bus_options: Any,
    ) -> Device:
        """Open a python-can bus and the device on it; :meth:`close` shuts the bus down.

        Examples: ``open_can("socketcan", "vcan0")``, ``open_can("slcan", "/dev/ttyACM0",
        500_000, sleep_after_open=0)``, ``open_can("virtual", "bench")`` (same process only).

        Raises
        ------
        LinkError
            python-can could not open the bus (the message names interface and channel).
        """
        given = {"interface": interface, "channel": channel, "bitrate": bitrate}
        kw: dict[str, Any] = {k: v for k, v in given.items() if v is not None}
        try:
            bus = can.Bus(**kw, **bus_options)
        except (can.CanError, OSError, ValueError, ImportError, serial.SerialException) as exc:
            raise LinkError(
                f"cannot open the CAN bus interface={interface!r} channel={channel!r}: {exc}"
            ) from exc
        return cls.from_bus(
            bus,
            node_id,
            own_bus=True,
            tap=tap,
            reply_timeout=reply_timeout,
            retries=retries,
            min_supervision_s=min_supervision_s,
            clock=clock,
        )

    @classmethod
    def open_serial(
        cls,
        port_or_url: str,
        baudrate: int = 115_200,
        *,
        reply_timeout: float = REPLY_TIMEOUT_S,
        retries: int = RETRIES,
        min_supervision_s: float = 0.0,
        clock: Clock | None = None,
        tap: Callable[[can.Message], None] | None = None,
        **port_options: Any,
    ) -> Device:
        """Open a serial port (a path such as ``/dev/ttyUSB0`` or ``/dev/pts/3``, or a pyserial
        URL such as ``rfc2217://host:port``) and the device on it; :meth:`close` closes the port.

        ``tap`` is called with every message sent and received, as the CAN frames that carry it
        (see :class:`~northfinder.driver.transport.SerialTransport`), so a serial session logs
        to a CAN log like a CAN one.

        Raises
        ------
        LinkError
            pyserial could not open the port.
        """
        port = open_serial_port(port_or_url, baudrate, **port_options)
        return cls(
            SerialTransport(port, tap=tap),
            reply_timeout=reply_timeout,
            retries=retries,
            min_supervision_s=min_supervision_s,
            clock=clock,
        )

    # -- life cycle ---------------------------------------------------------------------------
    def __enter__(self) -> Device:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the stream if this driver started it, stop the reader, release the bus or port.

        Idempotent; never raises for a device that stopped answering.
        """
        if self._closed:
            return
        reading = self._reader.is_alive() if self._reader is not None else True
        if self._streaming and self._dead is None and reading:
            try:
                with self._clock.participant():
                    self._request(StreamStop, attempts=1)
            except DriverError as exc:
                log.info("stream not stopped on close: %s", exc)
        self._closed = True
        self._stop.set()
        if self._reader is None:
            self._clock.remove_poller(self._pump)
        elif self._reader is not threading.current_thread():
            self._reader.join(2.0)
        self._transport.close()
        with self._lock:
            for waiter in self._waiters.values():
                waiter.error = LinkError("the device was closed")
            self._events += 1
        self._clock.notify()

    @property
    def clock(self) -> Clock:
        """The clock every timeout and wait of this device reads."""
        return self._clock

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    @property
    def link_kind(self) -> str:
        """``"can"`` or ``"serial"``."""
        return self._transport.kind

    def _connect(self) -> None:
        ident = self.identify()
        if ident.protocol_version[0] != PROTOCOL_VERSION_MAJOR:
            raise ProtocolError(
                f"the device speaks protocol {ident.protocol_version[0]}.{ident.protocol_version[1]}; "
                f"this driver speaks major version {PROTOCOL_VERSION_MAJOR}"
            )
        self.status()
        self._refresh_config()

    # -- the reader thread --------------------------------------------------------------------
    def _read_loop(self) -> None:
        try:
            while not self._stop.is_set():
                items = self._transport.recv(READ_POLL_S)
                if items:
                    self._link_idle = False
                    self._dispatch(items, self._clock.now(), self._clock.wall())
                elif not self._link_idle:
                    self._went_idle()
        except DriverError as exc:
            if not self._stop.is_set():
                self._fail(exc if isinstance(exc, LinkError) else LinkLost(str(exc)), exc)
        except Exception as exc:  # a bug must not leave callers waiting forever
            if not self._stop.is_set():
                self._fail(LinkLost(f"the driver's reader thread failed: {exc!r}"), exc)
                raise

    def _pump(self) -> bool:
        """On a virtual clock: receive what has arrived, without blocking (the clock calls this
        at every instant); True if anything came."""
        if self._closed or self._dead is not None:
            return False
        try:
            items = self._transport.recv(0.0)
        except DriverError as exc:
            self._fail(exc if isinstance(exc, LinkError) else LinkLost(str(exc)), exc)
            return True
        if not items:
            if not self._link_idle:
                self._went_idle()
            return False
        self._link_idle = False
        self._dispatch(items, self._clock.now(), self._clock.wall())
        return True

    def _went_idle(self) -> None:
        with self._lock:
            self._link_idle = True
            self._events += 1
        if self._reader is not None:
            self._clock.notify()

    def _fail(self, error: DriverError, cause: BaseException) -> None:
        error.__cause__ = cause
        log.error("link lost: %s", error)
        with self._lock:
            self._dead = error
            for waiter in self._waiters.values():
                waiter.error = error
            if self._inbox is not None:
                now = self._clock.now()
                self._inbox.append(("lost", error, now, self._clock.wall()))
            self._events += 1
        self._clock.notify()

    def _dispatch(self, items: list[Received], mono: float, wall: float) -> None:
        with self._lock:
            for item in items:
                if isinstance(item, Sample | TickLoss):
                    if isinstance(item, Sample):
                        self._counts["samples"] += 1
                    # Only what was received after acquire() was called belongs to its window.
                    if self._inbox is not None and mono >= self._inbox_since:
                        kind = "sample" if isinstance(item, Sample) else "loss"
                        self._inbox.append((kind, item, mono, wall))
                elif isinstance(item, Reply):
                    self._on_reply(item)
                elif isinstance(item, Status):
                    self._on_status(item, mono)
                elif isinstance(item, Identify):
                    self._on_identify(item, mono)
            self._events += 1
        if self._reader is not None:
            self._clock.notify()  # a virtual clock looks at its waiters after every poll anyway

    def _on_reply(self, reply: Reply) -> None:
        waiter = self._waiters.get(reply.seq)
        if waiter is None or waiter.opcode != reply.opcode or waiter.done:
            self._counts["stray"] += 1
            log.debug("stray reply %s", reply)
            return
        waiter.reply = reply

    def _on_status(self, status: Status, mono: float) -> None:
        sc = self._scales
        previous = self._status
        self._status = DeviceStatus(
            state=status.state,
            angle_deg=status.angle * sc.angle_deg,
            temperature_c=sc.temperature(status.temperature),
            faults=status.faults,
            sample_counter=status.sample_counter,
            rx_malformed=status.rx_malformed,
            tx_dropped=status.tx_dropped,
            cmd_rejected=status.cmd_rejected,
            received_at=mono,
        )
        self._status_count += 1
        if status.state in (DeviceState.ROTATING, DeviceState.SETTLING):
            self._motion_count = self._status_count
        if status.state == DeviceState.BOOT and previous is not None:
            if previous.state != DeviceState.BOOT:
                self._note_reset("the device reports state BOOT")

    def _on_identify(self, ident: Identify, mono: float) -> None:
        self._identify = ident
        self._identify_count += 1
        self._scales = CountScales.of(ident)
        booting = self._status is not None and self._status.state == DeviceState.BOOT
        if mono > self._identify_expected_until and self._status is not None and not booting:
            # protocol.md 5: a device announces itself in BOOT; nobody asked, so it restarted.
            self._note_reset("the device sent IDENTIFY unrequested, as it does after a restart")

    def _note_reset(self, reason: str) -> None:
        """Called with the lock held, in the reader thread."""
        self._boot_epoch += 1
        self._counts["resets"] += 1
        self._reset_reason = reason
        self._streaming = False
        self._config_stale = True
        self._transport.restart_stream()
        log.warning("device restart detected: %s", reason)
        if self._inbox is not None:
            self._inbox.append(("reset", reason, self._clock.now(), self._clock.wall()))

    # -- requests -----------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise LinkError("the device is closed")
        if self._dead is not None:
            raise LinkLost(f"the link is lost: {self._dead}") from self._dead

    def _heartbeat_period_s(self) -> float:
        return self._config.get(ConfigKey.HEARTBEAT_PERIOD_MS, HEARTBEAT_PERIOD_DEFAULT_MS) / 1000.0

    def _last_status_at(self) -> float:
        return self._status.received_at if self._status is not None else self._opened_at

    def _status_age_s(self) -> float:
        """Seconds since the latest status (or since opening, if none came yet)."""
        return self._clock.now() - self._last_status_at()

    def _supervision_s(self) -> float:
        """Seconds without a status before the link counts as lost (protocol.md 6: three
        heartbeat periods; never less than ``min_supervision_s``)."""
        return max(HEARTBEATS_UNTIL_LOST * self._heartbeat_period_s(), self.min_supervision_s)

    def _link_deadline(self) -> float:
        """Clock time at which supervision is to be judged again: when the link counts as lost if
        no status comes before, or (past that, while frames still arrive) a moment later."""
        deadline = self._last_status_at() + self._supervision_s()
        if deadline > self._clock.now():
            return deadline
        return self._clock.now() + READ_POLL_S

    def _link_alive(self) -> bool:
        """A status within the supervision time, or frames still being read (protocol.md 6: the
        time without a status counts once the host has read all that arrived)."""
        return self._status_age_s() < self._supervision_s() or not self._link_idle

    def _wait_change(self, seen: int, until: float) -> None:
        """Wait until the reader delivered something after ``seen`` (:attr:`_events`) or the
        clock reaches ``until``."""
        self._clock.wait_until(lambda: self._events != seen, until)

    def _link_lost_error(self) -> LinkLost:
        return LinkLost(
            f"no status from the device for {self._status_age_s():.2f} s "
            f"(limit {self._supervision_s():.2f} s, {HEARTBEATS_UNTIL_LOST} heartbeat periods): "
            "the device is silent, off or restarting, or the link is down"
        )

    def _request(
        self,
        command: type[Command],
        *args: Any,
        timeout: float | None = None,
        attempts: int | None = None,
    ) -> Reply:
        """Send a command and return its OK reply; retry only commands in :data:`RETRYABLE`."""
        opcode = command.OPCODE
        per = self.reply_timeout if timeout is None else timeout
        if attempts is None:
            attempts = 1 + self.retries if opcode in RETRYABLE else 1
        for attempt in range(attempts):
            self._check_open()
            waiter = _Waiter(opcode)
            with self._lock:
                seq = self._next_seq()
                self._waiters[seq] = waiter
                if opcode == Opcode.IDENTIFY:
                    self._identify_expected_until = self._clock.now() + per + 1.0
            try:
                self._transport.send(command(seq, *args))
                if self._reader is None:
                    self._clock.notify()  # the virtual clock: the device takes it now
                answered = self._clock.wait_until(waiter.is_done, self._clock.now() + per)
            finally:
                with self._lock:
                    self._waiters.pop(seq, None)
            if waiter.error is not None:
                raise type(waiter.error)(str(waiter.error)) from waiter.error
            if answered and waiter.reply is not None:
                reply = waiter.reply
                if reply.result != Result.OK:
                    raise DeviceRefused(opcode, reply.result, result_meaning(reply.result))
                return reply
            if attempt + 1 < attempts:
                self._counts["retries"] += 1
                log.info("no reply to %s (seq %d) in %.3f s; sending again", opcode.name, seq, per)
        self._counts["timeouts"] += 1
        deadline = attempts * per
        alive = self._link_alive()
        text = f"no reply to {opcode.name} within {deadline:.2f} s ({attempts} attempt(s) of {per:.2f} s)"
        if alive:
            text += "; the device's heartbeat still arrives: the command or its reply was lost"
        else:
            text += (
                f"; no status for {self._status_age_s():.2f} s either: the device is silent or "
                "off, or the link is down (check power, cable, bus termination, port)"
            )
        if opcode in (Opcode.ROTATE_TO, Opcode.ROTATE_BY, Opcode.HOME, Opcode.RESET):
            text += f"; {opcode.name} may have been carried out: read status() before repeating it"
        raise ReplyTimeout(text, deadline, opcode, attempts, alive)

    def _next_seq(self) -> int:
        for _ in range(256):
            self._seq = (self._seq + 1) & 0xFF
            if self._seq not in self._waiters:
                return self._seq
        raise DriverError("256 commands are waiting for replies")  # pragma: no cover

    def _wait_for(
        self,
        check: Callable[[], T | None],
        deadline: float,
        on_timeout: Callable[[], DriverError],
        *,
        supervise: bool = True,
    ) -> T:
        """Wait until ``check`` (called with the lock held) returns a value; it may raise."""
        while True:
            seen = self._events
            self._check_open()
            with self._lock:
                result = check()
            if result is not None:
                return result
            if self._clock.now() >= deadline:
                raise on_timeout()
            until = deadline
            if supervise:
                if not self._link_alive():
                    raise self._link_lost_error()
                until = min(until, self._link_deadline())
            self._wait_change(seen, until)

    # -- queries ------------------------------------------------------------------------------
    @_on_clock
    def identify(self) -> Identify:
        """Ask the device who it is (IDENTIFY) and return its answer.

        Raises
        ------
        ReplyTimeout
            No reply, or the identify message did not follow it (lost frames), after retries.
        """
        for _ in range(1 + self.retries):
            with self._lock:
                n0 = self._identify_count
            self._request(RequestIdentify)

            def arrived(n0: int = n0) -> Identify | None:
                return self._identify if self._identify_count > n0 else None

            try:
                return self._wait_for(
                    arrived,
                    self._clock.now() + self.reply_timeout,
                    lambda: DriverTimeout("", 0.0),
                    supervise=False,
                )
            except DriverTimeout:
                self._counts["retries"] += 1
        attempts = 1 + self.retries
        raise ReplyTimeout(
            "the device accepted IDENTIFY but its identify message did not arrive "
            f"({attempts} attempts): identify frames are being lost",
            attempts * 2 * self.reply_timeout,
            Opcode.IDENTIFY,
            attempts,
            self._link_alive(),
        )

    @property
    def identity(self) -> Identify:
        """The identify read when opening (or received since): model, serial number, scales."""
        assert self._identify is not None
        return self._identify

    @_on_clock
    def status(self) -> DeviceStatus:
        """Ask for the status now (GET_STATUS) and return it.

        Raises
        ------
        ReplyTimeout
            No reply, or no status followed it.
        """
        with self._lock:
            n0 = self._status_count
        self._request(GetStatus)
        return self._wait_for(
            lambda: self._status if self._status_count > n0 else None,
            self._clock.now() + self.reply_timeout,
            lambda: ReplyTimeout(
                "GET_STATUS was accepted but no status followed it",
                self.reply_timeout,
                Opcode.GET_STATUS,
                1,
                False,
            ),
            supervise=False,
        )

    @property
    def last_status(self) -> DeviceStatus | None:
        """The most recent status received (heartbeat or requested), without asking."""
        return self._status

    def stats(self) -> LinkStats:
        """Counters of what arrived and what was lost or rejected (see :class:`LinkStats`)."""
        t = self._transport.counters()
        c = self._counts
        return LinkStats(
            frames_received=t["frames_received"],
            frames_rejected=t["frames_rejected"],
            frames_foreign=t["frames_foreign"],
            frames_lost=t["frames_lost"],
            ticks_lost=t["ticks_lost"],
            ticks_incomplete=t["ticks_incomplete"],
            samples_received=c["samples"],
            stray_replies=c["stray"],
            retries=c["retries"],
            reply_timeouts=c["timeouts"],
            resets_detected=c["resets"],
        )

    @_on_clock
    def self_test(self) -> int:
        """Run the built-in test (SELF_TEST, sent once); return the failure mask (0 = passed)."""
        return int(
            self._request(SelfTest, timeout=max(self.reply_timeout, 0.7)).self_test_failures()
        )

    # -- configuration ------------------------------------------------------------------------
    @staticmethod
    def _key(key: ConfigKey | int | str) -> ConfigKey:
        try:
            if isinstance(key, str):
                return ConfigKey[key.upper()]
            return ConfigKey(key)
        except (KeyError, ValueError):
            raise ArgumentError(
                f"unknown configuration key {key!r}; keys are {_CONFIG_NAMES}"
            ) from None

    @_on_clock
    def get_config(self, key: ConfigKey | int | str) -> int:
        """Read one configuration value (GET_CONFIG), e.g. ``get_config("sample_rate_hz")``.

        Units are the key's (protocol.md 4.4): Hz, ms, 1e-3 deg/s, 1e-3 deg/s^2, bit/s.
        """
        return self._config_request(GetConfig, self._key(key))

    @_on_clock
    def set_config(self, key: ConfigKey | int | str, value: int) -> int:
        """Write one configuration value (SET_CONFIG); return the value now in effect.

        Raises
        ------
        DeviceRefused
            E.g. READ_ONLY, OUT_OF_RANGE, RATE_EXCEEDS_LINK (read ``link_max_sample_rate_hz``),
            BUSY for table keys while the table moves.
        """
        k = self._key(key)
        value = whole_number("value", value)
        if k == ConfigKey.STREAMING and value and not self._streaming:
            self._prepare_stream_start()
        return self._config_request(SetConfig, k, value)

    def _config_request(
        self, command: type[GetConfig | SetConfig], k: ConfigKey, *value: int
    ) -> int:
        """GET_CONFIG or SET_CONFIG; keep and return the value in effect that the reply echoes."""
        got_key, in_effect = self._request(command, k, *value).config_value()
        if got_key != k:
            raise ProtocolError(f"{command.OPCODE.name} {k.name} answered for key {got_key!r}")
        with self._lock:
            self._config[k] = in_effect
            if k == ConfigKey.STREAMING:
                self._streaming = bool(in_effect)
        return in_effect

    @_on_clock
    def config(self) -> dict[ConfigKey, int]:
        """Every configuration value the protocol defines, read from the device now."""
        return {k: self.get_config(k) for k in ConfigKey}

    def _refresh_config(self) -> None:
        for k in (
            ConfigKey.SAMPLE_RATE_HZ,
            ConfigKey.HEARTBEAT_PERIOD_MS,
            ConfigKey.TABLE_MAX_RATE_MDPS,
            ConfigKey.TABLE_MAX_ACCEL_MDPS2,
            ConfigKey.SETTLE_TIME_MS,
            ConfigKey.STREAMING,
        ):
            self.get_config(k)
        self._config_stale = False

    def _refresh_config_if_stale(self) -> None:
        if self._config_stale:
            self._refresh_config()

    @property
    def sample_rate_hz(self) -> int:
        """The sample rate in effect (read from the device after a restart)."""
        self._refresh_config_if_stale()
        return self._config[ConfigKey.SAMPLE_RATE_HZ]

    # -- streaming ----------------------------------------------------------------------------
    @property
    def streaming(self) -> bool:
        """Whether the driver believes the device streams (set by the calls; cleared by a restart)."""
        return self._streaming

    def _prepare_stream_start(self) -> None:
        # A fresh status anchors the CAN tick counter right before the stream starts
        # (protocol.md 8), and ticks not sent while the stream was off are not losses.
        self.status()
        self._transport.restart_stream()

    @_on_clock
    def start_streaming(self) -> None:
        """Start the sample stream (STREAM_START). :meth:`acquire` does this when needed."""
        if not self._streaming:
            self._prepare_stream_start()
        self._request(StreamStart)
        self._streaming = True

    @_on_clock
    def stop_streaming(self) -> None:
        """Stop the sample stream (STREAM_STOP)."""
        self._request(StreamStop)
        self._streaming = False

    # -- motion -------------------------------------------------------------------------------
    @_on_clock
    def move_duration_s(self, distance_deg: float) -> float:
        """Expected device seconds for a move of ``distance_deg`` and its settling, from the
        table's configured rate and acceleration limits and settle time (trapezoid profile)."""
        self._refresh_config_if_stale()
        return TableLimits.from_config(self._config).ready_after_s(distance_deg)

    def _current_angle(self) -> float:
        return self._status.angle_deg if self._status is not None else 0.0

    @_on_clock
    def rotate_to(
        self,
        angle_deg: float,
        *,
        direction: Direction | str = "shortest",
        wait: bool = True,
        timeout: float | None = None,
    ) -> DeviceStatus | None:
        """Turn the table to an absolute encoder angle (ROTATE_TO, sent once).

        Parameters
        ----------
        angle_deg : float
            Target, deg (taken modulo 360).
        direction : {"shortest", "positive", "negative"} or Direction
            Positive is counter-clockwise seen from above.
        wait : bool
            Wait until the table has settled (state READY) and return that status.
        timeout : float or None
            Wall seconds to wait; default: the expected move and settle time (from the table
            configuration) times 1.5 plus 2 s.

        Raises
        ------
        DeviceRefused
            BUSY while the table moves or settles, NOT_READY while warming up, FAULT.
        DeviceFault, DeviceReset, MoveTimeout, LinkLost
            While waiting.
        """
        angle_deg = finite_number("angle_deg", angle_deg, "degrees")
        d = self._direction(direction)
        scale = self._scales.angle_deg
        turn = round(360.0 / scale)
        counts = round((angle_deg % 360.0) / scale) % turn
        delta = (counts * scale - self._current_angle()) % 360.0
        if d == Direction.SHORTEST:
            distance = min(delta, 360.0 - delta)
        else:
            distance = delta if d == Direction.POSITIVE else (360.0 - delta) % 360.0
        return self._move(RotateTo, (counts, d), distance, wait, timeout)

    @_on_clock
    def rotate_by(
        self, delta_deg: float, *, wait: bool = True, timeout: float | None = None
    ) -> DeviceStatus | None:
        """Turn the table by ``delta_deg`` (positive counter-clockwise; the device accepts
        +-720 deg). See :meth:`rotate_to` for ``wait``, ``timeout`` and errors."""
        delta_deg = finite_number("delta_deg", delta_deg, "degrees")
        counts = round(delta_deg / self._scales.angle_deg)
        if abs(counts) > ROTATE_BY_LIMIT:
            raise ArgumentError(
                f"delta_deg={delta_deg!r}: the device turns at most "
                f"+-{ROTATE_BY_LIMIT * self._scales.angle_deg:g} deg in one ROTATE_BY"
            )
        return self._move(RotateBy, (counts,), abs(delta_deg), wait, timeout)

    @_on_clock
    def home(self, *, wait: bool = True, timeout: float | None = None) -> DeviceStatus | None:
        """Turn the table to the encoder zero by the shortest way (HOME, sent once)."""
        a = self._current_angle()
        return self._move(Home, (), min(a, 360.0 - a), wait, timeout)

    @_on_clock
    def stop(self, *, wait: bool = False, timeout: float | None = None) -> DeviceStatus | None:
        """Stop the table (STOP; accepted in every state, repeated if its reply is lost).

        With ``wait`` return the status once the table has settled (READY).
        """
        timeout = seconds("timeout", timeout)
        with self._lock:
            n0, epoch = self._status_count, self._boot_epoch
        t0 = self._clock.now()
        self._request(Stop)
        if not wait:
            return None
        self._refresh_config_if_stale()
        limit = self.move_duration_s(0.0) * 1.5 + 5.0 if timeout is None else timeout
        return self._wait_settled(n0, epoch, t0, 0.0, limit, "STOP")

    @_on_clock
    def wait_ready(self, timeout: float = 5.0) -> DeviceStatus:
        """Wait until the device reports READY (boot and warm-up done, table settled).

        Raises
        ------
        DeviceFault
            The device is in FAULT.
        DriverTimeout
            Not READY within ``timeout`` s.
        """
        timeout = float(seconds("timeout", timeout, allow_none=False) or 0.0)
        t0 = self._clock.now()

        def check() -> DeviceStatus | None:
            st = self._status
            if st is None:
                return None
            if st.state == DeviceState.FAULT:
                raise DeviceFault(f"the device is in FAULT ({st.faults!r})", int(st.faults))
            return st if st.state == DeviceState.READY else None

        return self._wait_for(
            check,
            t0 + timeout,
            lambda: DriverTimeout(
                f"the device is not READY after {timeout:.1f} s (state {self._state_name()})",
                timeout,
            ),
        )

    def _state_name(self) -> str:
        return self._status.state.name if self._status is not None else "unknown"

    @staticmethod
    def _direction(direction: Direction | str) -> Direction:
        if isinstance(direction, Direction):
            return direction
        try:
            return _DIRECTIONS[str(direction).lower()]
        except KeyError:
            raise ArgumentError(
                f"direction={direction!r}: choose one of {', '.join(_DIRECTIONS)}"
            ) from None

    def _move(
        self,
        command: type[Command],
        args: tuple[Any, ...],
        distance_deg: float,
        wait: bool,
        timeout: float | None,
    ) -> DeviceStatus | None:
        timeout = seconds("timeout", timeout)
        self._refresh_config_if_stale()
        expected = self.move_duration_s(distance_deg)
        with self._lock:
            n0, epoch = self._status_count, self._boot_epoch
        t0 = self._clock.now()
        self._request(command, *args)
        if not wait:
            return None
        limit = expected * 1.5 + 2.0 if timeout is None else timeout
        return self._wait_settled(n0, epoch, t0, expected, limit, command.OPCODE.name)

    def _wait_settled(
        self, n0: int, epoch: int, t0: float, min_s: float, limit: float, what: str
    ) -> DeviceStatus:
        """READY after having seen ROTATING or SETTLING since the command (or after ``min_s``)."""

        def check() -> DeviceStatus | None:
            if self._boot_epoch != epoch:
                raise DeviceReset(f"the device restarted during {what}: {self._reset_reason}")
            st = self._status
            if st is None or self._status_count <= n0:
                return None
            if st.state == DeviceState.FAULT:
                raise DeviceFault(
                    f"the device entered FAULT during {what} ({st.faults!r}) at table angle "
                    f"{st.angle_deg:.4f} deg; RESET clears it",
                    int(st.faults),
                )
            moved = self._motion_count > n0 or self._clock.now() - t0 >= min_s
            return st if st.state == DeviceState.READY and moved else None

        return self._wait_for(
            check,
            t0 + limit,
            lambda: MoveTimeout(
                f"{what}: the table did not settle within {limit:.1f} s (state "
                f"{self._state_name()}, angle {self._current_angle():.4f} deg)",
                limit,
            ),
        )

    @_on_clock
    def reset(self, *, wait: bool = True, timeout: float = 3.0) -> DeviceStatus | None:
        """Restart the device (RESET, sent once): configuration and counters go back to
        defaults and the stream stops. With ``wait``, return the first status after BOOT.

        Raises
        ------
        DriverTimeout
            The device did not leave BOOT within ``timeout`` s (protocol: at most 1 s).
        """
        timeout = float(seconds("timeout", timeout, allow_none=False) or 0.0)
        with self._lock:
            epoch = self._boot_epoch
        t0 = self._clock.now()
        self._request(Reset)
        with self._lock:
            self._streaming = False
            self._config_stale = True
        if not wait:
            return None

        def check() -> DeviceStatus | None:
            st = self._status
            if self._boot_epoch == epoch or st is None or st.state == DeviceState.BOOT:
                return None
            return st

        st = self._wait_for(
            check,
            t0 + timeout,
            lambda: DriverTimeout(
                f"the device did not come back from RESET within {timeout:.1f} s "
                f"(state {self._state_name()})",
                timeout,
            ),
            supervise=False,
        )
        self._refresh_config()
        return st

    # -- acquisition --------------------------------------------------------------------------
    @_on_clock
    def acquire(
        self, seconds: float, *, on_gap: OnGap = "raise", timeout: float | None = None
    ) -> Window:
        """Collect one window of ``round(seconds * sample_rate_hz)`` consecutive sample ticks.

        Starts the stream if it is off (and leaves it on; :meth:`stop_streaming` or
        :meth:`close` stop it). The window begins with the first sample received after the
        call, so it never holds a sample from before the request; it ends when the tick
        ``first + requested - 1`` arrived or is known to be lost.

        Parameters
        ----------
        seconds : float
            Window length in device seconds.
        on_gap : {"raise", "report"}
            What a missing tick does: ``"raise"`` stops at once with :class:`StreamGap`;
            ``"report"`` returns the window with ``missing`` and ``gaps`` stating them.
        timeout : float or None
            Wall seconds allowed; default ``seconds + 2`` plus the stall limit.

        Raises
        ------
        StreamGap
            ``on_gap="raise"`` and ticks are missing.
        DeviceReset
            The device restarted during the window (BOOT status, unrequested IDENTIFY, or the
            sample counter went back).
        StreamTimeout
            No sample for max(0.5 s, 3 heartbeat periods) although statuses arrive.
        LinkLost
            No status either for 3 heartbeat periods, or the bus or port failed.
        """
        if on_gap not in ("raise", "report"):
            raise ArgumentError(f"on_gap={on_gap!r}: choose one of 'raise', 'report'")
        seconds = _window_seconds("seconds", seconds, allow_none=False) or 0.0
        timeout = _timeout_seconds("timeout", timeout)
        with self._acquire_lock:
            self._check_open()
            if not self._link_alive():
                raise self._link_lost_error()
            self._refresh_config_if_stale()
            rate = self._config[ConfigKey.SAMPLE_RATE_HZ]
            n = round(seconds * rate)
            if n < 1:
                raise ArgumentError(f"seconds={seconds!r} is less than one sample at {rate} Hz")
            inbox: deque[tuple[str, Any, float, float]] = deque()
            with self._lock:
                epoch = self._boot_epoch
                self._inbox = inbox
                self._inbox_since = self._clock.now()
            try:
                if not self._streaming:
                    self.start_streaming()
                if self._boot_epoch != epoch:
                    raise DeviceReset(
                        f"the device restarted as the window began: {self._reset_reason}"
                    )
                return self._collect(inbox, n, rate, on_gap, timeout)
            finally:
                with self._lock:
                    self._inbox = None

    def _collect(
        self,
        inbox: deque[tuple[str, Any, float, float]],
        n: int,
        rate: float,
        on_gap: OnGap,
        timeout: float | None,
    ) -> Window:
        """Feed the window collector from the reader's queue, watching the link and deadlines."""
        clock = self._clock
        stall_limit = max(0.5, self._supervision_s(), 5.0 / rate)
        t_start = clock.now()
        limit = n / rate + 2.0 + stall_limit if timeout is None else timeout
        deadline = t_start + limit
        collector = WindowCollector(n, on_gap=on_gap)
        last_sample_at = t_start
        while not collector.done:
            seen = self._events
            with self._lock:
                items = list(inbox)
                inbox.clear()
            for kind, item, mono, wall in items:
                if kind == "lost":
                    raise LinkLost(f"the link was lost during the window: {item}") from item
                if kind == "reset":
                    raise DeviceReset(
                        f"the device restarted during the window after {collector.received} of "
                        f"{n} samples ({item}); its configuration and stream are back to defaults"
                    )
                if kind == "loss":
                    collector.add_loss(item)
                else:
                    last_sample_at = mono
                    if collector.add_sample(item, wall):
                        break
            if collector.done:
                break
            if items:
                continue
            now = clock.now()
            self._check_open()
            if not self._link_alive():
                raise self._link_lost_error() from None
            if now - last_sample_at >= stall_limit:
                raise StreamTimeout(
                    f"no sample for {now - last_sample_at:.2f} s while the device's status "
                    f"still arrives ({collector.received} of {n} received): the stream was "
                    "stopped (STREAM_STOP or a configuration change by another host?)",
                    stall_limit,
                ) from None
            if now >= deadline:
                raise StreamTimeout(
                    f"the window of {n} samples was not complete after {limit:.1f} s "
                    f"({collector.received} received)",
                    limit,
                ) from None
            self._wait_change(
                seen, min(deadline, last_sample_at + stall_limit, self._link_deadline())
            )
        return collector.window(rate, self._scales)
