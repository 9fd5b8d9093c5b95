"""Accuracy studies of gyro north finding: vectorised solvers, the physical bound, plan search.

Everything here is pure numpy on arrays of many runs at once; the samples come from the caller
(the ``northfinder study`` command draws them from the simulated instrument). Conventions are
those of :mod:`northfinder.host.heading`: azimuth of body x clockwise from true north, table angles
right-handed about up, gyro means in rad/s, accelerometer means (specific force) in m/s^2.

Plan and time
-------------
A plan is a list of table positions, one recording window of ``window_s`` at each, and a settle
time after every move. Moves go the shorter way with a trapezoidal profile (rate and acceleration
limits of the table); a position equal to the previous one needs no move and no settling. The
**plan time** runs from the start of the first window to the end of the last one: windows,
moves and settling, not the warm-up before the first window.

Bound and prediction
--------------------
:func:`bound_deg` is the white-noise limit of the notes (section 4): for two positions with total
dwell T, ``N / (Omega_H |sin(mu/2)| sqrt(T))``; for N positions the least-squares covariance of
the heading with both horizontal gyro biases estimated (the same as
:func:`northfinder.host.heading.solve_multi_position` with known noise). A simulated result that beats it is
a bug. :func:`predict` adds what a datasheet predicts beyond white noise: bias instability
(flicker, as Gauss-Markov components from 1 s to 10^4 s), rate random walk, the covariance of
window means across the gaps of the plan, a deterministic drift, table indexing error (when the
commanded angles are used), accelerometer noise through the tilt (``tan(lat)``) and axis
misalignment. It is what the planner minimises; the Monte Carlo checks it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.host.denoise import METHODS, denoise
from northfinder.host.errors import GeometryError, HostConfigError, InputError
from northfinder.host.heading import MIN_MU_SEPARATION_DEG, OMEGA_IE, _latitude_rad, normal_gravity

__all__ = [
    "ANGLE_SOURCES",
    "SOLVERS",
    "TILT_SOURCES",
    "ErrorModel",
    "Plan",
    "PlanCandidate",
    "Prediction",
    "Summary",
    "TableModel",
    "azimuth_errors",
    "bound_deg",
    "chunk_errors",
    "plan_time_s",
    "predict",
    "search_plans",
    "shortest_plan",
    "solve_least_squares_batch",
    "solve_two_position_batch",
    "summarize",
    "trapezoid_time_s",
    "window_means",
]

#: Heading solvers of a study.
SOLVERS: Mapping[str, str] = {
    "auto": "two-position for 2 positions, least-squares for more",
    "two-position": "paper eq. 14 (eq. 15 when level is assumed); exactly 2 positions",
    "least-squares": "multi-position least squares, gyro biases estimated",
    "pairwise": "every position against the first by eq. 14 (the paper's Table 2)",
}
#: Where the tilt comes from.
TILT_SOURCES: Mapping[str, str] = {
    "accel": "pitch and roll from the accelerometer means (bias-free, by differences)",
    "level": "the instrument is assumed level",
}
#: Which table angles the solver uses.
ANGLE_SOURCES: Mapping[str, str] = {
    "encoder": "the encoder reading in each window (indexing error seen)",
    "commanded": "the commanded angles (indexing error not seen)",
}

_DPH = math.pi / 180.0 / 3600.0
_ARW = math.pi / 180.0 / 60.0  # deg/sqrt(h) -> rad/sqrt(s)
_RRW = math.pi / 180.0 / 3600.0 / 60.0  # deg/h/sqrt(h) -> rad/s/sqrt(s)
_UG = 9.80665e-6
#: Flicker (bias instability B) as Gauss-Markov components, correlation times 10^(0, 0.5, .. 4) s,
#: each of variance B^2 ln(sqrt 10) / pi: their sum has the one-sided PSD B^2 / (pi f).
_FLICKER_TAUS = 10.0 ** np.arange(0.0, 4.01, 0.5)
_FLICKER_VAR = math.log(10.0**0.5) / math.pi


def _choice(value: str, table: Mapping[str, str], name: str) -> str:
    if value not in table:
        raise HostConfigError(
            f"{name}: unknown value {value!r}; choose one of {', '.join(repr(k) for k in table)}"
        )
    return value


# ----------------------------------------------------------------------------------------------
# Plans and their time
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TableModel:
    """What the planner needs to know about the turntable.

    Attributes
    ----------
    max_rate_dps, max_accel_dps2 : float
        Speed and acceleration limits, deg/s and deg/s^2.
    settle_s : float
        Wait after a move before recording, s.
    indexing_error_deg : float
        Stop-position error per move, 1 sigma, deg.
    """

    max_rate_dps: float = 10.0
    max_accel_dps2: float = 20.0
    settle_s: float = 2.0
    indexing_error_deg: float = 0.0


@dataclass(frozen=True)
class Plan:
    """Table positions with one window each.

    Attributes
    ----------
    positions_deg : tuple of float
        Commanded table angle of each window, deg.
    window_s : float
        Recording time per window, s.
    settle_s : float or None
        Wait after each move, s; None takes the table's.
    """

    positions_deg: tuple[float, ...]
    window_s: float
    settle_s: float | None = None

    def __post_init__(self) -> None:
        pos = tuple(float(p) for p in self.positions_deg)
        if len(pos) < 2:
            raise GeometryError(f"a plan needs at least 2 positions, got {len(pos)}")
        if not all(math.isfinite(p) for p in pos):
            raise InputError(f"positions_deg: must be finite, got {pos}")
        spread = np.abs(np.sin(np.radians(np.subtract.outer(pos, pos)) / 2.0)).max()
        if spread < math.sin(math.radians(MIN_MU_SEPARATION_DEG) / 2.0):
            raise GeometryError(
                f"positions {list(pos)} deg: at least two must be {MIN_MU_SEPARATION_DEG:g} deg "
                "apart (mod 360) for the gyro biases to separate from the Earth rate"
            )
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise InputError(f"window_s: must be a positive number of seconds, got {self.window_s}")
        if self.settle_s is not None and not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise InputError(f"settle_s: must be >= 0 s, got {self.settle_s}")
        object.__setattr__(self, "positions_deg", pos)

    def label(self) -> str:
        return ",".join(f"{p:g}" for p in self.positions_deg)


def trapezoid_time_s(distance_deg: float, max_rate_dps: float, max_accel_dps2: float) -> float:
    """Time (s) of a rest-to-rest move over ``|distance_deg|`` with rate and acceleration limits."""
    d, v, a = abs(distance_deg), max_rate_dps, max_accel_dps2
    if d == 0.0:
        return 0.0
    if d <= v * v / a:
        return 2.0 * math.sqrt(d / a)
    return v / a + d / v


def _moves(plan: Plan) -> list[float]:
    pos = plan.positions_deg
    return [(b - a + 180.0) % 360.0 - 180.0 for a, b in itertools.pairwise(pos)]


def window_starts_s(plan: Plan, table: TableModel) -> NDArray[np.float64]:
    """Start of each window relative to the start of the first, s."""
    settle = table.settle_s if plan.settle_s is None else plan.settle_s
    starts = [0.0]
    for d in _moves(plan):
        move = trapezoid_time_s(d, table.max_rate_dps, table.max_accel_dps2)
        starts.append(starts[-1] + plan.window_s + (move + settle if d != 0.0 else 0.0))
    return np.array(starts)


def plan_time_s(plan: Plan, table: TableModel) -> float:
    """Windows, moves and settling from the first window's start to the last one's end, s."""
    return float(window_starts_s(plan, table)[-1] + plan.window_s)


# ----------------------------------------------------------------------------------------------
# Bound and prediction
# ----------------------------------------------------------------------------------------------


def _weights(mu_deg: ArrayLike, omega_h: float, alpha: float = 0.0) -> NDArray[np.float64]:
    """Least-squares weights of the heading on the gyro window means, shape (N, 2), rad per rad/s.

    Level instrument, both horizontal gyro biases estimated: alpha_hat - alpha = sum c_i . r_i for
    small perturbations r_i of the window means; the weights sum to zero over the positions.
    """
    mu = np.radians(np.asarray(mu_deg, dtype=float))
    c, s = np.cos(mu), np.sin(mu)
    # h = omega_h (cos a, -sin a); dh/dalpha = -omega_h (sin a, cos a); R(mu) dh per position.
    dx, dy = -omega_h * math.sin(alpha), -omega_h * math.cos(alpha)
    j = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
    jp = j - j.mean(axis=0)
    norm2 = float(np.sum(jp * jp))
    if norm2 < 1e-30:
        raise GeometryError(f"positions {np.asarray(mu_deg).tolist()}: heading is not observable")
    return jp / norm2


def bound_deg(
    positions_deg: Sequence[float], window_s: float, arw_dpsh: float, latitude_deg: float
) -> float:
    """White-noise limit of the heading for a plan, 1 sigma, deg (notes, section 4).

    Parameters
    ----------
    positions_deg : sequence of float
        Table angles, deg (two or more; repeats allowed).
    window_s : float
        Recording time per position, s.
    arw_dpsh : float
        Gyro angle random walk, deg/sqrt(h).
    latitude_deg : float
        Latitude, deg.

    Returns
    -------
    float
        For two positions ``N / (Omega_H |sin(mu/2)| sqrt(T))`` with T = 2 window_s; for more,
        the least-squares standard deviation with both gyro biases estimated.
    """
    plan = Plan(tuple(positions_deg), window_s)
    omega_h = OMEGA_IE * math.cos(_latitude_rad(latitude_deg, "the bound"))
    c = _weights(plan.positions_deg, omega_h)
    s = arw_dpsh * _ARW / math.sqrt(window_s)
    return math.degrees(s * math.sqrt(float(np.sum(c * c))))


@dataclass(frozen=True)
class ErrorModel:
    """Datasheet figures of a gyro north finder, as the planner uses them.

    Attributes
    ----------
    arw_dpsh : float
        Gyro angle random walk, deg/sqrt(h).
    bias_instability_dph : float
        Gyro flicker bias instability B (Allan floor 0.664 B), deg/h.
    rrw_dphpsh : float
        Gyro rate random walk, deg/h/sqrt(h).
    misalignment_urad, scale_factor_ppm : float
        Gyro axis misalignment and scale-factor error, 1 sigma.
    vrw_ug_rthz : float
        Accelerometer white noise, ug/sqrt(Hz) (enters through the tilt).
    table : TableModel
        Turntable limits, settle time, indexing error.
    drift_rps : callable or None
        Deterministic gyro bias of time since power-on, ``f(t_s (k,)) -> (k, 2)`` rad/s for the
        x and y gyros (warm-up transient, temperature); None when there is none.
    """

    arw_dpsh: float
    bias_instability_dph: float = 0.0
    rrw_dphpsh: float = 0.0
    misalignment_urad: float = 0.0
    scale_factor_ppm: float = 0.0
    vrw_ug_rthz: float = 0.0
    table: TableModel = field(default_factory=TableModel)
    drift_rps: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = field(
        default=None, repr=False, compare=False
    )


@dataclass(frozen=True)
class Prediction:
    """Predicted 1-sigma heading error of a plan, deg, with its parts (rad^2 variances in deg)."""

    sigma_deg: float
    bound_deg: float
    plan_time_s: float
    parts_deg: dict[str, float]


def _window_mean_cov(starts: NDArray[np.float64], tau: float, model: ErrorModel) -> NDArray:
    """Covariance of one gyro axis' window means, (N, N), (rad/s)^2 (white, flicker, walk)."""
    n = starts.size
    cov = np.eye(n) * (model.arw_dpsh * _ARW) ** 2 / tau
    b = model.bias_instability_dph * _DPH
    if b:
        d = np.abs(np.subtract.outer(starts, starts))
        for tc in _FLICKER_TAUS:
            v = b * b * _FLICKER_VAR
            r = tau / tc
            same = 2.0 * v * (r - 1.0 + math.exp(-r)) / (r * r)
            # e^{-d/tc} (e^r - 2 + e^-r), written so that nothing overflows (d >= tau off the
            # diagonal).
            dd = np.maximum(d, tau)
            cross = (
                v
                * (np.exp(-(dd - tau) / tc) - 2.0 * np.exp(-dd / tc) + np.exp(-(dd + tau) / tc))
                / (r * r)
            )
            cov += np.where(d < tau * 0.5, same, cross)
    k = model.rrw_dphpsh * _RRW
    if k:
        lo = np.minimum.outer(starts, starts)
        same = np.equal.outer(starts, starts)
        cov += k * k * (lo + np.where(same, tau / 3.0, tau / 2.0))
    return cov


