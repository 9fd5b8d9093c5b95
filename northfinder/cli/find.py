"""``northfinder find``: find true north with a device, or with the embedded simulator (``--sim``).

With ``--sim`` the simulated instrument runs in this process in virtual time (the same result for
a ``--seed`` whatever the machine's load); a real device needs ``--latitude``. ``--json`` prints the
documented JSON result, ``--nmea TARGET`` sends the heading as NMEA 0183. Exit status 3: the
windows failed their consistency check.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import time

from northfinder import session
from northfinder.cli import measure, report, spinfind
from northfinder.cli.argtypes import baud_rate, positive_float, whole_number
from northfinder.cli.exits import result_status
from northfinder.cli.files import check_output_path
from northfinder.cli.measure import run_config
from northfinder.cli.plots import check_plot_path
from northfinder.config import DEFAULT_PLAN, FindConfig, NmeaConfig, OutputConfig
from northfinder.host.nmea import NMEA_BAUD, HeadingFix, NmeaOutput, hdt_sentence, nfdh_sentence
from northfinder.session import Measured

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


def output_config(args: argparse.Namespace) -> OutputConfig:
    """What ``find`` writes besides its result (``--json``, ``--plot``, ``--record``,
    ``--nmea`` and its options, ``-v``)."""
    nmea = None
    if args.nmea:
        nmea = NmeaConfig(
            args.nmea, rate_hz=args.nmea_rate, count=args.nmea_count, baud=args.nmea_baud,
            max_sigma_deg=args.nmea_max_sigma,
        )  # fmt: skip
    return OutputConfig(
        json=bool(args.json), plot=args.plot, record=args.record, nmea=nmea,
        verbose=getattr(args, "verbose", 0) or 0,
    )  # fmt: skip


def find_config(args: argparse.Namespace) -> FindConfig:
    """The run ``find``'s command line names, parsed once."""
    spinfind.check(args, PLAN_DEFAULTS)
    if args.record:
        check_output_path(args.record, "--record", (".csv", ".npz"))
    if args.plot:
        check_plot_path(args.plot)
    return dataclasses.replace(measure.find_config(args), output=output_config(args))


def send_nmea(nmea: NmeaConfig, m: Measured, out: NmeaOutput) -> int:
    """Send the heading ``nmea.count`` times at ``nmea.rate_hz``; return how many were sent."""
    r = m.result
    fix = HeadingFix(
        r.azimuth_deg, r.sigma_deg, r.pitch_deg, r.roll_deg, len(r.windows), nmea.max_sigma_deg,
        consistent=r.consistent,
    )  # fmt: skip
    return send_fix(nmea, fix, out)


def send_fix(nmea: NmeaConfig, fix: HeadingFix, out: NmeaOutput) -> int:
    """Send ``fix`` ``nmea.count`` times at ``nmea.rate_hz`` (count 0: until interrupted);
    return how many were sent."""
    lines = (hdt_sentence(fix), nfdh_sentence(fix))
    period = 1.0 / nmea.rate_hz
    n = 0
    next_at = time.monotonic()
    while nmea.count == 0 or n < nmea.count:
        out.send(*lines)
        n += 1
        if nmea.count and n >= nmea.count:
            break
        next_at += period
        time.sleep(max(0.0, next_at - time.monotonic()))
    return n


def run(args: argparse.Namespace) -> int:
    config = find_config(args)
    nmea = config.output.nmea
    to_stdout = nmea is not None and nmea.target == "-"
    with contextlib.ExitStack() as stack:
        out = (
            stack.enter_context(NmeaOutput(nmea.target, baudrate=nmea.baud))
            if nmea is not None
            else None
        )
        if config.spin is not None:
            return _find_spin(config, out, to_stdout)
        return _find(config, out, to_stdout)


def _find_spin(config: FindConfig, out: NmeaOutput | None, to_stdout: bool) -> int:
    spun = session.find_spin(config)
    found, identity = spun.found, spun.device
    truth = None if spun.truth is None else spun.truth.as_dict()  # as the JSON states it
    sol = found.solution
    output = config.output
    if output.plot:
        spinfind.plot(output.plot, found, truth)
    text = spinfind.as_json(found, truth, identity) if output.json else spinfind.text(found, truth)
    print(text, file=sys.stderr if to_stdout else sys.stdout, flush=True)
    if out is not None and output.nmea is not None:
        fix = HeadingFix(
            sol.azimuth_deg, sol.sigma_deg, sol.pitch_deg, sol.roll_deg, 1,
            output.nmea.max_sigma_deg, consistent=sol.consistent,
        )  # fmt: skip
        send_fix(output.nmea, fix, out)
    return result_status(sol.consistent)


def _find(config: FindConfig, out: NmeaOutput | None, to_stdout: bool) -> int:
    output = config.output
    m = run_config(config, progress=not (output.json or to_stdout), record_to=output.record)
    truth = None if m.truth is None else m.truth.as_dict()  # as the JSON states it
    if output.plot:
        report.plot(output.plot, m.result, m.windows, m.plan.denoise, truth)
    text = (
        report.as_json("find", m.result, truth, m.device)
        if output.json
        else report.text(m.result, truth)
    )
    print(text, file=sys.stderr if to_stdout else sys.stdout, flush=True)
    if m.errors:  # the heading is out; now what could not be written (exit 1)
        raise m.errors[0]
    if out is not None and output.nmea is not None:
        send_nmea(output.nmea, m, out)
    return result_status(m.result.consistent)
