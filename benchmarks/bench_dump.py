"""``northfinder dump`` on a large CAN log: peak memory and throughput against python-can.

Writes a log of ``--size-mb`` MB (default 1000) line by line, never held in memory: the 200 Hz
stream's frames (four sample frames a tick, two status frames every 100 ms, and a command with
its reply now and then) in python-can's ASC (``--format .asc``) or candump (``.log``) text, each
line as python-can's writer formats it. Then, each as a child process:

- ``northfinder dump LOG --count 5``: stops after five frames (its time and peak memory do not
  grow with the log);
- ``northfinder dump LOG`` to ``/dev/null``: every frame decoded with the DBC and printed;
- ``northfinder dump LOG --raw`` to ``/dev/null``: every frame read and printed, not decoded;
- python-can's ``can.LogReader`` iterating the same file, nothing else (the floor).

Peak memory is the child's ``ru_maxrss`` (``resource.getrusage(RUSAGE_CHILDREN)`` of a fresh
process that runs it, so earlier children do not count). Throughput is frames per second of wall
time; the ratio is python-can's time over dump's.

Run: ``.venv/bin/python benchmarks/bench_dump.py [--size-mb 1000] [--format .asc] [--keep DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can

from northfinder.driver.protocol import Sample, Validity
from northfinder.driver.protocol.can import encode_can
from northfinder.driver.protocol.messages import GetStatus, StatusCounters

#: Child that runs a command (argv in JSON) and prints its wall time and peak RSS (kB).
_MEASURE = r"""
import json, resource, subprocess, sys, time
argv = json.loads(sys.argv[1])
t0 = time.perf_counter()
with open("/dev/null", "w") as sink:
    rc = subprocess.run(argv, stdout=sink).returncode
wall = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"rc": rc, "wall_s": wall, "peak_kb": peak}))
"""

#: Iterates a log with python-can's reader and prints the frames read.
_PYTHON_CAN = "import can, sys; print(sum(1 for _ in can.LogReader(sys.argv[1])))"


def _frames_of_tick(k: int) -> list[can.Message]:
    """The frames the device sends in tick ``k`` of the 200 Hz stream (node 1), at its time."""
    t = 1_796_400_000.0 + k / 200
    s = Sample(k, (k, -k, 3 * k), (1, 2, 1_000_000), k * 1000, 2500, Validity(3))
    frames = [(f, True) for f in encode_can(s, 1)]
    if k % 20 == 0:  # a heartbeat: STATUS_COUNTERS (and the host's GET_STATUS now and then)
        frames += [(f, True) for f in encode_can(StatusCounters(k, 0, 0, 0), 1)]
        if k % 200 == 0:
            frames += [(f, False) for f in encode_can(GetStatus(k // 200 % 255 + 1), 1)]
    return [
        can.Message(
            arbitration_id=f.arbitration_id,
            data=f.data,
            is_extended_id=False,
            timestamp=t,
            channel=0,
            is_rx=rx,
        )
        for f, rx in frames
    ]


def write_log(path: Path, size_mb: float) -> int:
    """Write a log of about ``size_mb`` MB with python-can's writer for its ending, streamed;
    the frames written."""
    target = int(size_mb * 1e6)
    n = 0
    k = 0
    with can.Logger(str(path)) as writer:
        while True:
            for msg in _frames_of_tick(k):
                writer.on_message_received(msg)
                n += 1
            k += 1
            if k % 2000 == 0 and path.stat().st_size >= target:
                return n


def measure(argv: list[str]) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, "-c", _MEASURE, json.dumps(argv)], capture_output=True, text=True,
        check=True,
    )  # fmt: skip
    return json.loads(out.stdout)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size-mb", type=float, default=1000.0, help="log size, MB (default 1000)")
    ap.add_argument("--format", default=".asc", choices=(".asc", ".log"), help="log format")
    ap.add_argument("--keep", type=Path, default=None, help="write the log here and keep it")
    args = ap.parse_args()
    northfinder = str(Path(sys.executable).with_name("northfinder"))
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        log = folder / f"bench-dump{args.format}"
        t0 = time.perf_counter()
        frames = write_log(log, args.size_mb)
        size = log.stat().st_size
        print(
            f"log: {log.name}, {size / 1e6:.0f} MB, {frames} frames "
            f"(written in {time.perf_counter() - t0:.0f} s)"
        )
        runs = {
            "dump --count 5": [northfinder, "dump", str(log), "--count", "5"],
            "dump": [northfinder, "dump", str(log)],
            "dump --raw": [northfinder, "dump", str(log), "--raw"],
            "python-can LogReader": [sys.executable, "-c", _PYTHON_CAN, str(log)],
        }
        results = {}
        for name, argv in runs.items():
            r = measure(argv)
            results[name] = r
            rate = frames / r["wall_s"] if "count" not in name else float("nan")
            print(
                f"{name:22s} exit {r['rc']}  {r['wall_s']:8.1f} s  peak RSS "
                f"{r['peak_kb'] / 1024:7.1f} MiB"
                + ("" if rate != rate else f"  {rate:9.0f} frames/s")
            )
        floor = results["python-can LogReader"]["wall_s"]
        for name in ("dump", "dump --raw"):
            print(f"{name}: {results[name]['wall_s'] / floor:.2f} x python-can's LogReader time")
        if args.keep is None:
            os.unlink(log)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
