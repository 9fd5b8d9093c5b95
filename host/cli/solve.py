"""``northfinder solve FILE``: solve a recording written by ``northfinder record`` offline.

The recording carries its latitude; ``--latitude`` overrides it. ``--denoise`` and ``--method``
are the same as for ``find``, so a recording can be solved again with other settings.
"""

from __future__ import annotations

import argparse

from northfinder.host.cli import report
from northfinder.host.cli.common import bounded_float, check_output_path
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import (
    METHOD_CHOICES,
    FindResult,
    Plan,
    result_from_windows,
    summarise_window,
)
from northfinder.host.recording import Recording


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("solve", help="solve a recording offline", description=__doc__)
    p.add_argument("file", help="recording (.csv or .npz)")
    p.add_argument(
        "--latitude",
        type=bounded_float(-90.0, 90.0, "deg"),
        default=None,
        help="deg (default: from the recording)",
    )
    p.add_argument(
        "--denoise", default="none", choices=list(METHODS), help="denoising method (default none)"
    )
    p.add_argument("--method", default="auto", choices=METHOD_CHOICES, help="solver (default auto)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument(
        "--plot", metavar="FILE", help="plot the windows and per-pair azimuths (needs matplotlib)"
    )
    return p


def solve_recording(
    rec: Recording, latitude: float | None, denoise: str, method: str
) -> FindResult:
    if latitude is None and "latitude_deg" not in rec.meta:
        raise HostConfigError("--latitude: the recording has no latitude_deg; give --latitude")
    lat = float(rec.meta["latitude_deg"] if latitude is None else latitude)
    recorded = rec.meta.get("latitude_source")
    if latitude is not None:
        source = "--latitude"
    else:
        source = f"the recording (from {recorded})" if recorded else "the recording"
    plan = Plan(
        positions_deg=tuple(w.commanded_deg for w in rec.windows),
        window_s=max(len(w.counter) for w in rec.windows) / float(rec.meta["sample_rate_hz"]),
        denoise=denoise,
        method=method,
    )
    windows = [summarise_window(w, w.commanded_deg, denoise) for w in rec.windows]
    return result_from_windows(windows, lat, plan, latitude_source=source)


def run(args: argparse.Namespace) -> int:
    if args.plot:
        check_output_path(args.plot, "--plot")
        report.require_matplotlib()
    rec = Recording.load(args.file)
    result = solve_recording(rec, args.latitude, args.denoise, args.method)
    truth = rec.meta.get("truth")
    if args.plot:
        report.plot(args.plot, result, list(rec.windows), args.denoise)
    print(report.as_json(result, truth) if args.json else report.text(result, truth))
    return 0
