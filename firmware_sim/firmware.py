"""The simulated instrument's firmware: a state machine advanced by ``process(dt)``.

The firmware speaks protocol messages (the codec's dataclasses), not bytes: link adapters in
:mod:`northfinder.firmware_sim.adapters` turn them into CAN frames or serial frames. It never sleeps and never
reads the wall clock; a runner (:mod:`northfinder.firmware_sim.runner`) or a test decides how far time moves.

The state is a function of time and of the commands received: BOOT until ``boot_s`` after power-on
or reset, WARMUP until ``warmup_s`` after power-on, then READY; a move makes it ROTATING until the
motion profile ends and SETTLING for the settle time after; a drive fault makes it FAULT until
RESET. The sample stream runs independently of the state (if switched on) and carries the state in
its validity bits.
"""

from __future__ import annotations

import copy
import logging
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from northfinder.driver.protocol.budget import max_sample_rate, rate_fits
from northfinder.driver.protocol.constants import (
    ACCEL_G_PER_COUNT,
    ANGLE_DEG_PER_COUNT,
    ANGLE_FULL_TURN,
    CONFIG_LIMITS,
    GYRO_DPH_PER_COUNT,
    INT24_MAX,
    INT24_MIN,
    INT32_MAX,
    INT32_MIN,
    ROTATE_BY_LIMIT,
    SAMPLE_RATES_HZ,
    SPIN_RATE_MDPS_MIN,
    TEMPERATURE_DEGC_PER_COUNT,
    TEMPERATURE_NOT_AVAILABLE,
    VALIDITY_GOOD,
    VALIDITY_STEADY_RATE,
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    Opcode,
    Result,
    SelfTestFailure,
    Validity,
)
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    Identify,
    Reply,
    RotateBy,
    RotateTo,
    Sample,
    SetConfig,
    Spin,
    Status,
    sample_frames_block,
    validity_of,
)
from northfinder.driver.protocol.units import DEFAULT_WARMUP_S, DPH, G0
from northfinder.firmware_sim.error_terms import quantise_carry
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.imu import Instrument, SampleBlock, Truth
from northfinder.firmware_sim.sensors import SensorSpec

log = logging.getLogger("northfinder.sim")

#: Rate at which the physics runs; every output rate divides it and a tick is the sum of
#: ``BASE_RATE_HZ / rate`` physics increments, as a pulse-counting output would add them.
BASE_RATE_HZ = 400.0
#: The device's clock counts whole nanoseconds: the present, the computed horizon and the heartbeat
#: schedule are integers, so which tick is due at a time is exact integer arithmetic and no
#: rounding can accumulate over a long run.
NS_PER_S = 1_000_000_000
_BASE_RATE = round(BASE_RATE_HZ)
_GYRO_COUNT = GYRO_DPH_PER_COUNT * DPH  # rad/s per count
_ACCEL_COUNT = ACCEL_G_PER_COUNT * G0  # m/s^2 per count
# Counts per unit (exactly 1e6 and 100): a product rounds like the literal factors did.
_COUNTS_PER_DEG = 1.0 / ANGLE_DEG_PER_COUNT
_COUNTS_PER_DEGC = 1.0 / TEMPERATURE_DEGC_PER_COUNT
#: A move that ends further than this from its command is a drive fault, deg.
DRIVE_FAULT_LIMIT_DEG = 0.5
#: How far ahead of the present the firmware computes its output, s (see Firmware.process).
LOOKAHEAD_S = 0.2
_LOOKAHEAD_NS = round(LOOKAHEAD_S * NS_PER_S)
#: The look-ahead of a simulator in virtual time, s (:attr:`Firmware.lookahead_s`).
VIRTUAL_LOOKAHEAD_S = 2.0
#: Time from receiving a command to sending its reply, s.
REPLY_LATENCY_S = 0.001
_REPLY_LATENCY_NS = round(REPLY_LATENCY_S * NS_PER_S)
MOTION_OPCODES = (Opcode.ROTATE_TO, Opcode.ROTATE_BY, Opcode.HOME, Opcode.SPIN)
#: Most random impulses per second the device's physics is asked to draw: one per physics sample.
MAX_IMPULSE_RATE_HZ = BASE_RATE_HZ
#: Longest impulse, s: a shock, not a bias change (which ``bias_step`` injects).
MAX_IMPULSE_DURATION_S = 1.0
#: Table fields the device reports through configuration keys (protocol.md 4.4): field, key, and
#: the key's unit in the field's unit.
_TABLE_KEYS = (
    ("max_rate_dps", ConfigKey.TABLE_MAX_RATE_MDPS, 1e-3),
    ("max_accel_dps2", ConfigKey.TABLE_MAX_ACCEL_MDPS2, 1e-3),
    ("settle_s", ConfigKey.SETTLE_TIME_MS, 1e-3),
)


def check_device_spec(spec: SensorSpec) -> SensorSpec:
    """Return ``spec`` if the simulated device can run it, else raise.

    The table's limits must be values the device can report in its configuration keys
    (protocol.md 4.4), and the random impulses few and short enough to compute in real time.

    Raises
    ------
    SimConfigError
        Naming the field, its value and the bound.
    """
    table = spec.table
    for name, key, unit in _TABLE_KEYS:
        value = getattr(table, name)
        lo, hi = CONFIG_LIMITS[key]
        if not lo <= round(value / unit) <= hi:
            raise SimConfigError(
                f"table.{name}: {value:g} is outside what the device runs and reports as "
                f"{key.name} ({lo * unit:g} to {hi * unit:g})"
            )
    d = spec.disturbance
    if d.impulse_rate_hz > MAX_IMPULSE_RATE_HZ:
        raise SimConfigError(
            f"disturbance.impulse_rate_hz: {d.impulse_rate_hz:g} exceeds the "
            f"{MAX_IMPULSE_RATE_HZ:g} impulses per second the device simulates"
        )
    if d.impulse_duration_s > MAX_IMPULSE_DURATION_S:
        raise SimConfigError(
            f"disturbance.impulse_duration_s: {d.impulse_duration_s:g} s exceeds the "
            f"{MAX_IMPULSE_DURATION_S:g} s an impulse may last"
        )
    return spec


