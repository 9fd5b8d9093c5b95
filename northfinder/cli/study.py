"""``northfinder study``: Monte Carlo accuracy of a north-finding plan, and a planner.

Study mode solves N seeded simulated runs and reports the azimuth bias and RMSE beside the
white-noise bound of the same plan (a spin with ``--spin RATE``); planning mode
(``--plan-budget`` or ``--plan-target``) lists the plans with the smallest predicted error, and
``--plan-budget`` sets the best spins beside the best stop-and-go plans. The results for a seed
are the same wherever they run.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import Executor
from dataclasses import replace
from typing import Any

from northfinder.cli import spinfind
from northfinder.cli.common import (
    EXIT_RUNTIME,
    add_execution_arguments,
    add_key_values,
    add_sensor_argument,
    add_solver_argument,
    angle_list,
    bounded_float,
    bounded_int,
    check_plot_path,
    dumps,
    finite_float,
    load_sensor,
    pyplot,
    say,
    seed_value,
    study_executor,
)
from northfinder.cli.progress import Progress
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.host.accuracy import ANGLE_SOURCES, TILT_SOURCES, ErrorModel, budget_bound_deg
from northfinder.host.denoise import METHODS, check_denoise
from northfinder.host.errors import HostConfigError
from northfinder.host.kernels import MAX_TILT_DEG
from northfinder.host.montecarlo import (
    StudySettings,
    monte_carlo,
    monte_carlo_many,
    rmse_interval_deg,
    study_rows,
    verify_plan,
)
from northfinder.host.plan import (
    DEFAULT_POSITIONS_DEG,
    PLANS,
    SOLVERS,
    Plan,
    SpinPlan,
    plan_time_s,
    settle_time_s,
    spin_ramp_s,
)
from northfinder.host.plan_search import (
    PlanCandidate,
    SpinCandidate,
    search_plans,
    search_spin_plans,
    shortest_plan,
)
from northfinder.host.results import envelope
from northfinder.simwindows import SimulatedWindows, error_model, simulator_identity

#: Bounds of what a study may ask for: runs, seconds (window, settle, warm-up, budget), Hz, deg/h.
MAX_RUNS = 1_000_000
MAX_WINDOW_S = 3600.0
MAX_SETTLE_S = 3600.0
MAX_WARMUP_S = 86_400.0
MAX_BUDGET_S = 86_400.0
MAX_RATE_HZ = 1000.0
MAX_BIAS_STEP_DPH = 1e6
MAX_TOP = 1000


def add_arguments(p: argparse.ArgumentParser) -> None:
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
    tilt = bounded_float(-MAX_TILT_DEG, MAX_TILT_DEG, "deg (the solvers' tilt limit)")
    g.add_argument("--pitch", type=tilt, default=0.0, help="deg (default: 0)")
    g.add_argument("--roll", type=tilt, default=0.0, help="deg (default: 0)")
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
    spinfind.add_arguments(p)
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
    add_execution_arguments(p)
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


# ----------------------------------------------------------------------------------------------
# Command
# ----------------------------------------------------------------------------------------------


def _load(args: argparse.Namespace) -> SensorSpec:
    spec: SensorSpec = load_sensor(args.sensor, dict(args.overrides))
    return spec


def _processing(args: argparse.Namespace, plan: Plan) -> Plan:
    """The plan with the denoising and solver of the arguments."""
    return replace(
        plan,
        denoise=args.denoise,
        method=args.solver,
        denoise_options=tuple(args.denoise_options),
    )


#: The stop-and-go options and their defaults (refused with ``--spin`` when changed).
STOP_AND_GO_DEFAULTS: dict[str, Any] = {
    "positions": None, "named_plan": None, "window": None, "settle": None, "denoise": "none",
    "solver": "auto", "denoise_options": [], "denoise_accel": False, "angles": "encoder",
    "plot": None, "sweep": None,
}  # fmt: skip


def _check_spin(args: argparse.Namespace) -> None:
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


def _spin_plan(args: argparse.Namespace) -> SpinPlan:
    return SpinPlan(args.spin, spinfind.spin_seconds(args), args.spin_drift)


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
    return _processing(args, plan)


def _settings(args: argparse.Namespace, latitude_deg: float) -> StudySettings:
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


def _plan_json(plan: Plan | SpinPlan, model: ErrorModel, warmup_s: float) -> dict[str, Any]:
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


def _candidate_json(
    c: PlanCandidate | SpinCandidate, model: ErrorModel, warmup_s: float
) -> dict[str, Any]:
    out = {
        **_plan_json(c.plan, model, warmup_s),
        "predicted_deg": c.sigma_deg,
        "bound_deg": c.prediction.bound_deg,
        "predicted_parts_deg": c.prediction.parts_deg,
    }
    if isinstance(c, PlanCandidate):
        out["allan_limited"] = c.allan_limited
    return out


def _row_label(r: dict[str, Any]) -> str:
    if "rate_dps" in r:
        return f"{r['rate_dps']:+g} deg/s"
    if "mu_deg" in r:
        return f"{r['mu_deg']:g}"
    return ",".join(f"{p:g}" for p in r["positions_deg"])


def _print_rows(rows: list[dict[str, Any]]) -> None:
    first = "mu deg" if "mu_deg" in rows[0] else "spin" if "rate_dps" in rows[0] else "positions"
    say(
        f"{first:>14} {'bias deg':>10} {'RMSE deg':>10} {'+-':>6} {'bound deg':>10} "
        f"{'RMSE/bound':>10} {'predicted':>10}"
    )
    for r in rows:
        label = _row_label(r)
        say(
            f"{label:>14} {r['bias_deg']:10.4f} {r['rmse_deg']:10.4f} "
            f"{100 * r['rmse_rel_se']:5.1f}% {r['bound_deg']:10.4f} {r['ratio']:10.3f} "
            f"{r['predicted_deg']:10.4f}"
        )


def _run_planner(args: argparse.Namespace, spec: SensorSpec, settings: StudySettings) -> int:
    model = error_model(spec)
    common = {
        "settle_s": args.settle,
        "warmup_s": args.warmup,
        "tilt": args.tilt,
        "angles": args.angles,
        "sample_rate_hz": args.rate,
        "pitch_deg": args.pitch,
        "roll_deg": args.roll,
    }
    report: dict[str, Any] = {
        "kind": "plan-search",
        "sensor": spec.name,
        "latitude_deg": args.latitude,
    }
    best_plan: Plan | None = None
    best_spin: SpinPlan | None = None
    if args.plan_budget is not None:
        cands = search_plans(model, args.latitude, args.plan_budget, **common)
        report["budget_s"] = args.plan_budget
        # What no plan of this budget can beat: all of it spent recording, white noise only.
        report["budget_bound_deg"] = budget_bound_deg(
            args.plan_budget, model.arw_dpsh, args.latitude
        )
        report["plans"] = [_candidate_json(c, model, args.warmup) for c in cands[: args.top]]
        best_plan = cands[0].plan if cands else None
        spins: list[SpinCandidate] = []
        if args.angles == "encoder":  # a spin reads the encoder at every sample
            spins = search_spin_plans(
                model, args.latitude, args.plan_budget,
                **{k: v for k, v in common.items() if k != "settle_s"},
            )  # fmt: skip
        report["spin_plans"] = [_candidate_json(c, model, args.warmup) for c in spins[: args.top]]
        report["spins_searched"] = args.angles == "encoder"
        best_spin = spins[0].plan if spins else None
    else:
        cand = shortest_plan(model, args.latitude, args.plan_target, **common)
        report["target_deg"] = args.plan_target
        report["plans"] = [] if cand is None else [_candidate_json(cand, model, args.warmup)]
        best_plan = None if cand is None else cand.plan
    if best_plan is not None and args.runs > 0:
        t0 = time.perf_counter()
        with study_executor(args) as executor, _progress(args) as bar:
            bar.step("Monte Carlo of the best plan")
            plan, row = verify_plan(
                SimulatedWindows(spec),
                model,
                _processing(args, best_plan),
                settings,
                args.runs,
                args.seed,
                args.plan_target,
                executor=executor,
                progress=bar.count,
            )
        report["verified"] = {
            **_plan_json(plan, model, args.warmup),
            **row,
            "runs": args.runs,
            "wall_time_s": time.perf_counter() - t0,
        }
    if best_spin is not None and args.runs > 0:
        t0 = time.perf_counter()
        with study_executor(args) as executor, _progress(args) as bar:
            bar.step("Monte Carlo of the best spin")
            errors = monte_carlo(
                SimulatedWindows(spec), best_spin, settings, args.runs, args.seed,
                executor=executor, progress=bar.count,
            )  # fmt: skip
        report["verified_spin"] = {
            **_plan_json(best_spin, model, args.warmup),
            **study_rows(model, best_spin, settings, errors)[0],
            "runs": args.runs,
            "wall_time_s": time.perf_counter() - t0,
        }
    if args.plan_budget is not None:
        report["best"] = _best_of_budget(report)
    what = (
        f"plan time <= {args.plan_budget:g} s"
        if args.plan_budget is not None
        else f"predicted RMSE <= {args.plan_target:g} deg"
    )
    # No feasible plan is a failed search (exit 1), said on stderr; --json still prints the
    # (empty) result on stdout.
    failed = not report["plans"] and not report.get("spin_plans")
    if failed:
        say(
            f"northfinder study: error: no plan reaches {what} (within 4 h, or the budget "
            "is shorter than one move)",
            file=sys.stderr,
        )
    if args.json:
        say(dumps(envelope("study", simulator_identity(spec.name), report)))
        return EXIT_RUNTIME if failed else 0
    bound = (
        f" (physical bound of the budget {report['budget_bound_deg']:.4f} deg)"
        if "budget_bound_deg" in report
        else ""
    )
    say(f"sensor {spec.name}, latitude {args.latitude:g} deg: plans for {what}{bound}")
    if failed:
        return EXIT_RUNTIME
    if report["plans"]:
        _print_stop_and_go(args, report)
    if args.plan_budget is not None:
        _print_spins(report)
    return 0


def _best_of_budget(report: dict[str, Any]) -> dict[str, Any]:
    """The best stop-and-go plan, the best spin and the better of the two (by the Monte Carlo
    when both were simulated, else by the prediction)."""
    out: dict[str, Any] = {"stop_and_go": None, "spin": None, "overall": None, "judged_by": None}
    scores = {}
    for kind, plans, verified in (
        ("stop_and_go", report["plans"], report.get("verified")),
        ("spin", report["spin_plans"], report.get("verified_spin")),
    ):
        if plans:
            out[kind] = {
                **{k: v for k, v in plans[0].items() if k != "predicted_parts_deg"},
                "rmse_deg": None if verified is None else verified["rmse_deg"],
            }
            scores[kind] = (plans[0]["predicted_deg"], out[kind]["rmse_deg"])
    if scores:
        by_mc = all(rmse is not None for _, rmse in scores.values())
        out["judged_by"] = "monte-carlo" if by_mc else "prediction"
        out["overall"] = min(scores, key=lambda k: scores[k][1] if by_mc else scores[k][0])
        if by_mc and len(scores) == 2:
            # Resolved when the two RMSEs' 95 % intervals are apart.
            runs = {"stop_and_go": report["verified"]["runs"],
                    "spin": report["verified_spin"]["runs"]}  # fmt: skip
            iv = {k: rmse_interval_deg(scores[k][1], runs[k]) for k in scores}
            out["intervals_deg"] = {k: list(v) for k, v in iv.items()}
            (lo1, hi1), (lo2, hi2) = iv.values()
            out["resolved"] = hi1 < lo2 or hi2 < lo1
    return out


def _print_spins(report: dict[str, Any]) -> None:
    if report["spin_plans"]:
        say(
            f"{'spins (ramps counted)':>34} {'spin s':>9} {'plan s':>8} {'predicted deg':>14} "
            f"{'bound deg':>10}  note"
        )
        for c in report["spin_plans"]:
            label = f"{c['rate_dps']:+g} deg/s, {c['turns']:.2f} turns"
            say(
                f"{label:>34} {c['spin_s']:9.1f} {c['plan_time_s']:8.1f} "
                f"{c['predicted_deg']:14.4f} {c['bound_deg']:10.4f}  "
                + ("drift fitted" if c["drift"] else "")
            )
    if "verified_spin" in report:
        v = report["verified_spin"]
        say(
            f"Monte Carlo of the first spin ({v['runs']} runs, {v['rate_dps']:+g} deg/s for "
            f"{v['spin_s']:.1f} s, plan {v['plan_time_s']:.1f} s): RMSE {v['rmse_deg']:.4f} deg "
            f"(+-{100 * v['rmse_rel_se']:.1f}%), bound {v['bound_deg']:.4f}, ratio {v['ratio']:.3f}"
        )
    best = report["best"]
    if best["overall"] is not None:
        names = {"stop_and_go": "stop-and-go", "spin": "spin"}
        parts = []
        for kind in ("stop_and_go", "spin"):
            b = best[kind]
            if b is None:
                searched = kind != "spin" or report["spins_searched"]
                parts.append(
                    f"no {names[kind]} plan fits"
                    if searched
                    else "spins not searched (a spin needs --angles encoder)"
                )
                continue
            mc = "" if b["rmse_deg"] is None else f", Monte Carlo {b['rmse_deg']:.4f}"
            parts.append(f"best {names[kind]} predicted {b['predicted_deg']:.4f} deg{mc}")
        resolved = {None: "", True: ", 95 % intervals apart",
                    False: "; not resolved: the 95 % intervals overlap"}[best.get("resolved")]  # fmt: skip
        say(
            "; ".join(parts)
            + f". Best overall: {names[best['overall']]} (by the {best['judged_by']}{resolved}"
            + "); physical "
            f"bound of the budget {report['budget_bound_deg']:.4f} deg"
        )


def _print_stop_and_go(args: argparse.Namespace, report: dict[str, Any]) -> None:
    say(
        f"{'positions':>34} {'window s':>9} {'plan s':>8} {'predicted deg':>14} "
        f"{'bound deg':>10}  note"
    )
    for c in report["plans"]:
        pos = ",".join(f"{p:g}" for p in c["positions_deg"])
        note = "longer windows stop helping (Allan limit)" if c["allan_limited"] else ""
        say(
            f"{pos:>34} {c['window_s']:9.1f} {c['plan_time_s']:8.1f} "
            f"{c['predicted_deg']:14.4f} {c['bound_deg']:10.4f}  {note}"
        )
    if "verified" in report:
        v = report["verified"]
        say(
            f"Monte Carlo of the first plan ({v['runs']} runs, window {v['window_s']:.1f} s, plan "
            f"{v['plan_time_s']:.1f} s): RMSE {v['rmse_deg']:.4f} deg "
            f"(+-{100 * v['rmse_rel_se']:.1f}%), bound {v['bound_deg']:.4f}, ratio {v['ratio']:.3f}"
            + ("" if args.plan_target is None else f", meets target: {v['meets_target']}")
        )


def _sweep(
    spec: SensorSpec,
    plan: Plan,
    settings: StudySettings,
    windows: list[float],
    runs: int,
    seed: int,
    executor: Executor | None,
    bar: Progress | None = None,
) -> list[dict[str, Any]]:
    model = error_model(spec)
    generator = SimulatedWindows(spec)
    subs = [replace(plan, window_s=w) for w in windows]
    errors = monte_carlo_many(
        [(generator, sub, settings, runs, seed) for sub in subs],
        executor=executor,
        progress=None if bar is None else bar.count,
    )
    out = []
    for w, sub, e in zip(windows, subs, errors, strict=True):
        rows = study_rows(model, sub, settings, e)
        out.append({"window_s": w, **_plan_json(sub, model, settings.warmup_s), **rows[0]})
    return out


def _progress(args: argparse.Namespace) -> Progress:
    """The study's progress in chunks of runs (off with --json)."""
    return Progress("study", unit="chunks", enabled=not args.json)


