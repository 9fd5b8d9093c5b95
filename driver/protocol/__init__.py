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

from northfinder.driver.protocol.constants import (
    PROTOCOL_VERSION_MAJOR,
    PROTOCOL_VERSION_MINOR,
    VALIDITY_STEADY_RATE,
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
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    GetStatus,
    Home,
    Identify,
    IdentifyPage,
    Message,
    Reply,
    RequestIdentify,
    Reset,
    RotateBy,
    RotateTo,
    Sample,
    SampleAux,
    SampleAxis,
    SampleX,
    SampleY,
    SampleZ,
    Scale,
    SelfTest,
    SetConfig,
    Spin,
    Status,
    StatusCounters,
    StatusMain,
    Stop,
    StreamStart,
    StreamStop,
)

__all__ = [
    "PROTOCOL_VERSION_MAJOR",
    "PROTOCOL_VERSION_MINOR",
    "VALIDITY_STEADY_RATE",
    "Axis",
    "CanFunction",
    "Command",
    "ConfigKey",
    "DeviceState",
    "Direction",
    "Fault",
    "GetConfig",
    "GetStatus",
    "Home",
    "Identify",
    "IdentifyPage",
    "Message",
    "Opcode",
    "Reply",
    "RequestIdentify",
    "Reset",
    "Result",
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
    "SelfTestFailure",
    "SerialType",
    "SetConfig",
    "Spin",
    "Status",
    "StatusCounters",
    "StatusMain",
    "Stop",
    "StreamStart",
    "StreamStop",
    "Validity",
    "result_meaning",
]
