"""``northfinder simctl ADDRESS OP [KEY=VALUE ...]``: talk to a running simulator's control channel.

Values are read as JSON when they parse (numbers, true/false, lists), else as strings. Examples::

    northfinder simctl 127.0.0.1:7700 status
    northfinder simctl 127.0.0.1:7700 set_truth azimuth_deg=42.5
    northfinder simctl 127.0.0.1:7700 set_sensor 'values={"gyro.arw_dpsh": 0.01}'
    northfinder simctl 127.0.0.1:7700 drop count=5
"""

from __future__ import annotations

import argparse
import json
import textwrap

from northfinder.cli.output import dumps
from northfinder.firmware_sim.control import OPS, ControlClient
from northfinder.host.errors import HostConfigError


def operations_help(width: int = 100) -> str:
    """Every operation with its keys, defaults and bounds, from the table the simulator checks
    requests against (so the help cannot drift from what is accepted)."""
    lines = ["operations and their keys (KEY=DEFAULT: what it takes):"]
    for name in sorted(OPS):
        head, *keys = OPS[name].usage(name)
        lines += textwrap.wrap(head, width, initial_indent="  ", subsequent_indent="      ")
        for key in keys:
            lines += textwrap.wrap(
                key, width, initial_indent="      ", subsequent_indent="        "
            )
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = operations_help()
    p.add_argument("address", help="control address printed by `northfinder sim --control`")
    p.add_argument("op", help="operation (listed below)")
    p.add_argument("args", nargs="*", metavar="KEY=VALUE")


def run(args: argparse.Namespace) -> int:
    kwargs = {}
    for item in args.args:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise HostConfigError(f"argument {item!r}: expected KEY=VALUE")
        try:
            kwargs[key] = json.loads(value)
        except json.JSONDecodeError:
            kwargs[key] = value
    with ControlClient(args.address) as client:
        print(dumps(client.call(args.op, **kwargs)))
    return 0
