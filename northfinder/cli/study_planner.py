"""``northfinder study --plan-budget`` / ``--plan-target``: the plans (and spins) with the
smallest predicted error, the best one checked by a Monte Carlo.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from northfinder.cli.executors import study_executor
from northfinder.cli.exits import EXIT_RUNTIME
from northfinder.cli.output import dumps, say
from northfinder.cli.studies import describe_plan, study_progress, with_processing
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.host.accuracy import ErrorModel, budget_bound_deg
from northfinder.host.montecarlo import (
    StudySettings,
    monte_carlo,
    rmse_interval_deg,
    study_rows,
    verify_plan,
)
from northfinder.host.plan import Plan, SpinPlan
from northfinder.host.plan_search import (
    PlanCandidate,
    SpinCandidate,
    search_plans,
    search_spin_plans,
    shortest_plan,
)
from northfinder.host.results import envelope
from northfinder.simwindows import SimulatedWindows, error_model, simulator_identity


def _candidate_json(
    c: PlanCandidate | SpinCandidate, model: ErrorModel, warmup_s: float
) -> dict[str, Any]:
    out = {
        **describe_plan(c.plan, model, warmup_s),
        "predicted_deg": c.sigma_deg,
        "bound_deg": c.prediction.bound_deg,
        "predicted_parts_deg": c.prediction.parts_deg,
    }
    if isinstance(c, PlanCandidate):
        out["allan_limited"] = c.allan_limited
    return out


def run_planner(args: argparse.Namespace, spec: SensorSpec, settings: StudySettings) -> int:
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
        with study_executor(args) as executor, study_progress(args) as bar:
            bar.step("Monte Carlo of the best plan")
            plan, row = verify_plan(
                SimulatedWindows(spec),
                model,
                with_processing(args, best_plan),
                settings,
                args.runs,
                args.seed,
                args.plan_target,
                executor=executor,
                progress=bar.count,
            )
        report["verified"] = {
            **describe_plan(plan, model, args.warmup),
            **row,
            "runs": args.runs,
            "wall_time_s": time.perf_counter() - t0,
        }
    if best_spin is not None and args.runs > 0:
        t0 = time.perf_counter()
        with study_executor(args) as executor, study_progress(args) as bar:
            bar.step("Monte Carlo of the best spin")
            errors = monte_carlo(
                SimulatedWindows(spec), best_spin, settings, args.runs, args.seed,
                executor=executor, progress=bar.count,
            )  # fmt: skip
        report["verified_spin"] = {
            **describe_plan(best_spin, model, args.warmup),
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
