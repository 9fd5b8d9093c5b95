"""Speed of ``northfinder find --sim`` of a 160 s plan, end to end, and of the quick start.

Run: ``.venv/bin/python benchmarks/bench_find.py [--repeats 5] [--speed S] [--mode both]``.
Without ``--speed`` the simulator runs in virtual time (the default of ``find --sim``); with it,
paced at S x real time.

The plan: positions 0,180 with two 59.95 s windows; the paper-rlg table turns 180 deg in 30.1 s
(6 deg/s, 60 deg/s^2) and settles 10 s, so the plan time (BENCHMARKS.md convention: windows +
moves + settling) is 59.95 + 40.1 + 59.95 = 160.0 s. The CLI also simulates what a real unit
would spend before the first window: the 120 s warm-up (``--warmup`` default) and the settle
after the first ``rotate_to(0)`` (10 s, the table already being at 0).

Simulated time is read from the device's own clock: the recording (``--record``) holds every
sample's counter, and the last sample's end (``counter / 200 Hz``) is the instrument time from
boot to the end of the plan. The ratio is that over the wall time; the conservative ratio counts
only the 160 s plan as simulated.

The quick start (``northfinder find --sim``, default plan: 120 s warm-up, 0 and 180 deg, 10 s
windows) is timed as a command too (``--quickstart N`` repeats, 0 for none), with its simulated
time from ``--record``.

Modes: ``subprocess`` runs the venv's ``northfinder find --sim ... --json --record FILE`` as a
new process and times it from start to exit (interpreter start and imports included, as a user
sees it); ``inprocess`` calls ``northfinder.cli.main([...])`` in this process after the imports (the
run itself). Every repeat uses another ``--seed`` (another true azimuth); the error against the
simulated truth is printed as a sanity figure with the white-noise bound for the plan.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_RATIO = 150.0
POSITIONS = "0,180"
WINDOW_S = 59.95
WARMUP_S = 120.0


def plan_time_s(sensor: str, window_s: float) -> tuple[float, float]:
    """Plan time (two windows + the 180 deg move + settle) and the move + settle, s."""
    from northfinder.firmware_sim.sensors import load_spec

    t = load_spec(sensor).table
    v, a, d = t.max_rate_dps, t.max_accel_dps2, 180.0
    motion = d / v + v / a if d >= v * v / a else 2.0 * math.sqrt(d / a)
    return 2 * window_s + motion + t.settle_s, motion + t.settle_s


def bound_deg(sensor: str, window_s: float, latitude_deg: float = 34.0) -> float:
    """White-noise bound of the 0,180 plan (both windows' dwell), deg."""
    from northfinder.firmware_sim.sensors import load_spec
    from northfinder.host.heading import two_position_bound_deg

    return two_position_bound_deg(
        load_spec(sensor).gyro.arw_dpsh, 2 * window_s, 180.0, latitude_deg
    )


def argv(seed: int, speed: float | None, window_s: float, sensor: str, record: str) -> list[str]:
    pace = [] if speed is None else ["--speed", f"{speed:g}"]
    return [
        *("find", "--sim", *pace, "--sensor", sensor, "--seed", str(seed)),
        *("--positions", POSITIONS, "--window", f"{window_s:g}", "--warmup", f"{WARMUP_S:g}"),
        *("--json", "--record", record),
    ]


#: The commands run as a user's installed command does: Python keeps the bytecode of the modules
#: it compiled (``__pycache__``). An environment with ``PYTHONDONTWRITEBYTECODE`` set (this
#: workplace's) would compile every module changed since the last write again on every start, a
#: quarter of a second here; :func:`main` runs the command once, untimed, to write it.
COMMAND_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def quickstart_once(seed: int) -> tuple[float, float]:
    """Wall and simulated seconds of ``northfinder find --sim`` as the quick start runs it (plus
    ``--seed`` and ``--record``, to read the simulated time)."""
    with tempfile.TemporaryDirectory() as tmp:
        record = os.path.join(tmp, "run.npz")
        t0 = time.perf_counter()
        done = subprocess.run(
            [str(ROOT / ".venv/bin/northfinder"), "find", "--sim", "--seed", str(seed),
             "--record", record],
            capture_output=True, text=True, cwd=ROOT, env=COMMAND_ENV,
        )  # fmt: skip
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(f"northfinder find failed: {done.stderr.strip()}")
        with np.load(record) as rec:
            rate = float(json.loads(str(rec["meta_json"]))["sample_rate_hz"])
            sim = float(rec["time_s"][-1]) + 1.0 / rate
    return wall, sim


def run_once(
    mode: str, seed: int, speed: float | None, window_s: float, sensor: str
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        record = os.path.join(tmp, "run.npz")
        args = argv(seed, speed, window_s, sensor, record)
        if mode == "subprocess":
            t0 = time.perf_counter()
            done = subprocess.run(
                [str(ROOT / ".venv/bin/northfinder"), *args],
                capture_output=True,
                text=True,
                cwd=ROOT,
                env=COMMAND_ENV,
            )
            wall = time.perf_counter() - t0
            if done.returncode != 0:
                raise SystemExit(f"northfinder find failed: {done.stderr.strip()}")
            out = done.stdout
        else:
            from northfinder.cli import main as cli_main

            buf = io.StringIO()
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(buf):
                rc = cli_main(args)
            wall = time.perf_counter() - t0
            if rc != 0:
                raise SystemExit(f"northfinder find failed with status {rc}")
            out = buf.getvalue()
        result = json.loads(out)
        with np.load(record) as rec:
            meta = json.loads(str(rec["meta_json"]))
            rate = float(meta["sample_rate_hz"])
            time_s, window = rec["time_s"], rec["window"]
            end = float(time_s[-1]) + 1.0 / rate
            first = float(time_s[0])
            second = float(time_s[window == 1][0])
    return {
        "mode": mode,
        "seed": seed,
        "wall_s": wall,
        "sim_s": end,
        "first_window_s": first,
        "between_s": second - (first + window_s),
        "plan_measured_s": end - first,
        "error_deg": float(result["error_deg"]),
        "sigma_deg": float(result["sigma_deg"]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--speed", type=float, default=None, help="paced (default: virtual time)")
    ap.add_argument("--quickstart", type=int, default=5, help="quick-start repeats (0: none)")
    ap.add_argument("--window", type=float, default=WINDOW_S)
    ap.add_argument("--sensor", default="paper-rlg")
    ap.add_argument("--mode", choices=("subprocess", "inprocess", "both"), default="both")
    args = ap.parse_args()
    modes = ("subprocess", "inprocess") if args.mode == "both" else (args.mode,)
    plan_s, move_s = plan_time_s(args.sensor, args.window)
    if "inprocess" in modes:
        from northfinder.cli import build_parser

        build_parser()  # imports every subcommand once, outside the timed runs
    if "subprocess" in modes or args.quickstart:
        # Untimed: writes the bytecode caches a user's first run writes (see COMMAND_ENV).
        subprocess.run(
            [str(ROOT / ".venv/bin/northfinder"), "find", "--sim", "--warmup", "0", "--window",
             "1", "--json"],
            capture_output=True, cwd=ROOT, env=COMMAND_ENV, check=True,
        )  # fmt: skip
    print(
        f"{time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, load average "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    print(
        f"plan: {args.sensor}, positions {POSITIONS}, 2 x {args.window:g} s windows, 180 deg move + "
        f"settle {move_s:.1f} s: plan time {plan_s:.1f} s; plus {WARMUP_S:g} s warm-up and the "
        f"first settle, simulated; "
        f"{'virtual time' if args.speed is None else f'--speed {args.speed:g}'}\n"
    )
    print(
        "| mode | seed | wall s | simulated s | first window at s | plan measured s | "
        "x real time | plan / wall | error deg | sigma deg |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    runs: dict[str, list[dict[str, Any]]] = {m: [] for m in modes}
    for seed in range(1, args.repeats + 1):
        for mode in modes:
            r = run_once(mode, seed, args.speed, args.window, args.sensor)
            runs[mode].append(r)
            print(
                f"| {mode} | {seed} | {r['wall_s']:.2f} | {r['sim_s']:.1f} | "
                f"{r['first_window_s']:.1f} | {r['plan_measured_s']:.1f} | "
                f"{r['sim_s'] / r['wall_s']:.1f} | {plan_s / r['wall_s']:.1f} | "
                f"{r['error_deg']:+.4f} | {r['sigma_deg']:.4f} |",
                flush=True,
            )
    print()
    for mode, rs in runs.items():
        wall = statistics.median(r["wall_s"] for r in rs)
        sim = statistics.median(r["sim_s"] for r in rs)
        ratio = sim / wall
        errors = np.array([r["error_deg"] for r in rs])
        print(
            f"{mode}: median wall {wall:.2f} s (min {min(r['wall_s'] for r in rs):.2f}, max "
            f"{max(r['wall_s'] for r in rs):.2f}), median simulated {sim:.1f} s: {ratio:.1f} x real "
            f"time (target >= {TARGET_RATIO:g}: ratio {ratio / TARGET_RATIO:.2f}, "
            f"{'met' if ratio >= TARGET_RATIO else 'MISSED'}); plan only {plan_s:.1f} s / wall = "
            f"{plan_s / wall:.1f} x; azimuth RMSE over {len(rs)} runs {np.sqrt(np.mean(errors**2)):.4f}"
            f" deg, largest |error| {np.max(np.abs(errors)):.4f} deg, mean sigma "
            f"{np.mean([r['sigma_deg'] for r in rs]):.4f} deg; white-noise bound "
            f"{bound_deg(args.sensor, args.window):.4f} deg"
        )
    if args.quickstart:
        print("\nquick start: northfinder find --sim (default plan), as a command")
        quick = [quickstart_once(seed) for seed in range(1, args.quickstart + 1)]
        for i, (wall, sim) in enumerate(quick, 1):
            print(
                f"  seed {i}: wall {wall:.2f} s, simulated {sim:.1f} s, {sim / wall:.1f} x real time"
            )
        wall = statistics.median(w for w, _ in quick)
        sim = statistics.median(s for _, s in quick)
        print(
            f"quick start: median wall {wall:.2f} s for {sim:.1f} s simulated: "
            f"{sim / wall:.1f} x real time"
        )


if __name__ == "__main__":
    main()