def predict(
    model: ErrorModel,
    plan: Plan,
    latitude_deg: float,
    *,
    warmup_s: float = 0.0,
    tilt: str = "accel",
    angles: str = "encoder",
) -> Prediction:
    """Predicted heading error of a plan from the datasheet figures (see the module docstring).

    Parameters
    ----------
    model : ErrorModel
        Sensor and table figures.
    plan : Plan
        Positions, window, settle.
    latitude_deg : float
        Latitude, deg.
    warmup_s : float
        Time from power-on to the first window (for the drift term), s.
    tilt : {"accel", "level"}
        With ``accel`` the accelerometer noise enters through the tilt.
    angles : {"encoder", "commanded"}
        With ``commanded`` the table indexing error enters (d_azimuth = -d_mu / 2 for two
        positions).

    Returns
    -------
    Prediction
        ``sigma_deg`` (the root of the summed variances), ``bound_deg`` (white noise only).
    """
    _choice(tilt, TILT_SOURCES, "tilt")
    _choice(angles, ANGLE_SOURCES, "angles")
    lat = _latitude_rad(latitude_deg, "the prediction")
    omega_h = OMEGA_IE * math.cos(lat)
    tau = plan.window_s
    starts = window_starts_s(plan, model.table)
    c = _weights(plan.positions_deg, omega_h)
    cov = _window_mean_cov(starts, tau, model)
    # Each axis has the same covariance, the axes are independent: sum over both.
    parts = {
        "white": (model.arw_dpsh * _ARW) ** 2 / tau * float(np.sum(c * c)),
        "slow_noise": float(np.einsum("ia,ij,ja->", c, cov, c)),
    }
    parts["slow_noise"] -= parts["white"]
    if model.drift_rps is not None:
        # Exact effect of a known drift, averaged over the true azimuth (the weights turn with it).
        t = (warmup_s + starts[:, None] + (np.arange(64) + 0.5)[None, :] * tau / 64).ravel()
        means = np.asarray(model.drift_rps(t), dtype=float).reshape(starts.size, 64, 2).mean(1)
        alphas = np.linspace(0.0, 2 * math.pi, 8, endpoint=False)
        errs = [float(np.sum(_weights(plan.positions_deg, omega_h, a) * means)) for a in alphas]
        parts["drift"] = float(np.mean(np.square(errs)))
    if angles == "commanded" and model.table.indexing_error_deg:
        # A stop error e_k at position k shifts its window mean by R'(mu_k) h e_k.
        e = math.radians(model.table.indexing_error_deg)
        moved = np.r_[False, np.array(_moves(plan)) != 0.0]
        mu = np.radians(plan.positions_deg)
        deriv = np.stack([-omega_h * np.sin(mu), -omega_h * np.cos(mu)], axis=-1)  # R'(mu) h(0)
        # Positions that share one stop (no move between them) share its error.
        stop = np.cumsum(moved)
        sens = np.bincount(stop, weights=np.sum(c * deriv, axis=1))
        parts["indexing"] = e * e * float(np.sum(sens[1:] ** 2))  # stop 0: no move, no error
    if tilt == "accel" and model.vrw_ug_rthz:
        # Tilt from f_i = R_i f0 + b: same projected design as the gyros; d_az ~ tan(lat) d_tilt.
        s_a = model.vrw_ug_rthz * _UG / math.sqrt(tau) / normal_gravity(math.degrees(lat))
        ca = _weights(plan.positions_deg, 1.0)
        parts["tilt"] = (s_a * math.tan(lat)) ** 2 * float(np.sum(ca * ca))
    mis = model.misalignment_urad * 1e-6
    sf = model.scale_factor_ppm * 1e-6
    if mis or sf:
        parts["misalignment"] = 0.75 * mis * mis + 0.25 * sf * sf
    total = math.sqrt(max(sum(parts.values()), 0.0))
    return Prediction(
        sigma_deg=math.degrees(total),
        bound_deg=math.degrees(math.sqrt(parts["white"])),
        plan_time_s=plan_time_s(plan, model.table),
        parts_deg={k: math.degrees(math.sqrt(max(v, 0.0))) for k, v in parts.items()},
    )


