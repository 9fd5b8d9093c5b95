"""Robustness: bad input and faults never crash, hang or silently break the simulated instrument.

Run: ``.venv/bin/python benchmarks/bench_robustness.py [--sections control] [--seconds-per-case 0.3]``.

Each section is one function in :data:`SECTIONS` that prints its table and returns a summary
dict; add a section by adding its module to ``robustness/`` and its function there.

The sections live in ``benchmarks/robustness/``, one module each: ``control`` (control-channel
abuse of a simulator process on a pty, and the ``--control`` addresses it must refuse), ``codec``
(random and mutated input into every decoder), ``find`` (faults injected during ``find``) and
``cli`` (bad input over every subcommand) and ``interrupt`` (``find`` in another process ended by
SIGINT, SIGTERM or the unit's silence during a move or a spin, on every link; the unit's state
afterwards) and ``slcan`` (``find`` on an SLCAN pty with malformed lines before the frames).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

from robustness.cli import cli_sweep
from robustness.codec import codec_fuzz
from robustness.control import control_abuse
from robustness.find import find_faults
from robustness.interrupt import interrupt_runs
from robustness.slcan import slcan_junk

#: Section name -> function(args) that prints its table and returns a summary.
SECTIONS: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    "codec": codec_fuzz,
    "control": control_abuse,
    "cli": cli_sweep,
    "find": find_faults,
    "interrupt": interrupt_runs,
    "slcan": slcan_junk,
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS), help="comma-separated")
    parser.add_argument("--seconds-per-case", type=float, default=0.3)
    parser.add_argument("--seed", type=int, default=1, help="codec: random seed")
    parser.add_argument("--fuzz-inputs", type=int, default=200_000, help="codec: per decoder")
    parser.add_argument("--fuzz-frames", type=int, default=300_000, help="codec: mutated frames")
    parser.add_argument("--case-timeout", type=float, default=60.0, help="cli: s per case")
    parser.add_argument("--jobs", type=int, default=2, help="cli: cases run at once")
    parser.add_argument("--only-cli", default="", help="cli: only cases whose argv contains this")
    parser.add_argument(
        "--interrupt-runs", type=int, default=20, help="interrupt: per link, signal"
    )
    parser.add_argument(
        "--interrupt-links", default="", help="interrupt: comma-separated links (default: all here)"
    )
    parser.add_argument("--slcan-runs", type=int, default=5, help="slcan: runs of find")
    parser.add_argument(
        "--garble-lines", type=int, default=10_000, help="slcan: malformed lines a run"
    )
    parser.add_argument("--json", metavar="FILE", help="also write the summaries as JSON")
    args = parser.parse_args()
    names = [s for s in args.sections.split(",") if s]
    unknown = [s for s in names if s not in SECTIONS]
    if unknown:
        parser.error(f"unknown section {unknown[0]!r}; sections are {', '.join(SECTIONS)}")
    results = {name: SECTIONS[name](args) for name in names}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
