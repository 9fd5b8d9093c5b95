"""Exceptions of the driver package.

Every error raised by :mod:`driver` derives from :class:`DriverError`. Errors about bytes on the
wire derive from :class:`ProtocolError`; the codec in :mod:`driver.protocol` raises nothing else
for any input it is given.
"""


class DriverError(Exception):
    """Root of every error raised by :mod:`driver`."""


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
        The :class:`driver.protocol.constants.Result` code the device replies with.
    """

    def __init__(self, message: str, seq: int, opcode: int, result: int) -> None:
        super().__init__(message)
        self.seq = seq
        self.opcode = opcode
        self.result = result
