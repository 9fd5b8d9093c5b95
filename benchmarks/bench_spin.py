"""North finding on a turning table: RMSE against the spin bound, spin against stop-and-go for the
same time, and the time of ``find --sim --spin``.

Run: ``.venv/bin/python benchmarks/bench_spin.py [--runs 10000] [--only ratio|budget|find|sigma|heat|halves]``.
Prints markdown tables:

1. RMSE / bound for white gyro (ARW 0.0015 deg/sqrt(h)) and accelerometer (20 ug/sqrt(Hz)) noise,
   turn-on biases, 34 deg N, tilt within +-3 deg, 10 Hz samples (the bound does not depend on the
   rate), for several table rates, spin times and with a drift fitted; the Monte Carlo's own
   scatter is 1 / sqrt(2 runs).
2. For time budgets of 60, 160 and 600 s with the default table (6 deg/s, 10 deg/s^2, 2 s settle):
   the white-noise bound of a spin using the budget (less the acceleration to the rate) and of the
   stop-and-go plans 0, 180 and 0, 180, 180, 0 whose windows fill the budget after their moves and
   settling.
3. Wall time of ``northfinder find --sim --warmup 0 --spin 6`` (one turn, virtual time): median of
   three.
4. Sigma: for every preset, the planner's best spin of a 160 s budget solved run by run
   (:func:`~northfinder.host.spin.solve_spin`, 120 s after power-on, 50 Hz): the RMSE with its
   95 % chi-square interval, the mean reported sigma and their ratio (target 0.95 to 1.05).
5. The drive's heat in the step-by-step instrument: ``paper-prototype`` (``spin_heat`` 1) and
   the same with ``spin_heat`` 0, one turn at 6 deg/s 30 s after power-on, 20 Hz: the RMSE of
   the instrument's spins (``tests/test_spin_heat.py``, run by run as ``find --spin`` solves),
   that of the batch generator's (``simulate_spin``) and the prediction, with 95 % intervals.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from northfinder.firmware_sim.batch import simulate_spin
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import bound_deg, spin_bound_deg
from northfinder.host.plan import Plan, TableModel, plan_time_s
from northfinder.host.spin import solve_spin_batch

LAT = 34.0
ARW, VRW, FS = 0.0015, 20.0, 10.0


def ratio_rows(runs: int) -> None:
    spec = load_spec("ideal").with_values({
        "gyro.arw_dpsh": ARW, "accel.vrw_ug_rthz": VRW,
        "gyro.turn_on_bias_dph": 0.5, "accel.turn_on_bias_ug": 100.0,
    })  # fmt: skip
    print(
        "| rate deg/s | spin s | turns | drift fitted | runs | RMSE deg | bound deg | RMSE/bound | MC scatter |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for rate, duration, drift in ((6.0, 60.0, False), (-6.0, 120.0, False), (20.0, 54.0, False),
                                  (3.0, 60.0, False), (-9.0, 60.0, True)):  # fmt: skip
        rng = np.random.default_rng(11)
        errors = []
        for _ in range(runs // 500):
            truths = [Truth(azimuth_deg=a, pitch_deg=p, roll_deg=r, latitude_deg=LAT)
                      for a, p, r in zip(rng.uniform(0, 360, 500), rng.uniform(-3, 3, 500),
                                         rng.uniform(-3, 3, 500), strict=True)]  # fmt: skip
            b = simulate_spin(spec, truths, rate, duration, n_runs=500, rng=rng, sample_rate_hz=FS)
            az = solve_spin_batch(b.gyro_rps, b.accel_mps2, b.mu0_rad, b.mu1_rad,
                                  latitude_deg=LAT, time_s=b.time_s, drift=drift)  # fmt: skip
            errors.append((az - b.azimuth_deg + 180.0) % 360.0 - 180.0)
        e = np.concatenate(errors)
        bound = spin_bound_deg(duration, rate, ARW, LAT, sample_rate_hz=FS, vrw_ug_rthz=VRW,
                               drift=drift)  # fmt: skip
        rmse = math.sqrt(float(np.mean(e**2)))
        print(f"| {rate:+g} | {duration:g} | {abs(rate) * duration / 360:.2f} | {'yes' if drift else 'no'} "
              f"| {e.size} | {rmse:.4f} | {bound:.4f} | {rmse / bound:.3f} | {1 / math.sqrt(2 * e.size):.3f} |")  # fmt: skip


def budget_rows() -> None:
    table = TableModel(max_rate_dps=6.0, max_accel_dps2=10.0, settle_s=2.0)
    print("| budget s | spin: steady s | spin bound deg | 0,180: window s | bound deg "
          "| 0,180,180,0: window s | bound deg |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for budget in (60.0, 160.0, 600.0):
        steady = budget - 2 * table.max_rate_dps / table.max_accel_dps2  # spin up and brake
        # All the steady time, or the whole turns within it: whichever is better.
        turns = math.floor(steady * table.max_rate_dps / 360.0)
        choices = {steady, turns * 360.0 / table.max_rate_dps} - {0.0}
        b_spin, spin_s = min(
            (spin_bound_deg(t, table.max_rate_dps, ARW, LAT, sample_rate_hz=FS), t) for t in choices
        )
        cells = []
        for pos in ((0.0, 180.0), (0.0, 180.0, 180.0, 0.0)):
            overhead = plan_time_s(Plan(pos, 1.0), table) - len(pos)
            window = (budget - overhead) / len(pos)
            if window <= 0:
                cells += ["does not fit", "-"]
            else:
                cells += [f"{window:.1f}", f"{bound_deg(list(pos), window, ARW, LAT):.4f}"]
        print(f"| {budget:g} | {spin_s:.1f} | {b_spin:.4f} | " + " | ".join(cells) + " |")


def find_rows() -> None:
    exe = Path(sys.executable).with_name("northfinder")
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run([str(exe), "find", "--sim", "--warmup", "0", "--spin", "6"], check=True,
                       capture_output=True)  # fmt: skip
        times.append(time.perf_counter() - t0)
    print(
        f"find --sim --warmup 0 --spin 6 (60 s of 200 Hz samples): median {statistics.median(times):.2f} s wall"
    )


def sigma_rows(runs: int) -> None:
    from scipy.stats import chi2

    from northfinder.firmware_sim.sensors import preset_names
    from northfinder.host.accuracy import predict
    from northfinder.host.plan import spin_start_deg
    from northfinder.host.plan_search import search_spin_plans
    from northfinder.host.spin import SpinSamples, reported_sigma, solve_spin
    from northfinder.simwindows import error_model

    print("| preset | spin | runs | RMSE deg [95 %] | mean sigma deg | RMSE / mean sigma | "
          "predicted deg | mean sigma / predicted | batch reported | halves failed |")  # fmt: skip
    print("|---|---|---:|---|---:|---|---:|---:|---:|---:|")
    for name in preset_names():
        if name == "ideal":
            continue
        spec = load_spec(name)
        model = error_model(spec)
        plan = search_spin_plans(model, LAT, 160.0, warmup_s=120.0,
                                 sample_rate_hz=50.0)[0].plan  # fmt: skip
        pred = predict(model, plan, LAT, warmup_s=120.0, sample_rate_hz=50.0).sigma_deg
        rng = np.random.default_rng(17)
        truths = [Truth(azimuth_deg=a, pitch_deg=p, roll_deg=r, latitude_deg=LAT)
                  for a, p, r in zip(rng.uniform(0, 360, runs), rng.uniform(-1, 1, runs),
                                     rng.uniform(-1, 1, runs), strict=True)]  # fmt: skip
        start = spin_start_deg(plan, TableModel(max_rate_dps=spec.table.max_rate_dps,
                                                max_accel_dps2=spec.table.max_accel_dps2))  # fmt: skip
        b = simulate_spin(spec, truths, plan.rate_dps, plan.spin_s, n_runs=runs, rng=rng,
                          sample_rate_hz=50.0, start_deg=start, start_s=120.0)  # fmt: skip
        enc = (b.mu0_rad, b.mu1_rad) if b.encoder_rad is None else (
            b.encoder_rad[:, :-1], b.encoder_rad[:, 1:])  # fmt: skip
        err, sig, batch, failed = [], [], 0, 0
        for r in range(runs):
            sol = solve_spin(SpinSamples(b.gyro_rps[r], b.accel_mps2[r], enc[0][r], enc[1][r],
                                         b.time_s), latitude_deg=LAT, drift=plan.drift)  # fmt: skip
            err.append((sol.azimuth_deg - b.azimuth_deg[r] + 180.0) % 360.0 - 180.0)
            sig.append(sol.sigma_deg)
            # the batch estimate reported (before any scaling by the halves' disagreement)
            batch += reported_sigma(sol.sigma_white_deg, sol.sigma_batch_deg) != sol.sigma_white_deg
            failed += sol.consistent is False
        e = np.asarray(err)
        rmse = math.sqrt(float(np.mean(e**2)))
        lo, hi = (rmse * math.sqrt(runs / chi2.ppf(q, runs)) for q in (0.975, 0.025))
        ms = float(np.mean(sig))
        print(f"| {name} | {plan.rate_dps:+g} deg/s x {plan.spin_s:.1f} s"
              f"{', drift' if plan.drift else ''} | {runs} | {rmse:.5f} [{lo:.5f}, {hi:.5f}] | "
              f"{ms:.5f} | {rmse / ms:.3f} [{lo / ms:.3f}, {hi / ms:.3f}] | {pred:.5f} | "
              f"{ms / pred:.3f} | {batch} | {failed} |",
              flush=True)  # fmt: skip


def heat_rows(runs: int) -> None:
    from scipy.stats import chi2

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_spin_heat import instrument_spin_errors

    from northfinder.host.accuracy import predict
    from northfinder.host.plan import SpinPlan
    from northfinder.simwindows import error_model

    rate, spin_s, warmup_s, fs = 6.0, 60.0, 30.0, 20.0

    def cell(e: np.ndarray) -> str:
        rmse = math.sqrt(float(np.mean(e**2)))
        lo, hi = (rmse * math.sqrt(e.size / chi2.ppf(q, e.size)) for q in (0.975, 0.025))
        return f"{rmse:.4f} [{lo:.4f}, {hi:.4f}]"

    print("| preset | spin_heat | runs | instrument RMSE deg [95 %] | batch RMSE deg [95 %] | "
          "predicted deg |")  # fmt: skip
    print("|---|---:|---:|---|---|---:|")
    for spin_heat in (1.0, 0.0):
        spec = load_spec("paper-prototype").with_values({"table.spin_heat": spin_heat})
        ins = instrument_spin_errors(spec, runs, rate=rate, spin_s=spin_s, warmup_s=warmup_s,
                                     fs=fs)  # fmt: skip
        rng = np.random.default_rng(23)
        truths = [Truth(azimuth_deg=a, latitude_deg=LAT) for a in rng.uniform(0, 360, runs)]
        b = simulate_spin(spec, truths, rate, spin_s, n_runs=runs, rng=rng, sample_rate_hz=fs,
                          start_s=warmup_s + rate / spec.table.max_accel_dps2)  # fmt: skip
        enc = (b.mu0_rad, b.mu1_rad) if b.encoder_rad is None else (
            b.encoder_rad[:, :-1], b.encoder_rad[:, 1:])  # fmt: skip
        az = solve_spin_batch(b.gyro_rps, b.accel_mps2, *enc, latitude_deg=LAT)
        batch = (az - b.azimuth_deg + 180.0) % 360.0 - 180.0
        pred = predict(error_model(spec), SpinPlan(rate, spin_s), LAT, warmup_s=warmup_s,
                       sample_rate_hz=fs).sigma_deg  # fmt: skip
        print(f"| paper-prototype | {spin_heat:g} | {runs} | {cell(ins)} | {cell(batch)} | "
              f"{pred:.4f} |", flush=True)  # fmt: skip


def halves_rows(runs: int, sensor: str = "paper-prototype") -> None:
    """``find --sim --spin 6 --sensor SENSOR --seed N --json`` for seeds 1..runs (in process):
    how many fail the halves check (exit 3), and the RMSE against the mean sigma of those that
    pass, of those that fail (their sigma scaled by the halves' disagreement) and unscaled."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from clirun import run_cli

    rows = []
    for seed in range(1, runs + 1):
        code, out, _ = run_cli("find", "--sim", "--spin", "6", "--sensor", sensor, "--seed",
                               str(seed), "--json")  # fmt: skip
        doc = json.loads(out)
        rows.append((code, doc["error_deg"], doc["sigma_deg"], doc["spin"]["sigma_scale"]))
    codes, err, sig, scale = (np.array(c) for c in zip(*rows, strict=True))
    failed: np.ndarray = codes == 3

    def rmse(e: np.ndarray) -> float:
        return math.sqrt(float(np.mean(e**2))) if e.size else math.nan

    def mean(e: np.ndarray) -> float:
        return float(np.mean(e)) if e.size else math.nan

    print(f"find --sim --spin 6 --sensor {sensor}, seeds 1..{runs}: halves failed (exit 3) in "
          f"{int(failed.sum())}; RMSE {rmse(err):.4f} deg, mean sigma {sig.mean():.4f} "
          f"(unscaled {np.mean(sig / scale):.4f}); passed: RMSE {rmse(err[~failed]):.4f}, mean "
          f"sigma {mean(sig[~failed]):.4f}; failed: RMSE {rmse(err[failed]):.4f}, mean sigma "
          f"{mean(sig[failed]):.4f}; errors beyond 3 sigma "
          f"{int(np.sum(np.abs(err) > 3 * sig))} (unscaled "
          f"{int(np.sum(np.abs(err) > 3 * sig / scale))})")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=10_000)
    p.add_argument("--only", choices=("ratio", "budget", "find", "sigma", "heat", "halves"))
    a = p.parse_args()
    if a.only in (None, "ratio"):
        ratio_rows(a.runs)
    if a.only in (None, "budget"):
        budget_rows()
    if a.only in (None, "find"):
        find_rows()
    if a.only in (None, "sigma"):
        sigma_rows(min(a.runs, 400))
    if a.only in (None, "heat"):
        heat_rows(min(a.runs, 400))
    if a.only in (None, "halves"):
        halves_rows(min(a.runs, 80))


if __name__ == "__main__":
    main()
