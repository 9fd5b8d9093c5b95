"""``northfinder record FILE``: run a plan on a device and write the raw windows (.csv or .npz).

Device and plan options are those of ``find``. Each window is written as soon as it is measured;
an interrupted run keeps every complete window, marked ``interrupted`` (``solve`` says so). The columns are documented in ``northfinder.host.recording``
and the README; ``northfinder solve FILE`` solves the recording offline.
"""

from __future__ import annotations

import argparse

from northfinder.cli.common import check_output_path, command_parser
from northfinder.cli.measure import add_arguments, run_plan


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = command_parser(sub, "record", "record raw windows to CSV or NPZ", __doc__)
    p.add_argument("file", help="output file, .csv or .npz")
    add_arguments(p)
    return p


def run(args: argparse.Namespace) -> int:
    check_output_path(args.file, "file", (".csv", ".npz"))
    m = run_plan(args, record_to=args.file)
    if m.errors:
        raise m.errors[0]
    assert m.recording is not None
    samples = sum(len(w.counter) for w in m.recording.windows)
    print(f"wrote {len(m.recording.windows)} windows ({samples} samples) to {args.file}")
    return 0
