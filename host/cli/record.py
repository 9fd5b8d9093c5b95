"""``northfinder record FILE``: run a plan on a device and write the raw windows (.csv or .npz).

Device and plan options are those of ``find``. The columns are documented in ``northfinder.host.recording``
and the README; ``northfinder solve FILE`` solves the recording offline.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from northfinder.host.cli.find import add_device_arguments, add_plan_arguments, run_plan
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import Plan
from northfinder.host.recording import RecordedWindow, Recording


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "record", help="record raw windows to CSV or NPZ", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument("file", help="output file, .csv or .npz")
    add_device_arguments(p)
    add_plan_arguments(p)
    return p


def run(args: argparse.Namespace) -> int:
    if not args.file.endswith((".csv", ".npz")):
        raise HostConfigError(f"{args.file}: the file name must end in .csv or .npz")
    _, windows, plan, latitude, rate, truth = run_plan(args)
    recording = save_recording(args.file, windows, plan, latitude, rate, truth)
    samples = sum(len(w.counter) for w in recording.windows)
    print(f"wrote {len(recording.windows)} windows ({samples} samples) to {args.file}")
    return 0


def save_recording(
    path: str,
    windows: list[Any],
    plan: Plan,
    latitude: float,
    sample_rate_hz: float,
    truth: dict[str, Any] | None,
) -> Recording:
    """Write the raw windows of a run with what is needed to solve them again."""
    meta: dict[str, Any] = {
        "latitude_deg": latitude,
        "sample_rate_hz": sample_rate_hz,
        "plan": dataclasses.asdict(plan),
    }
    if truth is not None:
        meta["truth"] = truth
    recorded = tuple(
        RecordedWindow.from_window(w, p) for w, p in zip(windows, plan.positions_deg, strict=True)
    )
    recording = Recording(recorded, meta)
    recording.save(path)
    return recording
