"""``northfinder study --spin RATE``: the Monte Carlo of a spin beside its bound and prediction."""

from __future__ import annotations

import argparse
from typing import Any

from northfinder.cli import spinfind
from northfinder.cli.executors import study_executor
from northfinder.cli.output import dumps, say
from northfinder.cli.studies import describe_plan, print_rows, simulated_monte_carlo, study_progress
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.host.accuracy import ErrorModel
from northfinder.host.errors import HostConfigError
from northfinder.host.kernels import MAX_SOLVER_TILT_DEG
from northfinder.host.montecarlo import StudySettings, study_rows
from northfinder.host.plan import SpinPlan
from northfinder.host.results import envelope
from northfinder.simwindows import simulator_identity

#: The stop-and-go options and their defaults (refused with ``--spin`` when changed).
STOP_AND_GO_DEFAULTS: dict[str, Any] = {
    "positions": None, "named_plan": None, "window": None, "settle": None, "denoise": "none",
    "solver": "auto", "denoise_options": [], "denoise_accel": False, "angles": "encoder",
    "plot": None, "sweep": None,
}  # fmt: skip


def check_spin(args: argparse.Namespace) -> None:
    """Refuse what a spin study does not use (it would be ignored)."""
    if args.spin is None:
        for name in ("spin_time", "spin_drift"):
            if getattr(args, name):
                raise HostConfigError(f"--{name.replace('_', '-')}: needs --spin RATE_DPS")
        return
    if args.plan_budget is not None or args.plan_target is not None:
        raise HostConfigError(
            "--spin: give it without --plan-budget or --plan-target (the budget search tries "
            "spins by itself)"
        )
    for name, default in STOP_AND_GO_DEFAULTS.items():
        if getattr(args, name) != default:
            option = "plan" if name == "named_plan" else name.replace("_", "-")
            raise HostConfigError(
                f"--{option}: a stop-and-go plan option; with --spin the table turns instead"
            )


def spin_plan(args: argparse.Namespace) -> SpinPlan:
    return SpinPlan(args.spin, spinfind.spin_seconds(args), args.spin_drift)


def run_spin(
    args: argparse.Namespace, spec: SensorSpec, model: ErrorModel, settings: StudySettings
) -> int:
    """``study --spin RATE``: the Monte Carlo of a spin beside its bound and prediction."""
    plan = spin_plan(args)
    plan_json = describe_plan(plan, model, args.warmup)  # checks the rate against the table
    with study_executor(args) as executor, study_progress(args) as bar:
        errors, wall = simulated_monte_carlo(args, spec, plan, settings, executor, bar)
    rows = study_rows(model, plan, settings, errors)
    report: dict[str, Any] = {
        "kind": "monte-carlo",
        "sensor": spec.name,
        "latitude_deg": args.latitude,
        "plan": plan_json,
        "solver": "spin",
        "tilt": args.tilt,
        "runs": args.runs,
        "seed": args.seed,
        "results": rows,
        "wall_time_s": wall,
    }
    if args.json:
        say(dumps(envelope("study", simulator_identity(spec.name), report)))
        return 0
    say(
        f"sensor {spec.name}, latitude {args.latitude:g} deg, spin {plan.rate_dps:+g} deg/s for "
        f"{plan.spin_s:g} s ({plan.turns:.2f} turns), drift "
        f"{'fitted' if plan.drift else 'not fitted'}, tilt {args.tilt}, {args.runs} runs "
        f"(seed {args.seed})"
    )
    say(
        f"plan time {plan_json['plan_time_s']:.1f} s (ramps to the rate and back, "
        f"{plan_json['ramp_s']:.2f} s each; {plan_json['total_time_s']:.1f} s with "
        f"{args.warmup:g} s warm-up); Monte Carlo {wall:.2f} s"
    )
    print_rows(rows)
    if rows[0]["rejected"]:
        say(
            f"{rows[0]['rejected']} of {args.runs} runs had no solution (tilt beyond "
            f"+-{MAX_SOLVER_TILT_DEG:g} deg or a fit that did not converge); the statistics are over "
            "the others"
        )
    return 0
