"""Denoising methods against the raw window mean under each disturbance scenario.

Run: ``.venv/bin/python benchmarks/bench_filters.py [--runs 300] [--seed 2]``. Prints one markdown
table: azimuth RMSE (deg) of every method of ``northfinder.host.denoise.METHODS`` over the same seeded runs
(every method sees exactly the same samples), its ratio to the raw mean, and the winner of each
scenario. Plan 0,180 deg, 2 x 10 s at 200 Hz, 34 deg N, level instrument (no accelerometers, so
only the gyro processing is compared), gyro white noise ARW 0.0015 deg/sqrt(h) in every scenario.

Scenarios (added to the white noise):

- white: nothing else. The mean is optimal; no method can beat it (notes, section 4).
- impulses: door slams and footsteps, Poisson 0.5 /s, half-sine 0.05 s, 50 deg/h peak.
- vibration: a 37.37 Hz line (above 20 Hz), 100 deg/h on each gyro axis (a whole number of
  periods per window would cancel in the mean exactly; 37.37 Hz does not).
- drift: temperature drift, sensor warming by 10 degC with a 600 s time constant, 0.05 deg/h/degC.
  Also run with the symmetric order 0,180,180,0 (a plan remedy, not a filter).
- bias step: one 0.1 deg/h gyro bias step per run at a random time within the recording.

``moving-average`` uses a 5-sample window (one period of the vibration line rounded, 200 / 37.37).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from northfinder.firmware_sim.batch import simulate_windows
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import bound_deg
from northfinder.host.batch_solve import chunk_errors
from northfinder.host.denoise import METHODS

LATITUDE = 34.0
ARW = 0.0015
OPTIONS = {"moving-average": {"window": 5}}

SCENARIOS: dict[str, tuple[dict, float]] = {
    "white": ({}, 0.0),
    "impulses": (
        {"disturbance.impulse_rate_hz": 0.5, "gyro.impulse_dph": 50.0, "accel.impulse_ug": 5000.0},
        0.0,
    ),
    "vibration 37.37 Hz": ({"disturbance.vibration_hz": 37.37, "gyro.vibration_dph": 100.0}, 0.0),
    "temperature drift": (
        {
            "thermal.warmup_rise_c": 10.0,
            "thermal.warmup_tau_s": 600.0,
            "gyro.temp_coeff_dph_per_c": [0.05, -0.05, 0.05],
        },
        0.0,
    ),
    "bias step": ({}, 0.1),
}


def scenario_errors(
    overrides: dict, bias_step: float, positions: tuple[float, ...], runs: int, seed: int
) -> dict[str, np.ndarray]:
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": ARW, **overrides})
    rng = np.random.default_rng(seed)
    az = rng.uniform(0.0, 360.0, runs)
    out: dict[str, list[np.ndarray]] = {m: [] for m in METHODS}
    chunk = 100
    for start in range(0, runs, chunk):
        a = az[start : start + chunk]
        batch = simulate_windows(
            spec,
            [Truth(float(x), LATITUDE) for x in a],
            positions,
            10.0,
            2.0,
            n_runs=len(a),
            rng=rng,
            warmup_s=120.0,
            bias_step_dph=bias_step,
        )
        for m in METHODS:
            out[m].append(
                chunk_errors(
                    batch.gyro_rps,
                    None,
                    batch.commanded_deg,
                    batch.azimuth_deg,
                    LATITUDE,
                    denoise_method=m,
                    denoise_options=OPTIONS.get(m),
                )
            )
    return {m: np.concatenate(v) for m, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=300)
    ap.add_argument("--seed", type=int, default=2)
    args = ap.parse_args()
    methods = list(METHODS)
    rows = []
    t0 = time.perf_counter()
    cases: list[tuple[str, dict, float, tuple[float, ...]]] = [
        (name, ov, step, (0.0, 180.0)) for name, (ov, step) in SCENARIOS.items()
    ]
    ov, step = SCENARIOS["temperature drift"]
    cases.append(("temperature drift, order 0,180,180,0", ov, step, (0.0, 180.0, 180.0, 0.0)))
    for name, ov, step, positions in cases:
        errs = scenario_errors(ov, step, positions, args.runs, args.seed)
        rmse = {m: float(np.sqrt(np.mean(errs[m] ** 2))) for m in methods}
        rows.append((name, positions, rmse))
    wall = time.perf_counter() - t0
    b2 = bound_deg((0.0, 180.0), 10.0, ARW, LATITUDE)
    print(
        f"RMSE of the azimuth, deg, {args.runs} runs per scenario (same samples for every method; "
        f"relative standard error about {100 / np.sqrt(2 * args.runs):.0f} %), ratio to the raw "
        f"mean in brackets; white-noise bound {b2:.4f} deg (0,180) and "
        f"{bound_deg((0.0, 180.0, 180.0, 0.0), 10.0, ARW, LATITUDE):.4f} deg (0,180,180,0). "
        f"Wall time {wall:.0f} s.\n"
    )
    print("| scenario | " + " | ".join(methods) + " | winner | gain over raw mean |")
    print("|---|" + "---:|" * len(methods) + "---|---:|")
    for name, _, rmse in rows:
        raw = rmse["none"]
        cells = [
            f"{rmse[m]:.4f}" if m == "none" else f"{rmse[m]:.4f} ({rmse[m] / raw:.2f})"
            for m in methods
        ]
        win = min(methods, key=lambda m: rmse[m])
        gain = raw / rmse[win]
        # A gain inside the statistical spread of the same-sample comparison is no gain.
        verdict = win if gain > 1.03 else "none (raw mean)"
        print(f"| {name} | " + " | ".join(cells) + f" | {verdict} | x{gain:.2f} |")


if __name__ == "__main__":
    main()
