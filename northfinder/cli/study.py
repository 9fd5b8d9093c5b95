"""``northfinder study``: Monte Carlo accuracy of a north-finding plan, and a planner.

Study mode solves N seeded simulated runs and reports the azimuth bias and RMSE beside the
white-noise bound of the same plan (a spin with ``--spin RATE``); planning mode
(``--plan-budget`` or ``--plan-target``) lists the plans with the smallest predicted error, and
``--plan-budget`` sets the best spins beside the best stop-and-go plans. The results for a seed
are the same wherever they run.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

from northfinder.cli import spinfind
from northfinder.cli.argtypes import (
    angle_list,
    bounded_float,
    bounded_int,
    finite_float,
    seed_value,
)
from northfinder.cli.executors import add_execution_arguments, study_executor
from northfinder.cli.options import add_key_values, add_sensor_argument, add_solver_argument
from northfinder.cli.output import dumps, say
from northfinder.cli.plots import check_plot_path
from northfinder.cli.studies import (
    MAX_BIAS_STEP_DPH,
    MAX_BUDGET_S,
    MAX_RUNS,
    MAX_SETTLE_S,
    MAX_TOP,
    MAX_WARMUP_S,
    describe_plan,
    load_study_sensor,
    print_rows,
    simulated_monte_carlo,
    study_progress,
    study_settings,
    with_processing,
)
from northfinder.cli.study_planner import run_planner
from northfinder.cli.study_plot import plot_sweep, window_sweep
from northfinder.cli.study_spin import check_spin, run_spin
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.host.accuracy import ANGLE_SOURCES, TILT_SOURCES
from northfinder.host.denoise import METHODS, check_denoise
from northfinder.host.errors import HostConfigError
from northfinder.host.kernels import MAX_SOLVER_TILT_DEG
from northfinder.host.montecarlo import study_rows
from northfinder.host.plan import DEFAULT_POSITIONS_DEG, PLANS, SOLVERS, Plan
from northfinder.host.results import envelope
from northfinder.simwindows import MAX_RATE_HZ, MAX_WINDOW_S, error_model, simulator_identity


def add_arguments(p: argparse.ArgumentParser) -> None:
    _add_site_arguments(p)
    _add_plan_arguments(p)
    spinfind.add_arguments(p)
    _add_processing_arguments(p)
    _add_runs_arguments(p)
    add_execution_arguments(p)
    _add_output_arguments(p)


def _add_site_arguments(p: argparse.ArgumentParser) -> None:
    """The sensor and where it stands."""
    add_sensor_argument(p)
    add_key_values(
        p,
        "--set",
        "overrides",
        "SECTION.FIELD=VALUE",
        "override a sensor field, e.g. gyro.arw_dpsh=0.002 (repeatable)",
    )
    g = p.add_argument_group("site")
    g.add_argument(
        "--latitude", type=bounded_float(-90.0, 90.0, "deg"), default=DEFAULT_LATITUDE_DEG,
        help=f"deg (default: {DEFAULT_LATITUDE_DEG:g})",
    )  # fmt: skip
    g.add_argument(
        "--azimuth",
        type=finite_float,
        default=None,
        help="true azimuth, deg (default: uniform random per run)",
    )
    tilt = bounded_float(-MAX_SOLVER_TILT_DEG, MAX_SOLVER_TILT_DEG, "deg (the solvers' tilt limit)")
    g.add_argument("--pitch", type=tilt, default=0.0, help="deg (default: 0)")
    g.add_argument("--roll", type=tilt, default=0.0, help="deg (default: 0)")


def _add_plan_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("plan")
    g.add_argument(
        "--positions",
        type=angle_list,
        default=None,
        help="table angles, deg (default 0,180,180,0, as find)",
    )
    g.add_argument(
        "--plan",
        dest="named_plan",
        choices=sorted(PLANS),
        default=None,
        help="a named plan (positions and window) instead of --positions",
    )
    g.add_argument(
        "--window", type=bounded_float(0.0, MAX_WINDOW_S, "s", open_lo=True), default=None,
        help=f"s per position, up to {MAX_WINDOW_S:g} (10)",
    )  # fmt: skip
    g.add_argument(
        "--settle",
        type=bounded_float(0.0, MAX_SETTLE_S, "s"),
        default=None,
        help="s from the end of a move to the next window (default: the preset's table settle)",
    )
    g.add_argument(
        "--warmup",
        type=bounded_float(0.0, MAX_WARMUP_S, "s"),
        default=120.0,
        help="s from power-on to the first window, not counted in the plan time (default: 120)",
    )
    g.add_argument(
        "--rate", type=bounded_float(0.0, MAX_RATE_HZ, "Hz", open_lo=True), default=200.0,
        help=f"sample rate, Hz, up to {MAX_RATE_HZ:g} (200)",
    )  # fmt: skip


def _add_processing_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("processing")
    g.add_argument(
        "--denoise",
        choices=list(METHODS),
        default="none",
        help="denoising of every gyro window before its mean (default: none)",
    )
    add_key_values(
        g,
        "--denoise-option",
        "denoise_options",
        "KEY=VALUE",
        "option of the denoising method, e.g. window=6 for moving-average",
    )
    g.add_argument(
        "--denoise-accel", action="store_true", help="denoise the accelerometer windows too"
    )
    add_solver_argument(g, list(SOLVERS))
    g.add_argument("--tilt", choices=list(TILT_SOURCES), default="accel", help="tilt source")
    g.add_argument(
        "--angles", choices=list(ANGLE_SOURCES), default="encoder", help="table angles used"
    )


def _add_runs_arguments(p: argparse.ArgumentParser) -> None:
    """The Monte Carlo and the planner."""
    g = p.add_argument_group("Monte Carlo")
    g.add_argument(
        "--runs", type=bounded_int(0, MAX_RUNS), default=1000,
        help=f"seeded runs, up to {MAX_RUNS} (default: 1000)",
    )  # fmt: skip
    g.add_argument("--seed", type=seed_value, default=0, help="random seed (default: 0)")
    g.add_argument(
        "--bias-step",
        type=bounded_float(0.0, MAX_BIAS_STEP_DPH, "deg/h"),
        default=0.0,
        metavar="DPH",
        help="one gyro bias step of this size per run at a random time, deg/h",
    )
    g = p.add_argument_group("planning")
    g.add_argument(
        "--plan-budget",
        type=bounded_float(0.0, MAX_BUDGET_S, "s", open_lo=True),
        default=None,
        metavar="SECONDS",
        help="list the plans and spins with the smallest predicted error within this plan time",
    )
    g.add_argument(
        "--plan-target",
        type=bounded_float(0.0, 180.0, "deg", open_lo=True),
        default=None,
        metavar="DEG",
        help="find the shortest plan whose predicted (and, with --runs, simulated) RMSE meets DEG",
    )
    g.add_argument(
        "--top", type=bounded_int(1, MAX_TOP), default=5, help="plans listed (default: 5)"
    )


def _add_output_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("output")
    g.add_argument("--json", action="store_true", help="print JSON")
    g.add_argument(
        "--plot",
        metavar="FILE",
        default=None,
        help="plot error versus time to north over a sweep of windows (needs matplotlib)",
    )
    g.add_argument(
        "--sweep",
        type=angle_list,
        default=None,
        metavar="S,S,...",
        help="window lengths of the --plot sweep, s (default: window x 0.25..4)",
    )


def _plan(args: argparse.Namespace) -> Plan:
    if args.named_plan and args.positions:
        raise HostConfigError("give either --plan or --positions, not both")
    if args.named_plan:
        named = PLANS[args.named_plan]
        plan = replace(named, window_s=args.window or named.window_s, settle_s=args.settle)
    else:
        plan = Plan(
            tuple(args.positions or DEFAULT_POSITIONS_DEG), args.window or 10.0, args.settle
        )
    return with_processing(args, plan)


def _check_early(args: argparse.Namespace) -> None:
    """What can be refused before any simulation: output paths, the sweep, denoise options."""
    if args.plot:
        check_plot_path(args.plot)
    for w in args.sweep or ():
        if not 0 < w <= MAX_WINDOW_S:
            raise HostConfigError(f"--sweep: windows must be 0 to {MAX_WINDOW_S:g} s, got {w:g}")
    options = dict(args.denoise_options)
    if options or args.denoise != "none":
        n = max(2, round((args.window or 10.0) * args.rate))
        check_denoise(args.denoise, options, n, "--denoise-option")


def run(args: argparse.Namespace) -> int:
    _check_early(args)
    spec = load_study_sensor(args)
    settings = study_settings(args, args.latitude)
    if args.plan_budget is not None and args.plan_target is not None:
        raise HostConfigError("give either --plan-budget or --plan-target, not both")
    if args.runs < 0 or (args.runs < 2 and args.plan_budget is None and args.plan_target is None):
        raise HostConfigError(f"--runs: need at least 2 runs for statistics, got {args.runs}")
    check_spin(args)
    if args.plan_budget is not None or args.plan_target is not None:
        return run_planner(args, spec, settings)
    model = error_model(spec)
    if args.spin is not None:
        return run_spin(args, spec, model, settings)
    plan = _plan(args)
    with study_executor(args) as executor, study_progress(args) as bar:
        errors, wall = simulated_monte_carlo(args, spec, plan, settings, executor, bar)
        sweep = None
        if args.plot:
            windows = args.sweep or [plan.window_s * f for f in (0.25, 0.5, 1.0, 2.0, 4.0)]
            if any(w <= 0 for w in windows):
                raise HostConfigError(f"--sweep: windows must be positive, got {windows}")
            bar.step(f"window sweep for the plot ({len(windows)} studies)")
            sweep = window_sweep(spec, plan, settings, windows, args.runs, args.seed, executor, bar)
    rows = study_rows(model, plan, settings, errors)
    report: dict[str, Any] = {
        "kind": "monte-carlo",
        "sensor": spec.name,
        "latitude_deg": args.latitude,
        "plan": describe_plan(plan, model, args.warmup),
        "denoise": args.denoise,
        "denoise_options": dict(args.denoise_options),
        "solver": args.solver,
        "tilt": args.tilt,
        "angles": args.angles,
        "runs": args.runs,
        "seed": args.seed,
        "results": rows,
        "wall_time_s": wall,
    }
    if sweep is not None:
        report["sweep"] = sweep
        plot_sweep(
            args.plot,
            report["sweep"],
            f"{spec.name}, positions {plan.label()}, {args.denoise}, {args.runs} runs",
        )
        report["plot"] = args.plot
    if args.json:
        say(dumps(envelope("study", simulator_identity(spec.name), report)))
        return 0
    p = report["plan"]
    say(
        f"sensor {spec.name}, latitude {args.latitude:g} deg, positions {plan.label()} deg, "
        f"window {plan.window_s:g} s, denoise {args.denoise}, solver {args.solver}, "
        f"tilt {args.tilt}, {args.runs} runs (seed {args.seed})"
    )
    say(
        f"plan time {p['plan_time_s']:.1f} s (windows, moves, settling; "
        f"{p['total_time_s']:.1f} s with {args.warmup:g} s warm-up); Monte Carlo {wall:.2f} s"
    )
    print_rows(rows)
    rejected = max(r["rejected"] for r in rows)
    if rejected:
        say(
            f"{rejected} of {args.runs} runs had no solution (tilt beyond +-{MAX_SOLVER_TILT_DEG:g} deg "
            "or a fit that did not converge); the statistics are over the others"
        )
    if args.plot:
        say(f"plot of error versus time to north: {args.plot}")
    return 0
