"""``northfinder solve FILE``: solve a recording or a CAN log offline.

FILE is a recording of ``northfinder record`` (``.csv``, ``.npz``) or a CAN log in any format
python-can reads (``.log`` candump, ``.asc``, ``.blf``, ``.csv``, ``.db``, ``.trc``; written by
``northfinder sim --log``, ``find/record --can-log``, python-can's logger or candump). From a log
the windows are rebuilt from the frame stream: one per STREAM_START, at the angle of the last
rotation command, in the scales of the log's IDENTIFY; ``--window SECONDS`` keeps the first
seconds of each, as ``find``'s acquisition did (default: every sample streamed at the position).
Missing ticks are reported and stop the solution.

A recording carries its latitude; a log does not: give ``--latitude``. ``--denoise`` and
``--solver`` are those of ``find``, so a session can be solved again with other settings.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from northfinder.cli import report
from northfinder.cli.common import (
    add_solver_argument,
    bounded_float,
    check_plot_path,
    command_parser,
    node_id,
    positive_float,
)
from northfinder.host.canlog import is_can_log, read_can_log
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError, QualityError
from northfinder.host.procedure import (
    METHOD_CHOICES,
    FindResult,
    Plan,
    result_from_windows,
    summarise_window,
)
from northfinder.host.recording import Recording


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = command_parser(sub, "solve", "solve a recording or CAN log offline", __doc__)
    p.add_argument("file", help="recording (.csv, .npz) or CAN log (.log, .asc, .blf, ...)")
    p.add_argument(
        "--latitude",
        type=bounded_float(-90.0, 90.0, "deg"),
        default=None,
        help="deg (default: from the recording)",
    )
    p.add_argument(
        "--denoise", default="none", choices=list(METHODS), help="denoising method (default none)"
    )
    add_solver_argument(p, METHOD_CHOICES)
    g = p.add_argument_group("CAN logs")
    g.add_argument(
        "--window", type=positive_float, default=None, metavar="SECONDS",
        help="keep the first SECONDS of each window (default: all samples at the position)",
    )  # fmt: skip
    g.add_argument(
        "--node-id", type=node_id, default=None,
        help="the device's node id (default: the only node in the log)",
    )  # fmt: skip
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


def load(args: argparse.Namespace) -> tuple[Recording, dict[str, Any]]:
    """The recording named by the arguments (read from a CAN log if it is one) and where it
    came from."""
    path = Path(args.file)
    source: dict[str, Any]
    if is_can_log(path):
        session = read_can_log(path, node_id=args.node_id, window_s=args.window)
        source = {
            "file": str(path), "format": "can-log", "node_id": session.node_id,
            "frames": session.frames, "sample_rate_hz": session.sample_rate_hz,
            "window_s": args.window, "notes": list(session.notes),
        }  # fmt: skip
        if session.incomplete:
            raise QualityError(f"{path}: " + "; ".join(session.incomplete))
        return session.recording(), source
    if args.window is not None or args.node_id is not None:
        raise HostConfigError("--window and --node-id apply to CAN logs only")
    rec = Recording.load(path)
    source = {"file": str(path), "format": f"recording{path.suffix}"}
    if rec.partial is not None:
        source["partial"] = rec.partial
        source["notes"] = [f"partial recording ({rec.partial}): solved from the windows it holds"]
    return rec, source


def run(args: argparse.Namespace) -> int:
    if args.plot:
        check_plot_path(args.plot)
    rec, source = load(args)
    result = solve_recording(rec, args.latitude, args.denoise, args.solver)
    truth = rec.meta.get("truth")
    if args.plot:
        report.plot(args.plot, result, list(rec.windows), args.denoise, truth)
    device = rec.meta.get("device")
    if args.json:
        print(report.as_json("solve", result, truth, device, source=source))
    else:
        print(report.text(result, truth))
        for note in source.get("notes", []):
            print(f"note: {note}")
    return 0
