"""What the ``study`` modes and ``sweep`` share: the limits of their options, the sensor,
settings and processing of a study from the arguments, a plan's JSON, the seeded Monte Carlo
with its wall time and progress, and the table of its rows.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import Executor
from dataclasses import replace
from typing import Any

from northfinder.cli.output import say
from northfinder.cli.progress import Progress
from northfinder.cli.simulated import load_sensor
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.host.accuracy import ErrorModel
from northfinder.host.montecarlo import StudySettings, monte_carlo
from northfinder.host.plan import Plan, SpinPlan, plan_time_s, settle_time_s, spin_ramp_s
from northfinder.simwindows import SimulatedWindows

#: Bounds of what a study may ask for: runs, seconds (settle, warm-up, budget), deg/h (the window
#: and the sample rate: :data:`~northfinder.simwindows.MAX_WINDOW_S`, ``MAX_RATE_HZ``).
MAX_RUNS = 1_000_000
MAX_SETTLE_S = 3600.0
MAX_WARMUP_S = 86_400.0
MAX_BUDGET_S = 86_400.0
MAX_BIAS_STEP_DPH = 1e6
MAX_TOP = 1000


def load_study_sensor(args: argparse.Namespace) -> SensorSpec:
    spec: SensorSpec = load_sensor(args.sensor, dict(args.overrides))
    return spec


def with_processing(args: argparse.Namespace, plan: Plan) -> Plan:
    """The plan with the denoising and solver of the arguments."""
    return replace(
        plan,
        denoise=args.denoise,
        method=args.solver,
        denoise_options=tuple(args.denoise_options),
    )


def study_settings(args: argparse.Namespace, latitude_deg: float) -> StudySettings:
    """The study settings of the arguments (``study`` and ``sweep`` spell them alike)."""
    return StudySettings(
        latitude_deg=latitude_deg,
        azimuth_deg=args.azimuth,
        pitch_deg=args.pitch,
        roll_deg=args.roll,
        warmup_s=args.warmup,
        sample_rate_hz=args.rate,
        denoise_accel=args.denoise_accel,
        tilt=args.tilt,
        angles=args.angles,
        bias_step_dph=args.bias_step,
    )


def describe_plan(plan: Plan | SpinPlan, model: ErrorModel, warmup_s: float) -> dict[str, Any]:
    t = plan_time_s(plan, model.table)
    if isinstance(plan, SpinPlan):
        return {
            "kind": "spin",
            "rate_dps": plan.rate_dps,
            "spin_s": plan.spin_s,
            "turns": plan.turns,
            "drift": plan.drift,
            "ramp_s": spin_ramp_s(plan, model.table),
            "plan_time_s": t,
            "warmup_s": warmup_s,
            "total_time_s": t + warmup_s,
        }
    return {
        "positions_deg": list(plan.positions_deg),
        "window_s": plan.window_s,
        "settle_s": settle_time_s(plan, model.table),
        "plan_time_s": t,
        "warmup_s": warmup_s,
        "total_time_s": t + warmup_s,
    }


def row_label(r: dict[str, Any]) -> str:
    if "rate_dps" in r:
        return f"{r['rate_dps']:+g} deg/s"
    if "mu_deg" in r:
        return f"{r['mu_deg']:g}"
    return ",".join(f"{p:g}" for p in r["positions_deg"])


def print_rows(rows: list[dict[str, Any]]) -> None:
    first = "mu deg" if "mu_deg" in rows[0] else "spin" if "rate_dps" in rows[0] else "positions"
    say(
        f"{first:>14} {'bias deg':>10} {'RMSE deg':>10} {'+-':>6} {'bound deg':>10} "
        f"{'RMSE/bound':>10} {'predicted':>10}"
    )
    for r in rows:
        label = row_label(r)
        say(
            f"{label:>14} {r['bias_deg']:10.4f} {r['rmse_deg']:10.4f} "
            f"{100 * r['rmse_rel_se']:5.1f}% {r['bound_deg']:10.4f} {r['ratio']:10.3f} "
            f"{r['predicted_deg']:10.4f}"
        )


def study_progress(args: argparse.Namespace) -> Progress:
    """The study's progress in chunks of runs (off with --json)."""
    return Progress("study", unit="chunks", enabled=not args.json)


def simulated_monte_carlo(
    args: argparse.Namespace,
    spec: SensorSpec,
    plan: Any,
    settings: StudySettings,
    executor: Executor | None,
    bar: Progress,
) -> tuple[Any, float]:
    """The Monte Carlo of ``plan`` on the simulated ``spec`` (``--runs``, ``--seed``): the
    errors and the wall time it took, s."""
    t0 = time.perf_counter()
    errors = monte_carlo(
        SimulatedWindows(spec), plan, settings, args.runs, args.seed, executor=executor,
        progress=bar.count,
    )  # fmt: skip
    return errors, time.perf_counter() - t0
