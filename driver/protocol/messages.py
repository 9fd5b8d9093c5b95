"""Message payloads of the wire protocol: one frozen dataclass per message (see ``protocol.md``).

Each class has ``encode() -> bytes`` giving its payload (little-endian) and a ``decode(payload)``
classmethod. Link framing (CAN identifiers, serial frames) lives in :mod:`northfinder.driver.protocol.can`
and :mod:`northfinder.driver.protocol.serial`.

``encode`` checks only that every field fits its wire type and raises
:class:`~northfinder.driver.protocol.errors.EncodeError` otherwise; whether a value is acceptable (an angle below
360 deg, a known config key) is the device's decision, answered with a result code. ``decode``
raises :class:`~northfinder.driver.protocol.errors.PayloadError` (or its subclass
:class:`~northfinder.driver.protocol.errors.BadCommandError` for commands) for a wrong length or an undefined code,
and nothing else for any input.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Self

if TYPE_CHECKING:
    import numpy as np

from northfinder.driver.protocol.constants import (
    INT24_MAX,
    INT24_MIN,
    INT32_MAX,
    INT32_MIN,
    PROTOCOL_VERSION_MAJOR,
    PROTOCOL_VERSION_MINOR,
    UINT32_MAX,
    Axis,
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    Opcode,
    Result,
    SelfTestFailure,
    Validity,
)
from northfinder.driver.protocol.errors import BadCommandError, EncodeError, PayloadError

__all__ = [
    "Command",
    "GetConfig",
    "GetStatus",
    "Home",
    "Identify",
    "IdentifyPage",
    "Message",
    "Reply",
    "RequestIdentify",
    "Reset",
    "RotateBy",
    "RotateTo",
    "Sample",
    "SampleAux",
    "SampleAxis",
    "SampleX",
    "SampleY",
    "SampleZ",
    "Scale",
    "SelfTest",
    "SetConfig",
    "Spin",
    "Status",
    "StatusCounters",
    "StatusMain",
    "Stop",
    "StreamStart",
    "StreamStop",
]


def _check(name: str, value: int, lo: int, hi: int) -> None:
    if not isinstance(value, int) or not lo <= value <= hi:
        raise EncodeError(f"{name}={value!r} does not fit the wire range [{lo}, {hi}]")


def _check_u8(name: str, value: int) -> None:
    _check(name, value, 0, 0xFF)


def _expect_len(cls: type, payload: bytes, n: int) -> None:
    if len(payload) != n:
        raise PayloadError(f"{cls.__name__} payload must be {n} bytes, got {len(payload)}")


def _as_bytes(payload: bytes | bytearray | memoryview) -> bytes:
    return payload if type(payload) is bytes else bytes(payload)


def _state(code: int) -> DeviceState:
    try:
        return DeviceState(code)
    except ValueError:
        raise PayloadError(f"undefined device state {code}") from None


# --------------------------------------------------------------------------------------------
# Commands (host -> device) and replies
# --------------------------------------------------------------------------------------------

_COMMAND_TYPES: dict[int, type[Command]] = {}

#: The range of a command argument by its ``struct`` code.
_WIRE_RANGE: dict[str, tuple[int, int]] = {
    "B": (0, 0xFF),
    "I": (0, UINT32_MAX),
    "i": (INT32_MIN, INT32_MAX),
}


@dataclass(frozen=True, slots=True)
class Command:
    """Base of all commands: payload ``[u8 seq, u8 opcode, arguments...]``.

    ``Command.decode`` returns the subclass named by the opcode. Subclasses set ``OPCODE`` and,
    when the command has arguments, ``_FIELDS``: each argument's field name and its ``struct``
    code, in wire order (protocol.md 4.1); the wire range follows from the code.

    Attributes
    ----------
    seq : int
        Request sequence number (u8), chosen by the host and echoed in the reply.
    """

    seq: int
    OPCODE: ClassVar[Opcode]
    _FIELDS: ClassVar[tuple[tuple[str, str], ...]] = ()
    _ARGS: ClassVar[struct.Struct | None] = None

    def __init_subclass__(cls) -> None:
        # No super(): slotted dataclasses are rebuilt, which breaks its implicit class cell.
        # The rebuilt class registers last, so the registry ends up holding it.
        if cls._FIELDS:
            cls._ARGS = struct.Struct("<" + "".join(code for _, code in cls._FIELDS))
        if "OPCODE" in cls.__dict__:
            _COMMAND_TYPES[cls.OPCODE] = cls

    @property
    def opcode(self) -> Opcode:
        """Opcode of this command."""
        return self.OPCODE

    def _args(self) -> tuple[int, ...]:
        return tuple(getattr(self, name) for name, _ in self._FIELDS)

    def _check_args(self) -> None:
        for name, code in self._FIELDS:
            _check(name, getattr(self, name), *_WIRE_RANGE[code])

    def encode(self) -> bytes:
        """Payload bytes: seq, opcode, arguments (little-endian)."""
        _check_u8("seq", self.seq)
        self._check_args()
        head = bytes((self.seq, self.OPCODE))
        return head if self._ARGS is None else head + self._ARGS.pack(*self._args())

    @classmethod
    def decode(cls, payload: bytes) -> Command:
        """Decode a command payload into the class named by its opcode.

        Raises
        ------
        PayloadError
            Fewer than 2 bytes (no seq/opcode to reply to), or the opcode does not belong to
            ``cls`` when called on a subclass.
        BadCommandError
            Unknown opcode (result UNKNOWN_COMMAND) or wrong argument length or an undefined
            argument code (result BAD_ARGUMENT); carries ``seq`` and ``opcode`` for the reply.
        """
        if len(payload) < 2:
            raise PayloadError(f"command payload must be at least 2 bytes, got {len(payload)}")
        seq, opcode = payload[0], payload[1]
        sub = _COMMAND_TYPES.get(opcode)
        if sub is None:
            raise BadCommandError(
                f"unknown opcode 0x{opcode:02X}", seq, opcode, Result.UNKNOWN_COMMAND
            )
        if cls is not Command and sub is not cls:
            raise PayloadError(f"opcode 0x{opcode:02X} is {sub.__name__}, not {cls.__name__}")
        n_args = 0 if sub._ARGS is None else sub._ARGS.size
        if len(payload) != 2 + n_args:
            raise BadCommandError(
                f"{sub.__name__} needs {n_args} argument bytes, got {len(payload) - 2}",
                seq,
                opcode,
                Result.BAD_ARGUMENT,
            )
        if sub._ARGS is None:
            return sub(seq)
        return sub._from_args(seq, sub._ARGS.unpack_from(payload, 2))

    @classmethod
    def _from_args(cls, seq: int, args: tuple[int, ...]) -> Self:
        return cls(seq, *args)


@dataclass(frozen=True, slots=True)
class RequestIdentify(Command):
    """IDENTIFY: reply OK, then the IDENTIFY message follows. No arguments."""

    OPCODE: ClassVar[Opcode] = Opcode.IDENTIFY


@dataclass(frozen=True, slots=True)
class GetStatus(Command):
    """GET_STATUS: reply OK, then a STATUS message follows at once. No arguments."""

    OPCODE: ClassVar[Opcode] = Opcode.GET_STATUS


@dataclass(frozen=True, slots=True)
class RotateTo(Command):
    """ROTATE_TO: rotate the table to an absolute angle.

    Attributes
    ----------
    angle : int
        Target angle, u32 in 1e-6 deg; the device accepts [0, 360e6) and replies OUT_OF_RANGE
        otherwise.
    direction : Direction
        Which way to turn (u8).
    """

    angle: int = 0
    direction: Direction = Direction.SHORTEST
    OPCODE: ClassVar[Opcode] = Opcode.ROTATE_TO
    _FIELDS = (("angle", "I"), ("direction", "B"))

    @classmethod
    def _from_args(cls, seq: int, args: tuple[int, ...]) -> Self:
        angle, direction = args
        try:
            d = Direction(direction)
        except ValueError:
            raise BadCommandError(
                f"undefined direction {direction}", seq, cls.OPCODE, Result.BAD_ARGUMENT
            ) from None
        return cls(seq, angle, d)


@dataclass(frozen=True, slots=True)
class RotateBy(Command):
    """ROTATE_BY: rotate the table by a signed angle.

    Attributes
    ----------
    delta : int
        Rotation, i32 in 1e-6 deg, positive counter-clockwise seen from above; the device
        accepts ``|delta| <= 720 deg`` and replies OUT_OF_RANGE otherwise.
    """

    delta: int = 0
    OPCODE: ClassVar[Opcode] = Opcode.ROTATE_BY
    _FIELDS = (("delta", "i"),)


@dataclass(frozen=True, slots=True)
class Stop(Command):
    """STOP: decelerate the table to rest at once. Always accepted. No arguments."""

    OPCODE: ClassVar[Opcode] = Opcode.STOP


@dataclass(frozen=True, slots=True)
class Home(Command):
    """HOME: rotate to the encoder zero (absolute angle 0) by the shortest way. No arguments."""

    OPCODE: ClassVar[Opcode] = Opcode.HOME


@dataclass(frozen=True, slots=True)
class Spin(Command):
    """SPIN (version 1.1): turn the table at a constant rate until STOP.

    The table accelerates at TABLE_MAX_ACCEL_MDPS2 (state ROTATING), then holds the rate (state
    SPINNING, samples marked steady-rate); STOP brakes it to rest (ROTATING, SETTLING, READY).

    Attributes
    ----------
    rate : int
        Rate, i32 in 1e-3 deg/s, positive counter-clockwise seen from above; the device accepts
        ``1 <= |rate| <= TABLE_MAX_RATE_MDPS`` and replies OUT_OF_RANGE otherwise.
    """

    rate: int = 0
    OPCODE: ClassVar[Opcode] = Opcode.SPIN
    _FIELDS = (("rate", "i"),)


@dataclass(frozen=True, slots=True)
class StreamStart(Command):
    """STREAM_START: start the sample stream (STREAMING := 1). No arguments."""

    OPCODE: ClassVar[Opcode] = Opcode.STREAM_START


@dataclass(frozen=True, slots=True)
class StreamStop(Command):
    """STREAM_STOP: stop the sample stream (STREAMING := 0). No arguments."""

    OPCODE: ClassVar[Opcode] = Opcode.STREAM_STOP


@dataclass(frozen=True, slots=True)
class GetConfig(Command):
    """GET_CONFIG: read one configuration value; the reply carries :class:`ConfigValue` data.

    Attributes
    ----------
    key : ConfigKey or int
        Key (u8); an undefined key is answered with UNKNOWN_KEY.
    """

    key: ConfigKey | int = ConfigKey.SAMPLE_RATE_HZ
    OPCODE: ClassVar[Opcode] = Opcode.GET_CONFIG
    _FIELDS = (("key", "B"),)

    @classmethod
    def _from_args(cls, seq: int, args: tuple[int, ...]) -> Self:
        return cls(seq, _config_key(args[0]))


@dataclass(frozen=True, slots=True)
class SetConfig(Command):
    """SET_CONFIG: write one configuration value; the reply echoes the value now in effect.

    Attributes
    ----------
    key : ConfigKey or int
        Key (u8).
    value : int
        New value (u32, unit given by the key).
    """

    key: ConfigKey | int = ConfigKey.SAMPLE_RATE_HZ
    value: int = 0
    OPCODE: ClassVar[Opcode] = Opcode.SET_CONFIG
    _FIELDS = (("key", "B"), ("value", "I"))

    @classmethod
    def _from_args(cls, seq: int, args: tuple[int, ...]) -> Self:
        return cls(seq, _config_key(args[0]), args[1])


@dataclass(frozen=True, slots=True)
class Reset(Command):
    """RESET: reply OK, then restart (state BOOT, counters and configuration to defaults)."""

    OPCODE: ClassVar[Opcode] = Opcode.RESET


@dataclass(frozen=True, slots=True)
class SelfTest(Command):
    """SELF_TEST: run the built-in test; the reply carries a :class:`SelfTestFailure` mask."""

    OPCODE: ClassVar[Opcode] = Opcode.SELF_TEST


def _config_key(code: int) -> ConfigKey | int:
    try:
        return ConfigKey(code)
    except ValueError:
        return code


_REPLY_HEAD = struct.Struct("<BBB")
_CONFIG_VALUE = struct.Struct("<BI")
_SELF_TEST = struct.Struct("<H")
REPLY_DATA_MAX = 5
"""Largest reply data length in bytes (a CAN frame minus seq, opcode and result)."""


@dataclass(frozen=True, slots=True)
class Reply:
    """Reply to a command: payload ``[u8 seq, u8 opcode, u8 result, data...]``.

    Data is empty unless the result is OK and the opcode is GET_CONFIG or SET_CONFIG
    (``[u8 key, u32 value]``) or SELF_TEST (``[u16 failure mask]``).

    Attributes
    ----------
    seq : int
        Sequence number of the command answered.
    opcode : Opcode or int
        Opcode of the command answered (an undefined one is echoed as int).
    result : Result or int
        Result code (an undefined one, from a newer minor version, decodes as int).
    data : bytes
        Result data, at most 5 bytes.
    """

    seq: int
    opcode: Opcode | int
    result: Result | int = Result.OK
    data: bytes = b""

    @classmethod
    def to(cls, command: Command, result: Result = Result.OK, data: bytes = b"") -> Reply:
        """Reply answering ``command``."""
        return cls(command.seq, command.OPCODE, result, data)

    @classmethod
    def config(cls, seq: int, opcode: Opcode, key: ConfigKey | int, value: int) -> Reply:
        """OK reply to GET_CONFIG or SET_CONFIG carrying ``key`` and ``value``."""
        return cls(seq, opcode, Result.OK, _encode_config_value(key, value))

    @classmethod
    def self_test(cls, seq: int, failures: SelfTestFailure | int) -> Reply:
        """OK reply to SELF_TEST carrying the failure mask."""
        _check("failures", int(failures), 0, 0xFFFF)
        return cls(seq, Opcode.SELF_TEST, Result.OK, _SELF_TEST.pack(failures))

    @property
    def ok(self) -> bool:
        """True if the result is OK."""
        return self.result == Result.OK

    def config_value(self) -> tuple[ConfigKey | int, int]:
        """``(key, value)`` carried by an OK reply to GET_CONFIG or SET_CONFIG.

        Raises
        ------
        PayloadError
            The data is not 5 bytes.
        """
        if len(self.data) != _CONFIG_VALUE.size:
            raise PayloadError(f"config reply data must be 5 bytes, got {len(self.data)}")
        key, value = _CONFIG_VALUE.unpack(self.data)
        return _config_key(key), value

    def self_test_failures(self) -> SelfTestFailure:
        """Failure mask carried by an OK reply to SELF_TEST (zero means passed).

        Raises
        ------
        PayloadError
            The data is not 2 bytes.
        """
        if len(self.data) != _SELF_TEST.size:
            raise PayloadError(f"self-test reply data must be 2 bytes, got {len(self.data)}")
        return SelfTestFailure(_SELF_TEST.unpack(self.data)[0])

    def encode(self) -> bytes:
        """Payload bytes: seq, opcode, result, data."""
        _check_u8("seq", self.seq)
        _check_u8("opcode", int(self.opcode))
        _check_u8("result", int(self.result))
        if not isinstance(self.data, bytes | bytearray) or len(self.data) > REPLY_DATA_MAX:
            raise EncodeError(f"reply data must be bytes of length <= {REPLY_DATA_MAX}")
        return _REPLY_HEAD.pack(self.seq, self.opcode, self.result) + bytes(self.data)

    @classmethod
    def decode(cls, payload: bytes) -> Reply:
        """Decode a reply payload (3 to 8 bytes).

        Raises
        ------
        PayloadError
            Wrong length, or data of the wrong length for an OK reply to a known opcode.
        """
        n = len(payload)
        if not 3 <= n <= 3 + REPLY_DATA_MAX:
            raise PayloadError(f"reply payload must be 3..8 bytes, got {n}")
        seq, opcode, result = _REPLY_HEAD.unpack_from(payload)
        try:
            op: Opcode | int = Opcode(opcode)
        except ValueError:
            op = opcode
        try:
            res: Result | int = Result(result)
        except ValueError:
            res = result
        data = bytes(payload[3:])
        expected = _REPLY_DATA_LEN.get(op, 0) if res == Result.OK else 0
        if isinstance(op, Opcode) and len(data) != expected:
            raise PayloadError(
                f"reply to {op.name} with result {res!s} must carry {expected} data bytes, "
                f"got {len(data)}"
            )
        return cls(seq, op, res, data)


_REPLY_DATA_LEN: dict[Opcode | int, int] = {
    Opcode.GET_CONFIG: _CONFIG_VALUE.size,
    Opcode.SET_CONFIG: _CONFIG_VALUE.size,
    Opcode.SELF_TEST: _SELF_TEST.size,
}


def _encode_config_value(key: ConfigKey | int, value: int) -> bytes:
    _check_u8("key", int(key))
    _check("value", value, 0, UINT32_MAX)
    return _CONFIG_VALUE.pack(key, value)


# --------------------------------------------------------------------------------------------
# Sample stream
# --------------------------------------------------------------------------------------------

_SAMPLE = struct.Struct("<I3i3iIhB")
_SAMPLE_AXIS = struct.Struct("<BiHb")  # accel int24 = u16 low part + i8 high byte
_SAMPLE_AUX = struct.Struct("<BIhB")
#: The four frames of one tick end to end (X, Y, Z, AUX), unpacked at once.
_SAMPLE_TICK = struct.Struct("<" + _SAMPLE_AXIS.format[1:] * 3 + _SAMPLE_AUX.format[1:])


def _check_sample_common(angle: int, temperature: int, validity: int) -> None:
    _check("angle", angle, 0, UINT32_MAX)
    _check("temperature", temperature, -32768, 32767)
    _check_u8("validity", int(validity))


_VALIDITY: dict[int, Validity] = {}


def validity_of(bits: int) -> Validity:
    """``Validity(bits)``, built once for each of the 256 values (a flag enum is slow to build
    and every sample carries one)."""
    v = _VALIDITY.get(bits)
    if v is None:
        v = _VALIDITY[bits] = Validity(bits)
    return v


@functools.cache
def _tick_frames() -> np.dtype:
    """One tick's four CAN sample frames as one numpy record: SAMPLE_X, _Y, _Z (``<BiHb``:
    tick, gyro, the accelerometer's low 16 bits and its high byte) and SAMPLE_AUX (``<BIhB``:
    tick, angle, temperature, validity bits). numpy is imported here, not with the codec (a
    command's help needs no numpy)."""
    import numpy as np

    return np.dtype(
        [(f"{axis}{field}", code) for axis in "xyz" for field, code in
         (("tick", "u1"), ("gyro", "<i4"), ("accel_lo", "<u2"), ("accel_hi", "i1"))]
        + [("tick", "u1"), ("angle", "<u4"), ("temperature", "<i2"), ("validity", "u1")]
    )  # fmt: skip


def sample_frames_block(
    counter: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    angle: np.ndarray,
    temperature: np.ndarray,
    validity: np.ndarray,
) -> bytes:
    """The data of the four CAN frames of each of ``n`` ticks (what :meth:`Sample.can_payloads`
    packs for one), 32 bytes a tick in sending order: X, Y, Z, AUX, 8 bytes each.

    Parameters
    ----------
    counter, angle, temperature, validity : ndarray, shape (n,), integer
        The fields of each tick, each in its range (:class:`Sample`; not checked).
    gyro : ndarray, shape (n, 3), integer
        Rate counts (int32).
    accel : ndarray, shape (n, 3), integer
        Acceleration counts (int24).
    """
    import numpy as np

    rec = np.empty(len(counter), _tick_frames())
    tick = np.asarray(counter) & 0xFF
    accel = np.asarray(accel, np.int64)
    for k, axis in enumerate("xyz"):
        rec[f"{axis}tick"] = tick
        rec[f"{axis}gyro"] = gyro[:, k]
        rec[f"{axis}accel_lo"] = accel[:, k] & 0xFFFF
        rec[f"{axis}accel_hi"] = accel[:, k] >> 16
    rec["tick"] = tick
    rec["angle"] = angle
    rec["temperature"] = temperature
    rec["validity"] = validity
    return rec.tobytes()


def sample_axis_fields(payload: bytes | bytearray) -> tuple[int, int, int]:
    """``(tick, gyro, accel)`` of an 8-byte SAMPLE_X/Y/Z payload (the length unchecked)."""
    tick, gyro, lo, hi = _SAMPLE_AXIS.unpack(payload)
    return tick, gyro, lo | (hi << 16)


def sample_aux_fields(payload: bytes | bytearray) -> tuple[int, int, int, int]:
    """``(tick, angle, temperature, validity bits)`` of an 8-byte SAMPLE_AUX payload (the
    length unchecked)."""
    return _SAMPLE_AUX.unpack(payload)


def sample_tick_fields(
    x: bytes | bytearray, y: bytes | bytearray, z: bytes | bytearray, aux: bytes | bytearray
) -> tuple[int, ...]:
    """The fields of a tick's four 8-byte payloads (SAMPLE_X, _Y, _Z, _AUX; the lengths
    unchecked) in one unpack: :func:`sample_axis_fields` of each axis, the accelerometer as its
    two parts (low 16 bits, high byte: ``lo | hi << 16``), then :func:`sample_aux_fields`."""
    return _SAMPLE_TICK.unpack(x + y + z + aux)


@dataclass(frozen=True, slots=True)
class Sample:
    """One sample tick: the serial SAMPLE payload (35 bytes); on CAN four frames.

    Gyro and accelerometer values are increments over the sample interval expressed as a mean
    rate; the device carries the rounding remainder to the next sample, so sums over a window
    are exact to one count.

    Attributes
    ----------
    counter : int
        Sample counter (u32), +1 per tick since boot, wrapping.
    gyro : tuple of 3 int
        Angular rate x, y, z (i32, 1e-4 deg/h per count by default).
    accel : tuple of 3 int
        Specific force x, y, z (i32 on serial, i24 on CAN; 1e-6 g per count by default).
    angle : int
        Table angle from the encoder (u32, 1e-6 deg, [0, 360 deg)).
    temperature : int
        Sensor temperature (i16, 0.01 degC; -32768 = no reading).
    validity : Validity
        Validity bits (u8).
    """

    counter: int
    gyro: tuple[int, int, int]
    accel: tuple[int, int, int]
    angle: int
    temperature: int
    validity: Validity

    SIZE: ClassVar[int] = _SAMPLE.size

    @property
    def tick(self) -> int:
        """Low 8 bits of the counter, as carried by each CAN sample frame."""
        return self.counter & 0xFF

    def encode(self) -> bytes:
        """Serial payload: u32 counter, 3 x i32 gyro, 3 x i32 accel, u32 angle, i16, u8."""
        _check("counter", self.counter, 0, UINT32_MAX)
        if len(self.gyro) != 3 or len(self.accel) != 3:
            raise EncodeError("gyro and accel must have three channels")
        for name, values in (("gyro", self.gyro), ("accel", self.accel)):
            for axis, v in zip("xyz", values, strict=True):
                _check(f"{name}_{axis}", v, INT32_MIN, INT32_MAX)
        _check_sample_common(self.angle, self.temperature, self.validity)
        return _SAMPLE.pack(
            self.counter, *self.gyro, *self.accel, self.angle, self.temperature, self.validity
        )

    @classmethod
    def decode(cls, payload: bytes) -> Sample:
        """Decode a serial SAMPLE payload (35 bytes)."""
        _expect_len(cls, payload, _SAMPLE.size)
        c, gx, gy, gz, ax, ay, az, angle, temp, valid = _SAMPLE.unpack(payload)
        return cls(c, (gx, gy, gz), (ax, ay, az), angle, temp, validity_of(valid))

    @classmethod
    def fast(
        cls,
        counter: int,
        gyro: tuple[int, int, int],
        accel: tuple[int, int, int],
        angle: int,
        temperature: int,
        validity: Validity,
    ) -> Sample:
        """The same as ``Sample(...)``, built in half the time (a frozen dataclass sets each
        field through ``object.__setattr__``); for the stream, which builds one every tick."""
        sample = _new(cls)
        _SET_COUNTER(sample, counter)
        _SET_GYRO(sample, gyro)
        _SET_ACCEL(sample, accel)
        _SET_ANGLE(sample, angle)
        _SET_TEMPERATURE(sample, temperature)
        _SET_VALIDITY(sample, validity)
        return sample

    def can_payloads(self) -> tuple[bytes, bytes, bytes, bytes]:
        """The data of the four CAN frames of this tick, in sending order: what the frames of
        :meth:`split` encode to, without building them."""
        g, a = self.gyro, self.accel
        angle, temp, valid = self.angle, self.temperature, self.validity
        if not (
            len(g) == 3
            and len(a) == 3
            and (type(g0 := g[0]) is type(g1 := g[1]) is type(g2 := g[2]) is int)
            and INT32_MIN <= g0 <= INT32_MAX
            and INT32_MIN <= g1 <= INT32_MAX
            and INT32_MIN <= g2 <= INT32_MAX
            and (type(a0 := a[0]) is type(a1 := a[1]) is type(a2 := a[2]) is int)
            and INT24_MIN <= a0 <= INT24_MAX
            and INT24_MIN <= a1 <= INT24_MAX
            and INT24_MIN <= a2 <= INT24_MAX
            and type(angle) is int
            and 0 <= angle <= UINT32_MAX
            and type(temp) is int
            and -32768 <= temp <= 32767
            and isinstance(valid, int)
            and 0 <= valid <= 0xFF
        ):
            if len(g) != 3 or len(a) != 3:
                raise EncodeError("gyro and accel must have three channels")
            return tuple(part.encode() for part in self.split())  # type: ignore[return-value]
        t = self.counter & 0xFF
        pack = _SAMPLE_AXIS.pack
        return (
            pack(t, g0, a0 & 0xFFFF, a0 >> 16),
            pack(t, g1, a1 & 0xFFFF, a1 >> 16),
            pack(t, g2, a2 & 0xFFFF, a2 >> 16),
            _SAMPLE_AUX.pack(t, angle, temp, valid),
        )

    def split(self) -> tuple[SampleX, SampleY, SampleZ, SampleAux]:
        """The four CAN frames of this tick, in sending order."""
        t = self.counter & 0xFF
        g, a = self.gyro, self.accel
        return (
            SampleX(t, g[0], a[0]),
            SampleY(t, g[1], a[1]),
            SampleZ(t, g[2], a[2]),
            SampleAux(t, self.angle, self.temperature, self.validity),
        )

    @classmethod
    def from_parts(
        cls, counter: int, x: SampleAxis, y: SampleAxis, z: SampleAxis, aux: SampleAux
    ) -> Sample:
        """Join the four CAN frames of one tick, with the full 32-bit ``counter``."""
        return cls(
            counter,
            (x.gyro, y.gyro, z.gyro),
            (x.accel, y.accel, z.accel),
            aux.angle,
            aux.temperature,
            aux.validity,
        )


_new = object.__new__
_SET_COUNTER, _SET_GYRO, _SET_ACCEL, _SET_ANGLE, _SET_TEMPERATURE, _SET_VALIDITY = (
    getattr(Sample, name).__set__
    for name in ("counter", "gyro", "accel", "angle", "temperature", "validity")
)


@dataclass(frozen=True, slots=True)
class SampleAxis:
    """Base of the CAN frames SAMPLE_X, SAMPLE_Y, SAMPLE_Z: ``[u8 tick, i32 gyro, i24 accel]``.

    Attributes
    ----------
    tick : int
        Low 8 bits of the sample counter.
    gyro : int
        Gyro channel of this axis (i32 counts).
    accel : int
        Accelerometer channel of this axis (i24 counts; the device saturates to the i24 range
        and sets ACCEL_SATURATED).
    """

    tick: int
    gyro: int
    accel: int
    AXIS: ClassVar[Axis]

    @property
    def axis(self) -> Axis:
        """Sensor axis of this frame."""
        return self.AXIS

    def encode(self) -> bytes:
        """CAN payload (8 bytes)."""
        _check_u8("tick", self.tick)
        _check("gyro", self.gyro, INT32_MIN, INT32_MAX)
        _check("accel", self.accel, INT24_MIN, INT24_MAX)
        return _SAMPLE_AXIS.pack(self.tick, self.gyro, self.accel & 0xFFFF, self.accel >> 16)

    @classmethod
    def decode(cls, payload: bytes) -> Self:
        """Decode a CAN payload (8 bytes)."""
        _expect_len(cls, payload, 8)
        return cls(*sample_axis_fields(payload))


@dataclass(frozen=True, slots=True)
class SampleX(SampleAxis):
    """CAN SAMPLE_X frame."""

    AXIS: ClassVar[Axis] = Axis.X


@dataclass(frozen=True, slots=True)
class SampleY(SampleAxis):
    """CAN SAMPLE_Y frame."""

    AXIS: ClassVar[Axis] = Axis.Y


@dataclass(frozen=True, slots=True)
class SampleZ(SampleAxis):
    """CAN SAMPLE_Z frame."""

    AXIS: ClassVar[Axis] = Axis.Z


@dataclass(frozen=True, slots=True)
class SampleAux:
    """CAN SAMPLE_AUX frame: ``[u8 tick, u32 angle, i16 temperature, u8 validity]``.

    Attributes
    ----------
    tick : int
        Low 8 bits of the sample counter.
    angle : int
        Table angle (u32, 1e-6 deg).
    temperature : int
        Temperature (i16, 0.01 degC).
    validity : Validity
        Validity bits.
    """

    tick: int
    angle: int
    temperature: int
    validity: Validity

    def encode(self) -> bytes:
        """CAN payload (8 bytes)."""
        _check_u8("tick", self.tick)
        _check_sample_common(self.angle, self.temperature, self.validity)
        return _SAMPLE_AUX.pack(self.tick, self.angle, self.temperature, self.validity)

    @classmethod
    def decode(cls, payload: bytes) -> SampleAux:
        """Decode a CAN payload (8 bytes)."""
        _expect_len(cls, payload, 8)
        tick, angle, temp, valid = sample_aux_fields(payload)
        return cls(tick, angle, temp, validity_of(valid))


# --------------------------------------------------------------------------------------------
# Status / heartbeat
# --------------------------------------------------------------------------------------------

_STATUS_MAIN = struct.Struct("<BIhB")
_STATUS_COUNTERS = struct.Struct("<IHBB")


@dataclass(frozen=True, slots=True)
class Status:
    """Status / heartbeat: the serial STATUS payload (16 bytes); on CAN two frames.

    Attributes
    ----------
    state : DeviceState
        Device state (u8).
    angle : int
        Table angle from the encoder (u32, 1e-6 deg).
    temperature : int
        Sensor temperature (i16, 0.01 degC).
    faults : Fault
        Fault flags (u8).
    sample_counter : int
        Counter of the most recent sample tick (u32).
    rx_malformed : int
        Frames addressed to the device that it could not decode (u16, wrapping).
    tx_dropped : int
        Frames the device could not send (transmit queue full) (u8, wrapping).
    cmd_rejected : int
        Commands answered with a result other than OK (u8, wrapping).
    """

    state: DeviceState
    angle: int
    temperature: int
    faults: Fault
    sample_counter: int
    rx_malformed: int
    tx_dropped: int
    cmd_rejected: int

    SIZE: ClassVar[int] = _STATUS_MAIN.size + _STATUS_COUNTERS.size

    def split(self) -> tuple[StatusMain, StatusCounters]:
        """The two CAN frames, in sending order."""
        return (
            StatusMain(self.state, self.angle, self.temperature, self.faults),
            StatusCounters(
                self.sample_counter, self.rx_malformed, self.tx_dropped, self.cmd_rejected
            ),
        )

    @classmethod
    def from_parts(cls, main: StatusMain, counters: StatusCounters) -> Status:
        """Join the two CAN status frames."""
        return cls(
            main.state,
            main.angle,
            main.temperature,
            main.faults,
            counters.sample_counter,
            counters.rx_malformed,
            counters.tx_dropped,
            counters.cmd_rejected,
        )

    def encode(self) -> bytes:
        """Serial payload: the STATUS frame's 8 bytes then the STATUS_COUNTERS frame's 8 bytes."""
        main, counters = self.split()
        return main.encode() + counters.encode()

    @classmethod
    def decode(cls, payload: bytes) -> Status:
        """Decode a serial STATUS payload (16 bytes)."""
        _expect_len(cls, payload, cls.SIZE)
        return cls.from_parts(StatusMain.decode(payload[:8]), StatusCounters.decode(payload[8:]))


@dataclass(frozen=True, slots=True)
class StatusMain:
    """CAN STATUS frame: ``[u8 state, u32 angle, i16 temperature, u8 faults]``."""

    state: DeviceState
    angle: int
    temperature: int
    faults: Fault

    def encode(self) -> bytes:
        """CAN payload (8 bytes)."""
        _check_u8("state", int(self.state))
        _check("angle", self.angle, 0, UINT32_MAX)
        _check("temperature", self.temperature, -32768, 32767)
        _check_u8("faults", int(self.faults))
        return _STATUS_MAIN.pack(self.state, self.angle, self.temperature, self.faults)

    @classmethod
    def decode(cls, payload: bytes) -> StatusMain:
        """Decode a CAN payload (8 bytes)."""
        _expect_len(cls, payload, 8)
        state, angle, temp, faults = _STATUS_MAIN.unpack(payload)
        return cls(_state(state), angle, temp, Fault(faults))


@dataclass(frozen=True, slots=True)
class StatusCounters:
    """CAN STATUS_COUNTERS frame: ``[u32 sample counter, u16 rx malformed, u8 tx dropped,
    u8 commands rejected]``."""

    sample_counter: int
    rx_malformed: int
    tx_dropped: int
    cmd_rejected: int

    def encode(self) -> bytes:
        """CAN payload (8 bytes)."""
        _check("sample_counter", self.sample_counter, 0, UINT32_MAX)
        _check("rx_malformed", self.rx_malformed, 0, 0xFFFF)
        _check_u8("tx_dropped", self.tx_dropped)
        _check_u8("cmd_rejected", self.cmd_rejected)
        return _STATUS_COUNTERS.pack(
            self.sample_counter, self.rx_malformed, self.tx_dropped, self.cmd_rejected
        )

    @classmethod
    def decode(cls, payload: bytes) -> StatusCounters:
        """Decode a CAN payload (8 bytes)."""
        _expect_len(cls, payload, 8)
        return cls(*_STATUS_COUNTERS.unpack(payload))


# --------------------------------------------------------------------------------------------
# Identify
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Scale:
    """Physical value of one count as ``mantissa * 10**exponent`` (exact for decimal steps).

    Attributes
    ----------
    mantissa : int
        u32.
    exponent : int
        i8.
    """

    mantissa: int
    exponent: int

    @property
    def value(self) -> float:
        """The scale as a float."""
        return self.mantissa * 10.0**self.exponent

    def _check(self, name: str) -> None:
        _check(f"{name}.mantissa", self.mantissa, 0, UINT32_MAX)
        _check(f"{name}.exponent", self.exponent, -128, 127)


IDENTIFY_PAGE_SIZE = 7
"""Bytes of identify data per page (one CAN frame carries one page)."""
IDENTIFY_PAGES = 7
"""Pages in the identify data of protocol version 1."""
MODEL_LEN = 7
"""Longest model name, in printable ASCII characters."""

_PAGE_VERSION = struct.Struct("<BBBBBH")
_PAGE_SERIAL = struct.Struct("<IBH")
_PAGE_SCALE = struct.Struct("<IbH")
_PAGE_HEAD = struct.Struct("<B")


@dataclass(frozen=True, slots=True)
class Identify:
    """Identity of the device: the serial IDENTIFY payload (49 bytes); on CAN seven pages.

    The payload is seven 7-byte pages: 0 versions and the highest sample rate, 1 serial number
    and hardware revision, 2 model name, 3..6 the scale of gyro, accelerometer, angle and
    temperature counts. Reserved bytes are sent as zero and ignored on receipt.

    Attributes
    ----------
    model : str
        Model name, up to 7 printable ASCII characters.
    serial_number : int
        u32.
    hardware_revision : int
        u8.
    firmware_version : tuple of 3 int
        ``(major, minor, patch)``, each u8.
    protocol_version : tuple of 2 int
        ``(major, minor)``, each u8.
    max_sample_rate_hz : int
        Highest sample rate the unit supports (u16).
    gyro_scale : Scale
        deg/h per gyro count.
    accel_scale : Scale
        g per accelerometer count.
    angle_scale : Scale
        deg per angle count.
    temperature_scale : Scale
        degC per temperature count.
    """

    model: str
    serial_number: int
    hardware_revision: int = 0
    firmware_version: tuple[int, int, int] = (0, 0, 0)
    protocol_version: tuple[int, int] = (PROTOCOL_VERSION_MAJOR, PROTOCOL_VERSION_MINOR)
    max_sample_rate_hz: int = 400
    gyro_scale: Scale = Scale(1, -4)
    accel_scale: Scale = Scale(1, -6)
    angle_scale: Scale = Scale(1, -6)
    temperature_scale: Scale = Scale(1, -2)

    SIZE: ClassVar[int] = IDENTIFY_PAGE_SIZE * IDENTIFY_PAGES

    def encode(self) -> bytes:
        """Serial payload: the seven pages back to back (49 bytes)."""
        if (
            not isinstance(self.model, str)
            or len(self.model) > MODEL_LEN
            or not all(" " <= ch <= "~" for ch in self.model)
        ):
            raise EncodeError(f"model={self.model!r} must be <= 7 printable ASCII characters")
        _check("serial_number", self.serial_number, 0, UINT32_MAX)
        _check_u8("hardware_revision", self.hardware_revision)
        if len(self.firmware_version) != 3 or len(self.protocol_version) != 2:
            raise EncodeError("firmware_version needs 3 parts and protocol_version 2")
        for i, v in enumerate((*self.protocol_version, *self.firmware_version)):
            _check_u8(f"version part {i}", v)
        _check("max_sample_rate_hz", self.max_sample_rate_hz, 0, 0xFFFF)
        scales = (self.gyro_scale, self.accel_scale, self.angle_scale, self.temperature_scale)
        for name, s in zip(("gyro", "accel", "angle", "temperature"), scales, strict=True):
            s._check(f"{name}_scale")
        out = [
            _PAGE_VERSION.pack(
                *self.protocol_version, *self.firmware_version, self.max_sample_rate_hz
            ),
            _PAGE_SERIAL.pack(self.serial_number, self.hardware_revision, 0),
            self.model.encode("ascii").ljust(MODEL_LEN, b"\0"),
        ]
        out += [_PAGE_SCALE.pack(s.mantissa, s.exponent, 0) for s in scales]
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> Identify:
        """Decode a serial IDENTIFY payload (49 bytes)."""
        _expect_len(cls, payload, cls.SIZE)
        payload = _as_bytes(payload)
        p = [payload[i : i + IDENTIFY_PAGE_SIZE] for i in range(0, cls.SIZE, IDENTIFY_PAGE_SIZE)]
        pmaj, pmin, fmaj, fmin, fpatch, max_rate = _PAGE_VERSION.unpack(p[0])
        serial, hw, _ = _PAGE_SERIAL.unpack(p[1])
        raw_model = p[2].split(b"\0", 1)[0]
        if not all(0x20 <= b <= 0x7E for b in raw_model):
            raise PayloadError(f"model name {raw_model!r} is not printable ASCII")
        scales = [Scale(m, e) for m, e, _ in (_PAGE_SCALE.unpack(q) for q in p[3:7])]
        return cls(
            raw_model.decode("ascii"),
            serial,
            hw,
            (fmaj, fmin, fpatch),
            (pmaj, pmin),
            max_rate,
            *scales,
        )

    def pages(self) -> list[IdentifyPage]:
        """The CAN IDENTIFY frames, in sending order."""
        data = self.encode()
        last = IDENTIFY_PAGES - 1
        return [
            IdentifyPage(i, last, data[i * IDENTIFY_PAGE_SIZE : (i + 1) * IDENTIFY_PAGE_SIZE])
            for i in range(IDENTIFY_PAGES)
        ]

    @classmethod
    def from_pages(cls, pages: list[IdentifyPage]) -> Identify:
        """Join CAN IDENTIFY pages (any order; exactly one of each index 0..last).

        Raises
        ------
        PayloadError
            Missing, duplicate or inconsistent pages, or a malformed result.
        """
        if not pages:
            raise PayloadError("no identify pages")
        last = pages[0].last
        by_index = {p.index: p for p in pages}
        if any(p.last != last for p in pages) or sorted(by_index) != list(range(last + 1)):
            raise PayloadError("identify pages are incomplete or inconsistent")
        if len(pages) != last + 1:
            raise PayloadError("duplicate identify pages")
        data = b"".join(by_index[i].data for i in range(last + 1))
        # A newer minor version may append pages; version 1 reads the first seven.
        return cls.decode(data[: cls.SIZE])


@dataclass(frozen=True, slots=True)
class IdentifyPage:
    """CAN IDENTIFY frame: ``[u8 index (bits 0-3) | last index (bits 4-7), 7 data bytes]``.

    Attributes
    ----------
    index : int
        Page index, 0..15.
    last : int
        Index of the last page, 0..15 (6 in protocol version 1).
    data : bytes
        Seven bytes of the identify payload.
    """

    index: int
    last: int
    data: bytes

    def encode(self) -> bytes:
        """CAN payload (8 bytes)."""
        _check("index", self.index, 0, 15)
        _check("last", self.last, 0, 15)
        if not isinstance(self.data, bytes | bytearray) or len(self.data) != IDENTIFY_PAGE_SIZE:
            raise EncodeError("identify page data must be 7 bytes")
        return _PAGE_HEAD.pack(self.index | (self.last << 4)) + bytes(self.data)

    @classmethod
    def decode(cls, payload: bytes) -> IdentifyPage:
        """Decode a CAN payload (8 bytes)."""
        _expect_len(cls, payload, 8)
        head = payload[0]
        index, last = head & 0x0F, head >> 4
        if index > last:
            raise PayloadError(f"identify page index {index} beyond last page {last}")
        return cls(index, last, bytes(payload[1:]))


Message = Command | Reply | Sample | Status | Identify
"""A complete message as carried by one serial frame."""
