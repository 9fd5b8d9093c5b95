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
- :mod:`~northfinder.driver.protocol.heat`: the heat the table's drive puts into the unit (moves, spins).
- :mod:`~northfinder.driver.protocol.units`: units and physical constants.
- :mod:`~northfinder.driver.protocol.errors`: :class:`ProtocolError` and its family; the codec raises
  nothing else for any input, and imports nothing outside this package.
- :func:`dbc_path`: the protocol's CAN database (``protocol.dbc``) for cantools and CAN tools,
  installed with the package.
"""

from importlib import resources as _resources
from importlib.resources.abc import Traversable as _Traversable

from northfinder.driver.protocol import messages as _messages
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
from northfinder.driver.protocol.messages import *  # noqa: F403 (the messages: their __all__)

__all__ = [
    "DBC_NODE",
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
    "VALIDITY_STEADY_RATE",
    "Validity",
    "dbc_path",
    "result_meaning",
    *_messages.__all__,
]

#: The node whose identifiers the DBC's messages carry (the low four bits of an id are the node:
#: another node's frame decodes as node 1's message of the same function).
DBC_NODE = 1


def dbc_path() -> _Traversable:
    """``protocol.dbc``, the protocol's CAN database, as installed with this package (a copy of
    the repository's ``protocol.dbc``); ``cantools.database.load_file(str(dbc_path()))`` loads
    it. Use :func:`importlib.resources.as_file` where a file system path is required."""
    return _resources.files(__name__).joinpath("protocol.dbc")
