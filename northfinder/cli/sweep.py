"""``northfinder sweep``: Monte Carlo studies over sensor presets, latitudes, plans and windows.

Every combination of ``--sensors``, ``--latitudes``, plans and ``--windows`` is one study; its row
is what ``northfinder study`` prints for the same settings and seed.
"""

from __future__ import annotations

import argparse
import itertools
import time
from dataclasses import replace
from typing import Any

from northfinder.cli.argtypes import (
    angle_list,
    bounded_float,
    bounded_int,
    finite_float,
    seed_value,
)
from northfinder.cli.executors import add_execution_arguments, study_executor
from northfinder.cli.options import add_key_values
from northfinder.cli.output import dumps, say
from northfinder.cli.progress import Progress
from northfinder.cli.studies import (
    MAX_BIAS_STEP_DPH,
    MAX_RUNS,
    MAX_SETTLE_S,
    MAX_WARMUP_S,
    describe_plan,
    study_settings,
)
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.host.accuracy import ANGLE_SOURCES, TILT_SOURCES
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.kernels import MAX_SOLVER_TILT_DEG
from northfinder.host.montecarlo import monte_carlo_many, study_rows
from northfinder.host.plan import DEFAULT_POSITIONS_DEG, PLANS, SOLVERS, Plan
from northfinder.host.results import envelope
from northfinder.simwindows import (
    MAX_RATE_HZ,
    MAX_WINDOW_S,
    SimulatedWindows,
    error_model,
    simulator_identity,
)


def _names(text: str) -> list[str]:
    names = [t.strip() for t in text.split(",")]
    if not all(names):
        raise argparse.ArgumentTypeError(f"expected NAME,NAME,..., got {text!r}")
    return names


_LATITUDE = bounded_float(-90.0, 90.0, "deg")
_WINDOW = bounded_float(0.0, MAX_WINDOW_S, "s", open_lo=True)


def _floats(text: str) -> list[float]:
    try:
        return [_LATITUDE(t) for t in text.split(",")]
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc} in {text!r}") from None


def _windows(text: str) -> list[float]:
    try:
        return [_WINDOW(t) for t in text.split(",")]
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc} in {text!r}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("what to sweep (every combination is one study)")
    g.add_argument(
        "--sensors",
        type=_names,
        default=["paper-rlg"],
        metavar="PRESET|FILE,...",
        help="sensor presets or TOML files (default: paper-rlg)",
    )
    g.add_argument(
        "--latitudes",
        type=_floats,
        default=[DEFAULT_LATITUDE_DEG],
        metavar="DEG,...",
        help=f"(default: {DEFAULT_LATITUDE_DEG:g})",
    )
    g.add_argument(
        "--positions",
        type=angle_list,
        action="append",
        default=[],
        metavar="DEG,DEG,...",
        help="table angles of one plan (repeatable; default 0,180,180,0 as find, when no --plan)",
    )
    g.add_argument(
        "--plan",
        dest="named_plans",
        choices=sorted(PLANS),
        action="append",
        default=[],
        help="a named plan (repeatable)",
    )
    g.add_argument(
        "--windows",
        type=_windows,
        default=None,
        metavar="S,...",
        help="s per position (default: 10, or the named plan's)",
    )
    g = p.add_argument_group("every study")
    add_key_values(
        g,
        "--set",
        "overrides",
        "SECTION.FIELD=VALUE",
        "override a field of every sensor, e.g. gyro.arw_dpsh=0.002 (repeatable)",
    )
    g.add_argument("--azimuth", type=finite_float, default=None, help="deg (default: random)")
    tilt = bounded_float(-MAX_SOLVER_TILT_DEG, MAX_SOLVER_TILT_DEG, "deg (the solvers' tilt limit)")
    g.add_argument("--pitch", type=tilt, default=0.0, help="deg (default: 0)")
    g.add_argument("--roll", type=tilt, default=0.0, help="deg (default: 0)")
    g.add_argument(
        "--settle", type=bounded_float(0.0, MAX_SETTLE_S, "s"), default=None, help="s after a move"
    )
    g.add_argument(
        "--warmup", type=bounded_float(0.0, MAX_WARMUP_S, "s"), default=120.0,
        help="s (default: 120)",
    )  # fmt: skip
    g.add_argument(
        "--rate", type=bounded_float(0.0, MAX_RATE_HZ, "Hz", open_lo=True), default=200.0,
        help="sample rate, Hz (200)",
    )  # fmt: skip
    g.add_argument("--denoise", choices=list(METHODS), default="none", help="(default: none)")
    add_key_values(g, "--denoise-option", "denoise_options", "KEY=VALUE")
    g.add_argument("--denoise-accel", action="store_true")
    g.add_argument("--solver", choices=list(SOLVERS), default="auto")
    g.add_argument("--tilt", choices=list(TILT_SOURCES), default="accel")
    g.add_argument("--angles", choices=list(ANGLE_SOURCES), default="encoder")
    g.add_argument(
        "--bias-step", type=bounded_float(0.0, MAX_BIAS_STEP_DPH, "deg/h"), default=0.0,
        metavar="DPH",
    )  # fmt: skip
    g.add_argument(
        "--runs", type=bounded_int(2, MAX_RUNS), default=1000,
        help=f"runs per study, 2 to {MAX_RUNS} (default: 1000)",
    )  # fmt: skip
    g.add_argument("--seed", type=seed_value, default=0, help="seed of every study (default: 0)")
    add_execution_arguments(p)
    p.add_argument("--json", action="store_true", help="print JSON")


