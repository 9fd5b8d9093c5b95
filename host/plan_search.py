"""The planner: the plan with the smallest predicted error in a time budget, or the shortest plan
that meets an accuracy, from the datasheet prediction of :mod:`northfinder.host.accuracy` (every
error term of the model over the plan's own timeline, through the plan's own solver).

Plans are searched over position patterns (:data:`GEOMETRIES`) and window lengths; the plan time
counts moves and settling (:mod:`northfinder.host.plan`). Spin plans (:func:`search_spin_plans`)
are searched over table rates (:data:`SPIN_RATES_DPS` up to the table's limit), whole turns or
all the steady time the budget leaves after the ramps, with and without a fitted drift; the
plan time counts both ramps, so both kinds compete for the same budget. A Monte Carlo of the
chosen plan (:mod:`northfinder.host.montecarlo`) checks the prediction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Unpack

import numpy as np

from northfinder.host.accuracy import Conditions, ErrorModel, Prediction, predict
from northfinder.host.errors import GeometryError, HostConfigError
from northfinder.host.plan import Plan, SpinPlan, TableModel, plan_time_s, spin_ramp_s
from northfinder.host.spin import MIN_SWEEP_DEG

__all__ = [
    "GEOMETRIES",
    "SPIN_RATES_DPS",
    "PlanCandidate",
    "SpinCandidate",
    "search_plans",
    "search_spin_plans",
    "shortest_plan",
]


class _Predicted:
    """What a candidate reads from its prediction."""

    prediction: Prediction

    @property
    def sigma_deg(self) -> float:
        return self.prediction.sigma_deg

    @property
    def plan_time_s(self) -> float:
        return self.prediction.plan_time_s


@dataclass(frozen=True)
class PlanCandidate(_Predicted):
    """A plan with its predicted error and time."""

    plan: Plan
    prediction: Prediction
    allan_limited: bool


@dataclass(frozen=True)
class SpinCandidate(_Predicted):
    """A spin plan with its predicted error and time."""

    plan: SpinPlan
    prediction: Prediction


#: Position patterns the planner tries: two positions at several angles, equally spaced sets,
#: and symmetric orders that cancel a linear drift.
GEOMETRIES: tuple[tuple[float, ...], ...] = (
    (0.0, 30.0),
    (0.0, 60.0),
    (0.0, 90.0),
    (0.0, 120.0),
    (0.0, 150.0),
    (0.0, 180.0),
    (0.0, 180.0, 180.0, 0.0),
    (0.0, 120.0, 240.0),
    (0.0, 90.0, 180.0, 270.0),
    (0.0, 180.0, 90.0, 270.0),
    (0.0, 60.0, 120.0, 180.0, 240.0, 300.0),
    (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0),
)


def _overhead_s(positions: tuple[float, ...], table: TableModel, settle_s: float | None) -> float:
    plan = Plan(positions, 1.0, settle_s)
    return plan_time_s(plan, table) - len(positions) * 1.0


def search_plans(
    model: ErrorModel,
    latitude_deg: float,
    budget_s: float,
    *,
    settle_s: float | None = None,
    min_window_s: float = 1.0,
    geometries: Sequence[tuple[float, ...]] = GEOMETRIES,
    **conditions: Unpack[Conditions],
) -> list[PlanCandidate]:
    """The best window for each position pattern within a time budget, best first.

    For each pattern the windows are as long as the budget allows after moves and settling, or
    shorter when the prediction says a longer window no longer helps (beyond the Allan minimum
    bias instability and rate random walk take over): ``allan_limited`` is then True.

    Parameters
    ----------
    model : ErrorModel
    latitude_deg : float
    budget_s : float
        Largest plan time (windows, moves, settling), s.
    settle_s : float, optional
        Settle time; default the table's.
    min_window_s : float
        Shortest window considered, s.
    geometries : sequence of tuple of float
        Position patterns to try.
    **conditions
        :class:`~northfinder.host.accuracy.Conditions`: warm-up, tilt, angles, rate, pitch and
        roll, as for :func:`~northfinder.host.accuracy.predict` (the true azimuth is averaged
        over).

    Returns
    -------
    list of PlanCandidate
        One per pattern that fits the budget, sorted by predicted sigma (empty if none fits).
    """
    if not (math.isfinite(budget_s) and budget_s > 0):
        raise HostConfigError(f"budget: must be a positive number of seconds, got {budget_s!r}")
    out = []
    for pos in geometries:
        free = budget_s - _overhead_s(pos, model.table, settle_s)
        w_max = free / len(pos)
        if w_max < min_window_s:
            continue
        grid = np.unique(np.r_[np.geomspace(min_window_s, w_max, 40), w_max])
        best = None
        for w in grid:
            pred = predict(model, Plan(pos, float(w), settle_s), latitude_deg, **conditions)
            if best is None or pred.sigma_deg < best[1].sigma_deg * (1 - 1e-9):
                best = (float(w), pred)
        assert best is not None
        w, pred = best
        out.append(PlanCandidate(Plan(pos, w, settle_s), pred, allan_limited=w < 0.98 * w_max))
    out.sort(key=lambda c: (c.sigma_deg, c.plan_time_s))
    return out


def shortest_plan(
    model: ErrorModel,
    latitude_deg: float,
    target_deg: float,
    *,
    max_time_s: float = 4 * 3600.0,
    settle_s: float | None = None,
    geometries: Sequence[tuple[float, ...]] = GEOMETRIES,
    **conditions: Unpack[Conditions],
) -> PlanCandidate | None:
    """The plan with the shortest plan time whose predicted sigma meets ``target_deg``.

    For each pattern the window is found by bisection on the falling part of the predicted
    error (before the Allan minimum); patterns that cannot reach the target within
    ``max_time_s`` are skipped. None when no pattern can.
    """
    if not (math.isfinite(target_deg) and target_deg > 0):
        raise HostConfigError(f"target: must be a positive angle in deg, got {target_deg!r}")
    best: PlanCandidate | None = None

    def sigma(pos: tuple[float, ...], w: float) -> Prediction:
        return predict(model, Plan(pos, w, settle_s), latitude_deg, **conditions)

    for pos in geometries:
        w_max = (max_time_s - _overhead_s(pos, model.table, settle_s)) / len(pos)
        if w_max <= 0.01:
            continue
        grid = np.geomspace(0.01, w_max, 60)
        sig = np.array([sigma(pos, float(w)).sigma_deg for w in grid])
        ok = np.flatnonzero(sig <= target_deg)
        if ok.size == 0:
            continue
        hi = float(grid[ok[0]])
        lo = float(grid[ok[0] - 1]) if ok[0] > 0 else 0.0
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if mid > 0 and sigma(pos, mid).sigma_deg <= target_deg:
                hi = mid
            else:
                lo = mid
            if hi - lo < 1e-3 * hi:
                break
        pred = sigma(pos, hi)
        cand = PlanCandidate(Plan(pos, hi, settle_s), pred, allan_limited=False)
        if best is None or cand.plan_time_s < best.plan_time_s:
            best = cand
    return best


#: Table rates the spin search tries, deg/s (those within the table's limit, and the limit).
SPIN_RATES_DPS: tuple[float, ...] = (1.0, 2.0, 3.0, 6.0, 10.0, 20.0, 45.0, 90.0)


def search_spin_plans(
    model: ErrorModel,
    latitude_deg: float,
    budget_s: float,
    *,
    rates_dps: Sequence[float] = SPIN_RATES_DPS,
    **conditions: Unpack[Conditions],
) -> list[SpinCandidate]:
    """The best spin for each table rate within a time budget, best first.

    For each rate (those of ``rates_dps`` within the table's limit, and the limit itself) the
    spin lasts all the steady time the budget leaves after the ramp to the rate and the brake,
    or (below four turns) the whole turns within it, with or without a fitted drift: whichever
    the prediction prefers. Parameters as :func:`search_plans`.

    Returns
    -------
    list of SpinCandidate
        One per rate that turns at least 90 deg within the budget, sorted by predicted sigma.
    """
    if not (math.isfinite(budget_s) and budget_s > 0):
        raise HostConfigError(f"budget: must be a positive number of seconds, got {budget_s!r}")
    table = model.table
    top = table.max_rate_dps
    rates = sorted({float(r) for r in rates_dps if 0 < r < top} | {float(top)})
    out: list[SpinCandidate] = []
    for rate in rates:
        steady = budget_s - 2.0 * spin_ramp_s(SpinPlan(rate, 360.0 / rate), table)
        if steady * rate < MIN_SWEEP_DEG:
            continue
        turn = 360.0 / rate
        times = {steady}
        if turn <= steady < 4 * turn:  # beyond four turns a part turn costs next to nothing
            # Whole turns, with a margin against rounding the budget over.
            times.add(math.floor(steady / turn + 1e-9) * turn * (1 - 1e-12))
        best = None
        for spin_s in sorted(times):
            for drift in (False, True):
                plan = SpinPlan(rate, spin_s, drift)
                try:
                    pred = predict(model, plan, latitude_deg, **conditions)
                except GeometryError:
                    continue  # too few samples at this rate
                if best is None or pred.sigma_deg < best.sigma_deg * (1 - 1e-9):
                    best = SpinCandidate(plan, pred)
        if best is not None:
            out.append(best)
    out.sort(key=lambda c: (c.sigma_deg, c.plan_time_s))
    return out
