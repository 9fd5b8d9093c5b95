"""``northfinder study``: Monte Carlo accuracy of a north-finding plan, and a planner.

Study mode draws N seeded runs of the simulated instrument at once (whole arrays of runs, in
chunks), solves every run, and reports the azimuth bias and RMSE beside the white-noise bound of
the same plan (notes, section 4), their ratio, the predicted error from the datasheet figures,
and the time the plan takes. A ratio below 1 beyond its statistical spread would be a bug.

Planning mode (``--plan-budget SECONDS`` or ``--plan-target DEG``) searches position patterns and
window lengths, counting moves (trapezoidal profile at the preset's table limits) and settling,
and lists the plans with the smallest predicted error; ``--runs`` > 0 verifies the best one by
Monte Carlo.

Plan time = windows + moves + settling (the warm-up before the first window is simulated but not
counted; the total time including it is reported too).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from northfinder.firmware_sim.batch import simulate_windows
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import SensorSpec, load_spec
from northfinder.host.cli.common import (
    add_sensor_argument,
    angle_list,
    finite_float,
    positive_float,
)
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.heading import PLANS
from northfinder.host.study import (
    ANGLE_SOURCES,
    SOLVERS,
    TILT_SOURCES,
    ErrorModel,
    Plan,
    PlanCandidate,
    TableModel,
    bound_deg,
    chunk_errors,
    predict,
    search_plans,
    shortest_plan,
    summarize,
)

_DPH = math.pi / 180.0 / 3600.0
#: Samples (runs x positions x samples x 6 channels) generated at once.
CHUNK_VALUES = 24_000_000


def _non_negative_float(text: str) -> float:
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative: {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


def _key_value(text: str) -> tuple[str, Any]:
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return key.strip(), value


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "study",
        help="Monte Carlo accuracy of a plan against the physical bound; plan search",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_sensor_argument(p)
    p.add_argument(
        "--set",
        dest="overrides",
        type=_key_value,
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="override a sensor field, e.g. gyro.arw_dpsh=0.002 (repeatable)",
    )
    g = p.add_argument_group("site")
    g.add_argument("--latitude", type=finite_float, default=34.0, help="deg (default: 34)")
    g.add_argument(
        "--azimuth",
        type=finite_float,
        default=None,
        help="true azimuth, deg (default: uniform random per run)",
    )
    g.add_argument("--pitch", type=finite_float, default=0.0, help="deg (default: 0)")
    g.add_argument("--roll", type=finite_float, default=0.0, help="deg (default: 0)")
    g = p.add_argument_group("plan")
    g.add_argument(
        "--positions",
        type=angle_list,
        default=None,
        help="table angles, deg (default: 0,180)",
    )
    g.add_argument(
        "--plan",
        dest="named_plan",
        choices=sorted(PLANS),
        default=None,
        help="a named plan (positions and window) instead of --positions",
    )
    g.add_argument("--window", type=positive_float, default=None, help="s per position (10)")
    g.add_argument(
        "--settle", type=_non_negative_float, default=None, help="s after a move (preset's)"
    )
    g.add_argument(
        "--warmup",
        type=_non_negative_float,
        default=120.0,
        help="s from power-on to the first window, not counted in the plan time (default: 120)",
    )
    g.add_argument("--rate", type=positive_float, default=200.0, help="sample rate, Hz (200)")
    g = p.add_argument_group("processing")
    g.add_argument(
        "--denoise",
        choices=list(METHODS),
        default="none",
        help="denoising of every gyro window before its mean (default: none)",
    )
    g.add_argument(
        "--denoise-option",
        dest="denoise_options",
        type=_key_value,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="option of the denoising method, e.g. window=6 for moving-average",
    )
    g.add_argument(
        "--denoise-accel", action="store_true", help="denoise the accelerometer windows too"
    )
    g.add_argument("--solver", choices=list(SOLVERS), default="auto", help="heading solver")
    g.add_argument("--tilt", choices=list(TILT_SOURCES), default="accel", help="tilt source")
    g.add_argument(
        "--angles", choices=list(ANGLE_SOURCES), default="encoder", help="table angles used"
    )
    g = p.add_argument_group("Monte Carlo")
    g.add_argument("--runs", type=int, default=1000, help="seeded runs (default: 1000)")
    g.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    g.add_argument(
        "--bias-step",
        type=_non_negative_float,
        default=0.0,
        metavar="DPH",
        help="one gyro bias step of this size per run at a random time, deg/h",
    )
    g = p.add_argument_group("planning")
    g.add_argument(
        "--plan-budget",
        type=positive_float,
        default=None,
        metavar="SECONDS",
        help="list the plans with the smallest predicted error within this plan time",
    )
    g.add_argument(
        "--plan-target",
        type=positive_float,
        default=None,
        metavar="DEG",
        help="find the shortest plan whose predicted (and, with --runs, simulated) RMSE meets DEG",
    )
    g.add_argument("--top", type=_positive_int, default=5, help="plans listed (default: 5)")
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
    return p


# ----------------------------------------------------------------------------------------------
# Sensor spec -> planner model
# ----------------------------------------------------------------------------------------------


def error_model(spec: SensorSpec) -> ErrorModel:
    """The planner's view of a sensor spec (gyro x/y figures, table, deterministic drift)."""
    g, th = spec.gyro, spec.thermal
    warm = np.asarray(g.warmup_bias_dph[:2]) * _DPH
    coeff = np.asarray(g.temp_coeff_dph_per_c[:2]) * _DPH

    def drift(t: np.ndarray) -> np.ndarray:
        temp = (
            th.warmup_rise_c * (1.0 - np.exp(-t / th.warmup_tau_s)) + th.ramp_c_per_h * t / 3600.0
        )
        return np.exp(-t / g.warmup_tau_s)[:, None] * warm + temp[:, None] * coeff

    has_drift = bool(warm.any() or coeff.any())
    return ErrorModel(
        arw_dpsh=g.arw_dpsh,
        bias_instability_dph=g.bias_instability_dph,
        rrw_dphpsh=g.rrw_dphpsh,
        misalignment_urad=g.misalignment_urad,
        scale_factor_ppm=g.scale_factor_ppm,
        vrw_ug_rthz=spec.accel.vrw_ug_rthz,
        table=TableModel(
            max_rate_dps=spec.table.max_rate_dps,
            max_accel_dps2=spec.table.max_accel_dps2,
            settle_s=spec.table.settle_s,
            indexing_error_deg=spec.table.indexing_error_deg,
        ),
        drift_rps=drift if has_drift else None,
    )


