"""How long one hour of 200 Hz six-axis data takes to generate, per sensor preset.

Run: ``.venv/bin/python benchmarks/bench_physics.py [--repeats 5] [--hours 1]``
Prints the median wall time over the repeats and the ratio to real time. Target: well under 1 s
for one hour of data.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import load_spec, preset_names


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=200.0)
    args = ap.parse_args()
    n = int(args.hours * 3600 * args.rate)
    print(
        f"{n} samples x 6 channels ({args.hours:g} h at {args.rate:g} Hz), median of {args.repeats}"
    )
    print(f"{'preset':<14} {'median s':>9} {'min s':>8} {'x real time':>12} {'Msamples/s':>11}")
    for name in preset_names():
        spec = load_spec(name)
        times = []
        for seed in range(args.repeats):
            ins = Instrument(
                spec, Truth(azimuth_deg=30.0), np.random.default_rng(seed), sample_rate_hz=args.rate
            )
            t0 = time.perf_counter()
            ins.generate(n)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        print(
            f"{name:<14} {med:9.3f} {min(times):8.3f} {args.hours * 3600 / med:12.0f} {6 * n / med / 1e6:11.1f}"
        )


if __name__ == "__main__":
    main()
