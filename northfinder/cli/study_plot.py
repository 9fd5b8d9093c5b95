"""``northfinder study --plot``: error versus time to north over a sweep of window lengths."""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import replace
from typing import Any

from northfinder.cli.plots import pyplot
from northfinder.cli.progress import Progress
from northfinder.cli.studies import describe_plan
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.host.montecarlo import StudySettings, monte_carlo_many, study_rows
from northfinder.host.plan import Plan
from northfinder.simwindows import SimulatedWindows, error_model


def window_sweep(
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
        out.append({"window_s": w, **describe_plan(sub, model, settings.warmup_s), **rows[0]})
    return out


def plot_sweep(path: str, sweep: list[dict[str, Any]], title: str) -> None:
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
