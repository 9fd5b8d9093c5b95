"""``northfinder reset``: restart a unit (RESET), e.g. to clear FAULT, and report its state.

Links as for ``find``: python-can bus options (``-i socketcan -c vcan0``) or ``--serial PORT``.
The unit goes back to its configuration defaults, stops its stream and restarts; the command
waits until it has left BOOT and prints the state and faults it then reports (WARMUP or READY
when the fault is gone). Exit status 0 when the unit reports no fault afterwards, 1 when it
still does (or does not come back), 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import contextlib

from northfinder.cli.argtypes import bounded_float
from northfinder.cli.links import add_link_arguments, bus_given, open_can_bus
from northfinder.driver.device import Device
from northfinder.driver.errors import DeviceFault
from northfinder.driver.protocol.constants import DeviceState
from northfinder.host.errors import HostConfigError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--timeout",
        type=bounded_float(0.1, 60.0, "s"),
        default=3.0,
        metavar="SECONDS",
        help="longest wait for the unit to leave BOOT (default 3; the protocol allows 1)",
    )
    add_link_arguments(p, "link")


def run(args: argparse.Namespace) -> int:
    if sum((bus_given(args), bool(args.serial))) != 1:
        raise HostConfigError("choose exactly one device: -i/-c (python-can) or --serial PORT")
    with contextlib.ExitStack() as stack:
        if args.serial:
            device = Device.open_serial(args.serial, baudrate=args.baud)
        else:
            device = Device.from_bus(open_can_bus(args), node_id=args.node_id, own_bus=True)
        stack.enter_context(device)
        before = device.status()
        after = device.reset(timeout=args.timeout)
        assert after is not None
        was = before.state.name + (f" ({before.faults!r})" if before.faults else "")
        now = after.state.name + (f" ({after.faults!r})" if after.faults else "")
        print(f"reset: the unit was {was}; it now reads {now}")
        if after.state == DeviceState.FAULT:
            raise DeviceFault(
                f"the unit is still in FAULT after RESET ({after.faults!r}): the fault persists",
                int(after.faults),
            )
    return 0