@dataclass(frozen=True)
class LinkInfo:
    """What the firmware knows about its link, to decide which sample rates fit (protocol.md 7)."""

    kind: str = "can"  # "can" or "serial"
    bitrate: int = 500_000

    def fits(self, sample_rate_hz: float, heartbeat_ms: float) -> bool:
        return rate_fits(self.kind, self.bitrate, sample_rate_hz, heartbeat_ms)

    def max_rate(self, heartbeat_ms: float) -> int:
        return max_sample_rate(self.kind, self.bitrate, heartbeat_ms)


@dataclass
class FaultInjection:
    """Faults ordered through the control channel. Link adapters read the frame faults."""

    drop_frames: int = 0
    corrupt_frames: int = 0
    garble: int = 0
    """This many pieces of junk go out, ``garble_per_frame`` before each outgoing frame, which
    still goes out whole: on SLCAN a line that does not parse
    (:data:`~northfinder.firmware_sim.adapters.GARBLED_SLCAN_LINES`), on serial bytes of no frame,
    on CAN a frame of a protocol id with a wrong length."""
    garble_per_frame: int = 1
    reply_delay_s: float = 0.0
    silent: bool = False
    skip_counter: int = 0
    wrong_result: int | None = None
    drop_replies: int = 0
    """The next this many replies are never sent (the command is still carried out)."""
    heartbeat_factor: float = 1.0
    """The heartbeat comes every HEARTBEAT_PERIOD_MS times this (a unit whose timer is off)."""
    tick_factor: float = 1.0
    """A sample tick takes this many configured tick periods (rounded to whole physics samples):
    a unit that streams slower (or faster) than SAMPLE_RATE_HZ, its counters counting its ticks."""


class Outgoing(NamedTuple):
    """A message the firmware sends at simulated time ``time_s``; a sample of the stream also
    with the data of its four CAN frames, packed with its chunk (``frames``: 32 bytes, what
    :meth:`~northfinder.driver.protocol.messages.Sample.can_payloads` gives, or None)."""

    time_s: float
    message: Reply | Status | Sample | Identify
    frames: bytes | None = None


@dataclass(frozen=True, slots=True)
class _Snapshot:
    """The computation's state at the start of a look-ahead chunk (see Firmware._rewind)."""

    start_ns: int
    engine: dict[str, Any]
    skip_counter: int
    generators: tuple[tuple[np.random.Generator, Mapping[str, Any]], ...]


@dataclass
class _Tick:
    """Physics increments waiting to be summed into the next output tick."""

    gyro: list[np.ndarray] = field(default_factory=list)
    accel: list[np.ndarray] = field(default_factory=list)
    gyro_saturated: list[np.ndarray] = field(default_factory=list)
    accel_saturated: list[np.ndarray] = field(default_factory=list)


