"""The README's test command, timed on a fresh clone, idle or beside CPU-bound processes.

Run: ``python3 benchmarks/bench_suite.py [--runs 5] [--burners 2] [--nice-burners 1]
[--repo PATH] [--keep DIR] [--json]``.

What it does, in this order:

1. ``git clone`` the repository (``--repo``, default the one holding this script) into a new
   temporary folder, then, in the clone, the Quick start's test command as the README gives it:
   ``python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && .venv/bin/python -m
   pytest -q``; the install is timed apart and done once.
2. ``--runs`` times: start the burners (each ``python3 -c 'while True: pass'`` in a process of its
   own; ``--nice-burners`` more at ``nice -n 19``), run ``.venv/bin/python -m pytest -q -p
   no:cacheprovider`` (no state kept between runs), stop the burners, and keep the wall time, the
   exit code, pytest's last line (passed, failed, skipped: a realtime test the host starved is
   reported skipped with "NOT JUDGED" and the host's figures, counted here), the 1-minute load
   average before and after, and ``/proc/pressure/cpu`` ("some" avg60) after, where the kernel has
   it. A red run's whole output is kept in a file of the temporary folder (its path printed).

It prints one row a run and the median wall time, and exits 1 if any run was red. "Idle" in a
shared machine's figures means no burner of ours; the load column says what else ran.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BURN = "while True: pass"


def _load() -> float:
    return os.getloadavg()[0]


def _pressure() -> float | None:
    try:
        text = Path("/proc/pressure/cpu").read_text()
    except OSError:
        return None
    m = re.search(r"some avg10=[\d.]+ avg60=([\d.]+)", text)
    return float(m.group(1)) if m else None


def _burners(plain: int, niced: int) -> list[subprocess.Popen[bytes]]:
    procs = [subprocess.Popen([sys.executable, "-c", BURN]) for _ in range(plain)]
    procs += [
        subprocess.Popen([sys.executable, "-c", BURN], preexec_fn=lambda: os.nice(19))
        for _ in range(niced)
    ]
    return procs


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        p.kill()
    for p in procs:
        p.wait()


def _counts(last: str) -> dict[str, int]:
    return {word: int(n) for n, word in re.findall(r"(\d+) (passed|failed|skipped|errors?)", last)}


def run_once(clone: Path, plain: int, niced: int) -> dict[str, object]:
    procs = _burners(plain, niced)
    load0 = _load()
    t0 = time.monotonic()
    try:
        proc = subprocess.run(
            [str(clone / ".venv/bin/python"), "-m", "pytest", "-q", "-p", "no:cacheprovider"],
            cwd=clone,
            capture_output=True,
            text=True,
        )
    finally:
        wall = time.monotonic() - t0
        _stop(procs)
    log = None
    if proc.returncode != 0:  # the whole output of a red run, kept past the clone's removal
        fd, log = tempfile.mkstemp(prefix="nf-suite-run-", suffix=".log")
        with os.fdopen(fd, "w") as f:
            f.write(proc.stdout + proc.stderr)
    lines = [line for line in proc.stdout.strip().splitlines() if line.strip()]
    last = lines[-1] if lines else proc.stderr.strip()[-200:]
    failed = [line for line in lines if line.startswith(("FAILED ", "ERROR "))]
    not_judged = sum("NOT JUDGED" in line for line in lines)
    return {
        "wall_s": round(wall, 1),
        "exit": proc.returncode,
        "summary": last,
        "counts": _counts(last),
        "not_judged": not_judged,
        "failed": failed,
        "log": log,
        "load_before": round(load0, 1),
        "load_after": round(_load(), 1),
        "cpu_pressure_avg60": _pressure(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--burners", type=int, default=0, help="CPU-bound processes beside each run")
    ap.add_argument("--nice-burners", type=int, default=0, help="more of them at nice 19")
    ap.add_argument("--repo", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--keep", help="clone here (kept) instead of a temporary folder")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.burners < 0 or args.nice_burners < 0:
        ap.error("--runs must be at least 1, --burners and --nice-burners at least 0")

    tmp = None if args.keep else tempfile.mkdtemp(prefix="nf-suite-")
    clone = Path(args.keep or tmp) / "northfinder"  # type: ignore[arg-type]
    try:
        subprocess.run(["git", "clone", "-q", args.repo, str(clone)], check=True)
        commit = subprocess.run(
            ["git", "-C", str(clone), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        t0 = time.monotonic()
        subprocess.run(
            "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]'",
            shell=True,
            cwd=clone,
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        install_s = time.monotonic() - t0
        print(
            f"clone of {args.repo} at {commit}; install {install_s:.0f} s; burners "
            f"{args.burners} + {args.nice_burners} at nice 19",
            flush=True,
        )
        rows = []
        for k in range(args.runs):
            row = run_once(clone, args.burners, args.nice_burners)
            rows.append(row)
            print(
                f"run {k + 1}: {row['wall_s']:.0f} s, exit {row['exit']}, load "
                f"{row['load_before']}->{row['load_after']}, cpu pressure "
                f"{row['cpu_pressure_avg60']}, not judged {row['not_judged']}: {row['summary']}",
                flush=True,
            )
            for line in row["failed"]:  # type: ignore[attr-defined]
                print(f"    {line}", flush=True)
            if row["log"]:
                print(f"    the run's whole output: {row['log']}", flush=True)
        walls = [float(r["wall_s"]) for r in rows]  # type: ignore[arg-type]
        green = sum(r["exit"] == 0 for r in rows)
        median = statistics.median(walls)
        print(f"{green} of {len(rows)} green; median wall {median:.0f} s ({median / 60:.1f} min)")
        if args.json:
            print(json.dumps({"commit": commit, "install_s": install_s, "runs": rows}, indent=1))
        return 0 if green == len(rows) else 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
