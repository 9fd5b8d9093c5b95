"""Exceptions of the wire codec, and the root of every error of the driver package.

The codec (:mod:`northfinder.driver.protocol`) imports nothing outside itself, so that the simulated
firmware can use it alone. Its errors therefore live here, and so does the root they derive from:

- :class:`DriverError`: root of every error raised by ``northfinder.driver`` (codec, transports,
  :class:`~northfinder.driver.device.Device`, conformance suite). It is defined in this module only
  because the codec must be self-contained; callers import it from :mod:`northfinder.driver.errors`,
  which re-exports everything below beside the device's errors.
- :class:`ArgumentError`: a value handed to the driver is outside its domain (also a ``ValueError``).
- :class:`ProtocolError`: bytes or a CAN frame do not form a valid message; the codec raises nothing
  else for any input it is given. Its subclasses: :class:`EncodeError`, :class:`FrameError` /
  :class:`CrcError`, :class:`UnknownMessageError`, :class:`PayloadError` /
  :class:`BadCommandError`.

So a caller of the driver catches everything with ``except DriverError``, and the simulator catches
what the wire brings with ``except ProtocolError``.
"""

from __future__ import annotations

__all__ = [
    "ArgumentError",
    "BadCommandError",
    "CrcError",
    "DriverError",
    "EncodeError",
    "FrameError",
    "PayloadError",
    "ProtocolError",
    "UnknownMessageError",
]


class DriverError(Exception):
    """Root of every error raised by ``northfinder.driver``."""


class ArgumentError(DriverError, ValueError):
    """A value handed to the driver is outside its domain (the message names it and the choices)."""


class ProtocolError(DriverError):
    """Bytes or a CAN frame do not form a valid message of the wire protocol."""


class EncodeError(ProtocolError, ValueError):
    """A message field is outside the range its wire encoding can carry (the message names it)."""


class FrameError(ProtocolError):
    """A serial frame is structurally wrong: missing sync, bad length field or truncated."""


class CrcError(FrameError):
    """A serial frame's CRC-16 does not match its contents.

    Parameters
    ----------
    message : str
        Human-readable description.
    expected : int
        CRC computed over the received bytes.
    received : int
        CRC carried by the frame.
    """

    def __init__(self, message: str, expected: int, received: int) -> None:
        super().__init__(message)
        self.expected = expected
        self.received = received


class UnknownMessageError(ProtocolError):
    """A CAN identifier or serial message type that the protocol does not define."""


class PayloadError(ProtocolError):
    """A payload has the wrong length for its message, or a field holds an undefined value."""


class BadCommandError(PayloadError):
    """A command payload that the device must refuse, with what it needs to reply.

    The device echoes ``seq`` and ``opcode`` in a reply carrying ``result``
    (``UNKNOWN_COMMAND`` or ``BAD_ARGUMENT``).

    Parameters
    ----------
    message : str
        Human-readable description.
    seq : int
        Request sequence number of the refused command (0..255).
    opcode : int
        Opcode byte of the refused command (0..255).
    result : int
        The :class:`northfinder.driver.protocol.constants.Result` code the device replies with.
    """

    def __init__(self, message: str, seq: int, opcode: int, result: int) -> None:
        super().__init__(message)
        self.seq = seq
        self.opcode = opcode
        self.result = result