class Firmware:
    """The device: state machine, command handling, sample stream and heartbeat.

    Parameters
    ----------
    spec : SensorSpec
        The instrument (sensors and table).
    truth : Truth
        Where it stands.
    rng : numpy.random.Generator
        Seeded generator for the physics.
    warmup_s : float
        Warm-up time after power-on before moves are accepted (the paper's 2 min by default).
    boot_s : float
        Boot time after power-on or reset.
    node_id : int
        CAN node id, reported by GET_CONFIG NODE_ID.
    link : LinkInfo
        The link the device talks on, for the rate checks.
    serial_number : int
        Reported by IDENTIFY.
    """

    MODEL = "NF-SIM"
    FIRMWARE_VERSION = (0, 1, 0)

    def __init__(
        self,
        spec: SensorSpec,
        truth: Truth,
        rng: np.random.Generator,
        *,
        warmup_s: float = DEFAULT_WARMUP_S,
        boot_s: float = 0.5,
        node_id: int = 1,
        link: LinkInfo | None = None,
        serial_number: int = 1,
    ) -> None:
        for name, value in (("warmup_s", warmup_s), ("boot_s", boot_s)):
            if not (math.isfinite(value) and value >= 0):
                raise SimConfigError(
                    f"{name}: must be a finite number of seconds >= 0, got {value!r}"
                )
        self.instrument = Instrument(
            check_device_spec(spec), truth, rng, sample_rate_hz=BASE_RATE_HZ
        )
        self.link = link or LinkInfo()
        self.node_id = node_id
        self.serial_number = serial_number
        self.warmup_s = float(warmup_s)
        self.boot_s = float(boot_s)
        self.faults = FaultInjection()
        self.on_state_change: Callable[[DeviceState, DeviceState, float], None] | None = None
        self.rx_malformed = 0
        self.tx_dropped = 0
        self.cmd_rejected = 0
        self._fault = Fault(0)
        self._fault_time = math.inf
        self._pending: list[Outgoing] = []
        self._now_ns = 0  # time up to which the device has sent its output
        self._horizon_ns = 0  # time up to which output has been computed ahead
        self._ahead: deque[Outgoing] = deque()
        self._snapshots: list[_Snapshot] = []
        self._lookahead_ns = _LOOKAHEAD_NS
        self.boot_count = 0
        self._reboot(0, REPLY_LATENCY_S, first_status_ns=0)
        self._last_state = self.state_at(0.0)

    # -- configuration and state --------------------------------------------------------------
    def _reboot(self, t_ns: int, identify_s: float, first_status_ns: int) -> None:
        """Enter BOOT at ``t_ns``; IDENTIFY leaves at ``identify_s`` and the heartbeat starts at
        ``first_status_ns``."""
        table = self.instrument.spec.table
        self._boot_end = t_ns / NS_PER_S + self.boot_s
        self._counter = 0
        self._tick = _Tick()
        self._remainder = np.zeros(6)
        self._next_heartbeat_ns = first_status_ns
        self._settle_end = -math.inf
        self._checked_move = True
        self._commanded_deg = self.instrument.table.target_deg
        self._fault = Fault(0)
        self._fault_time = math.inf
        self.config: dict[ConfigKey, int] = {
            ConfigKey.SAMPLE_RATE_HZ: 200,
            ConfigKey.HEARTBEAT_PERIOD_MS: 100,
            **{key: round(getattr(table, name) / unit) for name, key, unit in _TABLE_KEYS},
            ConfigKey.STREAMING: 0,
        }
        if not self.link.fits(200, 100):
            self.config[ConfigKey.SAMPLE_RATE_HZ] = self.link.max_rate(100) or min(SAMPLE_RATES_HZ)
        self.boot_count += 1
        # protocol.md 5: the device announces itself during BOOT.
        self._pending.append(Outgoing(identify_s, self.identity()))

    def reboot(self) -> None:
        """Restart the firmware now, as a watchdog or supply reset does (the control channel's
        ``reset``): what waited in the transmit queue is lost; BOOT, counter 0, configuration back
        to defaults, streaming off. Warm-up is thermal and counts from power-on."""
        self._rewind()
        self._pending.clear()
        self._restart(self.now + REPLY_LATENCY_S)

    def _restart(self, first_s: float) -> None:
        """BOOT from now; its first message leaves at ``first_s`` (after the reply to RESET)."""
        self._rewind()
        first_ns = max(math.ceil(first_s * NS_PER_S), self._now_ns + _REPLY_LATENCY_NS)
        self._reboot(self._now_ns, first_ns / NS_PER_S, first_ns + _REPLY_LATENCY_NS)
        # protocol.md 4.6 and 6: the counters restart, and the reply to RESET leaves before the
        # first status of BOOT.
        self.rx_malformed = self.tx_dropped = self.cmd_rejected = 0
        log.info("t=%.3f s reset", self.now)

    @property
    def now(self) -> float:
        """Simulated time since power-on up to which the device has acted and sent, s."""
        return self._now_ns / NS_PER_S

    @property
    def now_ns(self) -> int:
        """:attr:`now` in whole nanoseconds (the device's own count)."""
        return self._now_ns

    @property
    def lookahead_s(self) -> float:
        """How much output one look-ahead chunk computes, s (:data:`LOOKAHEAD_S` by default).

        Longer chunks cost less per simulated second (one snapshot and one physics block per
        chunk) but hold the computation longer and make a rewind recompute more; a simulator in
        virtual time, which has no deadline to keep, uses :data:`VIRTUAL_LOOKAHEAD_S`.
        """
        return self._lookahead_ns / NS_PER_S

    @lookahead_s.setter
    def lookahead_s(self, seconds: float) -> None:
        if not (math.isfinite(seconds) and 0.001 <= seconds <= 10.0):
            raise SimConfigError(f"lookahead_s: must be 0.001 to 10 s, got {seconds!r}")
        self._lookahead_ns = round(seconds * NS_PER_S)

    @property
    def sample_rate_hz(self) -> int:
        return self.config[ConfigKey.SAMPLE_RATE_HZ]

    @property
    def streaming(self) -> bool:
        return bool(self.config[ConfigKey.STREAMING])

    @property
    def state(self) -> DeviceState:
        return self.state_at(self.now)

    def state_at(self, t: float) -> DeviceState:
        """The state at simulated time ``t`` (not before the last command)."""
        if self._fault and t >= self._fault_time:
            return DeviceState.FAULT
        if t < self._boot_end:
            return DeviceState.BOOT
        if t < self.warmup_s:
            return DeviceState.WARMUP
        table = self.instrument.table
        if table.steady_start_s <= t < table.steady_end_s:  # is_steady, for one time
            return DeviceState.SPINNING
        if table.is_moving(t):
            return DeviceState.ROTATING
        if t < self._settle_end:
            return DeviceState.SETTLING
        return DeviceState.READY

    def read_config(self, key: ConfigKey) -> int:
        if key == ConfigKey.LINK_BITRATE:
            return self.link.bitrate
        if key == ConfigKey.NODE_ID:
            return self.node_id
        if key == ConfigKey.LINK_MAX_SAMPLE_RATE_HZ:
            return self.link.max_rate(self.config[ConfigKey.HEARTBEAT_PERIOD_MS])
        return self.config[key]

    def apply(self, change: Callable[[], object]) -> None:
        """Make a change to the physics or the fault settings take effect now.

        Output is computed ahead (:data:`LOOKAHEAD_S`); a change first rewinds that computation to
        the present, so the device behaves as if it had happened exactly now.
        """
        self._rewind()
        change()

    def set_truth(self, truth: Truth) -> None:
        self.apply(lambda: self.instrument.set_truth(truth))

    def set_spec(self, spec: SensorSpec) -> None:
        """Change the instrument while running; the configuration keys of the table follow it.

        Raises
        ------
        SimConfigError
            A specification the device cannot run (:func:`check_device_spec`); nothing changed.
        """
        check_device_spec(spec)
        self.apply(lambda: self.instrument.set_spec(spec))
        for name, key, unit in _TABLE_KEYS:
            self.config[key] = round(getattr(spec.table, name) / unit)

    # -- commands ------------------------------------------------------------------------------
    def identity(self) -> Identify:
        return Identify(
            model=self.MODEL,
            serial_number=self.serial_number,
            hardware_revision=1,
            firmware_version=self.FIRMWARE_VERSION,
            max_sample_rate_hz=max(SAMPLE_RATES_HZ),
        )

    def status(self) -> Status:
        """The status now (as GET_STATUS answers it)."""
        self._rewind()
        return self._status_at(self.now, (self._counter - 1) & 0xFFFFFFFF)

    def _status_at(self, t: float, sample_counter: int) -> Status:
        return self._statuses_at([t], [sample_counter])[0]

    def _statuses_at(self, times: list[float], sample_counters: list[int]) -> list[Status]:
        """The statuses at ``times`` (the table and the temperature computed for all at once)."""
        if not times:
            return []
        table = self.instrument.table
        tt = np.asarray(times, dtype=float)
        angles = _angle_counts_array(table.encoder(table.state(tt)[0])).tolist()
        temperatures = _temperature_counts_array(self.instrument.temperature(tt)).tolist()
        rx, tx, rejected = self._wrapped_counters()
        return [
            Status(
                state=self.state_at(t),
                angle=angle,
                temperature=temperature,
                faults=self._fault if t >= self._fault_time else Fault(0),
                sample_counter=counter,
                rx_malformed=rx,
                tx_dropped=tx,
                cmd_rejected=rejected,
            )
            for t, counter, angle, temperature in zip(
                times, sample_counters, angles, temperatures, strict=True
            )
        ]

    def _wrapped_counters(self) -> tuple[int, int, int]:
        """``rx_malformed``, ``tx_dropped`` and ``cmd_rejected`` as a status carries them: wrapped
        to their fields' widths (u16, u8, u8; protocol.md 4.6)."""
        return self.rx_malformed & 0xFFFF, self.tx_dropped & 0xFF, self.cmd_rejected & 0xFF

    def note_malformed(self) -> None:
        """A frame addressed to the device could not be decoded at all: count it, nothing else."""
        self.rx_malformed += 1

    def refuse(self, seq: int, opcode: int, result: int) -> None:
        """A command the codec could not accept (unknown opcode, bad arguments): reply and count."""
        self.rx_malformed += 1
        self._reply(Reply(seq, _opcode(opcode), Result(result)))

    def handle(self, command: Command) -> None:
        """Act on one decoded command received now; its reply goes out with the next process()."""
        if self.faults.silent:
            return
        self._rewind()
        before = self.state
        result, data, follow = self._execute(command)
        self._check_move(self.now, self.now)  # a move into a jammed table fails at once
        self._reply(Reply(command.seq, command.OPCODE, result, data))
        if follow is not None:
            self._queue(follow, REPLY_LATENCY_S + self.faults.reply_delay_s)
        if command.OPCODE != Opcode.RESET and self.state != before:
            # protocol.md 5: a change caused by a command (a move starting) also sends a status.
            self._queue(self.status(), REPLY_LATENCY_S + self.faults.reply_delay_s)
        if command.OPCODE == Opcode.RESET and result == Result.OK:
            # protocol.md 4.2 and 6: replies queued before the RESET still go out, in order; then
            # the reply to RESET; then what BOOT sends.
            self._restart(self._pending[-1].time_s)

    def _reply(self, reply: Reply) -> None:
        if self.faults.drop_replies > 0:
            self.faults.drop_replies -= 1
            return
        if self.faults.wrong_result is not None:
            reply = replace(reply, result=self.faults.wrong_result, data=b"")
            self.faults.wrong_result = None
        if reply.result != Result.OK:
            self.cmd_rejected += 1
        self._queue(reply, REPLY_LATENCY_S + self.faults.reply_delay_s)

    def _queue(self, message: Reply | Status | Identify, delay: float) -> None:
        self._pending.append(Outgoing(self.now + delay, message))

    def _execute(self, cmd: Command) -> tuple[Result, bytes, Status | Identify | None]:
        """Carry out a decoded command; the checks run in the order of protocol.md table 4.3
        (unknown opcode and bad arguments were already refused by the codec)."""
        op = cmd.OPCODE
        state = self.state
        refusal = _state_refusal(cmd, state)
        if refusal is not None:
            return refusal, b"", None
        if op == Opcode.IDENTIFY:
            return Result.OK, b"", self.identity()
        if op == Opcode.GET_STATUS:
            return Result.OK, b"", self.status()
        if op == Opcode.STOP:
            self._stop()
            return Result.OK, b"", None
        if op in (Opcode.STREAM_START, Opcode.STREAM_STOP):
            self.config[ConfigKey.STREAMING] = int(op == Opcode.STREAM_START)
            return Result.OK, b"", None
        if op == Opcode.GET_CONFIG:
            assert isinstance(cmd, GetConfig)
            if not isinstance(cmd.key, ConfigKey):
                return Result.UNKNOWN_KEY, b"", None
            return (
                Result.OK,
                Reply.config(cmd.seq, op, cmd.key, self.read_config(cmd.key)).data,
                None,
            )
        if op == Opcode.RESET:
            return Result.OK, b"", None
        if op == Opcode.SET_CONFIG:
            assert isinstance(cmd, SetConfig)
            result = self._set_config(cmd)
            data = (
                Reply.config(cmd.seq, op, cmd.key, self.read_config(ConfigKey(cmd.key))).data
                if result == Result.OK
                else b""
            )
            return result, data, None
        if op == Opcode.SELF_TEST:
            failures = SelfTestFailure.DRIVE if self._fault & Fault.DRIVE else SelfTestFailure(0)
            return Result.OK, Reply.self_test(cmd.seq, failures).data, None
        if isinstance(cmd, Spin):
            return self._spin(cmd), b"", None
        if op in MOTION_OPCODES:
            return self._move(cmd), b"", None
        return Result.UNKNOWN_COMMAND, b"", None

    def _set_config(self, cmd: SetConfig) -> Result:
        key, value = cmd.key, cmd.value
        if not isinstance(key, ConfigKey):
            return Result.UNKNOWN_KEY
        if key.read_only:
            return Result.READ_ONLY
        lo, hi = CONFIG_LIMITS[key]
        if not lo <= value <= hi or (
            key == ConfigKey.SAMPLE_RATE_HZ and value not in SAMPLE_RATES_HZ
        ):
            return Result.OUT_OF_RANGE
        if key in (ConfigKey.SAMPLE_RATE_HZ, ConfigKey.HEARTBEAT_PERIOD_MS):
            rate = value if key == ConfigKey.SAMPLE_RATE_HZ else self.sample_rate_hz
            hb = (
                value
                if key == ConfigKey.HEARTBEAT_PERIOD_MS
                else self.config[ConfigKey.HEARTBEAT_PERIOD_MS]
            )
            if not self.link.fits(rate, hb):
                return Result.RATE_EXCEEDS_LINK
        for name, table_key, unit in _TABLE_KEYS:
            if key == table_key:
                table = replace(self.instrument.table.spec, **{name: value * unit})
                self.instrument.table.spec = table
        if key == ConfigKey.SAMPLE_RATE_HZ and value != self.sample_rate_hz:
            self._close_tick_for_rate_change()
        self.config[key] = value
        return Result.OK

    def _move(self, cmd: Command) -> Result:
        if isinstance(cmd, RotateTo) and not 0 <= cmd.angle < ANGLE_FULL_TURN:
            return Result.OUT_OF_RANGE
        if isinstance(cmd, RotateBy) and abs(cmd.delta) > ROTATE_BY_LIMIT:
            return Result.OUT_OF_RANGE
        table, t = self.instrument.table, self.now
        current = float(table.encoder(table.state(t)[0]))
        if isinstance(cmd, RotateBy):
            delta = cmd.delta * ANGLE_DEG_PER_COUNT
        else:
            target = cmd.angle * ANGLE_DEG_PER_COUNT if isinstance(cmd, RotateTo) else 0.0
            direction = cmd.direction if isinstance(cmd, RotateTo) else Direction.SHORTEST
            delta = (target - current) % 360.0
            if direction == Direction.SHORTEST and delta > 180.0:
                delta -= 360.0
            elif direction == Direction.NEGATIVE and delta > 0.0:
                delta -= 360.0
        table.move_by(t, delta)
        # The firmware keeps its own copy of the command: the drive's target moves when it is
        # stopped or jams, the command does not.
        self._commanded_deg = table.target_deg
        self._settle_end = table.motion_end_s + table.spec.settle_s
        self._checked_move = False
        return Result.OK

    def _spin(self, cmd: Spin) -> Result:
        if not SPIN_RATE_MDPS_MIN <= abs(cmd.rate) <= self.config[ConfigKey.TABLE_MAX_RATE_MDPS]:
            return Result.OUT_OF_RANGE
        table = self.instrument.table
        table.spin(self.now, cmd.rate * 1e-3)
        self._settle_end = -math.inf
        self._checked_move = True  # no target angle to supervise against
        return Result.OK

    def _stop(self) -> None:
        table, t = self.instrument.table, self.now
        if table.is_moving(t):
            table.stop(t)
            self._settle_end = table.motion_end_s + table.spec.settle_s
            self._checked_move = True  # a stopped move is short of its target by intent
            self._commanded_deg = table.target_deg

    def stall_table(self, stalled: bool = True) -> None:
        """Jam (or free) the table, as a control-channel fault.

        A table jammed during a move stops short of the command: the drive supervision sees it at
        once (DRIVE fault, state FAULT, a status sent; protocol.md 4.6). A table jammed at rest
        holds its angle, so the fault shows only when the next move cannot be carried out.
        """
        self._rewind()
        before = self.state
        self.instrument.table.stall(self.now, stalled)
        if stalled:
            self._settle_end = min(self._settle_end, self.now)
            self._check_move(self.now, self.now)
        if self.state != before:
            self._queue(self.status(), 0.0)  # protocol.md 5: a state change sends a status

    # -- time ----------------------------------------------------------------------------------
    #: Attributes the output computation changes; a snapshot of them allows a rewind.
    _ENGINE = (
        "instrument", "_counter", "_tick", "_remainder", "_next_heartbeat_ns",
        "_settle_end", "_checked_move", "_commanded_deg", "_fault", "_fault_time",
    )  # fmt: skip

    def process(self, dt: float) -> list[Outgoing]:
        """Advance simulated time by ``dt`` seconds; return what the device sends, in time order.

        Output is computed in chunks of :data:`LOOKAHEAD_S` ahead of time, because one large
        step of the physics costs little more than one small one; anything that changes the
        device rewinds to the present first (see :meth:`apply`), so the result is the same as
        computing every tick as it comes. The device's clock counts whole nanoseconds
        (:data:`NS_PER_S`): ``dt`` is rounded to one, so steps of 1 ms add up exactly and a tick
        is due at the same step whether or not a command came just before it.
        """
        if not (math.isfinite(dt) and dt >= 0):
            raise SimConfigError(f"dt: must be a finite number of seconds >= 0, got {dt!r}")
        target_ns = self._now_ns + round(dt * NS_PER_S)
        target = target_ns / NS_PER_S
        while self._horizon_ns < target_ns:
            self._compute_ahead()
        ahead = self._ahead
        out = []
        while ahead and ahead[0].time_s <= target:
            out.append(ahead.popleft())
        if self._pending:
            due = [p for p in self._pending if p.time_s <= target]
            if due:
                self._pending = [p for p in self._pending if p.time_s > target]
                out = sorted(out + due, key=lambda o: o.time_s)
        self._now_ns = target_ns
        while len(self._snapshots) > 1 and self._snapshots[1].start_ns <= target_ns:
            self._snapshots.pop(0)  # chunks wholly in the past are never rewound to
        state = self.state_at(target)
        if state != self._last_state:
            log.info("t=%.3f s state %s -> %s", target, self._last_state.name, state.name)
            if self.on_state_change is not None:
                self.on_state_change(self._last_state, state, target)
            self._last_state = state
        if self.faults.silent:
            return []
        for o in out:
            if isinstance(o.message, Status):
                break
        else:
            return out
        # Counters are the link's, not the computation's: a status carries their values when sent.
        rx, tx, rejected = self._wrapped_counters()
        return [
            Outgoing(
                o.time_s,
                replace(o.message, rx_malformed=rx, tx_dropped=tx, cmd_rejected=rejected),
            )
            if isinstance(o.message, Status)
            else o
            for o in out
        ]

    def _compute_ahead(self) -> None:
        """Compute one more chunk, keeping a snapshot of the state at its start for a rewind."""
        engine = {name: getattr(self, name) for name in self._ENGINE}
        # The specification, the truth and the error terms are frozen: shared, not copied. The
        # random generators are shared too, and their states recorded, to be set back on rewind.
        ins = self.instrument
        generators = ins.generators()
        memo: dict[int, Any] = {
            id(o): o for o in (ins.spec, ins.truth, ins.terms, ins.table.spec, *generators)
        }
        self._snapshots.append(
            _Snapshot(
                self._horizon_ns,
                copy.deepcopy(engine, memo),
                self.faults.skip_counter,
                tuple((g, g.bit_generator.state) for g in generators),
            )
        )
        self._ahead.extend(self._compute_to(self._horizon_ns + self._lookahead_ns))

    @property
    def prefetch_due(self) -> bool:
        """Whether less than half a chunk of output is left computed (:meth:`prefetch` would
        compute the next one)."""
        return self._horizon_ns - self._now_ns < self._lookahead_ns // 2

    def prefetch(self) -> None:
        """Compute the next chunk of output early, when less than half a chunk is left.

        A runner calls this between sendings, so that the computation does not delay a message
        that is due (the chunk then starts where the last one ended, as it would anyway).
        """
        if self.prefetch_due:
            self._compute_ahead()

    def next_output_s(self) -> float:
        """Simulated time of the next message the device will send (or of the computed horizon)."""
        t = self._ahead[0].time_s if self._ahead else self._horizon_ns / NS_PER_S
        if self._pending:
            t = min(t, min(p.time_s for p in self._pending))
        return t

    def _rewind(self) -> None:
        """Bring the computed state back to :attr:`now`, dropping output computed beyond it."""
        if self._horizon_ns <= self._now_ns or not self._snapshots:
            return
        # The latest chunk that starts at or before the present: its output up to the present
        # has been sent, everything after it is dropped and computed again. Sent and computed
        # again are decided by the same integer times, so nothing falls between them.
        snap = next(snap for snap in reversed(self._snapshots) if snap.start_ns <= self._now_ns)
        for name, value in snap.engine.items():
            setattr(self, name, value)
        for generator, state in snap.generators:
            generator.bit_generator.state = state
        self.faults.skip_counter = snap.skip_counter
        self._snapshots.clear()
        self._horizon_ns = snap.start_ns
        self._compute_to(self._now_ns)  # the same output again, already sent
        self._ahead.clear()

    def _compute_to(self, until_ns: int) -> list[Outgoing]:
        """Run the physics and the firmware from the computed horizon up to ``until_ns``.

        The physics samples due are those whose interval ends at or before ``until_ns``,
        counted in integers, exactly as :meth:`process` decides what has been sent.
        """
        t0, t1 = self._horizon_ns / NS_PER_S, until_ns / NS_PER_S
        counter0 = self._counter
        due = until_ns * _BASE_RATE // NS_PER_S - self.instrument.samples_emitted
        block = self.instrument.generate(max(due, 0))
        self._horizon_ns = until_ns
        self._check_move(t0, t1)
        out, tick_times, tick_counters = (
            self._ticks(block) if len(block) else ([], np.empty(0), np.empty(0, dtype=np.int64))
        )

        period_ns = round(
            self.config[ConfigKey.HEARTBEAT_PERIOD_MS] * 1_000_000 * self.faults.heartbeat_factor
        )
        times = []
        while self._next_heartbeat_ns <= until_ns:
            times.append(self._next_heartbeat_ns / NS_PER_S)
            self._next_heartbeat_ns += period_ns
        times += self._transitions(t0, t1)
        if times:
            # Each status carries the counter of the latest tick at or before its time.
            last = (counter0 - 1) & 0xFFFFFFFF
            if len(tick_counters):
                i = np.searchsorted(tick_times, times, side="right")
                counters = np.where(i > 0, tick_counters[np.maximum(i - 1, 0)], last).tolist()
            else:
                counters = [last] * len(times)
            out += map(Outgoing, times, self._statuses_at(times, counters))
            out.sort(key=lambda o: o.time_s)
        return out

    def _states_at(self, t: np.ndarray) -> np.ndarray:
        """:meth:`state_at` for an array of times (the state codes as integers)."""
        state = np.full(t.shape, int(DeviceState.READY), dtype=np.int64)
        state[t < self._settle_end] = DeviceState.SETTLING
        state[t < self.instrument.table.motion_end_s] = DeviceState.ROTATING
        state[self.instrument.table.is_steady(t)] = DeviceState.SPINNING
        state[t < self.warmup_s] = DeviceState.WARMUP
        state[t < self._boot_end] = DeviceState.BOOT
        if self._fault:
            state[t >= self._fault_time] = DeviceState.FAULT
        return state

    def _transitions(self, t0: float, t1: float) -> list[float]:
        """Times in (t0, t1] at which the state changes by itself (protocol.md 5: each sends a status)."""
        candidates = (
            self._boot_end,
            self.warmup_s,
            self.instrument.table.motion_end_s,
            self.instrument.table.steady_start_s,
            self.instrument.table.steady_end_s,
            self._settle_end,
            self._fault_time,
        )
        return sorted(
            t
            for t in set(candidates)
            if t0 < t <= t1 and self.state_at(t - 1e-9) != self.state_at(t)
        )

    def _check_move(self, t0: float, t1: float) -> None:
        """The drive supervision over the computed interval ``[t0, t1]``: a move that has ended
        further than :data:`DRIVE_FAULT_LIMIT_DEG` from its command sets DRIVE when it ended (not
        before ``t0``, which keeps a recomputation after a rewind identical)."""
        table = self.instrument.table
        if self._checked_move or table.is_moving(t1):
            return
        self._checked_move = True
        actual = float(table.encoder(table.state(t1)[0]))
        error = (actual - self._commanded_deg + 180.0) % 360.0 - 180.0
        if abs(error) > DRIVE_FAULT_LIMIT_DEG:
            self._fault |= Fault.DRIVE
            self._fault_time = min(self._fault_time, max(table.motion_end_s, t0))
            log.warning(
                "t=%.3f s drive fault: table at %.4f deg, commanded %.4f deg",
                self._fault_time,
                actual,
                self._commanded_deg,
            )

    def _close_tick_for_rate_change(self) -> None:
        # Increments already collected for the old rate would be mis-timed in a tick of the new
        # one; a rate change starts a fresh tick at the next physics sample.
        self._tick = _Tick()

    def _ticks(self, block: SampleBlock) -> tuple[list[Outgoing], np.ndarray, np.ndarray]:
        """The sample ticks completed by ``block``; also each tick's end time and the counter
        of each tick (for statuses computed between them)."""
        per_tick = max(1, round(BASE_RATE_HZ / self.sample_rate_hz * self.faults.tick_factor))
        self._tick.gyro.append(block.gyro_rps)
        self._tick.accel.append(block.accel_mps2)
        self._tick.gyro_saturated.append(block.gyro_saturated)
        self._tick.accel_saturated.append(block.accel_saturated)
        gyro = np.concatenate(self._tick.gyro)
        accel = np.concatenate(self._tick.accel)
        sat_g_all = np.concatenate(self._tick.gyro_saturated)
        sat_a_all = np.concatenate(self._tick.accel_saturated)
        # Samples of this block that complete a tick, aligned to the physics sample grid.
        have = len(gyro)
        n_ticks = have // per_tick
        used = n_ticks * per_tick
        self._tick = _Tick([gyro[used:]], [accel[used:]], [sat_g_all[used:]], [sat_a_all[used:]])
        if n_ticks == 0:
            return [], np.empty(0), np.empty(0, dtype=np.int64)
        # Times and table data at the end of each completed tick.
        end_idx = np.arange(1, n_ticks + 1) * per_tick - 1 - (have - len(block))
        g = gyro[:used].reshape(n_ticks, per_tick, 3).mean(axis=1)
        a = accel[:used].reshape(n_ticks, per_tick, 3).mean(axis=1)
        # A tick is saturated if any of its physics samples was.
        sat_g = np.asarray(sat_g_all[:used].reshape(n_ticks, per_tick).any(axis=1))
        sat_a = np.asarray(sat_a_all[:used].reshape(n_ticks, per_tick).any(axis=1))
        # A value that is not a number cannot be sent; the device reports it as an invalid
        # (saturated) reading instead of stopping, and it must not poison the quantiser's carry.
        for values, flags in ((g, sat_g), (a, sat_a)):
            bad = ~np.isfinite(values).all(axis=1)
            if bad.any():
                log.warning("%d samples not a number, sent as saturated", int(bad.sum()))
                values[bad] = 0.0
                flags |= bad
        # TABLE_MOVING marks ticks that overlap the motion profile (state ROTATING); the ring-down
        # after the stop belongs to SETTLING (protocol.md 4.5).
        table = self.instrument.table
        j = np.clip(end_idx, 0, len(block) - 1)
        t_end = block.time_s[j]
        moving = (t_end > table.motion_start_s) & (
            t_end - 1.0 / self.sample_rate_hz < table.motion_end_s
        )
        if not self.streaming:
            counters = (self._counter + np.arange(n_ticks)) & 0xFFFFFFFF
            self._counter = (self._counter + n_ticks) & 0xFFFFFFFF
            return [], t_end, counters
        gc, self._remainder[:3] = quantise_carry(g / _GYRO_COUNT, self._remainder[:3], axis=0)
        ac, self._remainder[3:] = quantise_carry(a / _ACCEL_COUNT, self._remainder[3:], axis=0)
        sat_g |= np.any((gc > INT32_MAX) | (gc < INT32_MIN), axis=1)
        sat_a |= np.any((ac > INT24_MAX) | (ac < INT24_MIN), axis=1)
        gc = np.clip(gc, INT32_MIN, INT32_MAX).astype(np.int64)
        ac = np.clip(ac, INT24_MIN, INT24_MAX).astype(np.int64)
        state = self._states_at(t_end)
        validity = np.where(state == DeviceState.FAULT, int(Validity.FAULT), int(VALIDITY_GOOD))
        validity |= np.where(moving, int(Validity.TABLE_MOVING), 0)
        # A tick that still overlaps the motion is moving, not settling: the pair of both bits
        # means a steady spin (protocol.md 4.5, version 1.1).
        settling = (state == DeviceState.SETTLING) & ~moving
        validity |= np.where(settling, int(Validity.TABLE_SETTLING), 0)
        # Version 1.1: the whole interval at the steady rate of a spin.
        steady = table.is_steady(t_end - 1.0 / self.sample_rate_hz) & table.is_steady(t_end)
        validity |= np.where(steady, int(VALIDITY_STEADY_RATE), 0)
        warming = (state == DeviceState.BOOT) | (state == DeviceState.WARMUP)
        validity |= np.where(warming, int(Validity.WARMING_UP), 0)
        validity |= np.where(sat_g, int(Validity.GYRO_SATURATED), 0)
        validity |= np.where(sat_a, int(Validity.ACCEL_SATURATED), 0)
        # A counter skip (fault injection) applies to the next tick sent.
        self._counter += self.faults.skip_counter
        self.faults.skip_counter = 0
        counters = (self._counter + np.arange(n_ticks, dtype=np.int64)) & 0xFFFFFFFF
        self._counter = (self._counter + n_ticks) & 0xFFFFFFFF
        angle = _angle_counts_array(block.table_deg[j])
        temperature = _temperature_counts_array(block.temperature_c[j])
        bits = validity.tolist()
        flag_of = {b: validity_of(b) for b in set(bits)}
        make, new = Sample.fast, tuple.__new__
        frames = sample_frames_block(counters, gc, ac, angle, temperature, validity)
        out = [
            new(Outgoing, (t, make(c, (g0, g1, g2), (a0, a1, a2), ang, temp, flag_of[v]),
                           frames[k : k + 32]))
            for t, c, (g0, g1, g2), (a0, a1, a2), ang, temp, v, k in zip(
                t_end.tolist(), counters.tolist(), gc.tolist(), ac.tolist(), angle.tolist(),
                temperature.tolist(), bits, range(0, 32 * n_ticks, 32), strict=True,
            )
        ]  # fmt: skip
        return out, t_end, counters


