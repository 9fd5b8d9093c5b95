"""``northfinder find``: find true north with a device, or with the embedded simulator (``--sim``).

Device links: python-can bus options as python-can's own tools spell them (``-i socketcan -c vcan0``),
or ``--serial PORT``. With ``--sim`` an in-process simulated instrument on python-can's ``virtual``
bus runs accelerated (``--speed``), and its truth is printed beside the result.

The plan: ``--positions`` any table angles (default 0,180), ``--window`` seconds per position,
``--settle`` extra seconds after the device reports READY, ``--denoise`` a method of northfinder.host.denoise,
``--method`` the solver. A progress line shows on a terminal; ``--json`` prints a machine-readable
result; ``--plot FILE`` draws the windows and per-pair azimuths (needs matplotlib).
"""

from __future__ import annotations

import argparse

from northfinder.host.cli import report
from northfinder.host.cli.common import check_output_path
from northfinder.host.cli.measure import add_arguments, run_plan, save_recording


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "find",
        help="find true north",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(p)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument(
        "--plot", metavar="FILE", help="plot the windows and per-pair azimuths (needs matplotlib)"
    )
    p.add_argument("--record", metavar="FILE", help="also write the raw windows (.csv or .npz)")
    return p


def run(args: argparse.Namespace) -> int:
    if args.record:
        check_output_path(args.record, "--record", (".csv", ".npz"))
    if args.plot:
        check_output_path(args.plot, "--plot")
        report.require_matplotlib()
    m = run_plan(args)
    if args.record:
        save_recording(args.record, m)
    if args.plot:
        report.plot(args.plot, m.result, m.windows, m.plan.denoise)
    print(report.as_json(m.result, m.truth) if args.json else report.text(m.result, m.truth))
    return 0
