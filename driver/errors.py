"""Exceptions of the driver package: what a caller of :mod:`northfinder.driver` catches.

Every error raised by the driver derives from :class:`DriverError`. The wire codec's errors
(:class:`ProtocolError` and its subclasses) and :class:`ArgumentError` are defined in
:mod:`northfinder.driver.protocol.errors`, beside the self-contained codec, and re-exported here;
the device's errors follow. The tree::

    DriverError
    ├── ArgumentError (ValueError)          a value outside its domain; names the choices
    ├── ProtocolError                       not a valid message (the codec raises nothing else)
    │   ├── EncodeError (ValueError), FrameError ── CrcError, UnknownMessageError,
    │   └── PayloadError ── BadCommandError
    ├── DeviceRefused                       the device answered a result other than OK
    ├── DriverTimeout (TimeoutError) ── ReplyTimeout, MoveTimeout, StreamTimeout
    ├── LinkError ── LinkLost
    ├── StreamGap, DeviceReset, DeviceFault
    ├── EmptyWindow (ValueError)            nothing to average in a window
    └── ConformanceError                    the conformance suite (northfinder.driver.conformance.errors)
"""

from northfinder.driver.protocol.errors import (
    ArgumentError,
    BadCommandError,
    CrcError,
    DriverError,
    EncodeError,
    FrameError,
    PayloadError,
    ProtocolError,
    UnknownMessageError,
)

__all__ = [
    "ArgumentError",
    "BadCommandError",
    "CrcError",
    "DeviceFault",
    "DeviceRefused",
    "DeviceReset",
    "DriverError",
    "DriverTimeout",
    "EmptyWindow",
    "EncodeError",
    "FrameError",
    "LinkError",
    "LinkLost",
    "MoveTimeout",
    "NodeConflict",
    "PayloadError",
    "ProtocolError",
    "ReplyTimeout",
    "StreamGap",
    "StreamTimeout",
    "UnknownMessageError",
]


# --------------------------------------------------------------------------------------------
# Errors of the device driver (northfinder.driver.device): what a caller of Device sees
# --------------------------------------------------------------------------------------------


class DeviceRefused(DriverError):
    """The device answered a command with a result other than OK.

    Parameters
    ----------
    opcode : int
        Opcode of the refused command (a :class:`~northfinder.driver.protocol.constants.Opcode` value).
    result : int
        The result code of the reply (a :class:`~northfinder.driver.protocol.constants.Result` value, or an
        undefined one from a newer minor version).
    meaning : str
        One-line meaning of the code (protocol.md table 4.2).
    """

    def __init__(self, opcode: int, result: int, meaning: str) -> None:
        self.opcode = opcode
        self.result = result
        self.meaning = meaning
        op = getattr(opcode, "name", f"opcode 0x{int(opcode):02X}")
        res = getattr(result, "name", f"result {int(result)}")
        super().__init__(f"the device refused {op}: {res} ({int(result)}): {meaning}")


class DriverTimeout(DriverError, TimeoutError):
    """Something the device should have done did not happen by a deadline.

    Parameters
    ----------
    message : str
        What was awaited and what the caller can do.
    deadline_s : float
        The time allowed, in seconds (wall clock) from the start of the call.
    """

    def __init__(self, message: str, deadline_s: float) -> None:
        super().__init__(message)
        self.deadline_s = deadline_s


class ReplyTimeout(DriverTimeout):
    """No reply to a command within its deadline (all attempts included).

    Attributes
    ----------
    opcode : int
        Opcode of the command.
    attempts : int
        How many times it was sent (more than one only for commands safe to repeat).
    link_alive : bool
        True if the device's heartbeat still arrived: the command or its reply was lost, or the
        device is stuck; False if the device or the link is silent altogether.
    """

    def __init__(
        self, message: str, deadline_s: float, opcode: int, attempts: int, link_alive: bool
    ) -> None:
        super().__init__(message, deadline_s)
        self.opcode = opcode
        self.attempts = attempts
        self.link_alive = link_alive


class MoveTimeout(DriverTimeout):
    """The table did not come to rest (state READY) within the move's deadline."""


class StreamTimeout(DriverTimeout):
    """Samples stopped arriving although the device's heartbeat still arrives.

    Typically the stream was switched off behind the driver's back (another host, a
    configuration change); the window is incomplete and is not returned.
    """


class LinkError(DriverError):
    """The bus or port could not be opened or used."""


class LinkLost(LinkError):
    """The link failed while in use: the bus or port reported an error or went away, or the device's
    heartbeat stopped (no status for three heartbeat periods, protocol.md section 6)."""


class StreamGap(DriverError):
    """Sample ticks are missing from a window requested with ``on_gap="raise"``.

    Attributes
    ----------
    gaps : tuple of (int, int)
        ``(first_counter, count)`` of each run of missing ticks found so far.
    missing : int
        Total ticks missing so far.
    received : int
        Samples received in the window before the error.
    """

    def __init__(
        self, message: str, gaps: tuple[tuple[int, int], ...], missing: int, received: int
    ) -> None:
        super().__init__(message)
        self.gaps = gaps
        self.missing = missing
        self.received = received


class DeviceReset(DriverError):
    """The device restarted (BOOT status, an unrequested IDENTIFY, or its sample counter went back)
    while the driver was waiting for it; its configuration and counters are back to defaults."""


class AnotherHost(DriverError):
    """Another host on the bus commanded this unit (its COMMAND frames were seen) in a way that
    broke what this host was doing: STREAM_STOP during a window, STOP or a move during a move,
    a configuration change. protocol.md 13 says what the protocol can and cannot do about it."""


class NodeConflict(DriverError):
    """Another unit answers as this node on the bus: two replies came to one command of this
    host (not another host's). Two units with one node id interleave their statuses, streams and
    replies: nothing measured on the bus can be trusted until each has its own node id."""


class DeviceFault(DriverError):
    """The device entered FAULT while the driver was waiting for it.

    Attributes
    ----------
    faults : int
        The fault flags of its status (a :class:`~northfinder.driver.protocol.constants.Fault` value).
    """

    def __init__(self, message: str, faults: int) -> None:
        super().__init__(message)
        self.faults = faults


class EmptyWindow(DriverError, ValueError):
    """A window holds no sample to average (none received, or none valid)."""
