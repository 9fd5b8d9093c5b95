"""What accuracy a plan can reach: the white-noise bound, and a prediction from a datasheet.

:func:`bound_deg` is the white-noise limit of the notes (section 4): for two positions with total
dwell T, ``N / (Omega_H |sin(mu/2)| sqrt(T))``; for N positions the least-squares covariance of
the heading with both horizontal gyro biases estimated (the same as
:func:`northfinder.host.heading.solve_multi_position` with known noise). A simulated result that
beats it is a bug. :func:`predict` adds what a datasheet predicts beyond white noise: bias
instability (flicker, as Gauss-Markov components from 1 s to 10^4 s), rate random walk, the
covariance of window means across the gaps of the plan, a deterministic drift, table indexing
error (when the commanded angles are used), accelerometer noise through the tilt (``tan(lat)``)
and axis misalignment. It is what the planner minimises; the Monte Carlo checks it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.units import DPH, DPH_PSH, DPSH, OMEGA_IE, UG, normal_gravity
from northfinder.host.errors import GeometryError, check_choice
from northfinder.host.kernels import latitude_rad
from northfinder.host.plan import Plan, TableModel, moves_deg, plan_time_s, window_starts_s
from northfinder.host.spin import MIN_SWEEP_DEG, spin_weights_level

__all__ = [
    "ANGLE_SOURCES",
    "TILT_SOURCES",
    "ErrorModel",
    "Prediction",
    "bound_deg",
    "predict",
    "spin_bound_deg",
]

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
#: Flicker (bias instability B) as Gauss-Markov components, correlation times 10^(0, 0.5, .. 4) s,
#: each of variance B^2 ln(sqrt 10) / pi: their sum has the one-sided PSD B^2 / (pi f).
_FLICKER_TAUS = 10.0 ** np.arange(0.0, 4.01, 0.5)
_FLICKER_VAR = math.log(10.0**0.5) / math.pi


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
    omega_h = OMEGA_IE * math.cos(latitude_rad(latitude_deg, "the bound"))
    c = _weights(plan.positions_deg, omega_h)
    s = arw_dpsh * DPSH / math.sqrt(window_s)
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
    cov = np.eye(n) * (model.arw_dpsh * DPSH) ** 2 / tau
    b = model.bias_instability_dph * DPH
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
    k = model.rrw_dphpsh * DPH_PSH
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
    check_choice(tilt, TILT_SOURCES, "tilt")
    check_choice(angles, ANGLE_SOURCES, "angles")
    lat = latitude_rad(latitude_deg, "the prediction")
    omega_h = OMEGA_IE * math.cos(lat)
    tau = plan.window_s
    starts = window_starts_s(plan, model.table)
    c = _weights(plan.positions_deg, omega_h)
    cov = _window_mean_cov(starts, tau, model)
    # Each axis has the same covariance, the axes are independent: sum over both.
    parts = {
        "white": (model.arw_dpsh * DPSH) ** 2 / tau * float(np.sum(c * c)),
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
        moved = np.r_[False, np.array(moves_deg(plan)) != 0.0]
        mu = np.radians(plan.positions_deg)
        deriv = np.stack([-omega_h * np.sin(mu), -omega_h * np.cos(mu)], axis=-1)  # R'(mu) h(0)
        # Positions that share one stop (no move between them) share its error.
        stop = np.cumsum(moved)
        sens = np.bincount(stop, weights=np.sum(c * deriv, axis=1))
        parts["indexing"] = e * e * float(np.sum(sens[1:] ** 2))  # stop 0: no move, no error
    if tilt == "accel" and model.vrw_ug_rthz:
        # Tilt from f_i = R_i f0 + b: same projected design as the gyros; d_az ~ tan(lat) d_tilt.
        s_a = model.vrw_ug_rthz * UG / math.sqrt(tau) / float(normal_gravity(lat))
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


def spin_bound_deg(
    duration_s: float,
    rate_dps: float,
    arw_dpsh: float,
    latitude_deg: float,
    *,
    sample_rate_hz: float = 200.0,
    vrw_ug_rthz: float = 0.0,
    start_deg: float = 0.0,
    drift: bool = False,
) -> float:
    """White-noise limit of the heading from a spin (rotation modulation), 1 sigma, deg.

    Derivation. Over a spin of T s at rate Omega_t, each sample of N_s = T f samples sees
    ``w = R(mu) h + b + e`` on both horizontal gyros, e white with variance s^2 = N^2 f per
    sample and axis (N the angle random walk in rad/sqrt(s)). With whole turns the columns
    cos(mu), sin(mu) are orthogonal to the constant bias and to each other, and each of h_x, h_y
    is fitted from 2 N_s equations whose regressors have squared norm ``sum(cos^2 + sin^2) = N_s``
    (both gyros together): var(h_k) = s^2 / N_s = N^2 / T. The heading moves h at right angles
    to itself by Omega_H per rad, so

        sigma_az = N / (Omega_H sqrt(T))          (whole turns, level, biases fitted)

    which is the two-position bound at mu = 180 deg with the same total time: every sample of
    a spin is as useful as a sample of the best stop-and-go plan, and no time goes to moves and
    settling. One gyro alone would give sqrt(2) more. For a part turn, a drift fitted as well, or
    accelerometer noise (tilt error times about tan(lat)), this function evaluates the same
    least-squares covariance exactly from the design (first order), sample by sample.

    Parameters
    ----------
    duration_s : float
        Time at the steady rate used, s.
    rate_dps : float
        Table rate, deg/s (either sign).
    arw_dpsh : float
        Gyro angle random walk, deg/sqrt(h).
    latitude_deg : float
    sample_rate_hz : float
        Sample rate (the bound hardly depends on it).
    vrw_ug_rthz : float
        Accelerometer white noise, ug/sqrt(Hz) (0: tilt known).
    start_deg : float
        Table angle at the start, deg (matters only for part turns).
    drift : bool
        A linear drift of each gyro and accelerometer is fitted too.

    Raises
    ------
    GeometryError
        The table turns less than 90 deg over the time.
    """

    n = round(duration_s * sample_rate_hz)
    if n < 16 or abs(rate_dps) * duration_s < MIN_SWEEP_DEG:
        raise GeometryError(
            f"a spin of {duration_s:g} s at {rate_dps:g} deg/s: the table must turn at least "
            f"{MIN_SWEEP_DEG:g} deg over at least 16 samples"
        )
    t = np.arange(1, n + 1) / sample_rate_hz
    mu1 = np.radians(start_deg + rate_dps * t)
    mu0 = mu1 - math.radians(rate_dps / sample_rate_hz)
    c_g, c_a = spin_weights_level(mu0, mu1, t, latitude_deg, drift)
    s_g = arw_dpsh * DPSH * math.sqrt(sample_rate_hz)
    s_a = vrw_ug_rthz * UG * math.sqrt(sample_rate_hz)
    return math.degrees(math.sqrt(s_g**2 * float(c_g @ c_g) + s_a**2 * float(c_a @ c_a)))
