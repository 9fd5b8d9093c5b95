"""Speed of the Monte Carlo study: 10000 two-position runs, 200 Hz samples, wavelet denoising.

Run: ``.venv/bin/python benchmarks/bench_study.py [--runs 10000] [--repeats 3]
[--denoise wavelet-soft]``. The study is the one ``northfinder study --runs 10000 --denoise
wavelet-soft`` runs: paper-rlg preset (every error term), positions 0,180, 10 s windows at
200 Hz (2 x 2000 samples of 6 channels per run), 120 s warm-up, accelerometer levelling, db4
soft-threshold wavelet denoising of both horizontal gyro windows of every run, eq. 14. One
process (numpy may use its own threads). Prints the median wall time over the repeats, the
ratio to the 60 s target, and the split between drawing samples and processing them.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from northfinder.firmware_sim.batch import simulate_windows
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.cli.simulated import SimulatedWindows, error_model
from northfinder.host.montecarlo import StudySettings, monte_carlo, study_rows
from northfinder.host.plan import Plan
from northfinder.host.study import chunk_errors

TARGET_S = 60.0


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--denoise", default="wavelet-soft")
    ap.add_argument("--sensor", default="paper-rlg")
    args = ap.parse_args()
    spec = load_spec(args.sensor)
    plan = Plan((0.0, 180.0), 10.0, denoise=args.denoise)
    settings = StudySettings()
    generator, model = SimulatedWindows(spec), error_model(spec)
    walls = []
    for seed in range(args.repeats):
        t0 = time.perf_counter()
        errors = monte_carlo(generator, plan, settings, args.runs, seed)
        walls.append(time.perf_counter() - t0)
        row = study_rows(model, plan, settings, errors)[0]
        print(
            f"repeat {seed}: {walls[-1]:.1f} s, RMSE {row['rmse_deg']:.4f} deg, "
            f"bound {row['bound_deg']:.4f} deg, ratio {row['ratio']:.3f}"
        )
    med = statistics.median(walls)
    samples = args.runs * 2 * 2000 * 6
    print(
        f"\n{args.runs} runs x 2 positions x 2000 samples x 6 channels, {args.denoise}: "
        f"median {med:.1f} s over {args.repeats} (min {min(walls):.1f}, max {max(walls):.1f}); "
        f"target < {TARGET_S:g} s: ratio {med / TARGET_S:.2f} "
        f"({'met' if med < TARGET_S else 'MISSED'}); {samples / med / 1e6:.1f} M samples/s end to end"
    )
    # Split one chunk of 500 runs into drawing samples and processing them.
    rng = np.random.default_rng(99)
    truths = [Truth(float(a), 34.0) for a in rng.uniform(0, 360, 500)]
    t0 = time.perf_counter()
    batch = simulate_windows(spec, truths, [0.0, 180.0], 10.0, n_runs=500, rng=rng, warmup_s=120)
    t1 = time.perf_counter()
    chunk_errors(
        batch.gyro_rps,
        batch.accel_mps2,
        batch.table_deg,
        batch.azimuth_deg,
        34.0,
        denoise_method=args.denoise,
    )
    t2 = time.perf_counter()
    print(
        f"one chunk of 500 runs: samples {t1 - t0:.2f} s "
        f"({500 * 2 * 2000 * 6 / (t1 - t0) / 1e6:.0f} M samples/s), "
        f"denoise + solve {t2 - t1:.2f} s"
    )


if __name__ == "__main__":
    main()