def _plot(path: str, sweep: list[dict[str, Any]], title: str) -> None:
    plt = pyplot()
    t = [s["plan_time_s"] for s in sweep]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.errorbar(
        t,
        [s["rmse_deg"] for s in sweep],
        yerr=[2 * s["rmse_deg"] * s["rmse_rel_se"] for s in sweep],
        fmt="o",
        label="Monte Carlo RMSE (2 sigma)",
    )
    ax.plot(t, [s["predicted_deg"] for s in sweep], "-", label="predicted (datasheet)")
    ax.plot(t, [s["bound_deg"] for s in sweep], "--", label="white-noise bound")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time to north: plan time (windows, moves, settling), s")
    ax.set_ylabel("azimuth error, deg (1 sigma)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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


def _run_spin(
    args: argparse.Namespace, spec: SensorSpec, model: ErrorModel, settings: StudySettings
) -> int:
    """``study --spin RATE``: the Monte Carlo of a spin beside its bound and prediction."""
    plan = _spin_plan(args)
    plan_json = _plan_json(plan, model, args.warmup)  # checks the rate against the table
    with study_executor(args) as executor, _progress(args) as bar:
        errors, wall = _simulated_monte_carlo(args, spec, plan, settings, executor, bar)
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
    _print_rows(rows)
    if rows[0]["rejected"]:
        say(
            f"{rows[0]['rejected']} of {args.runs} runs had no solution (tilt beyond "
            f"+-{MAX_TILT_DEG:g} deg or a fit that did not converge); the statistics are over "
            "the others"
        )
    return 0


def _simulated_monte_carlo(
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


def run(args: argparse.Namespace) -> int:
    _check_early(args)
    spec = _load(args)
    settings = _settings(args, args.latitude)
    if args.plan_budget is not None and args.plan_target is not None:
        raise HostConfigError("give either --plan-budget or --plan-target, not both")
    if args.runs < 0 or (args.runs < 2 and args.plan_budget is None and args.plan_target is None):
        raise HostConfigError(f"--runs: need at least 2 runs for statistics, got {args.runs}")
    _check_spin(args)
    if args.plan_budget is not None or args.plan_target is not None:
        return _run_planner(args, spec, settings)
    model = error_model(spec)
    if args.spin is not None:
        return _run_spin(args, spec, model, settings)
    plan = _plan(args)
    with study_executor(args) as executor, _progress(args) as bar:
        errors, wall = _simulated_monte_carlo(args, spec, plan, settings, executor, bar)
        sweep = None
        if args.plot:
            windows = args.sweep or [plan.window_s * f for f in (0.25, 0.5, 1.0, 2.0, 4.0)]
            if any(w <= 0 for w in windows):
                raise HostConfigError(f"--sweep: windows must be positive, got {windows}")
            bar.step(f"window sweep for the plot ({len(windows)} studies)")
            sweep = _sweep(spec, plan, settings, windows, args.runs, args.seed, executor, bar)
    rows = study_rows(model, plan, settings, errors)
    report: dict[str, Any] = {
        "kind": "monte-carlo",
        "sensor": spec.name,
        "latitude_deg": args.latitude,
        "plan": _plan_json(plan, model, args.warmup),
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
        _plot(
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
    _print_rows(rows)
    rejected = max(r["rejected"] for r in rows)
    if rejected:
        say(
            f"{rejected} of {args.runs} runs had no solution (tilt beyond +-{MAX_TILT_DEG:g} deg "
            "or a fit that did not converge); the statistics are over the others"
        )
    if args.plot:
        say(f"plot of error versus time to north: {args.plot}")
    return 0
