"""``northfinder find``: find true north with a device, or with the embedded simulator (``--sim``).

With ``--sim`` the simulated instrument runs in this process in virtual time (the same result for
a ``--seed`` whatever the machine's load); a real device needs ``--latitude``. ``--json`` prints the
documented JSON result, ``--nmea TARGET`` sends the heading as NMEA 0183. Exit status 3: the
windows failed their consistency check.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time

from northfinder.cli import measure, report, spinfind
from northfinder.cli.argtypes import baud_rate, positive_float, whole_number
from northfinder.cli.exits import result_status
from northfinder.cli.files import check_output_path
from northfinder.cli.measure import Measured, run_plan
from northfinder.cli.plots import check_plot_path
from northfinder.config import DEFAULT_PLAN
from northfinder.host.nmea import NMEA_BAUD, HeadingFix, NmeaOutput, hdt_sentence, nfdh_sentence

#: The stop-and-go plan options and their defaults (refused with ``--spin`` when changed).
PLAN_DEFAULTS = {
    "positions": list(DEFAULT_PLAN.positions_deg), "window": DEFAULT_PLAN.window_s,
    "settle": DEFAULT_PLAN.settle_s, "denoise": DEFAULT_PLAN.denoise,
    "solver": DEFAULT_PLAN.method,
}  # fmt: skip


def _count(text: str) -> int:
    value = whole_number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    measure.add_arguments(p)
    spinfind.add_arguments(p)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument(
        "--plot", metavar="FILE", help="plot the windows, or the spin's fit (matplotlib)"
    )
    p.add_argument("--record", metavar="FILE", help="also write the raw windows (.csv or .npz)")
    g = p.add_argument_group("NMEA 0183 output")
    g.add_argument(
        "--nmea",
        metavar="TARGET",
        help="-, a file, a port, udp://HOST:PORT or tcp://HOST:PORT",
    )
    g.add_argument(
        "--nmea-rate", type=positive_float, default=1.0, metavar="HZ",
        help="sentences per second (default 1)",
    )  # fmt: skip
    g.add_argument(
        "--nmea-count", type=_count, default=1, metavar="N",
        help="times to send (default 1; 0: until interrupted)",
    )  # fmt: skip
    g.add_argument(
        "--nmea-baud", type=baud_rate, default=NMEA_BAUD,
        help=f"baud rate of a serial TARGET (default {NMEA_BAUD})",
    )  # fmt: skip
    g.add_argument(
        "--nmea-max-sigma", type=positive_float, default=1.0, metavar="DEG",
        help="not valid (V) above this 1-sigma (default 1 deg)",
    )  # fmt: skip


def send_nmea(args: argparse.Namespace, m: Measured, out: NmeaOutput) -> int:
    """Send the heading ``--nmea-count`` times at ``--nmea-rate``; return how many were sent."""
    r = m.result
    fix = HeadingFix(
        r.azimuth_deg, r.sigma_deg, r.pitch_deg, r.roll_deg, len(r.windows), args.nmea_max_sigma,
        consistent=r.consistent,
    )  # fmt: skip
    return send_fix(args, fix, out)


def send_fix(args: argparse.Namespace, fix: HeadingFix, out: NmeaOutput) -> int:
    """Send ``fix`` ``--nmea-count`` times at ``--nmea-rate``; return how many were sent."""
    lines = (hdt_sentence(fix), nfdh_sentence(fix))
    period = 1.0 / args.nmea_rate
    n = 0
    next_at = time.monotonic()
    while args.nmea_count == 0 or n < args.nmea_count:
        out.send(*lines)
        n += 1
        if args.nmea_count and n >= args.nmea_count:
            break
        next_at += period
        time.sleep(max(0.0, next_at - time.monotonic()))
    return n


def run(args: argparse.Namespace) -> int:
    spinfind.check(args, PLAN_DEFAULTS)
    if args.record:
        check_output_path(args.record, "--record", (".csv", ".npz"))
    if args.plot:
        check_plot_path(args.plot)
    to_stdout = args.nmea == "-"
    with contextlib.ExitStack() as stack:
        nmea = (
            stack.enter_context(NmeaOutput(args.nmea, baudrate=args.nmea_baud))
            if args.nmea
            else None
        )
        if args.spin is not None:
            return _find_spin(args, nmea, to_stdout)
        return _find(args, nmea, to_stdout)


def _find_spin(args: argparse.Namespace, nmea: NmeaOutput | None, to_stdout: bool) -> int:
    found, truth, identity = spinfind.run(args)
    sol = found.solution
    if args.plot:
        spinfind.plot(args.plot, found, truth)
    out = spinfind.as_json(found, truth, identity) if args.json else spinfind.text(found, truth)
    print(out, file=sys.stderr if to_stdout else sys.stdout, flush=True)
    if nmea is not None:
        fix = HeadingFix(
            sol.azimuth_deg, sol.sigma_deg, sol.pitch_deg, sol.roll_deg, 1, args.nmea_max_sigma,
            consistent=sol.consistent,
        )  # fmt: skip
        send_fix(args, fix, nmea)
    return result_status(sol.consistent)


def _find(args: argparse.Namespace, nmea: NmeaOutput | None, to_stdout: bool) -> int:
    m = run_plan(args, progress=not (args.json or to_stdout), record_to=args.record)
    if args.plot:
        report.plot(args.plot, m.result, m.windows, m.plan.denoise, m.truth)
    text = (
        report.as_json("find", m.result, m.truth, m.device)
        if args.json
        else report.text(m.result, m.truth)
    )
    print(text, file=sys.stderr if to_stdout else sys.stdout, flush=True)
    if m.errors:  # the heading is out; now what could not be written (exit 1)
        raise m.errors[0]
    if nmea is not None:
        send_nmea(args, m, nmea)
    return result_status(m.result.consistent)
