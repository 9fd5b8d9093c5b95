"""``northfinder calibrate RECORDING...``: the sensor terms of an instrument from its recordings.

Allan deviation and an IEEE 952 fit from static windows, the between-position terms from windows
with table moves between them; the result is a sensor TOML file that ``--sensor FILE`` takes.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path
from typing import Any

from northfinder.cli.argtypes import bounded_float
from northfinder.cli.files import check_output_path
from northfinder.cli.logprogress import LogProgress
from northfinder.cli.output import dumps, say
from northfinder.cli.plots import check_plot_path
from northfinder.cli.progress import Progress
from northfinder.cli.simulated import load_sensor
from northfinder.firmware_sim.sensors import spec_from_dict
from northfinder.host.calibrate import DESIGNS, calibrate, read_runs
from northfinder.host.calibrate.readers import READERS
from northfinder.host.errors import QualityError
from northfinder.host.results import envelope


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "recordings", nargs="+", metavar="RECORDING",
        help=f"recordings, one per power-on ({', '.join(sorted(READERS))})",
    )  # fmt: skip
    p.add_argument("-o", "--output", metavar="FILE", help="write the sensor TOML here")
    p.add_argument("--name", default=None, help="sensor name in the TOML (default: the file stem)")
    p.add_argument(
        "--base", metavar="PRESET|FILE", default=None,
        help="complete the TOML with this sensor's other fields (table, ranges, ...)",
    )  # fmt: skip
    p.add_argument("--report", metavar="FILE", help="write the report here instead of printing it")
    p.add_argument("--plot", metavar="FILE", help="plot the Allan deviation and the fit (PNG)")
    p.add_argument("--json", action="store_true", help="print the fitted terms as JSON")
    p.add_argument(
        "--unresolved", choices=("bound", "zero", "refuse"), default="bound",
        help="a term the records do not resolve: written at its 95%% bound (default), as 0 "
        "(optimistic), or refused (exit 1, with the record length that would resolve it)",
    )  # fmt: skip
    g = p.add_argument_group("between-position assumptions")
    g.add_argument(
        "--move-tau", type=bounded_float(0.0, 86_400.0, "s", open_lo=True), default=10.0,
        metavar="SECONDS",
        help="time constant of the bias transient a move starts (default 10)",
    )  # fmt: skip
    g.add_argument(
        "--heat-tau", type=bounded_float(0.0, 86_400.0, "s"), default=0.0, metavar="SECONDS",
        help="time constant of the drive's heat that sizes move disturbances (default 0: none)",
    )  # fmt: skip
    g.add_argument(
        "--between", choices=DESIGNS, default="per-run",
        help="per-run: each recording its own heading; same-mount: one plan on one mount, "
        "repeated effects at a position removed (default per-run)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    for option, path in (
        ("--output", args.output),
        ("--report", args.report),
    ):
        if path:
            check_output_path(path, option)
    if args.plot:
        check_plot_path(args.plot)
    base: dict[str, Any] | None = load_sensor(args.base).to_dict() if args.base else None
    with Progress("calibrate", enabled=not args.json) as bar:
        bar.step(f"reading {len(args.recordings)} recording(s)")
        # Each window reduced as it is read (its Allan curves, slopes and means), its samples
        # dropped: memory is one window's, whatever the records' length.
        runs = read_runs(
            args.recordings,
            lambda p: LogProgress("calibrate", [p], enabled=not args.json),
            fitted=True,
        )
        samples = sum(f.samples for run in runs for f in run.fits)
        bar.step(f"fitting {samples} samples: Allan deviation, then the terms between positions")
        cal = calibrate(
            runs, tau_s=args.move_tau, heat_tau_s=args.heat_tau, design=args.between,
            unresolved="zero" if args.unresolved == "zero" else "bound",
        )  # fmt: skip
        if args.unresolved == "refuse" and cal.unresolved_terms():
            what = ", ".join(
                f"{sec}.{name} (<= {up:.3g})" for sec, name, up in cal.unresolved_terms()
            )
            need = ""
            if not cal.triad_fits["gyro"].resolved["bias_instability"]:
                need = "; " + cal.bias_instability_need()
            raise QualityError(f"the records do not resolve {what}{need}")
        bar.step("done")
    name = args.name or (Path(args.output).stem if args.output else "calibrated")
    text = cal.to_toml(name, base)
    # The simulator must take what is written: load it as --sensor FILE would.
    spec_from_dict(tomllib.loads(text), source=args.output or "<calibrated>")
    if args.plot:
        from northfinder.host.calibrate.plot import plot_calibration

        plot_calibration(cal, args.plot)
    report = cal.report()
    if args.report:
        Path(args.report).write_text(report + "\n")
    if args.output:
        Path(args.output).write_text(text)
    if args.json:
        say(dumps(envelope("calibrate", None, cal.to_json_dict(name))))
        return 0
    if not args.report:
        say(report)
    if args.output:
        say(f"wrote {args.output}")
    else:
        say()
        say(text, end="")
    return 0
