"""The planner's prediction against Monte Carlo: the paper's sweep, and the best plan of a budget.

Run: ``.venv/bin/python benchmarks/bench_planner.py [--runs 1000] [--only sweep|budget|compare]``.
Prints three markdown tables (34 deg N, 120 s warm-up, uniform random azimuth, seeded):

1. ``paper-prototype`` on the paper's sweep (eight positions 30 deg apart, 10 s windows, every
   position solved against the first): RMSE by Monte Carlo and the prediction for each mu.
2. For each preset and plan budgets of 60, 160 and 600 s: the planner's best stop-and-go plan
   (``northfinder study --sensor PRESET --plan-budget SECONDS``), its Monte Carlo RMSE, the
   prediction, the white-noise bound of that plan and the physical bound of the budget (all of
   it spent recording: N / (Omega_H sqrt(budget))).
3. For each preset and plan budgets of 60, 160 and 600 s: the best stop-and-go plan and the best
   spin (ramps counted; the first of each in ``northfinder study --sensor PRESET --plan-budget
   SECONDS``) side by side, each with its Monte Carlo RMSE, its 95 % chi-square interval and the
   prediction, and a verdict: the better kind where the intervals are apart, else "not resolved"
   (runs are doubled, with fresh seeds, while they overlap, up to ``--max-runs``).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.stats import chi2
from studies import LATITUDE, SETTINGS, WARMUP, noisy_presets

from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import budget_bound_deg
from northfinder.host.montecarlo import StudySettings, monte_carlo, study_rows
from northfinder.host.plan import PAPER_SWEEP, Plan, SpinPlan
from northfinder.host.plan_search import search_plans, search_spin_plans
from northfinder.simwindows import SimulatedWindows, error_model

BUDGETS = (60.0, 160.0, 600.0)


def sweep_table(runs: int, seed: int) -> None:
    spec = load_spec("paper-prototype")
    t0 = time.perf_counter()
    errors = monte_carlo(SimulatedWindows(spec), PAPER_SWEEP, SETTINGS, runs, seed)
    rows = study_rows(error_model(spec), PAPER_SWEEP, SETTINGS, errors)
    print(
        f"\n### paper-prototype on the paper's sweep, {runs} runs "
        f"(Monte Carlo {time.perf_counter() - t0:.0f} s)\n\n"
        "| mu deg | RMSE deg | +- (1 s.e.) | predicted deg | predicted/RMSE | bound deg |\n"
        "|---:|---:|---:|---:|---:|---:|"
    )
    for r in rows:
        print(
            f"| {r['mu_deg']:g} | {r['rmse_deg']:.4f} | {100 * r['rmse_rel_se']:.1f} % | "
            f"{r['predicted_deg']:.4f} | {r['predicted_deg'] / r['rmse_deg']:.3f} | "
            f"{r['bound_deg']:.4f} |"
        )


def budget_table(runs: int, seed: int) -> None:
    print(
        f"\n### Best stop-and-go plan of a budget, {runs} runs per plan\n\n"
        "| preset | budget s | positions | window s | plan s | RMSE deg | +- | predicted deg | "
        "predicted/RMSE | plan bound deg | budget bound deg |\n"
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"
    )
    worst = 0.0
    for name, spec, model in noisy_presets():
        for budget in BUDGETS:
            cands = search_plans(model, LATITUDE, budget, warmup_s=WARMUP)
            if not cands:
                print(f"| {name} | {budget:g} | no plan fits | | | | | | | | |")
                continue
            best = cands[0]
            errors = monte_carlo(SimulatedWindows(spec), best.plan, SETTINGS, runs, seed)
            row = study_rows(model, best.plan, SETTINGS, errors)[0]
            ratio = row["predicted_deg"] / row["rmse_deg"]
            worst = max(worst, abs(ratio - 1.0))
            print(
                f"| {name} | {budget:g} | {best.plan.label()} | {best.plan.window_s:.1f} | "
                f"{best.plan_time_s:.1f} | {row['rmse_deg']:.4f} | "
                f"{100 * row['rmse_rel_se']:.1f} % | {row['predicted_deg']:.4f} | {ratio:.3f} | "
                f"{row['bound_deg']:.4f} | "
                f"{budget_bound_deg(budget, model.arw_dpsh, LATITUDE):.4f} |",
                flush=True,
            )
    print(f"\nlargest |predicted/RMSE - 1|: {100 * worst:.1f} % (target <= 15 %)")


def rmse_interval(errors: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """RMSE and its chi-square interval (the errors zero-mean normal: n RMSE^2 / sigma^2 is
    chi-square with n degrees of freedom), deg."""
    e = errors[np.isfinite(errors)]
    n = e.size
    rmse = math.sqrt(float(np.mean(e * e)))
    lo = rmse * math.sqrt(n / chi2.ppf(0.5 + level / 2, n))
    hi = rmse * math.sqrt(n / chi2.ppf(0.5 - level / 2, n))
    return rmse, lo, hi


def _label(plan: Plan | SpinPlan) -> str:
    if isinstance(plan, SpinPlan):
        turns = abs(plan.rate_dps) * plan.spin_s / 360.0
        return f"{plan.rate_dps:+g} deg/s x {plan.spin_s:.1f} s ({turns:.2f} turns{', drift' if plan.drift else ''})"
    return f"{plan.label()} x {plan.window_s:.1f} s"


def compare_table(
    runs: int, seed: int, max_runs: int, settings: StudySettings = SETTINGS,
    presets: tuple[str, ...] = (), overrides: dict[str, float] | None = None,
) -> None:  # fmt: skip
    """Each row starts with ``runs`` runs a plan and doubles them (fresh seeds) while the two
    95 % intervals overlap, up to ``max_runs``; then says which is better or "not resolved"."""
    print(
        f"\n### Best stop-and-go plan and best spin of a budget: {runs} to {max_runs} runs a plan, "
        f"{settings.sample_rate_hz:g} Hz\n\n"
        "| preset | budget s | stop-and-go | runs | RMSE deg [95 %] | predicted deg | spin | runs | "
        "RMSE deg [95 %] | predicted deg | predicted ratio | RMSE ratio | verdict |\n"
        "|---|---:|---|---:|---|---:|---|---:|---|---:|---:|---:|---|"
    )
    worst, below = 0.0, 0
    for name, spec, model in noisy_presets():
        if presets and name not in presets:
            continue
        if overrides:
            spec = spec.with_values(overrides)
            model = error_model(spec)
        for budget in BUDGETS:
            bound = budget_bound_deg(budget, model.arw_dpsh, LATITUDE)
            kinds: dict[str, tuple[Any, list[np.ndarray]]] = {}
            for kind, cands in (
                ("stop-and-go", search_plans(model, LATITUDE, budget, warmup_s=WARMUP,
                                             sample_rate_hz=settings.sample_rate_hz)),
                ("spin", search_spin_plans(model, LATITUDE, budget, warmup_s=WARMUP,
                                           sample_rate_hz=settings.sample_rate_hz)),
            ):  # fmt: skip
                if cands:
                    kinds[kind] = (cands[0].plan, [])
            n, k = runs, 0
            while True:
                for plan, chunks in kinds.values():
                    have = sum(c.size for c in chunks)
                    chunks.append(monte_carlo(SimulatedWindows(spec), plan, settings,
                                              n - have, seed + 1000 * k))  # fmt: skip
                stats = {kd: rmse_interval(np.concatenate(c)) for kd, (_, c) in kinds.items()}
                if len(stats) < 2 or n >= max_runs:
                    break
                (_, lo1, hi1), (_, lo2, hi2) = stats.values()
                if hi1 < lo2 or hi2 < lo1:
                    break
                n, k = min(2 * n, max_runs), k + 1
            cells, pred = [], {}
            for kind in ("stop-and-go", "spin"):
                if kind not in kinds:
                    cells += ["none fits", "", "", ""]
                    continue
                plan, chunks = kinds[kind]
                errors = np.concatenate(chunks)
                row = study_rows(model, plan, settings, errors)[0]
                rmse, lo, hi = stats[kind]
                pred[kind] = row["predicted_deg"]
                worst = max(worst, abs(row["predicted_deg"] / rmse - 1.0))
                below += hi < bound  # beating the budget bound beyond the scatter: a bug
                cells += [_label(plan), f"{errors.size}", f"{rmse:.4f} [{lo:.4f}, {hi:.4f}]",
                          f"{row['predicted_deg']:.4f}"]  # fmt: skip
            if len(stats) == 2:
                (r1, lo1, hi1), (r2, lo2, hi2) = stats["stop-and-go"], stats["spin"]
                verdict = (
                    "spin better" if hi2 < lo1 else "stop-and-go better" if hi1 < lo2
                    else "not resolved"
                )  # fmt: skip
                ratios = [f"{pred['stop-and-go'] / pred['spin']:.2f}", f"{r1 / r2:.2f}"]
            else:
                verdict, ratios = "-", ["", ""]
            print(f"| {name} | {budget:g} | " + " | ".join(cells) + " | " + " | ".join(ratios)
                  + f" | {verdict} |", flush=True)  # fmt: skip
    print(
        f"\nratios are stop-and-go over spin (above 1: the spin is better); largest "
        f"|predicted/RMSE - 1|: {100 * worst:.1f} % (target <= 15 %); upper 95 % limit of an RMSE "
        f"below the budget bound: {below} (must be 0)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=1000, help="Monte Carlo runs per plan")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", choices=("sweep", "budget", "compare"), default=None)
    ap.add_argument("--max-runs", type=int, default=3200, help="compare: most runs per plan")
    ap.add_argument("--rate", type=float, default=200.0, help="compare: sample rate, Hz")
    ap.add_argument("--presets", nargs="*", default=(), help="compare: these presets only")
    ap.add_argument("--set", nargs="*", default=(), metavar="SECTION.FIELD=VALUE",
                    help="compare: override sensor fields of every preset")  # fmt: skip
    args = ap.parse_args()
    if args.only in (None, "sweep"):
        sweep_table(args.runs, args.seed)
    if args.only in (None, "budget"):
        budget_table(args.runs, args.seed)
    if args.only in (None, "compare"):
        compare_table(args.runs, args.seed, args.max_runs,
                      replace(SETTINGS, sample_rate_hz=args.rate), tuple(args.presets),
                      {k: float(v) for k, v in (a.split("=", 1) for a in args.set)})  # fmt: skip


if __name__ == "__main__":
    main()
