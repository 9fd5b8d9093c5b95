"""Calibration round trip: preset -> simulated recording -> ``northfinder calibrate`` -> terms.

Run: ``.venv/bin/python benchmarks/bench_calibrate.py [--only static|positions] [--seeds 5]``

``static``: for each preset and record length, ``--seeds`` static recordings (one window, the
instrument still at 0 deg after a 2 min warm-up; ``Instrument`` samples written as a northfinder
recording) are calibrated by the command (``northfinder calibrate FILE --json``); each gyro term
is given as the ratio fitted / true (mean and range over the seeds and the three axes), or as
``n.r.`` when the record does not resolve it, with the ratio of the 95 % bound to the true value.
The value is the one written to the sensor file (the three axes pooled). The sample rate is
20 Hz: the presets' quantisation is far below their white noise at any rate, so nothing is lost,
and records stay small. A rate random walk passes the flicker floor only after
tau = 3 (0.664 B / K)^2 (5.3 h for tactical-fog's 0.5 deg/h/sqrt(h)), and a record must be about
30 times that long to show it; the case with RRW 5 deg/h/sqrt(h) (3 min) shows the recovery.

``positions``: ``paper-prototype`` runs of the paper's plan (eight 10 s windows 30 deg apart,
2 min warm-up, one recording per power-on, batch generator at 20 Hz) calibrated together with
``--between same-mount --heat-tau 100``: the between-position terms and the table's stop error
against the preset, for 7, 30 and 100 recordings.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from northfinder.cli import main as cli
from northfinder.driver.protocol.units import DPH
from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import SensorSpec, load_spec
from northfinder.host.recording import RecordedWindow, Recording
from northfinder.simwindows import write_recordings

TRUTH = Truth(azimuth_deg=75.0, latitude_deg=34.0)
#: (label, preset, overrides, hours, sample rate Hz)
STATIC_CASES = [
    ("paper-rlg", "paper-rlg", {}, 1.0, 20.0),
    ("paper-rlg", "paper-rlg", {}, 4.0, 20.0),
    ("paper-prototype", "paper-prototype", {}, 4.0, 20.0),
    ("nav-fog", "nav-fog", {}, 1.0, 20.0),
    ("nav-fog", "nav-fog", {}, 4.0, 20.0),
    ("tactical-fog", "tactical-fog", {}, 1.0, 20.0),
    ("tactical-fog", "tactical-fog", {}, 4.0, 20.0),
    ("tactical-fog, RRW 5", "tactical-fog", {"gyro.rrw_dphpsh": 5.0}, 4.0, 20.0),
    ("mems", "mems", {}, 1.0, 20.0),
    ("fog-0.08", "fog-0.08", {}, 4.0, 20.0),
]
#: Gyro terms: (column, JSON sensor field, axis coefficient -> datasheet unit)
GYRO_TERMS = [
    ("ARW", "arw", 1.0 / 60.0),
    ("bias instability", "bias_instability", 1.0),
    ("RRW", "rrw", 60.0),
    ("rate ramp", "rate_ramp", 3600.0),
]


def true_terms(spec: SensorSpec) -> dict[str, np.ndarray]:
    """The preset's gyro terms per axis in datasheet units. The rate ramp is the preset's ramp
    plus its temperature ramp times the temperature coefficient (the linear part of its drift;
    the fitted ramp is compared with the quadratic mean over the axes)."""
    g = spec.gyro
    ramp = np.asarray(g.rate_ramp_dph_per_h) + spec.thermal.ramp_c_per_h * np.asarray(
        g.temp_coeff_dph_per_c
    )
    return {
        "arw": np.full(3, g.arw_dpsh),
        "bias_instability": np.full(3, g.bias_instability_dph),
        "rrw": np.full(3, g.rrw_dphpsh),
        "rate_ramp": np.abs(ramp),
    }


def static_recording(spec: SensorSpec, hours: float, fs: float, seed: int, path: Path) -> None:
    ins = Instrument(spec, TRUTH, np.random.default_rng(seed), sample_rate_hz=fs)
    ins.generate(round(120.0 * fs))  # warm-up
    block = ins.generate(round(hours * 3600.0 * fs))
    window = RecordedWindow(
        0.0,
        block.counter,
        block.time_s,
        block.gyro_rps / DPH,
        block.accel_mps2,
        block.table_deg,
        block.temperature_c,
        np.full(len(block), 3, dtype=np.uint8),
    )
    Recording((window,), {"latitude_deg": TRUTH.latitude_deg, "sample_rate_hz": fs}).save(path)


def run_cli(args: list[str]) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = cli(["calibrate", *args, "--json"])
    if status:
        raise SystemExit(f"northfinder calibrate {' '.join(args)} failed ({status})")
    return json.loads(out.getvalue())


def cell(ratios: list[float], resolved: list[bool], bounds: list[float]) -> str:
    if all(resolved):
        return f"{np.mean(ratios):.3f} ({min(ratios):.2f}-{max(ratios):.2f})"
    if not any(resolved):
        return f"n.r. (bound {np.median(bounds):.2g}x)"
    k = sum(resolved)
    r = [x for x, ok in zip(ratios, resolved, strict=True) if ok]
    return f"{np.mean(r):.3f} ({min(r):.2f}-{max(r):.2f}), {k}/{len(resolved)} resolved"


def run_static(seeds: int, tmp: Path) -> None:
    print(
        "| sensor | record | rate Hz | "
        + " | ".join(f"{name} fitted/true" for name, _, _ in GYRO_TERMS)
        + " | s per run |"
    )
    print("|---|---:|---:|" + "---:|" * len(GYRO_TERMS) + "---:|")
    for label, preset, overrides, hours, fs in STATIC_CASES:
        spec = load_spec(preset).with_values(overrides)
        truth = true_terms(spec)
        got: dict[str, tuple[list[float], list[bool], list[float]]] = {
            key: ([], [], []) for _, key, _ in GYRO_TERMS
        }
        t0 = time.perf_counter()
        for seed in range(seeds):
            path = tmp / f"{preset}-{hours:g}h-{seed}.npz"
            static_recording(spec, hours, fs, seed, path)
            result = run_cli([str(path)])
            path.unlink()
            fit = result["triads"]["gyro"]
            for _, key, factor in GYRO_TERMS:
                true = float(np.sqrt(np.mean(truth[key] ** 2)))
                if true == 0.0:
                    continue
                ratios, resolved, bounds = got[key]
                ratios.append(fit["coefficients"][key] * factor / true)
                resolved.append(bool(fit["resolved"][key]))
                upper = fit["upper"][key]
                bounds.append(math.nan if upper is None else upper * factor / true)
        per_run = (time.perf_counter() - t0) / seeds
        cells = [
            cell(*got[key]) if got[key][0] else "(0 in the preset)" for _, key, _ in GYRO_TERMS
        ]
        print(f"| {label} | {hours:g} h | {fs:g} | " + " | ".join(cells) + f" | {per_run:.1f} |")


def position_recordings(spec: SensorSpec, runs: int, seed: int, tmp: Path) -> list[str]:
    positions = [float(a) for a in range(0, 240, 30)]
    return write_recordings(spec, TRUTH, positions, 10.0, runs, seed, tmp, sample_rate_hz=20.0)


def run_positions(seeds: int, tmp: Path) -> None:
    spec = load_spec("paper-prototype")
    g = spec.gyro
    truth = {
        "move_transient": g.move_transient_dph_per_rtdeg,
        "turn_on": g.turn_on_bias_dph,
        "arw": g.arw_dpsh,
        "indexing": spec.table.indexing_error_deg,
    }
    print(
        "| recordings | transient fitted/true | 95 % interval / true | turn-on fitted/true | "
        "95 % interval / true | move step (true 0) upper bound | ARW from the Allan fit / true "
        "| stop error fitted/true | s per set |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for runs in (7, 30, 100):
        rows: dict[str, list[float]] = {}
        t0 = time.perf_counter()
        for seed in range(seeds):
            paths = position_recordings(spec, runs, 100 * runs + seed, tmp)
            result = run_cli([*paths, "--between", "same-mount", "--heat-tau", "100"])
            for p in paths:
                Path(p).unlink()
            b = result["between"]
            for key in ("move_transient", "turn_on"):
                rows.setdefault(key, []).append(b["sigma"][key] / truth[key])
                lo, hi = b["interval"][key]
                rows.setdefault(key + " lo", []).append(lo / truth[key])
                rows.setdefault(key + " hi", []).append(hi / truth[key])
            rows.setdefault("walk", []).append(b["interval"]["move_walk"][1])
            rows.setdefault("arw", []).append(result["sensor"]["gyro"]["arw_dpsh"] / truth["arw"])
            rows.setdefault("indexing", []).append(
                result["indexing"]["sigma_deg"] / truth["indexing"]
            )
        per = (time.perf_counter() - t0) / seeds

        def rng(key: str, rows: dict[str, list[float]] = rows) -> str:
            v = rows[key]
            return f"{np.mean(v):.2f} ({min(v):.2f}-{max(v):.2f})"

        print(
            f"| {runs} | {rng('move_transient')} | {np.mean(rows['move_transient lo']):.2f}-"
            f"{np.mean(rows['move_transient hi']):.2f} | {rng('turn_on')} | "
            f"{np.mean(rows['turn_on lo']):.2f}-{np.mean(rows['turn_on hi']):.2f} | "
            f"{np.mean(rows['walk']):.2g} deg/h/sqrt(deg) | {rng('arw')} | {rng('indexing')} | "
            f"{per:.1f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("static", "positions"), default=None)
    ap.add_argument("--seeds", type=int, default=5, help="recordings (sets) per case (default 5)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.only in (None, "static"):
            run_static(args.seeds, tmp)
        if args.only in (None, "positions"):
            print()
            run_positions(args.seeds, tmp)


if __name__ == "__main__":
    main()
