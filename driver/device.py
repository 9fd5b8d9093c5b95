"""The host driver: one :class:`Device` object per instrument, on CAN or serial.

Units at this interface: angles in degrees (table angle counter-clockwise seen from above, as the
encoder reports it), gyro rates in deg/h (``Window.gyro_rps`` gives rad/s), specific force in
m/s^2, temperature in degC, times in seconds. Count scales come from the device's IDENTIFY, not
from constants.

Threads. A reader thread receives everything the device sends and sorts it: replies go to the
caller waiting for their sequence number, statuses update :attr:`Device.last_status` (and feed
link supervision), identify updates :attr:`Device.identity`, samples go to an :meth:`Device.acquire`
in progress and are dropped otherwise. Every public method may be called from any thread;
:meth:`Device.acquire` calls run one at a time.

Timing. Every deadline, timeout and wait reads the device's clock (``clock=``: the wall clock by
default, or a :class:`~northfinder.driver.clock.VirtualClock` shared with an in-process simulator,
on which time jumps to the next event whenever every party waits). A command is sent with a fresh sequence number and waits
``reply_timeout`` (default 0.25 s; protocol.md 6 asks for at least 0.1 s) for its reply. Commands
that are safe to repeat (:data:`RETRYABLE`) are sent again with a new sequence number, up to
``retries`` more times (default 2), so a query fails with :class:`~northfinder.driver.errors.ReplyTimeout`
after ``(1 + retries) * reply_timeout`` = 0.75 s (each wait is judged once a read begun after it
is done: a reply that waited in the link while the host stood still counts; one read, 0.05 s,
more on an idle host, at most 1 s more on a starved one). Moves, HOME, RESET and SELF_TEST are
sent once: a lost reply leaves open whether they were carried out. The link counts as lost when
no status arrived for three heartbeat periods (0.3 s by default; ``min_supervision_s`` raises it),
counted once the reader has read everything that arrived (protocol.md 6), so a host that is busy
or an adapter that reads slowly does not take a late status for a lost link: past the deadline
the link is lost only once a read that began after it found nothing (a host that stood still
longer than the supervision time reads what waited in the link first). The same holds for a
reply's wait and a window's stall limit: each is judged once a read that began after its deadline
is done.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from typing import Any, Concatenate, ParamSpec, TypeVar

import can
import serial

from northfinder.driver.arguments import finite_number, seconds, whole_number
from northfinder.driver.clock import Clock
from northfinder.driver.device_link import (
    HEARTBEATS_UNTIL_LOST,
    REPLY_TIMEOUT_S,
    RETRIES,
    RETRYABLE,
    AtRest,
    DeviceLink,
    DeviceStatus,
    LinkStats,
)
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
    NodeConflict,
    ProtocolError,
    ReplyTimeout,
    StreamTimeout,
)
from northfinder.driver.protocol.constants import (
    PROTOCOL_VERSION_MAJOR,
    ROTATE_BY_LIMIT,
    SPIN_RATE_MDPS_MIN,
    ConfigKey,
    DeviceState,
    Direction,
    Opcode,
)
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    GetStatus,
    Home,
    Identify,
    RequestIdentify,
    Reset,
    RotateBy,
    RotateTo,
    SelfTest,
    SetConfig,
    Spin,
    Stop,
    StreamStart,
    StreamStop,
)
from northfinder.driver.protocol.motion import TableLimits
from northfinder.driver.transport import (
    READ_POLL_S,
    CanTransport,
    SerialTransport,
    bus_open_hint,
    open_serial_port,
)
from northfinder.driver.window import (
    OnGap,
    SampleColumns,
    SampleInbox,
    Window,
    WindowCollector,
)

__all__ = [
    "HEARTBEATS_UNTIL_LOST",
    "RETRYABLE",
    "AtRest",
    "Device",
    "DeviceStatus",
    "LinkStats",
    "OnGap",
    "Window",
]

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
            try:
                result = method(self, *args, **kwargs)
            except (ArgumentError, NodeConflict):
                raise
            except DriverError as exc:
                # A second unit on this node id makes every kind of error (gaps, restarts,
                # counters going back): name the cause, not the symptom.
                self._check_node_conflict(exc)
                raise
            self._check_node_conflict()
            return result

    return call


class Device(DeviceLink):
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
                f"{bus_open_hint(exc)}"
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

    def _connect(self) -> None:
        ident = self.identify()
        if ident.protocol_version[0] != PROTOCOL_VERSION_MAJOR:
            raise ProtocolError(
                f"the device speaks protocol {ident.protocol_version[0]}.{ident.protocol_version[1]}; "
                f"this driver speaks major version {PROTOCOL_VERSION_MAJOR}"
            )
        self.status()
        self._refresh_config()

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
                if command is SetConfig:
                    self._stream_owned = bool(in_effect)
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
        owned = self._stream_owned
        # Owned from before it is sent: a lost reply may hide a stream that did start, and
        # leaving must stop it then.
        self._stream_owned = True
        try:
            self._request(StreamStart)
        except DeviceRefused:
            self._stream_owned = owned  # refused: nothing started
            raise
        self._streaming = True

    @_on_clock
    def stop_streaming(self) -> None:
        """Stop the sample stream (STREAM_STOP), whoever started it."""
        self._request(StreamStop)
        self._streaming = self._stream_owned = False

    @_on_clock
    def release_stream(self) -> None:
        """Stop the sample stream if this object started it (STREAM_STOP); leave another
        host's stream running."""
        if self._stream_owned:
            self.stop_streaming()

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
    def spin(
        self, rate_dps: float, *, wait: bool = True, timeout: float | None = None
    ) -> DeviceStatus | None:
        """Turn the table at a constant rate until :meth:`stop` (SPIN, protocol 1.1, sent once).

        The table accelerates at its limit (ROTATING), then holds the rate (SPINNING); samples
        taken at the steady rate carry the steady-rate validity pair
        (:data:`~northfinder.driver.protocol.constants.VALIDITY_STEADY_RATE`) and each its
        encoder angle, so :meth:`acquire` while spinning gives angle-tagged samples.

        Parameters
        ----------
        rate_dps : float
            Rate, deg/s, positive counter-clockwise seen from above; sent in steps of 0.001
            deg/s; ``0.001 <= |rate_dps| <=`` the table's rate limit (TABLE_MAX_RATE_MDPS).
        wait : bool
            Wait until the device reports SPINNING (the rate reached) and return that status.
        timeout : float or None
            Seconds to wait; default: the acceleration time times 1.5 plus 2 s.

        Raises
        ------
        ArgumentError
            A rate that is not a finite number, rounds to 0, or exceeds the table's limit; or a
            device of protocol 1.0 (it has no SPIN).
        DeviceRefused
            BUSY while the table moves, spins or settles, NOT_READY while warming up, FAULT.
        DeviceFault, DeviceReset, MoveTimeout, LinkLost
            While waiting.
        """
        rate_dps = finite_number("rate_dps", rate_dps, "deg/s")
        timeout = seconds("timeout", timeout)
        ident = self._identify
        if ident is not None and tuple(ident.protocol_version) < (1, 1):
            raise ArgumentError(
                f"the device speaks protocol {ident.protocol_version[0]}."
                f"{ident.protocol_version[1]}; turning at a constant rate (SPIN) needs 1.1"
            )
        self._refresh_config_if_stale()
        limit_mdps = self._config[ConfigKey.TABLE_MAX_RATE_MDPS]
        mdps = round(rate_dps * 1000.0)
        if not SPIN_RATE_MDPS_MIN <= abs(mdps) <= limit_mdps:
            raise ArgumentError(
                f"rate_dps={rate_dps!r}: the table turns at 0.001 to {limit_mdps / 1000:g} deg/s "
                "either way (its rate limit, TABLE_MAX_RATE_MDPS)"
            )
        limits = TableLimits.from_config(self._config)
        ramp = abs(mdps) / 1000.0 / limits.max_accel_dps2
        with self._lock:
            n0, epoch = self._status_count, self._boot_epoch
            # Open from before it is sent, as a move: an interrupt or a lost reply between the
            # send and its answer must still leave the table stopped (:meth:`leave_at_rest`).
            self._move_open, self._move_n0 = True, n0
        t0 = self._clock.now()
        try:
            self._request(Spin, mdps)
        except DeviceRefused:
            self._move_open = False  # refused: nothing turns
            raise
        if not wait:
            return None
        wait_s = ramp * 1.5 + 2.0 if timeout is None else timeout

        def check() -> DeviceStatus | None:
            if self._boot_epoch != epoch:
                raise DeviceReset(f"the device restarted during SPIN: {self._reset_reason}")
            st = self._status
            if st is None or self._status_count <= n0:
                return None
            if st.state == DeviceState.FAULT:
                raise DeviceFault(
                    f"the device entered FAULT during SPIN ({st.faults!r}); RESET clears it",
                    int(st.faults),
                )
            return st if st.state == DeviceState.SPINNING else None

        return self._wait_for(
            check,
            t0 + wait_s,
            lambda: MoveTimeout(
                f"SPIN: the table did not reach {rate_dps:g} deg/s within {wait_s:.1f} s "
                f"(state {self._state_name()})",
                wait_s,
            ),
        )

    @_on_clock
    def stop(self, *, wait: bool = False, timeout: float | None = None) -> DeviceStatus | None:
        """Stop the table (STOP; accepted in every state, repeated if its reply is lost); a
        spinning table brakes at the acceleration limit.

        With ``wait`` return the status once the table has settled (READY).
        """
        timeout = seconds("timeout", timeout)
        with self._lock:
            n0, epoch = self._status_count, self._boot_epoch
        t0 = self._clock.now()
        self._request(Stop)
        if not wait:
            self._move_open = False
            return None
        # Still open while braking: an error or an interrupt before the table settled leaves
        # it to leave_at_rest, which sends STOP again and waits until the table is seen braked.
        self._refresh_config_if_stale()
        limits = TableLimits.from_config(self._config)
        braking = limits.max_rate_dps / limits.max_accel_dps2
        limit = (braking + limits.settle_s) * 1.5 + 5.0 if timeout is None else timeout
        st = self._wait_settled(n0, epoch, t0, 0.0, limit, "STOP")
        self._move_open = False
        return st

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
            # Open from before it is sent: an interrupt between the send and its reply must
            # still leave the table stopped.
            self._move_open, self._move_n0 = True, n0
        t0 = self._clock.now()
        try:
            self._request(command, *args)
        except DeviceRefused:
            self._move_open = False  # refused: nothing moves
            raise
        if not wait:
            return None
        limit = expected * 1.5 + 2.0 if timeout is None else timeout
        st = self._wait_settled(n0, epoch, t0, expected, limit, command.OPCODE.name)
        self._move_open = False
        return st

    def _wait_settled(
        self, n0: int, epoch: int, t0: float, min_s: float, limit: float, what: str
    ) -> DeviceStatus:
        """READY after having seen ROTATING or SETTLING since the command (or after ``min_s``)."""

        foreign0 = self._foreign_disruptive[0]

        def check() -> DeviceStatus | None:
            if self._boot_epoch != epoch:
                raise DeviceReset(f"the device restarted during {what}: {self._reset_reason}")
            count, op = self._foreign_disruptive
            if count != foreign0 and op != Opcode.RESET:
                self._move_open = False  # the other host has the table now
                raise self._another_host(op, f"during {what}")
            st = self._status
            if st is None or self._status_count <= n0:
                return None
            if st.state == DeviceState.FAULT:
                raise DeviceFault(
                    f"the device entered FAULT during {what} ({st.faults!r}) at table angle "
                    f"{st.angle_deg:.4f} deg; RESET clears it",
                    int(st.faults),
                )
            moved = self._motion_count > n0 or self._clock.now() >= t0 + min_s
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
            self._streaming = self._stream_owned = self._move_open = False
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

        Notes
        -----
        An exception raised during the window (an interruption, a lost link, a gap) carries
        the samples received so far as its ``partial_window`` attribute (a :class:`Window`;
        absent when none arrived).
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
            inbox = SampleInbox()
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

    def _stream_stalled(self, stall_at: float, inbox: SampleInbox) -> bool:
        """Whether the stream counts as stopped at ``stall_at``: a read that began after it
        brought no sample and no sample waits to be collected. A host that did not run the reader
        for the stall time (a loaded machine) reads the samples that waited in the link first."""
        if not self._no_sample_since(stall_at):
            return False
        with self._lock:
            return not len(inbox)

    def _collect(
        self,
        inbox: SampleInbox,
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
        try:
            return self._collect_into(collector, inbox, n, rate, t_start, deadline, limit)
        except BaseException as exc:
            # What was received stays with the error (an interruption, a lost link): a caller
            # that keeps a partial run (a spin recording) takes it from there.
            if collector.received:
                with contextlib.suppress(Exception):
                    exc.partial_window = collector.take_window(rate, self._scales)  # type: ignore[attr-defined]
            raise

    def _collect_into(
        self,
        collector: WindowCollector,
        inbox: SampleInbox,
        n: int,
        rate: float,
        t_start: float,
        deadline: float,
        limit: float,
    ) -> Window:
        clock = self._clock
        stall_limit = max(0.5, self._supervision_s(), 5.0 / rate)
        last_sample_at = t_start
        while not collector.done:
            with self._lock:
                alerts = self._inbox_alerts
                block, events = inbox.take()
                block_mono = inbox.last_sample_mono
            if self._take_items(collector, block, events, n):
                break
            if len(block):
                last_sample_at = block_mono
            if collector.done:
                break
            if len(block) or events:
                continue
            now = clock.now()
            self._check_open()
            if not self._link_alive():
                raise self._link_lost_error() from None
            stall_at = last_sample_at + stall_limit  # the sum the wait below uses
            if now >= stall_at and self._stream_stalled(stall_at, inbox):
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
            # Sleep until the window can be complete, or something else than a sample came (a
            # loss, a reset, a lost or closed link), or a deadline is to be judged: one wake-up
            # for the whole window on a steady stream, not one for each sample.
            need = n - collector.received

            def window_ready(need: int = need, alerts: int = alerts) -> bool:
                return len(inbox) >= need or self._inbox_alerts != alerts

            # Past the stall deadline, the reader's next read is awaited (:meth:`_stream_stalled`).
            stall_wait = stall_at if now < stall_at else now + READ_POLL_S
            self._clock.wait_until(window_ready, min(deadline, stall_wait, self._link_deadline()))
        return collector.take_window(rate, self._scales)

    def _take_items(
        self,
        collector: WindowCollector,
        block: SampleColumns,
        events: list[tuple[int, str, Any, float, float]],
        n: int,
    ) -> bool:
        """Feed the collector what the inbox held, in arrival order; True once a sample
        completed the window (what follows it is not looked at)."""
        pos = 0
        for before, kind, item, _mono, _wall in events:
            if before > pos and collector.add_samples(block, pos, before):
                return True
            pos = before
            if kind == "lost":
                raise LinkLost(f"the link was lost during the window: {item}") from item
            if kind == "reset":
                raise DeviceReset(
                    f"the device restarted during the window after {collector.received} of "
                    f"{n} samples ({item}); its configuration and stream are back to defaults"
                )
            if kind == "foreign":
                raise self._another_host(
                    item, f"during the window, after {collector.received} of {n} samples"
                )
            collector.add_loss(item)
        return pos < len(block) and collector.add_samples(block, pos, len(block))
