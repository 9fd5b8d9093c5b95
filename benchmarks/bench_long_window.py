"""Time and memory of ``northfinder find --sim`` (and ``record``) as the window grows to an hour.

Run: ``.venv/bin/python benchmarks/bench_long_window.py [--windows 10,600,3600] [--repeats 3]
[--record-window 3600]``.

Each run is ``northfinder find --sim --seed S --positions 0,90 --window W`` as a new process
(interpreter start and imports included, as a user sees it), started by a small wrapper process
that reads the command's own peak resident memory (``RUSAGE_CHILDREN`` ``ru_maxrss``) and CPU
time once it exits; ``record run.npz`` with the same plan is measured the same way for
``--record-window`` (0: none).

Columns:

- ``wall s``, ``cpu s``: median over the repeats (each repeat another seed);
- ``x real``: simulated time over wall time (``x cpu``: over the CPU time, which the machine's
  other load changes less); the simulated time is the instrument's, read from a
  recording of the plan with 10 s windows: the last sample's counter over 200 Hz (120 s warm-up,
  the moves, the settling and both windows; ``simulated_s``), plus the longer windows;
- ``MB``: peak resident memory of the command, median;
- ``B/sample``: the peak over the samples of both windows, and ``+B/sample``: the growth of the
  peak from the shortest window's over the samples added (what each sample costs).

The machine's other load shows in the wall time; the CPU time is the steadier figure. What one
200 Hz tick of the stream costs, against the floor of python-can's ``virtual`` bus carrying its
four frames: ``benchmarks/bench_engine_floor.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RATE_HZ = 200
POSITIONS = "0,90"

#: Runs a command, then prints its peak RSS (KiB) and CPU seconds as JSON on the last line.
_WRAPPER = """
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
wall = time.perf_counter() - t0
r = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": p.returncode, "wall": wall, "cpu": r.ru_utime + r.ru_stime,
                  "maxrss_kib": r.ru_maxrss, "stderr": p.stderr[-400:]}))
"""


def northfinder() -> str:
    exe = Path(sys.executable).with_name("northfinder")
    return str(exe if exe.exists() else "northfinder")


def measure(args: list[str]) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, "-c", _WRAPPER, northfinder(), *args],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    ).stdout
    r = json.loads(out.strip().splitlines()[-1])
    if r["rc"] != 0:
        raise SystemExit(f"northfinder {' '.join(args)} failed ({r['rc']}): {r['stderr']}")
    return r


def simulated_s(window_s: float, seed: int, tmp: Path) -> float:
    """Instrument time from boot to the end of the plan, from a recording's last counter (the
    plan's time does not depend on the seed)."""
    path = tmp / f"sim-{window_s:g}.npz"
    if not path.exists():
        subprocess.run(
            [northfinder(), "record", str(path), "--sim", "--seed", str(seed),
             "--positions", POSITIONS, "--window", f"{window_s:g}"],
            check=True, capture_output=True, cwd=ROOT,
        )  # fmt: skip
    with np.load(path) as d:
        return (int(d["counter"][-1]) + 1) / RATE_HZ


def row(label: str, runs: list[dict[str, Any]], sim_s: float, samples: int) -> dict[str, Any]:
    wall = statistics.median(r["wall"] for r in runs)
    cpu = statistics.median(r["cpu"] for r in runs)
    mb = statistics.median(r["maxrss_kib"] for r in runs) / 1024
    return {"label": label, "wall": wall, "cpu": cpu, "x": sim_s / wall, "xcpu": sim_s / cpu, "mb": mb,
            "samples": samples, "n": len(runs)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", default="10,600,3600", help="window lengths, s")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each (median)")
    ap.add_argument("--long-repeats", type=int, default=1, help="runs of windows >= 1800 s")
    ap.add_argument("--record-window", type=float, default=3600.0, help="0: no record run")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    windows = [float(w) for w in a.windows.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for w in windows:
            reps = a.long_repeats if w >= 1800 else a.repeats
            runs = []
            for k in range(reps):
                runs.append(measure(["find", "--sim", "--seed", str(a.seed + k),
                                     "--positions", POSITIONS, "--window", f"{w:g}"]))  # fmt: skip
            # The plan's time grows by the windows only (moves and settling are the same).
            sim = simulated_s(10.0, a.seed, tmp) + 2 * (w - 10.0)
            rows.append(row(f"find --window {w:g}", runs, sim, 2 * round(w * RATE_HZ)))
            print(json.dumps(rows[-1]), file=sys.stderr)
        if a.record_window:
            w = a.record_window
            out = tmp / "run.npz"
            r = measure(["record", str(out), "--sim", "--seed", str(a.seed),
                         "--positions", POSITIONS, "--window", f"{w:g}"])  # fmt: skip
            sim = simulated_s(10.0, a.seed, tmp) + 2 * (w - 10.0)
            rows.append(row(f"record run.npz --window {w:g}", [r], sim, 2 * round(w * RATE_HZ)))
            rows[-1]["npz_mb"] = os.path.getsize(out) / 1e6
            print(json.dumps(rows[-1]), file=sys.stderr)
    base = rows[0]
    print(f"{'command (--sim --positions 0,90)':34} {'runs':>4} {'samples':>9} {'wall s':>7} "
          f"{'cpu s':>7} {'x real':>7} {'x cpu':>6} {'MB':>6} {'B/sample':>9} {'+B/sample':>9}")  # fmt: skip
    for r in rows:
        per = r["mb"] * 2**20 / r["samples"]
        grow = (
            (r["mb"] - base["mb"]) * 2**20 / (r["samples"] - base["samples"])
            if r is not base and r["samples"] > base["samples"]
            else float("nan")
        )
        extra = f"  (NPZ {r['npz_mb']:.1f} MB)" if "npz_mb" in r else ""
        print(f"{r['label']:34} {r['n']:4d} {r['samples']:9d} {r['wall']:7.1f} {r['cpu']:7.1f} "
              f"{r['x']:7.0f} {r['xcpu']:6.0f} {r['mb']:6.0f} {per:9.0f} {grow:9.0f}{extra}")  # fmt: skip


if __name__ == "__main__":
    main()
