"""How fast the physics generates data: one instrument step by step, and many runs at once.

Run: ``.venv/bin/python benchmarks/bench_physics.py [--repeats 5] [--hours 1] [--runs 1000]``

First table: one hour of 200 Hz six-axis data from one :class:`Instrument`, per sensor preset.
Second table: the batch generator (:func:`simulate_windows`) drawing ``--runs`` independent runs
of a two-position plan (0 and 180 deg, 2 x 10 s windows at 200 Hz, 120 s warm-up), per preset.
Both print the median wall time over the repeats and the throughput. Target for the first: well
under 1 s for one hour of data.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from northfinder.firmware_sim.batch import simulate_windows
from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import load_spec, preset_names


def bench_instrument(hours: float, rate: float, repeats: int) -> None:
    n = int(hours * 3600 * rate)
    print(f"Instrument: {n} samples x 6 channels ({hours:g} h at {rate:g} Hz), median of {repeats}")
    print(f"{'preset':<14} {'median s':>9} {'min s':>8} {'x real time':>12} {'Msamples/s':>11}")
    for name in preset_names():
        spec = load_spec(name)
        times = []
        for seed in range(repeats):
            ins = Instrument(
                spec, Truth(azimuth_deg=30.0), np.random.default_rng(seed), sample_rate_hz=rate
            )
            t0 = time.perf_counter()
            ins.generate(n)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        print(
            f"{name:<14} {med:9.3f} {min(times):8.3f} {hours * 3600 / med:12.0f} "
            f"{6 * n / med / 1e6:11.1f}"
        )


def bench_batch(runs: int, repeats: int) -> None:
    samples = runs * 2 * 2000 * 6
    print(
        f"\nBatch: {runs} runs x 2 windows x 2000 samples x 6 channels (0,180 deg, 10 s at "
        f"200 Hz, 120 s warm-up), median of {repeats}"
    )
    print(f"{'preset':<14} {'median s':>9} {'min s':>8} {'Msamples/s':>11}")
    for name in preset_names():
        spec = load_spec(name)
        times = []
        for seed in range(repeats):
            rng = np.random.default_rng(seed)
            truths = [Truth(float(a), 34.0) for a in rng.uniform(0.0, 360.0, runs)]
            t0 = time.perf_counter()
            simulate_windows(spec, truths, [0.0, 180.0], 10.0, n_runs=runs, rng=rng, warmup_s=120)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        print(f"{name:<14} {med:9.3f} {min(times):8.3f} {samples / med / 1e6:11.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--runs", type=int, default=1000, help="runs of the batch table (0: skip it)")
    args = ap.parse_args()
    bench_instrument(args.hours, args.rate, args.repeats)
    if args.runs:
        bench_batch(args.runs, args.repeats)


if __name__ == "__main__":
    main()