# ----------------------------------------------------------------------------------------------
# Plan search
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanCandidate:
    """A plan with its predicted error and time."""

    plan: Plan
    prediction: Prediction
    allan_limited: bool

    @property
    def sigma_deg(self) -> float:
        return self.prediction.sigma_deg

    @property
    def plan_time_s(self) -> float:
        return self.prediction.plan_time_s


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
    warmup_s: float = 0.0,
    tilt: str = "accel",
    angles: str = "encoder",
    min_window_s: float = 1.0,
    geometries: Sequence[tuple[float, ...]] = GEOMETRIES,
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
    warmup_s, tilt, angles
        As for :func:`predict`.
    min_window_s : float
        Shortest window considered, s.
    geometries : sequence of tuple of float
        Position patterns to try.

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
            pred = predict(
                model,
                Plan(pos, float(w), settle_s),
                latitude_deg,
                warmup_s=warmup_s,
                tilt=tilt,
                angles=angles,
            )
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
    warmup_s: float = 0.0,
    tilt: str = "accel",
    angles: str = "encoder",
    geometries: Sequence[tuple[float, ...]] = GEOMETRIES,
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
        return predict(
            model,
            Plan(pos, w, settle_s),
            latitude_deg,
            warmup_s=warmup_s,
            tilt=tilt,
            angles=angles,
        )

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


