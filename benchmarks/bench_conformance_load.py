"""The full conformance suite against the correct simulator on a pseudo-terminal, beside CPU-bound
processes: how many checks pass, fail and are not judged, and the load.

Run: ``python3 benchmarks/bench_conformance_load.py [--links slcan,serial] [--runs 3]
[--burners 2] [--nice-burners 1] [--speed 2] [--json]`` from a checkout with its ``.venv``.

Each run: ``northfinder sim --slcan-pty`` (or ``--pty``) in a process of its own (the fast table
of the tests, seed 3), the burners started (each ``python3 -c 'while True: pass'``; the
``--nice-burners`` at ``nice -n 19``), then ``northfinder conformance --json`` in another process
with the tests' host-side margins (``--time-scale S --stream-seconds 3 --jitter-margin-ms 60
--reply-limit-ms 400 --settle-margin 1 --ready-timeout 10``), the burners and the simulator
stopped by their process ids. A row a run: the counts, the checks that failed and those not
judged, the 1-minute load average at the end, the simulator's slips (its control channel) and
the host's pace over the run (the timer loop's loss, and how long the suite's reader and the
simulator waited for a CPU). Exits 1 if any run had a FAIL.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from simprocess import fast_sensor_file, sim_process  # noqa: E402

from northfinder.firmware_sim.control import ControlClient  # noqa: E402

BURN = "while True: pass"


@contextmanager
def burners(plain: int, niced: int) -> Iterator[None]:
    procs = [subprocess.Popen([sys.executable, "-c", BURN]) for _ in range(plain)]
    procs += [
        subprocess.Popen([sys.executable, "-c", BURN], preexec_fn=lambda: os.nice(19))
        for _ in range(niced)
    ]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def one_run(link: str, sensor: Path, speed: float, plain: int, niced: int) -> dict[str, Any]:
    flag = "--slcan-pty" if link == "slcan" else "--pty"
    sim = [flag, "--warmup", "0", "--seed", "3", "--speed", str(speed), "--sensor", str(sensor)]
    with sim_process(*sim, "--control", "127.0.0.1:0", ready=True, timeout=60) as facts:
        path = facts["pty"]
        if link == "slcan":
            args = ["-i", "slcan", "-c", path, "-b", "500000", "--bus-kwargs", "sleep_after_open=0"]
        else:
            args = ["--serial", path]
        args += ["--time-scale", str(speed), "--stream-seconds", "3", "--jitter-margin-ms", "60"]
        args += ["--reply-limit-ms", "400", "--settle-margin", "1", "--ready-timeout", "10"]
        t0 = time.monotonic()
        with burners(plain, niced):
            p = subprocess.run(
                [str(ROOT / ".venv/bin/northfinder"), "conformance", *args, "--json"],
                capture_output=True,
                text=True,
            )
            load = os.getloadavg()[0]
        seconds = time.monotonic() - t0
        with ControlClient(facts["control"]) as ctl:
            lag = ctl.call("status").get("lag", {})
    result = json.loads(p.stdout)
    names: dict[str, list[str]] = {}
    for c in result["checks"]:
        names.setdefault(c["outcome"], []).append(c["name"])
    return {
        "link": link,
        "status": p.returncode,
        "seconds": round(seconds, 1),
        "load": round(load, 1),
        "counts": result["counts"],
        "failed": names.get("fail", []),
        "not_judged": names.get("not judged", []),
        "messages": {c["name"]: c["message"] for c in result["checks"] if c["outcome"] == "fail"},
        "sim_slipped_s": round(lag.get("slipped_s", 0.0), 1),
        "host_pace": result.get("host_pace"),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--links", default="slcan,serial")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--burners", type=int, default=2)
    ap.add_argument("--nice-burners", type=int, default=1)
    ap.add_argument("--speed", type=float, default=2.0)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        sensor = fast_sensor_file(Path(tmp))
        for k in range(a.runs):
            for link in a.links.split(","):
                row = one_run(link, sensor, a.speed, a.burners, a.nice_burners)
                rows.append(row)
                if a.json:
                    continue
                c = row["counts"]
                pace = row["host_pace"] or {}
                lost = pace.get("timer_lost_s", 0.0) / pace["seconds"] if pace else 0.0
                waits = "".join(
                    f", {who} waited {pace[key] / pace['seconds']:.0%} for a CPU"
                    for who, key in (("reader", "reader_wait_s"), ("unit", "unit_wait_s"))
                    if pace.get(key) is not None and pace.get("seconds")
                )
                print(
                    f"{k + 1} {link:6} exit {row['status']} load {row['load']:5.1f} "
                    f"{row['seconds']:6.1f} s: {c['pass']} passed, {c['fail']} failed, "
                    f"{c['not judged']} not judged, {c['skip']} skipped; sim slipped "
                    f"{row['sim_slipped_s']} s; timer loop lost {lost:.0%}{waits}"
                    + (f"; FAILED {', '.join(row['failed'])}" if row["failed"] else ""),
                    flush=True,
                )
                for name, message in row["messages"].items():
                    print(f"    {name}: {message[:400]}", flush=True)
    if a.json:
        print(json.dumps(rows, indent=2))
    return 1 if any(r["failed"] for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