_BOOT_ALLOWED = frozenset({Opcode.IDENTIFY, Opcode.GET_STATUS, Opcode.GET_CONFIG, Opcode.RESET})
_FAULT_REFUSED = frozenset({*MOTION_OPCODES, Opcode.SET_CONFIG})
_BUSY_REFUSED = frozenset({*MOTION_OPCODES, Opcode.SELF_TEST})


_MOTION_KEYS = frozenset(
    {ConfigKey.TABLE_MAX_RATE_MDPS, ConfigKey.TABLE_MAX_ACCEL_MDPS2, ConfigKey.SETTLE_TIME_MS}
)


def _state_refusal(cmd: Command, state: DeviceState) -> Result | None:
    """The state check of protocol.md table 4.3 (third in order)."""
    op = cmd.OPCODE
    if state == DeviceState.FAULT and op in _FAULT_REFUSED:
        return Result.FAULT
    if state == DeviceState.BOOT and op not in _BOOT_ALLOWED:
        return Result.NOT_READY
    if state == DeviceState.WARMUP and op in MOTION_OPCODES:
        return Result.NOT_READY
    if state in (DeviceState.ROTATING, DeviceState.SETTLING, DeviceState.SPINNING) and (
        op in _BUSY_REFUSED or (isinstance(cmd, SetConfig) and cmd.key in _MOTION_KEYS)
    ):
        return Result.BUSY
    return None