# ----------------------------------------------------------------------------------------------
# Vectorised solvers
# ----------------------------------------------------------------------------------------------


def _tilt_from_f0(
    fx0: NDArray[np.float64], fy0: NDArray[np.float64], g: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    s_theta = -fx0 / g
    theta = np.arcsin(np.clip(s_theta, -1.0, 1.0))
    gamma = np.arcsin(np.clip(fy0 / (g * np.cos(theta)), -1.0, 1.0))
    return theta, gamma


def solve_two_position_batch(
    gyro0: ArrayLike,
    gyro1: ArrayLike,
    mu_deg: ArrayLike,
    *,
    latitude_deg: float,
    accel0: ArrayLike | None = None,
    accel1: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Azimuths of many two-position runs (paper eqs. 12-14, or eq. 15 without accelerometers).

    The vectorised twin of :func:`northfinder.host.heading.solve_two_position` (rad/s and m/s^2 units).

    Parameters
    ----------
    gyro0, gyro1 : array_like, shape (R, 2) or (R, 3)
        Gyro window means at the two positions, rad/s.
    mu_deg : array_like, shape (R,) or scalar
        Table angle between the positions, deg.
    latitude_deg : float
        Latitude, deg.
    accel0, accel1 : array_like, shape (R, 2) or (R, 3), optional
        Accelerometer window means, m/s^2; without them the instrument is taken as level.

    Returns
    -------
    ndarray, shape (R,)
        Azimuth of body x at the first position, [0, 360) deg.
    """
    g0 = np.asarray(gyro0, dtype=float)
    g1 = np.asarray(gyro1, dtype=float)
    mu = np.radians(np.broadcast_to(np.asarray(mu_deg, dtype=float), g0.shape[:-1]))
    lat = _latitude_rad(latitude_deg, "the solution")
    c, s = np.cos(mu), np.sin(mu)
    dwx, dwy = g0[..., 0] - g1[..., 0], g0[..., 1] - g1[..., 1]
    if accel0 is None:
        num, den = -(1.0 - c) * dwy + s * dwx, (1.0 - c) * dwx + s * dwy
        return np.mod(-np.degrees(np.arctan2(num, den)), 360.0)
    a0 = np.asarray(accel0, dtype=float)
    a1 = np.asarray(accel1, dtype=float)
    g = normal_gravity(math.degrees(lat))
    dfx, dfy = a0[..., 0] - a1[..., 0], a0[..., 1] - a1[..., 1]
    det = 2.0 * (1.0 - c)
    s_pitch = ((1.0 - c) * -dfx - s * dfy) / det
    c_roll = (s * -dfx + (1.0 - c) * dfy) / det
    theta, gamma = _tilt_from_f0(-s_pitch, c_roll, g)
    omega_u = OMEGA_IE * math.sin(lat)
    st, ct, sg, cg = np.sin(theta), np.cos(theta), np.sin(gamma), np.cos(gamma)
    n1 = st * sg + s * ct - c * st * sg
    n2 = -(ct - c * ct - s * st * sg)
    n0 = 2.0 * omega_u * sg * (1.0 - c)
    d1 = -(c - 1.0) * cg
    d2 = s * cg
    d0 = -2.0 * omega_u * st * (c - 1.0) * cg
    num = n1 * dwx + n2 * dwy + n0
    den = d1 * dwx + d2 * dwy + d0
    return np.mod(-np.degrees(np.arctan2(num, den)), 360.0)


def _rot(mu: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = np.cos(mu), np.sin(mu)
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)


def _solve_normal(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least squares a x ~ b for stacks: a (R, M, P), b (R, M) -> x (R, P)."""
    ata = np.einsum("rmp,rmq->rpq", a, a)
    atb = np.einsum("rmp,rm->rp", a, b)
    return np.linalg.solve(ata, atb[..., None])[..., 0]


def solve_least_squares_batch(
    gyro_means: ArrayLike,
    mu_deg: ArrayLike,
    *,
    latitude_deg: float,
    accel_means: ArrayLike | None = None,
    iterations: int = 6,
) -> NDArray[np.float64]:
    """Azimuths of many multi-position runs by least squares (gyro biases estimated).

    The vectorised twin of :func:`northfinder.host.heading.solve_multi_position` with equal weights: tilt
    and accelerometer biases from ``f_i = R(mu_i) f0 + b_a`` (linear), then Gauss-Newton on
    ``w_i = R(mu_i) h(alpha, tilt) + b`` from the linear fit's starting point.

    Parameters
    ----------
    gyro_means : array_like, shape (R, N, 2) or (R, N, 3)
        Gyro window means, rad/s.
    mu_deg : array_like, shape (R, N) or (N,)
        Table angles, deg.
    latitude_deg : float
    accel_means : array_like, shape (R, N, 2) or (R, N, 3), optional
        Accelerometer window means, m/s^2; without them the instrument is taken as level.
    iterations : int
        Gauss-Newton steps (the start is already close: a few suffice).

    Returns
    -------
    ndarray, shape (R,)
        Azimuth of body x at table angle 0, [0, 360) deg.
    """
    w = np.asarray(gyro_means, dtype=float)[..., :2]
    r_count, n = w.shape[:2]
    mu = np.radians(np.broadcast_to(np.asarray(mu_deg, dtype=float), (r_count, n)))
    lat = _latitude_rad(latitude_deg, "the solution")
    rot = _rot(mu)  # (R, N, 2, 2)
    design = np.concatenate([rot, np.broadcast_to(np.eye(2), rot.shape)], axis=-1).reshape(
        r_count, 2 * n, 4
    )
    if accel_means is not None:
        f = np.asarray(accel_means, dtype=float)[..., :2].reshape(r_count, 2 * n)
        xa = _solve_normal(design, f)
        theta, gamma = _tilt_from_f0(xa[:, 0], xa[:, 1], normal_gravity(math.degrees(lat)))
    else:
        theta = gamma = np.zeros(r_count)
    on, ou = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    st, ct, sg, cg = np.sin(theta), np.cos(theta), np.sin(gamma), np.cos(gamma)
    x_lin = _solve_normal(design, w.reshape(r_count, 2 * n))
    # h = M (cos a, sin a) + c0 with M = [[on ct, 0], [on st sg, -on cg]].
    u0 = (x_lin[:, 0] + ou * st) / (on * ct)
    u1 = -((x_lin[:, 1] - ou * ct * sg) - on * st * sg * u0) / (on * cg)
    alpha = np.arctan2(u1, u0)
    bias = x_lin[:, 2:].copy()
    eye = np.broadcast_to(np.eye(2), (r_count, n, 2, 2))
    for _ in range(int(iterations)):
        sa, ca = np.sin(alpha), np.cos(alpha)
        h = np.stack([on * ca * ct - ou * st, on * (ca * st * sg - sa * cg) + ou * ct * sg], -1)
        dh = np.stack([-on * sa * ct, -on * (sa * st * sg + ca * cg)], -1)
        res = (w - np.einsum("rnij,rj->rni", rot, h) - bias[:, None, :]).reshape(r_count, 2 * n)
        jac = np.concatenate([np.einsum("rnij,rj->rni", rot, dh)[..., None], eye], axis=-1)
        step = _solve_normal(jac.reshape(r_count, 2 * n, 3), res)
        alpha = alpha + step[:, 0]
        bias = bias + step[:, 1:]
    return np.mod(-np.degrees(alpha), 360.0)


# ----------------------------------------------------------------------------------------------
# From samples to errors
# ----------------------------------------------------------------------------------------------


def window_means(
    samples: ArrayLike,
    method: str = "none",
    *,
    axis: int = -1,
    options: Mapping[str, Any] | None = None,
) -> NDArray[np.float64]:
    """Mean of every window after denoising with a :data:`northfinder.host.denoise.METHODS` method.

    Parameters
    ----------
    samples : array_like
        Samples along ``axis`` (any other axes: runs, positions, channels).
    method : str
        Denoising method name (``none``: the plain mean).
    axis : int
        Sample axis.
    options : mapping, optional
        Passed to the method.

    Returns
    -------
    ndarray
        ``samples`` with ``axis`` reduced.
    """
    if method not in METHODS:
        raise HostConfigError(
            f"denoise: unknown method {method!r}; choose one of {', '.join(METHODS)}"
        )
    if method == "none":
        return np.mean(samples, axis=axis)
    return np.mean(denoise(samples, method, axis=axis, **dict(options or {})), axis=axis)


def azimuth_errors(estimate_deg: ArrayLike, truth_deg: ArrayLike) -> NDArray[np.float64]:
    """Estimate minus truth wrapped to [-180, 180) deg."""
    d = np.asarray(estimate_deg, dtype=float) - np.asarray(truth_deg, dtype=float)
    return np.mod(d + 180.0, 360.0) - 180.0


def chunk_errors(
    gyro: NDArray[np.float64],
    accel: NDArray[np.float64] | None,
    angles_deg: ArrayLike,
    truth_azimuth_deg: ArrayLike,
    latitude_deg: float,
    *,
    solver: str = "auto",
    denoise_method: str = "none",
    denoise_options: Mapping[str, Any] | None = None,
    denoise_accel: bool = False,
) -> NDArray[np.float64]:
    """Azimuth errors of a chunk of runs from their window samples.

    Parameters
    ----------
    gyro : ndarray, shape (R, P, n, 3)
        Gyro samples of every window, rad/s (only x and y are used).
    accel : ndarray, shape (R, P, n, 3), or None
        Accelerometer samples, m/s^2; None assumes a level instrument.
    angles_deg : array_like, shape (R, P) or (P,)
        Table angles the solver uses (encoder readings or commanded angles), deg.
    truth_azimuth_deg : array_like, shape (R,)
        True azimuth of each run.
    latitude_deg : float
    solver : str
        A key of :data:`SOLVERS`.
    denoise_method : str
        A key of :data:`northfinder.host.denoise.METHODS`, applied to every window of gyro x and y.
    denoise_options : mapping, optional
        Options of the method.
    denoise_accel : bool
        Also denoise the accelerometer windows (else their plain means).

    Returns
    -------
    ndarray
        Shape (R,), or (R, P - 1) for ``pairwise``, deg.
    """
    _choice(solver, SOLVERS, "solver")
    if gyro.ndim != 4 or gyro.shape[-1] < 2:
        raise InputError(f"gyro: expected shape (runs, positions, samples, 3), got {gyro.shape}")
    p = gyro.shape[1]
    if solver == "auto":
        solver = "two-position" if p == 2 else "least-squares"
    if solver == "two-position" and p != 2:
        raise GeometryError(f"solver two-position needs exactly 2 positions, got {p}")
    # Samples last: the views the simulator returns are then contiguous per channel.
    gm = window_means(np.moveaxis(gyro[..., :2], 2, -1), denoise_method, options=denoise_options)
    am = None
    if accel is not None:
        a = np.moveaxis(accel[..., :2], 2, -1)
        am = (
            window_means(a, denoise_method, options=denoise_options)
            if denoise_accel
            else a.mean(axis=-1)
        )
    ang = np.broadcast_to(np.asarray(angles_deg, dtype=float), gm.shape[:2])
    truth = np.asarray(truth_azimuth_deg, dtype=float)
    if solver == "least-squares":
        az = solve_least_squares_batch(gm, ang, latitude_deg=latitude_deg, accel_means=am)
        # Azimuth at table angle 0; the truth is the body azimuth, also at table angle 0.
        return azimuth_errors(az, truth)

    def pair(k: int) -> NDArray[np.float64]:
        az = solve_two_position_batch(
            gm[:, 0],
            gm[:, k],
            ang[:, k] - ang[:, 0],
            latitude_deg=latitude_deg,
            accel0=None if am is None else am[:, 0],
            accel1=None if am is None else am[:, k],
        )
        # The two-position solution is the azimuth of body x at the first window's table angle.
        return azimuth_errors(az, truth - ang[:, 0])

    if solver == "two-position":
        return pair(1)
    return np.stack([pair(k) for k in range(1, p)], axis=-1)


@dataclass(frozen=True)
class Summary:
    """Statistics of azimuth errors, deg.

    Attributes
    ----------
    runs : int
    bias_deg, std_deg, rmse_deg, max_abs_deg : float
    rmse_rel_se : float
        Relative standard error of the RMSE (1 / sqrt(2 runs) for Gaussian errors).
    """

    runs: int
    bias_deg: float
    std_deg: float
    rmse_deg: float
    max_abs_deg: float
    rmse_rel_se: float


def summarize(errors_deg: ArrayLike, axis: int = 0) -> list[Summary] | Summary:
    """Bias, standard deviation, RMSE and largest error of errors along ``axis`` (runs)."""
    e = np.moveaxis(np.asarray(errors_deg, dtype=float), axis, 0)
    if e.shape[0] < 2:
        raise InputError(f"errors: need at least 2 runs, got {e.shape[0]}")
    flat = e.reshape(e.shape[0], -1)
    out = []
    for col in flat.T:
        rmse = float(np.sqrt(np.mean(col * col)))
        kurt = float(np.mean(col**4) / max(np.mean(col * col) ** 2, 1e-300))
        out.append(
            Summary(
                runs=int(col.size),
                bias_deg=float(col.mean()),
                std_deg=float(col.std(ddof=1)),
                rmse_deg=rmse,
                max_abs_deg=float(np.abs(col).max()),
                # var(mean e^2) / (4 rmse^4) = (kurtosis - 1) / (4 n) for the squared errors.
                rmse_rel_se=math.sqrt(max(kurt - 1.0, 0.0) / (4.0 * col.size)),
            )
        )
    return out[0] if e.ndim == 1 else out
