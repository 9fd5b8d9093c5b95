"""The paper's prototype against the simulator: the fit of Table 1, and Tables 1 and 2 replayed.

Run: ``.venv/bin/python benchmarks/bench_prototype.py [--only fit|compare] [--sets 1000]``

``fit`` fits the variance components of Table 1 (seed 000: seven runs of 10 s window means at
eight positions 30 deg apart) with :func:`northfinder.host.calibrate.between.fit_between_positions`
and prints the estimates, their 95 % profile intervals, the likelihood of the alternatives (a
random walk through the moves, other transient time constants, a bias instability) and the
refit with the values the ``paper-prototype`` preset sets.

``compare`` simulates ``--sets`` independent seven-run sets of the paper's procedure (2 min
warm-up, then 10 s windows at 0, 30, ..., 210 deg, 30 deg moves at the table's 6 deg/s and 10 s
still after each) on one mount (true azimuth 75.08632 deg, 34 deg N, level) for
``paper-prototype`` and ``paper-rlg``, and sets the paper's scatter beside them:

- Table 2: the spread (standard deviation over the seven runs) of the azimuth per mu, from
  positions 1 and k + 1 by the level formula (eq. 15), as the paper computed it;
- Table 1: the scatter over the runs of the window means at each position, and of their
  differences from position 1 (between-position), x and y gyro pooled.

Each row gives the paper's value, the simulated value (root mean square over the sets of the
seven-run figure), their ratio, the range that holds 68 % of the simulated seven-run figures
(as a ratio to the simulated value: the 7-run sampling interval) and how often a simulated set
scatters at least as much as the paper's data did (the paper's percentile from the top).
Samples are simulated at 20 Hz: window means and their statistics do not depend on the rate
for these sensors (no quantisation).
"""

from __future__ import annotations

import argparse
import math
import time
import tomllib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.units import DPH, OMEGA_IE
from northfinder.firmware_sim.batch import plan_timeline, simulate_windows
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.calibrate.between import RunWindows, SlowNoise, fit_between_positions
from northfinder.host.heading import pairwise_azimuths

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "prototype_tables.toml"
LATITUDE_DEG = 34.0
WARMUP_S = 120.0


def load_tables() -> dict:
    with DATA.open("rb") as fh:
        return tomllib.load(fh)


def table1_dph(tables: dict) -> tuple[NDArray[np.float64], float]:
    """Table 1 in deg/h, (runs, positions, 2), and the scale used (deg/h per mV).

    The scale makes the mean amplitude of (x, y) the horizontal Earth rate at 34 deg N.
    """
    x = np.array(tables["table1_x_mv"])
    y = np.array(tables["table1_y_mv"])
    scale = OMEGA_IE * math.cos(math.radians(LATITUDE_DEG)) / DPH / float(np.hypot(x, y).mean())
    return np.stack([x, y], axis=-1) * scale, scale


def paper_runs(tables: dict, step_s: float) -> list[RunWindows]:
    means, _ = table1_dph(tables)
    return [RunWindows.regular(m, tables["mu_deg"], tables["window_s"], step_s) for m in means]


def step_s(spec_name: str = "paper-prototype") -> float:
    """Window start to window start of the paper's plan on the preset's table, s."""
    spec = load_spec(spec_name)
    starts, _, _, _ = plan_timeline(spec, [0.0, 30.0], 10.0, sample_rate_hz=200.0)
    return float(starts[1] - starts[0]) / 200.0


def fmt_fit(label: str, fit) -> str:
    parts = []
    for name in ("white", "turn_on", "move_walk", "move_transient"):
        v, (lo, hi) = fit.sigma[name], fit.interval[name]
        parts.append(f"{name} {v:.5f} ({lo:.5f}-{hi:.5f})")
    return f"{label:<44} logL {fit.log_likelihood:8.3f}  " + ", ".join(parts)


