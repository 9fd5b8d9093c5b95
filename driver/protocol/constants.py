"""Codes, flags and scale constants of the wire protocol (see ``protocol.md``).

Every value here is a wire value: changing one changes the protocol.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

PROTOCOL_VERSION_MAJOR = 1
"""Incremented on any incompatible change; a host refuses a device with another major version."""
PROTOCOL_VERSION_MINOR = 1
"""Incremented when messages, opcodes, config keys or result codes are added."""

# Physical value of one count (the defaults; a unit reports its own in IDENTIFY).
GYRO_DPH_PER_COUNT = 1e-4
"""Gyro channel: degrees per hour per count (mean rate over the sample interval)."""
ACCEL_G_PER_COUNT = 1e-6
"""Accelerometer channel: standard gravity per count (mean over the sample interval); the value of
one g in m/s^2 is :data:`northfinder.driver.protocol.units.G0`."""
ANGLE_DEG_PER_COUNT = 1e-6
"""Table angle: degrees per count (u32 in [0, 360) for absolute, i32 for signed deltas)."""
TEMPERATURE_DEGC_PER_COUNT = 1e-2
"""Temperature: degrees Celsius per count (i16)."""
TEMPERATURE_NOT_AVAILABLE = -32768
"""Temperature value sent when the sensor has no valid reading."""

ANGLE_FULL_TURN = 360_000_000
"""Counts in one turn; absolute angles lie in ``[0, ANGLE_FULL_TURN)``."""
ROTATE_BY_LIMIT = 720_000_000
"""Largest accepted ``|delta|`` of ROTATE_BY in counts (720 deg); larger is OUT_OF_RANGE."""

INT24_MIN = -(1 << 23)
INT24_MAX = (1 << 23) - 1
INT32_MIN = -(1 << 31)
INT32_MAX = (1 << 31) - 1
UINT32_MAX = (1 << 32) - 1

NODE_ID_MIN = 1
NODE_ID_MAX = 15
NODE_ID_DEFAULT = 1

CAN_BITRATE_DEFAULT = 500_000
"""Default CAN bit rate in bit/s."""
CAN_BITRATES = (125_000, 250_000, 500_000, 1_000_000)
"""CAN bit rates a device supports (bit/s)."""
SERIAL_BAUD_DEFAULT = 115_200
"""Default serial baud rate (8N1)."""
SERIAL_BAUDS = (38_400, 57_600, 115_200, 230_400, 460_800, 921_600)
"""Serial baud rates a device supports (8N1)."""

SAMPLE_RATES_HZ = (50, 100, 200, 400)
"""Allowed values of the SAMPLE_RATE_HZ configuration key."""
SAMPLE_RATE_DEFAULT_HZ = 200
HEARTBEAT_PERIOD_DEFAULT_MS = 100
REPLY_DEADLINE_MS = 20
"""The device sends the reply to a command within this time of receiving it."""


class DeviceState(IntEnum):
    """Device state, sent in STATUS (u8)."""

    BOOT = 0
    WARMUP = 1
    READY = 2
    ROTATING = 3
    SETTLING = 4
    FAULT = 5
    SPINNING = 6
    """Version 1.1: the table turns at the rate SPIN commanded, held steady (until STOP)."""


class Opcode(IntEnum):
    """Command opcode (u8), echoed in the reply."""

    IDENTIFY = 0x01
    GET_STATUS = 0x02
    ROTATE_TO = 0x10
    ROTATE_BY = 0x11
    STOP = 0x12
    HOME = 0x13
    SPIN = 0x14
    """Version 1.1: turn the table at a constant rate until STOP."""
    STREAM_START = 0x20
    STREAM_STOP = 0x21
    GET_CONFIG = 0x30
    SET_CONFIG = 0x31
    RESET = 0x40
    SELF_TEST = 0x41


class Result(IntEnum):
    """Result code of a reply (u8). :attr:`meaning` gives a one-line explanation."""

    OK = 0
    BUSY = 1
    NOT_READY = 2
    OUT_OF_RANGE = 3
    UNKNOWN_COMMAND = 4
    BAD_ARGUMENT = 5
    RATE_EXCEEDS_LINK = 6
    FAULT = 7
    READ_ONLY = 8
    UNKNOWN_KEY = 9

    @property
    def meaning(self) -> str:
        """One-line meaning of the code, suitable for an exception message."""
        return _RESULT_MEANINGS[self]


_RESULT_MEANINGS: dict[Result, str] = {
    Result.OK: "command accepted and carried out (or started)",
    Result.BUSY: "the table is rotating or settling; wait for READY or send STOP",
    Result.NOT_READY: "the device is booting or warming up; wait for READY",
    Result.OUT_OF_RANGE: "an argument is outside its allowed range",
    Result.UNKNOWN_COMMAND: "the opcode is not defined by this protocol version",
    Result.BAD_ARGUMENT: "the command has the wrong length or a malformed argument",
    Result.RATE_EXCEEDS_LINK: "the requested data rate does not fit the link; nothing was changed",
    Result.FAULT: "the device is in FAULT; only RESET, SELF_TEST, queries and streaming are allowed",
    Result.READ_ONLY: "the configuration key is read-only",
    Result.UNKNOWN_KEY: "the configuration key is not defined by this protocol version",
}


def result_meaning(code: int) -> str:
    """One-line meaning of a result code, also for codes this version does not define.

    Parameters
    ----------
    code : int
        Result byte from a reply.

    Returns
    -------
    str
        The meaning, or ``"undefined result code N"``.
    """
    try:
        return Result(code).meaning
    except ValueError:
        return f"undefined result code {code}"


class Direction(IntEnum):
    """Direction argument of ROTATE_TO (u8)."""

    SHORTEST = 0
    POSITIVE = 1
    """Increasing angle: counter-clockwise seen from above (right-handed about up)."""
    NEGATIVE = 2


class ConfigKey(IntEnum):
    """Configuration key (u8); every value is a u32. Keys 0x10 and above are read-only."""

    SAMPLE_RATE_HZ = 0x01
    HEARTBEAT_PERIOD_MS = 0x02
    TABLE_MAX_RATE_MDPS = 0x03
    """Table speed limit in 1e-3 deg/s."""
    TABLE_MAX_ACCEL_MDPS2 = 0x04
    """Table acceleration limit in 1e-3 deg/s^2."""
    SETTLE_TIME_MS = 0x05
    STREAMING = 0x06
    LINK_BITRATE = 0x10
    """CAN bit rate in bit/s, or serial baud rate."""
    NODE_ID = 0x11
    LINK_MAX_SAMPLE_RATE_HZ = 0x12
    """Highest allowed sample rate that fits the link with the current heartbeat period."""

    @property
    def read_only(self) -> bool:
        """True for keys that SET_CONFIG refuses with READ_ONLY."""
        return self.value >= 0x10


CONFIG_LIMITS: dict[ConfigKey, tuple[int, int]] = {
    ConfigKey.SAMPLE_RATE_HZ: (min(SAMPLE_RATES_HZ), max(SAMPLE_RATES_HZ)),
    ConfigKey.HEARTBEAT_PERIOD_MS: (10, 5000),
    ConfigKey.TABLE_MAX_RATE_MDPS: (1, 50_000),
    ConfigKey.TABLE_MAX_ACCEL_MDPS2: (1, 200_000),
    ConfigKey.SETTLE_TIME_MS: (0, 60_000),
    ConfigKey.STREAMING: (0, 1),
}
"""Inclusive range of each writable key; SET_CONFIG outside it is OUT_OF_RANGE.

