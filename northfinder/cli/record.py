"""``northfinder record FILE``: run a plan on a device and write the raw windows (.csv or .npz).

The device, simulator and plan options are those of ``find`` (``--spin RATE_DPS`` records a spin
instead); ``northfinder solve FILE`` solves the recording offline. Each window is written as soon as it is measured; an interrupted run keeps
every complete window, marked ``interrupted`` (``solve`` says so).
"""

from __future__ import annotations

import argparse

from northfinder.cli import measure, spinfind
from northfinder.cli.files import check_output_path
from northfinder.cli.measure import run_plan


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="output file, .csv or .npz")
    measure.add_arguments(p)
    spinfind.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    check_output_path(args.file, "file", (".csv", ".npz"))
    if args.spin is not None or args.spin_time or args.spin_drift:
        from northfinder.cli.find import PLAN_DEFAULTS

        spinfind.check(args, PLAN_DEFAULTS)
        found, truth, identity = spinfind.run(args, record_to=args.file)
        rec, _ = spinfind.save(
            args.file, args, found.window, found.latitude_deg, found.latitude_source, truth,
            identity,
        )  # fmt: skip
        seed = f" (simulated, seed {truth['seed']})" if truth and "seed" in truth else ""
        n = len(rec.windows[0].counter)
        print(f"wrote a spin of {n} samples at {args.spin:+g} deg/s to {args.file}{seed}")
        return 0
    m = run_plan(args, record_to=args.file)
    if m.errors:
        raise m.errors[0]
    recording = m.recording
    assert recording is not None
    samples = sum(m.recorded_sizes)
    truth = recording.meta.get("truth")
    seed = f" (simulated, seed {truth['seed']})" if truth and "seed" in truth else ""
    print(f"wrote {len(m.recorded_sizes)} windows ({samples} samples) to {args.file}{seed}")
    return 0
