"""The wire protocol shared by the driver and the simulated instrument (see ``protocol.md``).

Pure code: no I/O, no clock, no threads. Byte order is little-endian everywhere.

- :mod:`~northfinder.driver.protocol.constants`: codes (states, opcodes, results, config keys), flags
  (validity, faults) and the physical value of one count.
- :mod:`~northfinder.driver.protocol.messages`: one frozen dataclass per message, ``encode() -> bytes`` of
  its payload and a ``decode(payload)`` classmethod.
- :mod:`~northfinder.driver.protocol.can`: CAN 2.0A identifiers, frame mapping and reassembly.
- :mod:`~northfinder.driver.protocol.serial`: serial framing, CRC-16/CCITT-FALSE and the de-framer.
- :mod:`~northfinder.driver.protocol.budget`: link load and which sample rates fit a link.
- :mod:`~northfinder.driver.protocol.counters`: the sample counter across its wrap, the CAN tick extension.
- :mod:`~northfinder.driver.protocol.motion`: the table's move time (trapezoidal profile).
- :mod:`~northfinder.driver.protocol.units`: units and physical constants.
- :mod:`~northfinder.driver.protocol.errors`: :class:`ProtocolError` and its family; the codec raises
  nothing else for any input, and imports nothing outside this package.
"""

from northfinder.driver.protocol import messages as _messages
from northfinder.driver.protocol.constants import (
    PROTOCOL_VERSION_MAJOR,
    PROTOCOL_VERSION_MINOR,
    Axis,
    CanFunction,
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    Opcode,
    Result,
    SelfTestFailure,
    SerialType,
    Validity,
    result_meaning,
)
from northfinder.driver.protocol.messages import *  # noqa: F403 (the messages: their __all__)

__all__ = [
    "PROTOCOL_VERSION_MAJOR",
    "PROTOCOL_VERSION_MINOR",
    "Axis",
    "CanFunction",
    "ConfigKey",
    "DeviceState",
    "Direction",
    "Fault",
    "Opcode",
    "Result",
    "SelfTestFailure",
    "SerialType",
    "Validity",
    "result_meaning",
    *_messages.__all__,
]
