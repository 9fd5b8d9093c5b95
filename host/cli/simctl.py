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

from northfinder.firmware_sim.control import ControlClient
from northfinder.host.errors import HostConfigError


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "simctl",
        help="control a running simulator",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("address", help="control address printed by `northfinder sim --control`")
    p.add_argument(
        "op",
        help="operation, e.g. status, set_truth, drop, silent, reset (`status` lists none; a bad op lists all)",
    )
    p.add_argument("args", nargs="*", metavar="KEY=VALUE")
    return p


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
        print(json.dumps(client.call(args.op, **kwargs), indent=2))
    return 0