# ----------------------------------------------------------------------------------------------
# Monte Carlo
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StudySettings:
    """Everything a Monte Carlo study needs besides the spec and the plan."""

    latitude_deg: float = 34.0
    azimuth_deg: float | None = None
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    warmup_s: float = 120.0
    sample_rate_hz: float = 200.0
    denoise: str = "none"
    denoise_options: tuple[tuple[str, Any], ...] = ()
    denoise_accel: bool = False
    solver: str = "auto"
    tilt: str = "accel"
    angles: str = "encoder"
    bias_step_dph: float = 0.0


def monte_carlo(
    spec: SensorSpec,
    plan: Plan,
    settings: StudySettings,
    runs: int,
    seed: int,
    *,
    chunk_values: int = CHUNK_VALUES,
) -> np.ndarray:
    """Azimuth errors of ``runs`` seeded runs, deg: shape (runs,), or (runs, P - 1) pairwise.

    Runs are drawn in chunks so that at most about ``chunk_values`` samples exist at once; the
    result depends on the chunk size only through the order of the random draws.
    """
    if runs < 2:
        raise HostConfigError(f"runs: need at least 2 runs for statistics, got {runs}")
    rng = np.random.default_rng(seed)
    p = len(plan.positions_deg)
    n = round(plan.window_s * settings.sample_rate_hz)
    chunk = max(1, min(runs, chunk_values // max(1, p * n * 6)))
    out = []
    done = 0
    while done < runs:
        m = min(chunk, runs - done)
        if settings.azimuth_deg is None:
            az = rng.uniform(0.0, 360.0, m)
        else:
            az = np.full(m, settings.azimuth_deg)
        truths = [
            Truth(float(a), settings.latitude_deg, settings.pitch_deg, settings.roll_deg)
            for a in az
        ]
        batch = simulate_windows(
            spec,
            truths,
            plan.positions_deg,
            plan.window_s,
            plan.settle_s,
            n_runs=m,
            rng=rng,
            sample_rate_hz=settings.sample_rate_hz,
            warmup_s=settings.warmup_s,
            bias_step_dph=settings.bias_step_dph,
        )
        angles = batch.table_deg if settings.angles == "encoder" else batch.commanded_deg
        out.append(
            chunk_errors(
                batch.gyro_rps,
                None if settings.tilt == "level" else batch.accel_mps2,
                angles,
                batch.azimuth_deg,
                settings.latitude_deg,
                solver=settings.solver,
                denoise_method=settings.denoise,
                denoise_options=dict(settings.denoise_options),
                denoise_accel=settings.denoise_accel,
            )
        )
        done += m
        del batch
    return np.concatenate(out)


def study_rows(
    spec: SensorSpec, plan: Plan, settings: StudySettings, errors: np.ndarray
) -> list[dict[str, Any]]:
    """One result row per solution (one, or one per pair with ``pairwise``)."""
    model = error_model(spec)
    pos = plan.positions_deg
    pairwise = errors.ndim == 2
    subplans = (
        [Plan((pos[0], pos[k]), plan.window_s, plan.settle_s) for k in range(1, len(pos))]
        if pairwise
        else []
    )
    rows = []
    stats = summarize(errors)
    for i, s in enumerate(stats if pairwise else [stats]):
        sub = subplans[i] if pairwise else plan
        b = bound_deg(sub.positions_deg, plan.window_s, spec.gyro.arw_dpsh, settings.latitude_deg)
        pred = predict(
            model,
            sub,
            settings.latitude_deg,
            warmup_s=settings.warmup_s,
            tilt=settings.tilt,
            angles=settings.angles,
        )
        row: dict[str, Any] = {
            "positions_deg": list(sub.positions_deg),
            **asdict(s),
            "bound_deg": b,
            "ratio": s.rmse_deg / b if b > 0 else math.inf,
            "predicted_deg": pred.sigma_deg,
            "predicted_parts_deg": pred.parts_deg,
        }
        if pairwise:
            row["mu_deg"] = sub.positions_deg[1] - sub.positions_deg[0]
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# Command
# ----------------------------------------------------------------------------------------------


def _load(args: argparse.Namespace) -> SensorSpec:
    spec = load_spec(args.sensor)
    if args.overrides:
        spec = spec.with_values(dict(args.overrides))
    return spec


def _plan(args: argparse.Namespace, spec: SensorSpec) -> Plan:
    if args.named_plan and args.positions:
        raise HostConfigError("give either --plan or --positions, not both")
    if args.named_plan:
        named = PLANS[args.named_plan]
        return Plan(named.angles_deg, args.window or named.dwell_s, args.settle)
    return Plan(tuple(args.positions or (0.0, 180.0)), args.window or 10.0, args.settle)


def _settings(args: argparse.Namespace) -> StudySettings:
    return StudySettings(
        latitude_deg=args.latitude,
        azimuth_deg=args.azimuth,
        pitch_deg=args.pitch,
        roll_deg=args.roll,
        warmup_s=args.warmup,
        sample_rate_hz=args.rate,
        denoise=args.denoise,
        denoise_options=tuple(args.denoise_options),
        denoise_accel=args.denoise_accel,
        solver=args.solver,
        tilt=args.tilt,
        angles=args.angles,
        bias_step_dph=args.bias_step,
    )


def _plan_json(plan: Plan, model: ErrorModel, warmup_s: float) -> dict[str, Any]:
    t = predict(model, plan, 45.0).plan_time_s  # plan time does not depend on latitude
    return {
        "positions_deg": list(plan.positions_deg),
        "window_s": plan.window_s,
        "settle_s": model.table.settle_s if plan.settle_s is None else plan.settle_s,
        "plan_time_s": t,
        "warmup_s": warmup_s,
        "total_time_s": t + warmup_s,
    }


def _candidate_json(c: PlanCandidate, model: ErrorModel, warmup_s: float) -> dict[str, Any]:
    return {
        **_plan_json(c.plan, model, warmup_s),
        "predicted_deg": c.sigma_deg,
        "bound_deg": c.prediction.bound_deg,
        "predicted_parts_deg": c.prediction.parts_deg,
        "allan_limited": c.allan_limited,
    }


def verify_plan(
    spec: SensorSpec,
    plan: Plan,
    settings: StudySettings,
    runs: int,
    seed: int,
    target_deg: float | None = None,
    max_rounds: int = 4,
) -> tuple[Plan, dict[str, Any]]:
    """Monte Carlo of a plan; with a target, lengthen the window until the simulated RMSE meets it.

    Each round scales the window by ``1.05 (RMSE / target)^2`` (white noise falls as the square
    root of the dwell), at most ``max_rounds`` rounds.
    """
    for _ in range(max_rounds):
        errors = monte_carlo(spec, plan, settings, runs, seed)
        row = study_rows(spec, plan, settings, errors)[0]
        if target_deg is None or row["rmse_deg"] <= target_deg:
            row["meets_target"] = target_deg is None or row["rmse_deg"] <= target_deg
            return plan, row
        grow = 1.05 * (row["rmse_deg"] / target_deg) ** 2
        plan = Plan(plan.positions_deg, plan.window_s * grow, plan.settle_s)
    row["meets_target"] = False
    return plan, row


def _print_rows(rows: list[dict[str, Any]]) -> None:
    first = "mu deg" if "mu_deg" in rows[0] else "positions"
    print(
        f"{first:>14} {'bias deg':>10} {'RMSE deg':>10} {'+-':>6} {'bound deg':>10} "
        f"{'RMSE/bound':>10} {'predicted':>10}"
    )
    for r in rows:
        label = (
            f"{r['mu_deg']:g}" if "mu_deg" in r else ",".join(f"{p:g}" for p in r["positions_deg"])
        )
        print(
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
    }
    report: dict[str, Any] = {"sensor": spec.name, "latitude_deg": args.latitude}
    best_plan: Plan | None = None
    if args.plan_budget is not None:
        cands = search_plans(model, args.latitude, args.plan_budget, **common)
        report["budget_s"] = args.plan_budget
        report["plans"] = [_candidate_json(c, model, args.warmup) for c in cands[: args.top]]
        best_plan = cands[0].plan if cands else None
    else:
        cand = shortest_plan(model, args.latitude, args.plan_target, **common)
        report["target_deg"] = args.plan_target
        report["plans"] = [] if cand is None else [_candidate_json(cand, model, args.warmup)]
        best_plan = None if cand is None else cand.plan
    if best_plan is not None and args.runs > 0:
        t0 = time.perf_counter()
        plan, row = verify_plan(spec, best_plan, settings, args.runs, args.seed, args.plan_target)
        report["verified"] = {
            **_plan_json(plan, model, args.warmup),
            **row,
            "runs": args.runs,
            "wall_time_s": time.perf_counter() - t0,
        }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    what = (
        f"plan time <= {args.plan_budget:g} s"
        if args.plan_budget is not None
        else f"predicted RMSE <= {args.plan_target:g} deg"
    )
    print(f"sensor {spec.name}, latitude {args.latitude:g} deg: plans for {what}")
    if not report["plans"]:
        print("no plan reaches it (within 4 h, or the budget is shorter than one move)")
        return 0
    print(
        f"{'positions':>34} {'window s':>9} {'plan s':>8} {'predicted deg':>14} "
        f"{'bound deg':>10}  note"
    )
    for c in report["plans"]:
        pos = ",".join(f"{p:g}" for p in c["positions_deg"])
        note = "longer windows stop helping (Allan limit)" if c["allan_limited"] else ""
        print(
            f"{pos:>34} {c['window_s']:9.1f} {c['plan_time_s']:8.1f} "
            f"{c['predicted_deg']:14.4f} {c['bound_deg']:10.4f}  {note}"
        )
    if "verified" in report:
        v = report["verified"]
        print(
            f"Monte Carlo of the first plan ({v['runs']} runs, window {v['window_s']:.1f} s, plan "
            f"{v['plan_time_s']:.1f} s): RMSE {v['rmse_deg']:.4f} deg "
            f"(+-{100 * v['rmse_rel_se']:.1f}%), bound {v['bound_deg']:.4f}, ratio {v['ratio']:.3f}"
            + ("" if args.plan_target is None else f", meets target: {v['meets_target']}")
        )
    return 0


def _sweep(
    spec: SensorSpec,
    plan: Plan,
    settings: StudySettings,
    windows: list[float],
    runs: int,
    seed: int,
) -> list[dict[str, Any]]:
    model = error_model(spec)
    out = []
    for w in windows:
        sub = Plan(plan.positions_deg, w, plan.settle_s)
        rows = study_rows(spec, sub, settings, monte_carlo(spec, sub, settings, runs, seed))
        out.append({"window_s": w, **_plan_json(sub, model, settings.warmup_s), **rows[0]})
    return out


def _plot(path: str, sweep: list[dict[str, Any]], title: str) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise HostConfigError(
            "--plot needs matplotlib: install the plot extra (pip install 'northfinder[plot]')"
        ) from exc
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


def run(args: argparse.Namespace) -> int:
    spec = _load(args)
    settings = _settings(args)
    if args.plan_budget is not None and args.plan_target is not None:
        raise HostConfigError("give either --plan-budget or --plan-target, not both")
    if args.runs < 0 or (args.runs < 2 and args.plan_budget is None and args.plan_target is None):
        raise HostConfigError(f"--runs: need at least 2 runs for statistics, got {args.runs}")
    if args.plan_budget is not None or args.plan_target is not None:
        return _run_planner(args, spec, settings)
    plan = _plan(args, spec)
    model = error_model(spec)
    t0 = time.perf_counter()
    errors = monte_carlo(spec, plan, settings, args.runs, args.seed)
    wall = time.perf_counter() - t0
    rows = study_rows(spec, plan, settings, errors)
    report: dict[str, Any] = {
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
    if args.plot:
        windows = args.sweep or [plan.window_s * f for f in (0.25, 0.5, 1.0, 2.0, 4.0)]
        if any(w <= 0 for w in windows):
            raise HostConfigError(f"--sweep: windows must be positive, got {windows}")
        report["sweep"] = _sweep(spec, plan, settings, windows, args.runs, args.seed)
        _plot(
            args.plot,
            report["sweep"],
            f"{spec.name}, positions {plan.label()}, {args.denoise}, {args.runs} runs",
        )
        report["plot"] = args.plot
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    p = report["plan"]
    print(
        f"sensor {spec.name}, latitude {args.latitude:g} deg, positions {plan.label()} deg, "
        f"window {plan.window_s:g} s, denoise {args.denoise}, solver {args.solver}, "
        f"tilt {args.tilt}, {args.runs} runs (seed {args.seed})"
    )
    print(
        f"plan time {p['plan_time_s']:.1f} s (windows, moves, settling; "
        f"{p['total_time_s']:.1f} s with {args.warmup:g} s warm-up); Monte Carlo {wall:.2f} s"
    )
    _print_rows(rows)
    if args.plot:
        print(f"plot of error versus time to north: {args.plot}")
    return 0
