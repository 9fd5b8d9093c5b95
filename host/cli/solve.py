"""``northfinder solve FILE``: solve a recording written by ``northfinder record`` offline.

The recording carries its latitude; ``--latitude`` overrides it. ``--denoise`` and ``--method``
are the same as for ``find``, so a recording can be solved again with other settings.
"""

from __future__ import annotations

import argparse

from northfinder.host.cli import report
from northfinder.host.cli.common import finite_float
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import (
    METHOD_CHOICES,
    FindResult,
    Plan,
    solve_windows,
    summarise_window,
)
from northfinder.host.recording import Recording


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("solve", help="solve a recording offline", description=__doc__)
    p.add_argument("file", help="recording (.csv or .npz)")
    p.add_argument(
        "--latitude", type=finite_float, default=None, help="deg (default: from the recording)"
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
    lat = rec.meta.get("latitude_deg") if latitude is None else latitude
    if not isinstance(lat, int | float):
        raise HostConfigError("the recording has no latitude_deg; give --latitude")
    plan = Plan(
        positions_deg=tuple(w.commanded_deg for w in rec.windows),
        window_s=max(len(w.counter) for w in rec.windows)
        / float(rec.meta.get("sample_rate_hz", 200)),
        denoise=denoise,
        method=method,
    )
    windows = [summarise_window(w, w.commanded_deg, denoise) for w in rec.windows]
    azimuth, sigma, pitch, roll, pairwise = solve_windows(windows, float(lat), plan)
    return FindResult(
        azimuth, sigma, pitch, roll, plan.solver, denoise, float(lat), tuple(windows),
        pairwise if len(windows) > 2 else (),
        tuple(f"position {i + 1}: {n}" for i, w in enumerate(windows) for n in w.notes),
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    rec = Recording.load(args.file)
    result = solve_recording(rec, args.latitude, args.denoise, args.method)
    truth = rec.meta.get("truth")
    if args.plot:
        report.plot(args.plot, result, list(rec.windows), args.denoise)
    print(report.as_json(result, truth) if args.json else report.text(result, truth))
    return 0
