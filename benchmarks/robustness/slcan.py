"""``slcan``: ``northfinder find`` on an SLCAN pty while the adapter puts malformed lines before its
frames (a section of ``bench_robustness.py``).

``northfinder sim --slcan-pty`` runs at real time with its control channel; the ``garble`` fault
puts ``--garble-lines`` lines that python-can's ``slcan`` reader cannot parse (its own list in
turn: ``T1234``, a frame shorter than its header; lengths and data that are not hex; bytes that
are not ASCII; bare letters; FD frames cut short), four before each frame, while ``find`` runs in
another process with ``-v``. Counted per run: the exit status, a traceback or a dead reader in
its stderr, the heading's error against the simulator's truth, and the lines the driver counted
(rejected frames, and frames of ids not the unit's for the lines whose first fields parse).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from simprocess import sim_process

FIND = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())", "find"]


def slcan_junk(args: argparse.Namespace) -> dict[str, Any]:
    n, lines = args.slcan_runs, args.garble_lines
    print(f"find on an SLCAN pty with {lines} malformed lines before its frames (4 a frame), "
          f"{n} runs")  # fmt: skip
    print(f"{'run':>3} {'exit':>4} {'traceback':>9} {'rejected':>8} {'foreign':>7} "
          f"{'error deg':>9} {'sigma deg':>9}")  # fmt: skip
    rows = []
    for k in range(n):
        sim_args = ["--slcan-pty", "--warmup", "0", "--control", "127.0.0.1:0",
                    "--seed", str(k + 1)]  # fmt: skip
        with sim_process(*sim_args, ready=True) as facts:
            from northfinder.firmware_sim.control import ControlClient

            argv = [*FIND, "-i", "slcan", "-c", facts["pty"], "-b", "500000",
                    "--bus-kwargs", "sleep_after_open=0", "--latitude", "34", "--window", "2",
                    "--positions", "0,180", "--json", "-v", "--link-timeout", "2"]  # fmt: skip
            with ControlClient(facts["control"]) as ctl:
                truth = ctl.call("get_truth")["truth"]["azimuth_deg"]
                ctl.call("garble", count=lines, per_frame=4)
                proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
                left = ctl.call("status")["faults"]["garble"]
        counted = re.search(r"(\d+) rejected, (\d+) foreign", proc.stderr)
        row: dict[str, Any] = {
            "exit": proc.returncode,
            "traceback": "Traceback" in proc.stderr or "reader thread failed" in proc.stderr,
            "rejected": int(counted.group(1)) if counted else None,
            "foreign": int(counted.group(2)) if counted else None,
            "sent": lines - left,
        }
        try:
            found = json.loads(proc.stdout)
            row["error_deg"] = (found["azimuth_deg"] - truth + 180.0) % 360.0 - 180.0
            row["sigma_deg"] = found["sigma_deg"]
        except (ValueError, KeyError):
            row["error_deg"] = row["sigma_deg"] = None
            row["stderr"] = proc.stderr.strip().splitlines()[-1:]
        rows.append(row)
        e = f"{row['error_deg']:+9.4f}" if row["error_deg"] is not None else f"{'-':>9}"
        s = f"{row['sigma_deg']:9.4f}" if row["sigma_deg"] is not None else f"{'-':>9}"
        print(f"{k + 1:>3} {row['exit']:>4} {row['traceback']!s:>9} {row['rejected']!s:>8} "
              f"{row['foreign']!s:>7} {e} {s}", flush=True)  # fmt: skip
    ok = [r for r in rows if r["exit"] == 0 and not r["traceback"]]
    summary = {
        "runs": n,
        "found": len(ok),
        "reader_deaths": sum(r["traceback"] for r in rows),
        "rejected_median": statistics.median(r["rejected"] or 0 for r in rows) if rows else 0,
        "rows": rows,
    }
    print(f"runs {n}: heading found {len(ok)}, reader deaths {summary['reader_deaths']}, "
          f"rejected frames (median) {summary['rejected_median']:.0f}")  # fmt: skip
    return summary
