"""CAN log tap throughput: frames per second each python-can writer takes through
:class:`~northfinder.driver.framelog.FrameLog`, as a multiple of the 200 Hz stream's frame rate.

The stream at 200 Hz is 4 sample frames per tick plus two status frames per 100 ms heartbeat:
820 frames/s; a tap must take that with room to spare, or logging slows the link's reader.
Median over repeats of writing ``--frames`` sample frames (and closing the file); the formats
python-can rotates are measured again rotated every 64 KiB (``FrameLog(max_bytes=...)``: a part
closed and renamed every few hundred frames, far more often than any real rotation).
Run: ``.venv/bin/python benchmarks/bench_framelog.py [--frames N] [--repeats R]``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import can

from northfinder.driver.framelog import FrameLog
from northfinder.driver.protocol import Sample, Validity
from northfinder.driver.protocol.can import encode_can

STREAM_FRAMES_PER_S = 4 * 200 + 2 * 10
FORMATS = (".log", ".asc", ".blf", ".csv", ".db", ".trc")


def frames(n: int) -> list[can.Message]:
    out: list[can.Message] = []
    k = 0
    while len(out) < n:
        s = Sample(k, (k, -k, 3 * k), (1, 2, 1_000_000), k * 1000, 2500, Validity(3))
        for f in encode_can(s, 1):
            out.append(
                can.Message(
                    arbitration_id=f.arbitration_id,
                    data=f.data,
                    is_extended_id=False,
                    timestamp=1.0 + k / 200,
                )
            )
        k += 1
    return out[:n]


#: Formats measured rotated too, and the part size, bytes.
ROTATED = (".log", ".asc", ".blf", ".csv")
PART_BYTES = 64 * 1024


def rate(suffix: str, msgs: list[can.Message], d: Path, max_bytes: int = 0) -> float:
    path = d / f"bench{max_bytes}{suffix}"
    for old in d.glob(f"bench{max_bytes}_#*"):
        old.unlink()
    t0 = time.perf_counter()
    with FrameLog(path, max_bytes=max_bytes) as log:
        for m in msgs:
            log(m)
    return len(msgs) / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=40_000)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    msgs = frames(a.frames)
    print(
        f"{'format':>7} {'frames/s':>10} {'x stream':>9}   ({a.frames} frames, median of {a.repeats})"
    )
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in FORMATS:
            r = statistics.median(rate(suffix, msgs, Path(tmp)) for _ in range(a.repeats))
            print(f"{suffix:>7} {r:10.0f} {r / STREAM_FRAMES_PER_S:9.1f}")
        for suffix in ROTATED:
            r = statistics.median(
                rate(suffix, msgs, Path(tmp), PART_BYTES) for _ in range(a.repeats)
            )
            name = f"{suffix} rot"
            print(f"{name:>7} {r:10.0f} {r / STREAM_FRAMES_PER_S:9.1f}")


if __name__ == "__main__":
    main()