SAMPLE_RATE_HZ must also be one of :data:`SAMPLE_RATES_HZ`.
"""

CONFIG_DEFAULTS: dict[ConfigKey, int] = {
    ConfigKey.SAMPLE_RATE_HZ: SAMPLE_RATE_DEFAULT_HZ,
    ConfigKey.HEARTBEAT_PERIOD_MS: HEARTBEAT_PERIOD_DEFAULT_MS,
    ConfigKey.TABLE_MAX_RATE_MDPS: 6_000,
    ConfigKey.TABLE_MAX_ACCEL_MDPS2: 10_000,
    ConfigKey.SETTLE_TIME_MS: 1_000,
    ConfigKey.STREAMING: 0,
}
"""Value of each writable key after boot (configuration is not kept across RESET)."""


class Validity(IntFlag):
    """Validity bits of a sample (u8)."""

    GYRO_VALID = 0x01
    ACCEL_VALID = 0x02
    TABLE_MOVING = 0x04
    TABLE_SETTLING = 0x08
    GYRO_SATURATED = 0x10
    ACCEL_SATURATED = 0x20
    WARMING_UP = 0x40
    FAULT = 0x80


VALIDITY_GOOD = Validity.GYRO_VALID | Validity.ACCEL_VALID
"""Bits a sample fit for north finding has set: both channels valid."""
VALIDITY_UNFIT = (
    Validity.TABLE_MOVING
    | Validity.TABLE_SETTLING
    | Validity.GYRO_SATURATED
    | Validity.ACCEL_SATURATED
    | Validity.WARMING_UP
    | Validity.FAULT
)
"""Bits 2..7: any of them set makes a sample unfit for north finding (protocol.md 4.5)."""
VALIDITY_STEADY_RATE = Validity.TABLE_MOVING | Validity.TABLE_SETTLING
"""Version 1.1: both motion bits set (a pair version 1.0 never sends) mark a sample taken while
the table turns at the steady rate of SPIN (state SPINNING); fit for a spin solution when the
other unfit bits (4..7) are clear (protocol.md 4.5)."""
VALIDITY_SPIN_UNFIT = (
    Validity.GYRO_SATURATED | Validity.ACCEL_SATURATED | Validity.WARMING_UP | Validity.FAULT
)
"""Bits 4..7: any of them makes a steady-rate sample unfit for a spin solution."""
SPIN_RATE_MDPS_MIN = 1
"""Smallest ``|rate|`` SPIN accepts, 1e-3 deg/s; the largest is TABLE_MAX_RATE_MDPS."""


class Fault(IntFlag):
    """Fault flags in STATUS (u8); any set flag puts the device in FAULT."""

    GYRO = 0x01
    ACCEL = 0x02
    ENCODER = 0x04
    DRIVE = 0x08
    OVER_TEMPERATURE = 0x10
    SELF_TEST = 0x20
    SUPPLY = 0x40
    INTERNAL = 0x80


class SelfTestFailure(IntFlag):
    """Failure mask (u16) in the reply to SELF_TEST; zero means passed."""

    GYRO_X = 0x0001
    GYRO_Y = 0x0002
    GYRO_Z = 0x0004
    ACCEL_X = 0x0008
    ACCEL_Y = 0x0010
    ACCEL_Z = 0x0020
    ENCODER = 0x0040
    TEMPERATURE_SENSOR = 0x0080
    DRIVE = 0x0100
    MEMORY = 0x0200


class SerialType(IntEnum):
    """Message type byte of a serial frame."""

    COMMAND = 0x01
    REPLY = 0x02
    STATUS = 0x03
    IDENTIFY = 0x04
    SAMPLE = 0x05


class CanFunction(IntEnum):
    """CAN identifier base of each message; identifier = base + node id (1..15).

    Lower identifiers win arbitration: commands (STOP must get through), replies, the sample
    stream in X, Y, Z, AUX order, status, then identify.
    """

    COMMAND = 0x040
    REPLY = 0x050
    SAMPLE_X = 0x100
    SAMPLE_Y = 0x110
    SAMPLE_Z = 0x120
    SAMPLE_AUX = 0x130
    STATUS = 0x200
    STATUS_COUNTERS = 0x210
    IDENTIFY = 0x300


class Axis(IntEnum):
    """Sensor axis of a CAN sample frame (body frame: x reference, y left, z up)."""

    X = 0
    Y = 1
    Z = 2
