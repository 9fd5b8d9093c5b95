"""Static alignment (seed 001's Sage-Husa filter) under disturbances: error against reported sigma.

Run: ``.venv/bin/python benchmarks/bench_align.py [--runs 16]``

A resting FOG triad (gyro noise 0.05 deg/h/sqrt(Hz) and accelerometer noise 50 ug/sqrt(Hz), as
the filter's Q; turn-on biases 0.1 deg/h and 100 ug, the filter's P0), 300 s at 200 Hz, 39.8 deg
N, random azimuth and a tilt of a few degrees, simulated by the instrument. Scenarios: quiet; an
engine (vibration line 37.37 Hz: 1800 deg/h on each gyro, 0.2 g on each accelerometer); the
engine and people on the vehicle (Poisson impulses 0.5 per second, 0.05 s half-sines of 300 or
1000 deg/h and 20 mg, random directions). Filters: a conventional Kalman filter (KF), the
Sage-Husa adaptive filter (AKF) and AKF after wavelet forced denoising with a median filter on
the approximation (``forced-median``), each with the paper's fixed noise (``paper Q``) and with
the record's own noise where larger (``measured``, the default).

Per cell: the RMS azimuth error, the RMS reported sigma, the RMS of error / sigma (1 when the
sigma is honest; 1.08 is expected of the quiet case, whose P0 takes the coarse azimuth error as
independent of the east gyro bias), the share of runs with |error| <= 2 sigma (95 % if honest)
and the share the filter flags as not consistent with its model.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import AccelSpec, DisturbanceSpec, GyroSpec, SensorSpec
from northfinder.host.align import KalmanSettings, sage_husa_alignment
from northfinder.host.denoise import denoise

LATITUDE_DEG = 39.804
FS_HZ = 200.0
SCENARIOS = {
    "quiet": (0.0, 0.0, 0.0),
    "engine": (1800.0, 200_000.0, 0.0),
    "engine + impulses 300 deg/h": (1800.0, 200_000.0, 300.0),
    "engine + impulses 1000 deg/h": (1800.0, 200_000.0, 1000.0),
}
FILTERS = ("KF", "AKF", "wavelet + AKF")


def spec(vib_dph: float, vib_ug: float, impulse_dph: float) -> SensorSpec:
    return SensorSpec(
        gyro=GyroSpec(
            arw_dpsh=0.05 / 60.0, turn_on_bias_dph=0.1, vibration_dph=vib_dph,
            impulse_dph=impulse_dph,
        ),
        accel=AccelSpec(
            vrw_ug_rthz=50.0, turn_on_bias_ug=100.0, vibration_ug=vib_ug,
            impulse_ug=20_000.0 if impulse_dph else 0.0,
        ),
        disturbance=DisturbanceSpec(
            vibration_hz=37.37 if vib_dph else 0.0, impulse_rate_hz=0.5 if impulse_dph else 0.0,
            impulse_duration_s=0.05,
        ),
    )  # fmt: skip


def angle_error(a: float, b: float) -> float:
    return (a - b + 180.0) % 360.0 - 180.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=16, help="runs per scenario (default 16)")
    args = ap.parse_args()
    print(
        "| scenario | filter | noise | RMS error deg | RMS sigma deg | RMS error/sigma | "
        "abs(error) <= 2 sigma | flagged |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|")
    t0 = time.perf_counter()
    for label, params in SCENARIOS.items():
        rows: dict[tuple[str, bool], list[tuple[float, float, bool]]] = {}
        for seed in range(args.runs):
            rng = np.random.default_rng(seed)
            az = float(rng.uniform(0.0, 360.0))
            truth = Truth(az, LATITUDE_DEG, *rng.uniform(-3.0, 3.0, 2))
            block = Instrument(spec(*params), truth, rng).generate(round(300 * FS_HZ))
            for name in FILTERS:
                gyro, accel = block.gyro_rps, block.accel_mps2
                if name.startswith("wavelet"):
                    gyro = denoise(gyro, "forced-median", axis=0)
                    accel = denoise(accel, "forced-median", axis=0)
                for measured in (False, True):
                    settings = KalmanSettings(adaptive=name != "KF", measured_noise=measured)
                    r = sage_husa_alignment(gyro, accel, FS_HZ, LATITUDE_DEG, settings=settings)
                    rows.setdefault((name, measured), []).append(
                        (angle_error(r.azimuth_deg, az), r.sigma_deg, r.consistent)
                    )
        for (name, measured), values in rows.items():
            e = np.array([v[0] for v in values])
            s = np.array([v[1] for v in values])
            flagged = np.mean([not v[2] for v in values])
            print(
                f"| {label} | {name} | {'measured' if measured else 'paper Q'} | "
                f"{np.sqrt(np.mean(e**2)):.3f} | {np.sqrt(np.mean(s**2)):.3f} | "
                f"{np.sqrt(np.mean((e / s) ** 2)):.2f} | {100 * np.mean(np.abs(e) <= 2 * s):.0f} % | "
                f"{100 * flagged:.0f} % |"
            )
    print(f"\n{args.runs} runs per scenario, {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