def _angle_counts_array(angle_deg: np.ndarray) -> np.ndarray:
    """:func:`_angle_counts` of every element (the same rounding: half to even)."""
    return np.round(angle_deg * _COUNTS_PER_DEG).astype(np.int64) % ANGLE_FULL_TURN


def _temperature_counts_array(temp_c: np.ndarray) -> np.ndarray:
    """:func:`_temperature_counts` of every element."""
    finite = np.isfinite(temp_c)
    counts = np.clip(np.round(np.where(finite, temp_c, 0.0) * _COUNTS_PER_DEGC), -32767, 32767)
    return np.where(finite, counts.astype(np.int64), TEMPERATURE_NOT_AVAILABLE)


def _angle_counts(angle_deg: float) -> int:
    return round(angle_deg * _COUNTS_PER_DEG) % ANGLE_FULL_TURN


def _temperature_counts(temp_c: float) -> int:
    if not math.isfinite(temp_c):
        return TEMPERATURE_NOT_AVAILABLE
    return max(-32767, min(32767, round(temp_c * _COUNTS_PER_DEGC)))


def _opcode(code: int) -> Opcode | int:
    try:
        return Opcode(code)
    except ValueError:
        return code


__all__ = ["BASE_RATE_HZ", "FaultInjection", "Firmware", "LinkInfo", "Outgoing", "Truth"]
