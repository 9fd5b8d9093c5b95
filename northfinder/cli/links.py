"""The links a command speaks: python-can bus options, ``--serial``, ``--baud``, ``--node-id``,
and opening them.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any

from northfinder.cli.argtypes import (
    baud_rate,
    node_id,
)
from northfinder.cli.parsers import common_group
from northfinder.driver.errors import LinkError
from northfinder.driver.protocol.constants import (
    NODE_ID_DEFAULT,
    NODE_ID_MAX,
    NODE_ID_MIN,
    SERIAL_BAUD_DEFAULT,
)
from northfinder.host.errors import HostConfigError

#: python-can interfaces the commands refuse, and why: their frames leave this machine as network
#: traffic to addresses the user did not name (udp_multicast sends to a multicast group on every
#: interface of the host, not to a bus).
REFUSED_INTERFACES: Mapping[str, str] = {
    "udp_multicast": "it sends every frame as IP multicast off this machine, not onto a CAN bus",
}


def _refuse_interfaces_off_the_machine(parser: argparse.ArgumentParser) -> None:
    """Take the refused interfaces out of ``-i/--interface``'s choices, with a message that says
    why and lists what is accepted."""
    for action in parser._actions:
        if "--interface" not in action.option_strings or not action.choices:
            continue
        accepted = sorted(c for c in action.choices if c not in REFUSED_INTERFACES)

        def interface(text: str, accepted: list[str] = accepted) -> str:
            if text in REFUSED_INTERFACES:
                raise argparse.ArgumentTypeError(
                    f"{text!r} is refused: {REFUSED_INTERFACES[text]}; accepted: {', '.join(accepted)}"
                )
            return text

        action.type = interface
        action.choices = accepted
        action.metavar = "INTERFACE"
        action.help = "python-can interface, e.g. socketcan, slcan, virtual"


#: Shorter help of python-can's bus options, by destination (its own run to 8 lines each).
_BUS_HELP: Mapping[str, str] = {
    "channel": "the bus channel, e.g. vcan0, can0, or /dev/ttyACM0 for SLCAN",
    "timing": "bit timing as KEY=VALUE fields of python-can's BitTiming (see its docs)",
    "bus_kwargs": "KEY=VALUE passed to the python-can bus, e.g. sleep_after_open=0 for SLCAN "
    "on a pseudo-terminal",
}


def _short_bus_help(parser: argparse.ArgumentParser) -> None:
    for action in parser._actions:
        if action.dest in _BUS_HELP:
            action.help = _BUS_HELP[action.dest]


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """python-can's bus options (``-i/-c/-b``, as python-can's own tools spell them), without
    the interfaces that would send off the machine."""
    import can.cli

    can.cli.add_bus_arguments(parser)
    _refuse_interfaces_off_the_machine(parser)
    _short_bus_help(parser)


def add_link_arguments(parser: argparse.ArgumentParser, title: str) -> argparse._ArgumentGroup:
    """The links every command speaks: python-can bus options (``-i/-c/-b``, as python-can's own
    tools spell them), ``--serial PORT``, ``--baud`` and ``--node-id``. Returns the serial group so
    a command can add its own links to it."""
    add_bus_arguments(parser)
    group = common_group(parser, title)
    group.add_argument("--serial", metavar="PORT", help="serial port path or pyserial URL")
    group.add_argument(
        "--baud",
        type=baud_rate,
        default=SERIAL_BAUD_DEFAULT,
        help=f"serial baud rate (default {SERIAL_BAUD_DEFAULT})",
    )
    group.add_argument(
        "--node-id",
        type=node_id,
        default=NODE_ID_DEFAULT,
        help=f"CAN node id {NODE_ID_MIN}..{NODE_ID_MAX} (default {NODE_ID_DEFAULT})",
    )
    return group


def open_can_bus(args: argparse.Namespace) -> Any:
    """The python-can bus of the ``-i/-c/-b`` options.

    Raises
    ------
    HostConfigError
        An interface python-can does not know, or options it refuses (exit status 2).
    LinkError
        The bus exists but cannot be opened (exit status 1).
    """
    import can
    import can.cli

    try:
        return can.cli.create_bus_from_namespace(args)
    except (can.CanError, OSError, argparse.ArgumentError, ValueError, TypeError) as exc:
        # python-can wraps every failure in an argparse.ArgumentError: its cause says which
        # it is, a bus that cannot be opened now (1) or options it refuses (2).
        cause = exc.__cause__ if isinstance(exc, argparse.ArgumentError) and exc.__cause__ else exc
        from northfinder.session import bus_error

        raise bus_error(cause) from exc


def open_serial_option(path: str, baud: int) -> Any:
    """A pyserial port (non-blocking) for the option ``--serial PATH``, its errors naming the
    option (the driver's own is :func:`northfinder.driver.transport.open_serial_port`).

    Raises
    ------
    HostConfigError
        A URL or setting pyserial refuses (exit status 2).
    LinkError
        The port cannot be opened (missing, busy, not a serial device: exit status 1).
    """
    import serial

    try:
        return serial.serial_for_url(path, baudrate=baud, timeout=0)
    except serial.SerialException as exc:
        raise LinkError(f"--serial {path}: cannot open the port: {exc}") from exc
    except ValueError as exc:
        raise HostConfigError(f"--serial {path}: {exc}") from exc


def bus_given(args: argparse.Namespace) -> bool:
    """Whether python-can bus options were given."""
    return any(getattr(args, k, None) is not None for k in ("interface", "channel"))