def run_fit() -> None:
    tables = load_tables()
    step = step_s()
    runs = paper_runs(tables, step)
    _, scale = table1_dph(tables)
    print(f"Table 1: 7 runs x 8 positions, {scale:.2f} deg/h per mV, windows 10 s every {step} s")
    print("units: white and turn_on deg/h (10 s mean), move terms deg/h/sqrt(deg); 95 % intervals")
    best = fit_between_positions(runs, tau_s=10.0, design="same-mount")
    print(fmt_fit("maximum likelihood, tau 10 s", best))
    delay = step - 10.0
    lo, hi = best.interval["move_transient"]
    w = best.transient_in_window_dph(delay, 10.0, 30.0) / best.sigma["move_transient"]
    print(
        f"  transient in the window {delay:.1f} s after a 30 deg move: "
        f"{best.sigma['move_transient'] * w:.4f} deg/h ({lo * w:.4f}-{hi * w:.4f}); "
        f"ARW from white: {best.sigma['white'] * math.sqrt(10.0) / 60.0:.6f} deg/sqrt(h)"
    )
    walk = fit_between_positions(
        runs, tau_s=10.0, design="same-mount", fixed={"move_transient": 0.0}
    )
    print(fmt_fit("no transient (a random walk through the moves)", walk))
    print(f"  log-likelihood below the transient: {best.log_likelihood - walk.log_likelihood:.1f}")
    print("transient time constant (the rest refitted):")
    for tau in (2.5, 5.0, 10.0, 15.0, 20.0, 30.0, 60.0):
        f = fit_between_positions(runs, tau_s=tau, design="same-mount")
        print(
            f"  tau {tau:5.1f} s: logL {f.log_likelihood:8.3f}  drop {best.log_likelihood - f.log_likelihood:5.2f}"
        )
    print("drive heat: a move's disturbance has the variance of the angles turned so far, each")
    print("decayed with the heat time constant (the rest refitted):")
    for heat in (25.0, 50.0, 100.0, 200.0, 400.0, 1e6):
        f = fit_between_positions(runs, tau_s=10.0, design="same-mount", heat_tau_s=heat)
        print(
            f"  heat {heat:7.0f} s: logL {f.log_likelihood:8.3f}  gain {f.log_likelihood - best.log_likelihood:5.2f}  transient {f.sigma['move_transient']:.4f}"
        )
    print("bias instability B as a known part (the rest refitted):")
    for b in (0.001, 0.002, 0.003, 0.004, 0.005):
        f = fit_between_positions(runs, tau_s=10.0, design="same-mount", slow=SlowNoise(b))
        print(
            f"  B {b:.3f} deg/h: logL {f.log_likelihood:8.3f}  drop {best.log_likelihood - f.log_likelihood:5.2f}"
        )
    spec = load_spec("paper-prototype")
    g = spec.gyro
    heat = spec.table.heat_tau_s
    ml = fit_between_positions(
        runs, tau_s=g.move_transient_tau_s, design="same-mount", heat_tau_s=heat
    )
    print(fmt_fit(f"maximum likelihood, tau 10 s, heat {heat:g} s", ml))
    print(f"  ARW from white: {ml.sigma['white'] * math.sqrt(10.0) / 60.0:.6f} deg/sqrt(h)")
    preset = fit_between_positions(
        runs,
        tau_s=g.move_transient_tau_s,
        design="same-mount",
        slow=SlowNoise(g.bias_instability_dph),
        fixed={"turn_on": g.turn_on_bias_dph, "move_walk": g.move_walk_dph_per_rtdeg},
        heat_tau_s=heat,
    )
    print(fmt_fit(f"refit with the preset's B and turn-on {g.bias_instability_dph}", preset))
    print(
        f"  drop from the heat fit {ml.log_likelihood - preset.log_likelihood:.2f}; ARW "
        f"{preset.sigma['white'] * math.sqrt(10.0) / 60.0:.6f} deg/sqrt(h) (preset "
        f"{g.arw_dpsh}), transient {preset.sigma['move_transient']:.4f} (preset "
        f"{g.move_transient_dph_per_rtdeg})"
    )