def _plans(args: argparse.Namespace) -> list[Plan]:
    base: list[Plan] = [Plan(tuple(pos), 10.0) for pos in args.positions]
    base += [PLANS[name] for name in args.named_plans]
    if not base:
        base = [Plan(DEFAULT_POSITIONS_DEG, 10.0)]
    windows = args.windows
    plans = []
    for plan in base:
        for w in windows or [plan.window_s]:
            plans.append(
                replace(
                    plan,
                    window_s=w,
                    settle_s=args.settle,
                    denoise=args.denoise,
                    method=args.solver if plan.method == "auto" else plan.method,
                    denoise_options=tuple(args.denoise_options),
                )
            )
    return plans


def run(args: argparse.Namespace) -> int:
    from northfinder.firmware_sim.sensors import load_spec

    if args.runs < 2:
        raise HostConfigError(f"--runs: need at least 2 runs for statistics, got {args.runs}")
    specs = []
    for name in args.sensors:
        spec = load_spec(name)
        specs.append(spec.with_values(dict(args.overrides)) if args.overrides else spec)
    plans = _plans(args)
    combos = list(itertools.product(specs, args.latitudes, plans))
    settings = {lat: study_settings(args, lat) for lat in args.latitudes}
    bar = Progress("sweep", unit="chunks", enabled=not args.json)
    with study_executor(args) as executor, bar:
        bar.step(f"{len(combos)} studies of {args.runs} runs")
        t0 = time.perf_counter()
        errors = monte_carlo_many(
            [
                (SimulatedWindows(spec), plan, settings[lat], args.runs, args.seed)
                for spec, lat, plan in combos
            ],
            executor=executor,
            progress=bar.count,
        )
        wall = time.perf_counter() - t0
    studies: list[dict[str, Any]] = []
    for (spec, lat, plan), e in zip(combos, errors, strict=True):
        model = error_model(spec)
        studies.append(
            {
                "sensor": spec.name,
                "latitude_deg": lat,
                "plan": describe_plan(plan, model, args.warmup),
                "results": study_rows(model, plan, settings[lat], e),
            }
        )
    report = {
        "runs": args.runs,
        "seed": args.seed,
        "denoise": args.denoise,
        "studies": studies,
        "wall_time_s": wall,
    }
    if args.json:
        names = {spec.name for spec in specs}
        device = simulator_identity(names.pop()) if len(names) == 1 else simulator_identity()
        say(dumps(envelope("sweep", device, report)))
        return 0
    say(
        f"{len(studies)} studies of {args.runs} runs (seed {args.seed}), denoise {args.denoise}: "
        f"Monte Carlo {wall:.2f} s"
    )
    say(
        f"{'sensor':>14} {'lat deg':>8} {'positions':>22} {'window s':>9} {'plan s':>8} "
        f"{'RMSE deg':>10} {'+-':>6} {'bound deg':>10} {'RMSE/bound':>10} {'predicted':>10}"
    )
    for s in studies:
        for r in s["results"]:
            pos = ",".join(f"{a:g}" for a in r["positions_deg"])
            say(
                f"{s['sensor']:>14} {s['latitude_deg']:8g} {pos:>22} "
                f"{s['plan']['window_s']:9g} {s['plan']['plan_time_s']:8.1f} "
                f"{r['rmse_deg']:10.4f} {100 * r['rmse_rel_se']:5.1f}% {r['bound_deg']:10.4f} "
                f"{r['ratio']:10.3f} {r['predicted_deg']:10.4f}"
            )
    rejected = sum(max(r["rejected"] for r in s["results"]) for s in studies)
    if rejected:
        say(f"{rejected} runs had no solution (tilt beyond the limit); left out of their rows")
    return 0