def simulate_sets(name: str, sets: int, seed: int) -> dict[str, NDArray[np.float64]]:
    """Statistics of ``sets`` simulated seven-run sets (same keys as :func:`paper_stats`)."""
    spec = load_spec(name)
    positions = [float(a) for a in range(0, 240, 30)]
    truth = Truth(azimuth_deg=75.08632, latitude_deg=LATITUDE_DEG)
    rng = np.random.default_rng(seed)
    chunk = 100
    out: dict[str, list[NDArray[np.float64]]] = {}
    for first in range(0, sets, chunk):
        n = min(chunk, sets - first)
        batch = simulate_windows(
            spec, truth, positions, 10.0, n_runs=7 * n, rng=rng, sample_rate_hz=20.0,
            warmup_s=WARMUP_S,
        )  # fmt: skip
        means = batch.gyro_rps.mean(axis=2) / DPH  # (runs, positions, 3), deg/h
        az = np.array(
            [
                [s.azimuth_deg for s in pairwise_azimuths(m[:, :2], positions, rate_unit="deg/h")]
                for m in means
            ]
        )
        for key, value in stats(means[..., :2].reshape(n, 7, 8, 2), az.reshape(n, 7, 7)).items():
            out.setdefault(key, []).append(value)
    return {k: np.concatenate(v) for k, v in out.items()}


def stats(means: NDArray[np.float64], az: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """Seven-run figures of sets: means (sets, 7, 8, 2) deg/h, azimuths (sets, 7, 7) deg."""
    pooled = np.sqrt(np.mean(np.var(means, axis=1, ddof=1), axis=-1))  # (sets, 8)
    diff = means[:, :, 1:] - means[:, :, :1]
    between = np.sqrt(np.mean(np.var(diff, axis=1, ddof=1), axis=-1))  # (sets, 7)
    wrapped = (az - az[:, :1] + 180.0) % 360.0 - 180.0  # spread needs no common reference
    return {
        "table2": np.std(wrapped, axis=1, ddof=1),
        "position": pooled,
        "between": between,
    }


def paper_stats(tables: dict) -> dict[str, NDArray[np.float64]]:
    means, _ = table1_dph(tables)
    az = np.array(tables["table2_azimuth_deg"])
    return {k: v[0] for k, v in stats(means[None], az[None]).items()}


def run_compare(sets: int) -> None:
    tables = load_tables()
    paper = paper_stats(tables)
    labels = {
        "table2": ("Table 2: azimuth spread over 7 runs, deg", [f"mu {m:g}" for m in tables["pair_mu_deg"]]),
        "position": ("Table 1: scatter of the window means over 7 runs (x, y pooled), deg/h", [f"pos {k + 1} ({m:g})" for k, m in enumerate(tables["mu_deg"])]),
        "between": ("Table 1: scatter of (position k - position 1) over 7 runs (x, y pooled), deg/h", [f"pos {k + 2} - pos 1" for k in range(7)]),
    }  # fmt: skip
    sims = {}
    for name in ("paper-prototype", "paper-rlg"):
        t0 = time.perf_counter()
        sims[name] = simulate_sets(name, sets, seed=2024)
        print(f"{name}: {sets} sets of 7 runs simulated in {time.perf_counter() - t0:.1f} s")
    for key, (title, rows) in labels.items():
        print()
        print(f"### {title}")
        print()
        print(
            "| row | paper | paper-prototype | ratio | 68 % of 7-run sets | sets >= paper "
            "| paper-rlg | ratio |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        inside = inside95 = 0
        for i, row in enumerate(rows):
            p = paper[key][i]
            proto = sims["paper-prototype"][key][:, i]
            rms = float(np.sqrt(np.mean(proto**2)))
            lo, hi = np.percentile(proto / rms, [16.0, 84.0])
            above = float(np.mean(proto >= p))
            rlg = float(np.sqrt(np.mean(sims["paper-rlg"][key][:, i] ** 2)))
            inside += lo <= p / rms <= hi
            inside95 += 0.025 <= above <= 0.975
            print(
                f"| {row} | {p:.4f} | {rms:.4f} | {p / rms:.2f} | {lo:.2f}-{hi:.2f} | "
                f"{100 * above:.0f} % | {rlg:.4f} | {p / rlg:.2f} |"
            )
        print()
        print(
            f"paper/paper-prototype inside the 68 % interval: {inside} of {len(rows)} (a right "
            f"model puts 68 % there); inside the 95 % interval: {inside95} of {len(rows)}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("fit", "compare"), default=None)
    ap.add_argument("--sets", type=int, default=1000, help="simulated 7-run sets (default 1000)")
    args = ap.parse_args()
    if args.only in (None, "fit"):
        run_fit()
    if args.only in (None, "compare"):
        print()
        run_compare(args.sets)


if __name__ == "__main__":
    main()
