"""What accuracy a plan can reach: the white-noise bound, and a prediction from a datasheet.

:func:`bound_deg` is the white-noise limit of the notes (section 4): for two positions with total
dwell T, ``N / (Omega_H |sin(mu/2)| sqrt(T))``; for N positions the least-squares covariance of
the heading with both horizontal gyro biases estimated (the same as
:func:`northfinder.host.heading.solve_multi_position` with known noise). A simulated result that
beats it is a bug. :func:`budget_bound_deg` is the limit of a whole time budget (all of it spent
recording).

:func:`predict` is the planner's prediction: the RMSE of a plan's azimuth over runs, from every
error term an :class:`ErrorModel` can hold, propagated through the plan's own solver.

How the prediction is made
--------------------------
The solver (two-position, least squares or pairwise, with the tilt from the accelerometers or
level) is linearised around the truth: ``g``, the gradient of the azimuth with respect to each
window mean (gyro x and y, accelerometer x and y) and each table angle the solver is given, is
taken by central differences of the solver itself on noise-free window means, for twelve true
azimuths (a study draws the azimuth uniformly; its RMSE is the mean over azimuths). The
predicted variance is ``g^T C g`` plus the square of the deterministic error ``g . d``:

- ``C``, the covariance of the window-mean errors over the plan's actual timeline (the windows,
  the moves between them and the settling; time counted from power-on): white noise (ARW, VRW),
  flicker bias instability (as the simulator builds it, Gauss-Markov components from 1 s to
  10^4 s), random walks, the bias walk and decaying transient that each move starts (sized by
  the heat the drive holds, as :mod:`northfinder.firmware_sim.error_terms` defines it), output
  quantisation with carry, a vibration line of random phase, Poisson impulses and a bias step at
  a random time; table indexing error (commanded angles) and encoder resolution; scale-factor and
  misalignment draws of both triads (through the true rates and forces at each position);
- ``d``, the deterministic bias of each window mean: warm-up transient, temperature and ramp of
  both triads over the plan's timeline, the encoder's periodic error at each stop (with encoder
  angles), plus the solver's own error on noise-free data (a level solver on a tilted
  instrument).

A spin plan (:class:`~northfinder.host.plan.SpinPlan`) is predicted the same way through the
demodulating solver (:mod:`northfinder.host.spin`), whose first-order weights on every sample are
exact (:func:`~northfinder.host.spin.heading_weights`): white noise, flicker and walks (their
covariance along the samples by a recursion), quantisation with carry, vibration, impulses, a
bias step, the encoder's resolution (each reading bounds two samples), scale-factor and
misalignment draws through the true sensor-frame rates and forces (the table rate and its ripple
on the table axis, the table top's wobble), and, as ``drift``, the drifts and the solver's own
error on the noise-free samples with the table's ripple, wobble and periodic encoder error. A
spin starts no move transient.

Constant biases and the turn-on bias are the same in every window and cancel in every solver
(``g`` sums to zero over the windows of each channel). The prediction is exact to first order;
it is what the planner minimises, and seeded Monte Carlo studies check it for every preset.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TypedDict, Unpack

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.heat import move_heat, spin_heat_state, spin_heat_steps
from northfinder.driver.protocol.motion import encoder_angle_deg, spin_angle_deg, wobble_matrix
from northfinder.driver.protocol.units import DPH, DPH_PSH, DPSH, OMEGA_IE, UG, normal_gravity
from northfinder.host.errors import GeometryError, HostConfigError, check_choice
from northfinder.host.kernels import MAX_SOLVER_TILT_DEG as MAX_TILT_DEG
from northfinder.host.kernels import earth_rate_body, latitude_rad, table_rotation
from northfinder.host.plan import (
    Plan,
    SpinPlan,
    TableModel,
    moves_deg,
    plan_time_s,
    spin_ramp_s,
    spin_start_deg,
    window_starts_s,
)
from northfinder.host.spin import (
    MIN_SWEEP_DEG,
    amplitude_pinv,
    heading_weights,
    interval_rotation,
    nuisance_design,
    solve_spin_batch,
    spin_weights_level,
)

__all__ = [
    "ANGLE_SOURCES",
    "TILT_SOURCES",
    "Conditions",
    "ErrorModel",
    "PredictOptions",
    "Prediction",
    "angle_rms",
    "bound_deg",
    "budget_bound_deg",
    "move_heat",
    "predict",
    "predict_solutions",
    "spin_bound_deg",
    "window_change_dph",
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


def budget_bound_deg(budget_s: float, arw_dpsh: float, latitude_deg: float) -> float:
    """White-noise limit of a whole time budget, 1 sigma, deg: ``N / (Omega_H sqrt(T))``.

    What any plan of ``budget_s`` could reach if every second of it were spent recording (no
    moves, no settling) with both horizontal gyros: two positions 180 deg apart and any set of
    equally spaced positions reach it at equal total dwell. No plan of that budget beats it.
    """
    omega_h = OMEGA_IE * math.cos(latitude_rad(latitude_deg, "the bound"))
    return math.degrees(arw_dpsh * DPSH / (omega_h * math.sqrt(budget_s)))


Drift = Callable[[NDArray[np.float64]], NDArray[np.float64]]


@dataclass(frozen=True)
class ErrorModel:
    """Datasheet figures of a gyro north finder, as the planner's prediction uses them.

    Every figure is 0 (absent) unless given, except the time constants. Gyro figures apply to
    the x and y gyros, accelerometer figures (``accel_``) to the x and y accelerometers (they
    enter through the tilt).

    Attributes
    ----------
    arw_dpsh : float
        Gyro angle random walk, deg/sqrt(h).
    bias_instability_dph : float
        Gyro flicker bias instability B (Allan floor 0.664 B), deg/h.
    rrw_dphpsh : float
        Gyro rate random walk, deg/h/sqrt(h).
    misalignment_urad, scale_factor_ppm : float
        Gyro axis misalignment (per off-diagonal) and scale-factor error (per axis), 1 sigma.
    vrw_ug_rthz : float
        Accelerometer white noise, ug/sqrt(Hz).
    table : TableModel
        Turntable limits, settle time, indexing error, encoder, motor heat.
    drift_rps : callable or None
        Deterministic gyro bias of time since power-on, ``f(t_s (k,)) -> (k, 2)`` rad/s for the
        x and y gyros (warm-up transient, temperature, ramp); None when there is none.
    lsb_dph : float
        Gyro output quantum, deg/h (quantised with carry).
    move_walk_dph_per_rtdeg, move_transient_dph_per_rtdeg : float
        Lasting bias step and initial amplitude of the decaying transient each table move
        starts, 1 sigma per sqrt(deg) of the heat the drive holds, deg/h/sqrt(deg).
    move_transient_tau_s : float
        Time constant of that transient, s.
    vibration_dph, impulse_dph : float
        Vibration amplitude and impulse peak seen by each gyro axis, deg/h.
    accel_bias_instability_ug, accel_random_walk_ug_rts : float
        Accelerometer flicker (ug) and bias random walk (ug/sqrt(s)).
    accel_scale_factor_ppm, accel_misalignment_urad, accel_lsb_ug : float
        Accelerometer scale factor, misalignment and output quantum.
    accel_move_walk_ug_per_rtdeg, accel_move_transient_ug_per_rtdeg, accel_move_transient_tau_s
        The accelerometers' move terms, ug/sqrt(deg) and s.
    accel_vibration_ug, accel_impulse_ug : float
        Vibration amplitude and impulse peak seen by each accelerometer axis, ug.
    vibration_hz : float
        Frequency of the vibration line, Hz (0: none).
    impulse_rate_hz, impulse_duration_s : float
        Mean rate of half-sine impulses (Poisson) and their duration.
    accel_drift_mps2 : callable or None
        Deterministic accelerometer bias of time since power-on, ``f(t_s (k,)) -> (k, 2)`` m/s^2.
    """

    arw_dpsh: float
    bias_instability_dph: float = 0.0
    rrw_dphpsh: float = 0.0
    misalignment_urad: float = 0.0
    scale_factor_ppm: float = 0.0
    vrw_ug_rthz: float = 0.0
    table: TableModel = field(default_factory=TableModel)
    drift_rps: Drift | None = field(default=None, repr=False, compare=False)
    lsb_dph: float = 0.0
    move_walk_dph_per_rtdeg: float = 0.0
    move_transient_dph_per_rtdeg: float = 0.0
    move_transient_tau_s: float = 10.0
    vibration_dph: float = 0.0
    impulse_dph: float = 0.0
    accel_bias_instability_ug: float = 0.0
    accel_random_walk_ug_rts: float = 0.0
    accel_scale_factor_ppm: float = 0.0
    accel_misalignment_urad: float = 0.0
    accel_lsb_ug: float = 0.0
    accel_move_walk_ug_per_rtdeg: float = 0.0
    accel_move_transient_ug_per_rtdeg: float = 0.0
    accel_move_transient_tau_s: float = 10.0
    accel_vibration_ug: float = 0.0
    accel_impulse_ug: float = 0.0
    vibration_hz: float = 0.0
    impulse_rate_hz: float = 0.0
    impulse_duration_s: float = 0.05
    accel_drift_mps2: Drift | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class Prediction:
    """Predicted 1-sigma (RMS over runs) heading error of a plan, deg, with its parts.

    ``sigma_deg`` is :func:`angle_rms` of the linear error (the same below a few degrees).
    ``parts_deg`` holds the square root of each part's linear variance, deg (they add in squares):
    ``white`` (gyro ARW; its value is ``bound_deg``), ``slow_noise`` (gyro flicker and rate
    random walk), ``tilt`` (accelerometer noise), ``moves`` (move transients and walks),
    ``drift`` (deterministic terms), ``quantisation``, ``misalignment`` (scale factor and
    misalignment), ``indexing`` (commanded angles), ``encoder``, ``vibration``, ``impulses``,
    ``bias_step``: each only when the model has that term.
    """

    sigma_deg: float
    bound_deg: float
    plan_time_s: float
    parts_deg: dict[str, float]


def _window_mean_cov(starts: NDArray[np.float64], tau: float, model: ErrorModel) -> NDArray:
    """Covariance of one gyro axis' window means, (N, N), (rad/s)^2 (white, flicker, walk)."""
    cov = np.eye(starts.size) * (model.arw_dpsh * DPSH) ** 2 / tau
    cov += _flicker_cov(starts, tau, model.bias_instability_dph * DPH)
    cov += _walk_cov(starts, tau, model.rrw_dphpsh * DPH_PSH)
    return cov


def _flicker_cov(starts: NDArray[np.float64], tau: float, b: float) -> NDArray[np.float64]:
    """Covariance of window means of flicker noise ``b`` (SI) over windows of ``tau`` s."""
    n = starts.size
    cov = np.zeros((n, n))
    if not b:
        return cov
    d = np.abs(np.subtract.outer(starts, starts))
    v = b * b * _FLICKER_VAR
    for tc in _FLICKER_TAUS:
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
    return cov


def _walk_cov(starts: NDArray[np.float64], tau: float, k: float) -> NDArray[np.float64]:
    """Covariance of window means of a random walk ``k`` (SI per sqrt(s)) from t = 0."""
    if not k:
        return np.zeros((starts.size, starts.size))
    lo = np.minimum.outer(starts, starts)
    same = np.equal.outer(starts, starts)
    return k * k * (lo + np.where(same, tau / 3.0, tau / 2.0))


# ----------------------------------------------------------------------------------------------
# The solver, linearised
# ----------------------------------------------------------------------------------------------

#: True azimuths over which the prediction is averaged (a study draws them uniformly), deg.
_AZIMUTHS_DEG: tuple[float, ...] = tuple(float(a) for a in np.arange(12) * 30.0)
#: Central-difference steps of the inputs: gyro x, y (rad/s), accelerometer x, y (m/s^2), table
#: angle (rad). Small enough to stay linear, large against the solver's own tolerance (1e-12 rad).
_STEPS = np.array([1e-9, 1e-9, 1e-5, 1e-5, 1e-6])
#: Inputs per window: gyro x, y, accelerometer x, y, table angle.
_INPUTS = 5


@dataclass(frozen=True, eq=False)
class _Linearisation:
    """The solver's azimuth error near the truth, per true azimuth (A) and solution (S).

    ``grad`` (A, S, P, 5): rad per unit of each input of each window; ``offset`` (A, S): its error
    on noise-free means, rad; ``gyro_matrix`` and ``accel_matrix`` (A, S, 2): summed squared
    sensitivity to unit scale-factor draws (column 0) and unit misalignment draws (column 1).
    """

    grad: NDArray[np.float64]
    offset: NDArray[np.float64]
    gyro_matrix: NDArray[np.float64]
    accel_matrix: NDArray[np.float64]


def _matrix_sensitivity(grad: NDArray[np.float64], true: NDArray[np.float64]) -> NDArray:
    """Summed squared sensitivity of the azimuth to a triad's scale-factor and misalignment draws.

    ``grad`` (A, S, P, 2) over the x and y means, ``true`` (A, P, 3) what the triad would read
    without errors; a triad reads ``M true`` with diagonal ``1 + sf`` and off-diagonals ``mis``.
    """
    sf = [np.einsum("asp,ap->as", grad[..., i], true[..., i]) for i in range(2)]
    mis = [
        np.einsum("asp,ap->as", grad[..., i], true[..., k])
        for i in range(2)
        for k in range(3)
        if i != k
    ]
    return np.stack([sum(x * x for x in sf), sum(x * x for x in mis)], axis=-1)


@functools.lru_cache(maxsize=256)
def _linearise(
    positions_deg: tuple[float, ...],
    latitude_deg: float,
    pitch_deg: float,
    roll_deg: float,
    azimuths_deg: tuple[float, ...],
    method: str,
    level: bool,
) -> _Linearisation:
    """Central differences of the plan's solver around noise-free window means."""
    from northfinder.host.batch_solve import chunk_errors  # the solvers the studies run

    lat = latitude_rad(latitude_deg, "the prediction")
    grav = float(normal_gravity(lat))
    az = np.radians(np.asarray(azimuths_deg, dtype=float))
    alpha = -az
    # On the solvers' tilt limit the noise-free solution may round beyond it: just inside.
    limit = MAX_TILT_DEG - 1e-6
    th = math.radians(min(max(pitch_deg, -limit), limit))
    ga = math.radians(min(max(roll_deg, -limit), limit))
    st, ct, sg, cg = math.sin(th), math.cos(th), math.sin(ga), math.cos(ga)
    on, ou = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    h, _ = earth_rate_body(alpha, th, ga, on, ou)  # (A, 2)
    sa, ca = np.sin(alpha), np.cos(alpha)
    omega_z = on * (sa * sg + ca * st * cg) + ou * ct * cg
    omega_b = np.concatenate([h, omega_z[:, None]], axis=-1)  # (A, 3)
    f_b = np.broadcast_to(np.array([-st, sg * ct, cg * ct]) * grav, omega_b.shape)
    mu = np.radians(np.asarray(positions_deg, dtype=float))
    rot = table_rotation(mu)  # (P, 2, 2)

    def turn(v: NDArray[np.float64]) -> NDArray[np.float64]:
        xy = np.einsum("pij,aj->api", rot, v[:, :2])
        return np.concatenate([xy, np.broadcast_to(v[:, None, 2:], (*xy.shape[:2], 1))], -1)

    gyro, accel = turn(omega_b), turn(f_b)  # (A, P, 3)
    a_count, p_count = gyro.shape[:2]
    k_count = _INPUTS * p_count
    base = np.concatenate(
        [gyro[..., :2], accel[..., :2], np.broadcast_to(mu, (a_count, p_count))[..., None]], -1
    )
    runs = np.repeat(base[:, None], 2 * k_count + 1, axis=1)  # (A, 2K + 1, P, 5)
    idx = np.arange(k_count)
    pos, inp = np.divmod(idx, _INPUTS)
    step = _STEPS[inp]
    runs[:, 1 + 2 * idx, pos, inp] += step
    runs[:, 2 + 2 * idx, pos, inp] -= step
    flat = runs.reshape(-1, p_count, _INPUTS)
    samples = np.zeros((flat.shape[0], p_count, 1, 3))
    samples[:, :, 0, :2] = flat[..., :2]
    acc = None
    if not level:
        acc = np.zeros_like(samples)
        acc[:, :, 0, :2] = flat[..., 2:4]
        acc[:, :, 0, 2] = np.repeat(accel[:, None, :, 2], 2 * k_count + 1, axis=1).reshape(
            -1, p_count
        )
    truth = np.repeat(np.degrees(az), 2 * k_count + 1)
    err = chunk_errors(samples, acc, np.degrees(flat[..., 4]), truth, latitude_deg, solver=method)
    err = np.radians(err).reshape(a_count, 2 * k_count + 1, -1)  # (A, 2K + 1, S)
    up, down, base = err[:, 1::2], err[:, 2::2], err[:, :1]
    # At the solvers' tilt limit one side of a difference may have no solution: the other side.
    grad = (
        np.where(
            np.isfinite(up) & np.isfinite(down),
            (up - down) / 2.0,
            np.where(np.isfinite(up), up - base, base - down),
        )
        / step[None, :, None]
    )  # (A, K, S)
    if not (np.all(np.isfinite(grad)) and np.all(np.isfinite(base))):
        raise GeometryError(
            f"positions {list(positions_deg)} at pitch {pitch_deg:g}, roll {roll_deg:g} deg: "
            "the solver has no solution even without noise; no prediction"
        )
    grad = np.moveaxis(grad, 2, 1).reshape(a_count, -1, p_count, _INPUTS)
    return _Linearisation(
        grad=grad,
        offset=err[:, 0],
        gyro_matrix=_matrix_sensitivity(grad[..., 0:2], gyro),
        accel_matrix=_matrix_sensitivity(grad[..., 2:4], accel),
    )


# ----------------------------------------------------------------------------------------------
# The window means' errors over the plan's timeline
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Channel:
    """One channel's random figures in SI (gyro rad/s, accelerometer m/s^2)."""

    white: float
    flicker: float
    walk: float
    lsb: float
    move_walk: float
    move_transient: float
    move_tau_s: float
    vibration: float
    impulse: float


def _channels(model: ErrorModel) -> tuple[_Channel, _Channel]:
    gyro = _Channel(
        model.arw_dpsh * DPSH,
        model.bias_instability_dph * DPH,
        model.rrw_dphpsh * DPH_PSH,
        model.lsb_dph * DPH,
        model.move_walk_dph_per_rtdeg * DPH,
        model.move_transient_dph_per_rtdeg * DPH,
        model.move_transient_tau_s,
        model.vibration_dph * DPH,
        model.impulse_dph * DPH,
    )
    accel = _Channel(
        model.vrw_ug_rthz * UG,
        model.accel_bias_instability_ug * UG,
        model.accel_random_walk_ug_rts * UG,
        model.accel_lsb_ug * UG,
        model.accel_move_walk_ug_per_rtdeg * UG,
        model.accel_move_transient_ug_per_rtdeg * UG,
        model.accel_move_transient_tau_s,
        model.accel_vibration_ug * UG,
        model.accel_impulse_ug * UG,
    )
    return gyro, accel


@dataclass(frozen=True)
class _Timeline:
    """Window starts (s since power-on), samples per window, the moves (start s, deg, first
    window after each) and the sample rate."""

    starts: NDArray[np.float64]
    n: int
    fs: float
    move_start: NDArray[np.float64]
    move_deg: NDArray[np.float64]
    move_window: NDArray[np.int64]

    @property
    def length_s(self) -> float:
        return self.n / self.fs

    def mean_of_exp(self, t0: float, rate: complex) -> NDArray[np.complex128]:
        """Mean over each window's samples of ``exp(rate (t - t0))``, (P,) (sample ``k`` at
        ``start + (k + 1) / fs``); a decay (real ``rate`` < 0) only for windows after ``t0``
        (0 before: it has not started)."""
        z = rate / self.fs
        factor = self.n if z == 0 else np.expm1(self.n * z) / np.expm1(z)
        dt = self.starts + 1.0 / self.fs - t0
        if rate.real < 0:
            return np.where(dt >= 0, np.exp(rate * np.maximum(dt, 0.0)) * factor / self.n, 0.0)
        return np.exp(rate * dt) * factor / self.n


def _timeline(plan: Plan, table: TableModel, warmup_s: float, fs: float) -> _Timeline:
    n = max(1, round(plan.window_s * fs))
    starts = warmup_s + window_starts_s(plan, table)
    d = np.array(moves_deg(plan))
    moved = np.flatnonzero(d != 0.0)
    # A move starts as the window before it ends.
    return _Timeline(
        starts, n, fs, starts[moved] + plan.window_s, d[moved], (moved + 1).astype(np.int64)
    )


def _move_cov(tl: _Timeline, ch: _Channel, heat_tau_s: float) -> NDArray[np.float64]:
    """Window-mean covariance of the bias walk and transient that the moves start."""
    p = tl.starts.size
    cov = np.zeros((p, p))
    if not (ch.move_walk or ch.move_transient) or not tl.move_start.size:
        return cov
    q = move_heat(tl.move_start, tl.move_deg, heat_tau_s)
    for t0, size, first in zip(tl.move_start, q, tl.move_window, strict=True):
        after = np.arange(p) >= first
        decay = tl.mean_of_exp(t0, -1.0 / ch.move_tau_s).real
        cov += size * (
            ch.move_walk**2 * np.outer(after, after) + ch.move_transient**2 * np.outer(decay, decay)
        )
    return cov


def _channel_covs(
    tl: _Timeline, ch: _Channel, model: ErrorModel, step: float
) -> dict[str, NDArray[np.float64]]:
    """Window-mean covariances of one channel by cause, (P, P) each (only the causes present)."""
    p, tau = tl.starts.size, tl.length_s
    out: dict[str, NDArray[np.float64]] = {}
    if ch.white:
        out["white"] = np.eye(p) * ch.white**2 / tau
    if ch.flicker or ch.walk:
        out["slow_noise"] = _flicker_cov(tl.starts, tau, ch.flicker) + _walk_cov(
            tl.starts, tau, ch.walk
        )
    if ch.move_walk or ch.move_transient:
        out["moves"] = _move_cov(tl, ch, model.table.heat_tau_s)
    if ch.lsb:
        # Quantised with carry: the error of a window's sum is round(r + S) - S with the
        # remainder r uniform, of variance x (1 - x) over the fraction x: 1/6 on average.
        out["quantisation"] = np.eye(p) * ch.lsb**2 / (6.0 * tl.n**2)
    if ch.vibration and model.vibration_hz > 0:
        m = tl.mean_of_exp(0.0, 2j * math.pi * model.vibration_hz)
        out["vibration"] = 0.5 * ch.vibration**2 * np.real(np.outer(m, np.conj(m)))
    if ch.impulse and model.impulse_rate_hz > 0:
        # Each half-sine adds its area (2 duration / pi) times a random direction's component
        # (mean square 1/3) to one window mean.
        area = ch.impulse * 2.0 * model.impulse_duration_s / math.pi
        out["impulses"] = np.eye(p) * model.impulse_rate_hz * area**2 / (3.0 * tau)
    if step:
        # One step at a uniform time over the recorded span, in a random direction (1/3 per axis).
        lo, hi = tl.starts[0], tl.starts[-1] + tau
        ts = lo + (np.arange(4096) + 0.5) * (hi - lo) / 4096
        frac = np.clip((tl.starts[:, None] + tau - ts[None, :]) / tau, 0.0, 1.0)
        out["bias_step"] = step**2 / 3.0 * (frac @ frac.T) / ts.size
    return out


def _window_drift(tl: _Timeline, drift: Drift) -> NDArray[np.float64]:
    """Mean of a deterministic drift over each window, (P, 2), by Gauss-Legendre quadrature."""
    x, w = np.polynomial.legendre.leggauss(16)
    t = tl.starts[:, None] + 0.5 / tl.fs + 0.5 * (x[None, :] + 1.0) * tl.length_s
    values = np.asarray(drift(t.ravel()), dtype=float).reshape(*t.shape, 2)
    return np.einsum("pkc,k->pc", values, 0.5 * w)


# ----------------------------------------------------------------------------------------------
# The prediction
# ----------------------------------------------------------------------------------------------


def angle_rms(sigma_rad: float) -> float:
    """RMS of the angle of a noisy unit vector, rad: ``arg(1 + s (z1 + i z2))``, z unit normal.

    A solver's azimuth is the direction of the horizontal Earth rate it estimates; its linear
    error ``s`` (the gradient's) is that of the angle only while ``s`` is small. Beyond a few
    degrees the angle's error grows faster (the vector's length shrinks in some runs) and, wrapped
    to +-180 deg, tends to ``pi / sqrt(3)`` (uniform) as ``s`` grows. The density of the angle of
    an isotropic normal vector about (1, 0) is
    ``(exp(-1 / 2s^2) + sqrt(2 pi) (c / s) exp(-sin^2 / 2s^2) Phi(c / s)) / 2 pi``, c = cos.
    """
    s = float(sigma_rad)
    if s < 0.02:  # the correction is below 0.05 %
        return s
    from scipy.special import ndtr  # imported when first needed

    phi = np.linspace(-math.pi, math.pi, 8001)
    c = np.cos(phi) / s
    dens = (
        math.exp(-0.5 / (s * s))
        + math.sqrt(2 * math.pi) * c * np.exp(-0.5 * (np.sin(phi) / s) ** 2) * ndtr(c)
    ) / (2 * math.pi)
    f = phi * phi * dens
    return math.sqrt(float(np.sum(f[1:] + f[:-1]) * 0.5 * (phi[1] - phi[0])))


class Conditions(TypedDict, total=False):
    """How a plan is run, as keyword arguments of :func:`predict` and the planner (each optional;
    the defaults are those of :func:`predict_solutions`)."""

    warmup_s: float
    tilt: str
    angles: str
    sample_rate_hz: float
    pitch_deg: float
    roll_deg: float


class PredictOptions(Conditions, total=False):
    """The keyword arguments of :func:`predict`: :class:`Conditions`, the true azimuth and a bias
    step."""

    azimuth_deg: float | None
    bias_step_dph: float


def _deterministic_error(
    lin: _Linearisation, tl: _Timeline, model: ErrorModel, plan: Plan, angles: str
) -> NDArray[np.float64] | None:
    """The deterministic heading error per (azimuth, solution): the drifts over the timeline, the
    encoder's periodic error at each stop and the solver's own error on noise-free data; None
    when there is none."""
    det = lin.offset.copy()
    has_drift = False
    for drift, cols in ((model.drift_rps, (0, 1)), (model.accel_drift_mps2, (2, 3))):
        if drift is not None:
            d = _window_drift(tl, drift)  # (P, 2)
            det += np.einsum("aspc,pc->as", lin.grad[..., cols[0] : cols[1] + 1], d)
            has_drift = True
    tab = model.table
    if angles == "encoder" and tab.encoder_error_deg:
        # The encoder's periodic error at each stop (the continuous commanded angle: the
        # indexing error moves it by a second-order amount).
        angle = plan.positions_deg[0] + np.concatenate([[0.0], np.cumsum(moves_deg(plan))])
        read = encoder_angle_deg(
            angle, tab.encoder_error_deg, tab.encoder_error_harmonic, tab.encoder_error_phase_deg
        )
        det += np.einsum("asp,p->as", lin.grad[..., 4], np.radians(read - angle))
        has_drift = True
    return det if has_drift or np.any(np.abs(lin.offset) > 1e-9) else None


def predict_solutions(
    model: ErrorModel,
    plan: Plan | SpinPlan,
    latitude_deg: float,
    *,
    warmup_s: float = 0.0,
    tilt: str = "accel",
    angles: str = "encoder",
    sample_rate_hz: float = 200.0,
    pitch_deg: float = 0.0,
    roll_deg: float = 0.0,
    azimuth_deg: float | None = None,
    bias_step_dph: float = 0.0,
) -> list[Prediction]:
    """Predicted error of every solution of a plan (one; one per pair with ``pairwise``).

    See the module docstring for what the prediction holds; the parameters are those of
    :func:`predict`.
    """
    check_choice(tilt, TILT_SOURCES, "tilt")
    check_choice(angles, ANGLE_SOURCES, "angles")
    azimuths = _AZIMUTHS_DEG if azimuth_deg is None else (float(azimuth_deg),)
    if isinstance(plan, SpinPlan):
        if angles != "encoder":
            raise HostConfigError(
                "angles: a spin solves with the encoder angle of every sample (angles encoder)"
            )
        return [
            _spin_prediction(
                model, plan, float(latitude_deg), azimuths, warmup_s=warmup_s,
                level=tilt == "level", fs=float(sample_rate_hz), pitch_deg=pitch_deg,
                roll_deg=roll_deg, bias_step_dph=bias_step_dph,
            )
        ]  # fmt: skip
    lin = _linearise(
        tuple(plan.positions_deg),
        float(latitude_deg),
        float(pitch_deg),
        float(roll_deg),
        azimuths,
        plan.method,
        tilt == "level",
    )
    tl = _timeline(plan, model.table, warmup_s, sample_rate_hz)
    grad = lin.grad  # (A, S, P, 5)
    gyro, accel = _channels(model)
    parts: dict[str, NDArray[np.float64]] = {}

    def add(name: str, var: NDArray[np.float64]) -> None:
        parts[name] = parts.get(name, 0.0) + var

    def quad(g: NDArray[np.float64], cov: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.einsum("asp,pq,asq->as", g, cov, g)

    step = bias_step_dph * DPH
    for channels, figures, gyro_triad in (((0, 1), gyro, True), ((2, 3), accel, False)):
        covs = _channel_covs(tl, figures, model, step if gyro_triad else 0.0)
        for cause, cov in covs.items():
            name = cause
            if not gyro_triad and cause in ("white", "slow_noise"):
                name = "tilt"
            for c in channels:
                add(name, quad(grad[..., c], cov))
    det = _deterministic_error(lin, tl, model, plan, angles)
    if det is not None:
        add("drift", det * det)
    # Table angles: a stop error is shared by the windows of one stop (no move between them).
    stops = np.concatenate([[0], np.cumsum(np.array(moves_deg(plan)) != 0.0)])
    per_stop = np.zeros((stops.size, int(stops[-1]) + 1))
    per_stop[np.arange(stops.size), stops] = 1.0
    g_stop = (grad[..., 4] @ per_stop)[..., 1:]  # (A, S, stops after a move)
    if angles == "commanded" and model.table.indexing_error_deg:
        add("indexing", math.radians(model.table.indexing_error_deg) ** 2 * np.sum(g_stop**2, -1))
    if angles == "encoder" and model.table.encoder_resolution_deg:
        res = math.radians(model.table.encoder_resolution_deg)
        add("encoder", res * res / 12.0 * np.sum(g_stop**2, -1))
    sf, mis = model.scale_factor_ppm * 1e-6, model.misalignment_urad * 1e-6
    sf_a, mis_a = model.accel_scale_factor_ppm * 1e-6, model.accel_misalignment_urad * 1e-6
    if sf or mis or (tilt != "level" and (sf_a or mis_a)):
        var = sf * sf * lin.gyro_matrix[..., 0] + mis * mis * lin.gyro_matrix[..., 1]
        if tilt != "level":
            var = var + sf_a * sf_a * lin.accel_matrix[..., 0] + mis_a**2 * lin.accel_matrix[..., 1]
        add("misalignment", var)
    if "white" not in parts:
        parts["white"] = np.zeros(lin.offset.shape)
    # Mean over the true azimuths, per solution.
    mean_parts = {
        k: np.mean(np.broadcast_to(v, lin.offset.shape), axis=0) for k, v in parts.items()
    }
    total = sum(mean_parts.values())
    t_plan = plan_time_s(plan, model.table)
    out = []
    for s in range(lin.offset.shape[1]):
        out.append(
            Prediction(
                sigma_deg=math.degrees(angle_rms(math.sqrt(max(float(total[s]), 0.0)))),
                bound_deg=math.degrees(math.sqrt(float(mean_parts["white"][s]))),
                plan_time_s=t_plan,
                parts_deg={
                    k: math.degrees(math.sqrt(max(float(v[s]), 0.0))) for k, v in mean_parts.items()
                },
            )
        )
    return out


def predict(
    model: ErrorModel, plan: Plan | SpinPlan, latitude_deg: float, **options: Unpack[PredictOptions]
) -> Prediction:
    """Predicted RMS heading error of a plan over runs (see the module docstring).

    Parameters
    ----------
    model : ErrorModel
        Sensor and table figures.
    plan : Plan or SpinPlan
        Positions, window, settle and solver (the windows are reduced by their plain means);
        or a spin (rate, time, drift fitted), solved by the demodulating solver.
    latitude_deg : float
        Latitude, deg.
    warmup_s : float, default 0
        Time from power-on to the first window, s (for the drift and the random walks).
    tilt : {"accel", "level"}, default "accel"
        With ``accel`` the accelerometer errors enter through the tilt.
    angles : {"encoder", "commanded"}, default "encoder"
        With ``commanded`` the table indexing error enters (d_azimuth = -d_mu / 2 for two
        positions), with ``encoder`` the encoder's resolution.
    sample_rate_hz : float, default 200
        Sample rate, Hz (samples per window, quantisation).
    pitch_deg, roll_deg : float, default 0
        Tilt of the instrument, deg.
    azimuth_deg : float, optional
        True azimuth; default the mean over azimuths (a study's uniform draw).
    bias_step_dph : float, default 0
        One gyro bias step of this size at a random time in a random direction, deg/h.

    Returns
    -------
    Prediction
        ``sigma_deg`` (the root of the summed variances), ``bound_deg`` (gyro white noise only).
        With the ``pairwise`` solver the first pair's; :func:`predict_solutions` gives all.
    """
    return predict_solutions(model, plan, latitude_deg, **options)[0]


def window_change_dph(
    model: ErrorModel,
    plan: Plan,
    pairs: Sequence[tuple[int, int]],
    *,
    warmup_s: float = 0.0,
    sample_rate_hz: float = 200.0,
) -> float:
    """Predicted 1-sigma change of a gyro's window mean between two windows of one run, deg/h:
    the root mean square over ``pairs`` (window indices ``(i, j)`` of ``plan``, e.g. the windows
    at one table angle), of the x or y gyro, whichever changes more.

    The change is what the acceptance's bias repeatability line measures
    (:func:`northfinder.host.acceptance.bias_repeatability_lines`): each pair's variance
    ``C_ii + C_jj - 2 C_ij`` of the window-mean covariance of the prediction (white noise,
    flicker, rate random walk, the bias walk and transient the moves start, quantisation,
    vibration, impulses; the module docstring), plus the square of the deterministic drift's
    change between the two windows (warm-up transient, temperature, ramp). The turn-on bias is
    the same in every window of a run; the table's angle errors, which move the Earth rate's
    share between stops, are left out.

    Parameters
    ----------
    model : ErrorModel
        Sensor and table figures.
    plan : Plan
        The positions, window and settle time (the timeline of the windows and moves).
    pairs : sequence of (int, int)
        Window indices, each pair one change.
    warmup_s : float, default 0
        Time from power-on to the first window, s.
    sample_rate_hz : float, default 200
        Sample rate, Hz.
    """
    if not pairs:
        raise HostConfigError("window_change_dph: no pair of windows given")
    tl = _timeline(plan, model.table, warmup_s, sample_rate_hz)
    gyro, _ = _channels(model)
    p = tl.starts.size
    cov = sum(_channel_covs(tl, gyro, model, 0.0).values(), np.zeros((p, p)))
    i, j = np.asarray(pairs, dtype=np.int64).T
    var = cov[i, i] + cov[j, j] - 2.0 * cov[i, j]  # (pairs,), the same for both axes
    drift = np.zeros((i.size, 2))
    if model.drift_rps is not None:
        d = _window_drift(tl, model.drift_rps)  # (P, 2)
        drift = d[j] - d[i]
    mean_square = np.mean(var[:, None] + drift * drift, axis=0)  # per axis
    return math.sqrt(float(np.max(mean_square))) / DPH


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


# ----------------------------------------------------------------------------------------------
# Spin plans
# ----------------------------------------------------------------------------------------------


def _ar1_quad(c: NDArray[np.float64], rho: float) -> NDArray[np.float64]:
    """``c^T K c`` with ``K_ij = rho^|i - j|`` along the last axis, in O(N) (a first-order
    recursion)."""
    from scipy.signal import lfilter  # imported when first needed

    y = lfilter([1.0], [1.0, -rho], c, axis=-1)
    return np.asarray(2.0 * np.sum(c * y, axis=-1) - np.sum(c * c, axis=-1))


def _spin_channel_vars(
    c: NDArray[np.float64],
    ch: _Channel,
    model: ErrorModel,
    t_on: NDArray[np.float64],
    fs: float,
    step: float,
) -> dict[str, NDArray[np.float64]]:
    """Variance of ``sum_k c_k e_k`` for one kind of channel's sample errors ``e`` by cause,
    rad^2; ``c`` (..., N), the results (...)."""
    out: dict[str, NDArray[np.float64]] = {}
    cc = np.sum(c * c, axis=-1)
    if ch.white:
        out["white"] = ch.white**2 * fs * cc
    slow = np.zeros(cc.shape)
    if ch.flicker:
        # The weights summed over blocks of at most 50 ms: the correlation times are 1 s and
        # more (and the simulator draws the flicker on a 0.1 s grid).
        b = max(1, int(0.05 * fs))
        m = c.shape[-1] // b * b
        blocks = c[..., :m].reshape(*c.shape[:-1], -1, b).sum(axis=-1)
        if m < c.shape[-1]:
            blocks = np.concatenate([blocks, c[..., m:].sum(axis=-1, keepdims=True)], axis=-1)
        v = ch.flicker**2 * _FLICKER_VAR
        for tc in _FLICKER_TAUS:
            slow += v * _ar1_quad(blocks, math.exp(-b / (fs * tc)))
    rev = np.cumsum(c[..., ::-1], axis=-1)[..., ::-1]  # sum of the weights from each sample on
    if ch.walk:
        # k^2 min(s_i, s_j) at the sample times s (the walk runs from power-on).
        s0 = float(t_on[0] - 0.5 / fs)
        slow += ch.walk**2 * (s0 * rev[..., 0] ** 2 + np.sum(rev[..., 1:] ** 2, axis=-1) / fs)
    if ch.flicker or ch.walk:
        out["slow_noise"] = slow
    if ch.lsb:
        # Quantised with carry: the error of sample k is r_(k-1) - r_k, r uniform.
        d = np.diff(c, axis=-1)
        out["quantisation"] = (
            ch.lsb**2 / 12.0 * (np.sum(d * d, axis=-1) + c[..., 0] ** 2 + c[..., -1] ** 2)
        )
    if ch.vibration and model.vibration_hz > 0:
        m = np.exp(2j * math.pi * model.vibration_hz * t_on)
        out["vibration"] = 0.5 * ch.vibration**2 * np.abs(c @ m) ** 2
    if ch.impulse and model.impulse_rate_hz > 0:
        area = ch.impulse * 2.0 * model.impulse_duration_s / math.pi
        out["impulses"] = model.impulse_rate_hz * area**2 / 3.0 * fs * cc
    if step:
        # A step at a uniform time, in a random direction (1/3 per axis), on from a sample on.
        out["bias_step"] = step**2 / 3.0 * np.mean(rev * rev, axis=-1)
    return out


def _spin_heat_var(
    c: NDArray[np.float64], ch: _Channel, table: TableModel, rate_dps: float, fs: float
) -> NDArray[np.float64] | None:
    """Variance of ``sum_k c_k e_k`` for the drive's heat during a spin
    (:mod:`northfinder.driver.protocol.heat`: a transient and a walk from the state the ramp
    left), rad^2; None when off. ``c`` (..., N)."""
    if table.spin_heat <= 0.0 or not (ch.move_transient or ch.move_walk):
        return None
    from scipy.signal import lfilter  # imported when first needed

    tau = ch.move_tau_s
    v0_t, v0_w = spin_heat_state(rate_dps, table.max_accel_dps2, tau, table.spin_heat)
    phi, q_t, q_w = spin_heat_steps(rate_dps, tau, table.spin_heat, 1.0 / fs)
    out = np.zeros(c.shape[:-1])
    for amp, v0, a, q in ((ch.move_transient, v0_t, phi, q_t), (ch.move_walk, v0_w, 1.0, q_w)):
        if amp:
            # sum_k c_k x_k = x_0 a sum_k c_k a^(k-1) + sum_m w_m g_m, g_m = sum_(k>=m) c_k a^(k-m).
            g = lfilter([1.0], [1.0, -a], c[..., ::-1], axis=-1)[..., ::-1]
            out += amp * amp * (v0 * (a * g[..., 0]) ** 2 + q * np.sum(g * g, axis=-1))
    return out


@dataclass(frozen=True)
class _SpinSetup:
    """A spin plan's noise-free samples and the solver's first-order weights on them."""

    t: NDArray[np.float64]  # (n,) s from the steady start
    t_on: NDArray[np.float64]  # (n,) s from power-on
    edge: NDArray[np.float64]  # (n+1,) true table angle at the sample edges, deg
    mu: NDArray[np.float64]  # the same, rad
    h: NDArray[np.float64]  # (A, 2) horizontal Earth rate in the body frame
    f_xy: NDArray[np.float64]  # (2,) horizontal specific force
    gyro: NDArray[np.float64]  # (A, n, 3) noise-free gyro samples, sensor frame
    accel: NDArray[np.float64]  # (A, n, 3)
    wg: NDArray[np.float64]  # (A, 2, n) azimuth weights on the gyro x, y samples
    wa: NDArray[np.float64]  # (A, 2, n) on the accelerometer's (0: level)


def _spin_setup(
    model: ErrorModel,
    plan: SpinPlan,
    latitude_deg: float,
    az: NDArray[np.float64],
    warmup_s: float,
    level: bool,
    fs: float,
    tilt: tuple[float, float],
) -> _SpinSetup:
    """The samples and weights of :func:`_spin_prediction` (``tilt``: pitch, roll in rad)."""
    tab = model.table
    n = round(plan.spin_s * fs)
    if n < 16:
        raise GeometryError(f"a spin of {plan.spin_s:g} s at {fs:g} Hz holds fewer than 16 samples")
    lat = latitude_rad(latitude_deg, "the prediction")
    grav = float(normal_gravity(lat))
    on, ou = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    t = np.arange(1, n + 1) / fs
    edge = spin_angle_deg(
        plan.rate_dps, spin_start_deg(plan, tab), np.arange(n + 1) / fs, tab.rate_ripple,
        tab.rate_ripple_phase_deg,
    )  # fmt: skip
    mu = np.radians(edge)
    rot = interval_rotation(mu[:-1], mu[1:])  # (n, 2, 2)
    nuisance = nuisance_design(t, plan.drift)[0]
    th, ga = tilt
    st, ct, sg, cg = math.sin(th), math.cos(th), math.sin(ga), math.cos(ga)
    a_count = az.size
    alpha = -np.radians(az)
    h, _ = earth_rate_body(alpha, th, ga, on, ou)  # (A, 2)
    omega_z = on * (np.sin(alpha) * sg + np.cos(alpha) * st * cg) + ou * ct * cg
    f_xy = np.array([-st, sg * ct]) * grav
    # Noise-free samples in the sensor frame, (A, n, 3): the table rate on its axis, the wobble.
    gyro = np.concatenate(
        [np.einsum("nij,aj->ani", rot, h),
         (omega_z[:, None] + np.diff(mu)[None, :] * fs)[..., None]], -1,
    )  # fmt: skip
    accel = np.concatenate(
        [np.broadcast_to(np.einsum("nij,j->ni", rot, f_xy), (a_count, n, 2)),
         np.full((a_count, n, 1), cg * ct * grav)], -1,
    )  # fmt: skip
    wob = wobble_matrix(tab.wobble_urad, tab.wobble_phase_deg)
    if wob is not None:
        gyro, accel = gyro @ wob.T, accel @ wob.T
    # Weights of the azimuth (= -alpha) on every sample's gyro and accelerometer x and y.
    wg = np.empty((a_count, 2, n))
    wa = np.zeros((a_count, 2, n))
    pinv = amplitude_pinv(rot, nuisance)
    for a in range(a_count):
        c_g, c_a = heading_weights(
            rot, nuisance, float(alpha[a]), 0.0 if level else th, 0.0 if level else ga, on, ou,
            grav, pinv=pinv,
        )  # fmt: skip
        wg[a] = -c_g.reshape(n, 2).T
        if not level:
            wa[a] = -c_a.reshape(n, 2).T
    return _SpinSetup(t, warmup_s + spin_ramp_s(plan, tab) + t, edge, mu, h, f_xy, gyro, accel,
                      wg, wa)  # fmt: skip


def _spin_deterministic(
    su: _SpinSetup, model: ErrorModel, plan: SpinPlan, latitude_deg: float,
    az: NDArray[np.float64], level: bool, tilted: bool,
) -> NDArray[np.float64]:  # fmt: skip
    """The error of the solver itself on the noise-free samples given the encoder's reading
    (table ripple and wobble, periodic encoder error, a level solver tilted), rad, (A,)."""
    tab = model.table
    if not (tab.rate_ripple or tab.wobble_urad or tab.encoder_error_deg or (level and tilted)):
        return np.zeros(az.size)
    read = np.radians(encoder_angle_deg(
        su.edge, tab.encoder_error_deg, tab.encoder_error_harmonic, tab.encoder_error_phase_deg
    ))  # fmt: skip
    found = solve_spin_batch(
        su.gyro, None if level else su.accel, read[:-1], read[1:], latitude_deg=latitude_deg,
        time_s=su.t, drift=plan.drift,
    )  # fmt: skip
    if not np.all(np.isfinite(found)):
        raise GeometryError(
            f"{plan.label()}: the solver has no solution even without noise; no prediction"
        )
    return np.radians((found - az + 180.0) % 360.0 - 180.0)


def _spin_table_vars(
    su: _SpinSetup, model: ErrorModel, level: bool
) -> dict[str, NDArray[np.float64]]:
    """The encoder resolution's and the error matrices' variances, rad^2, (A,) each."""
    out: dict[str, NDArray[np.float64]] = {}
    wg, wa, mu = su.wg, su.wa, su.mu
    res = math.radians(model.table.encoder_resolution_deg)
    if res:
        # An angle error at an edge moves both samples it bounds by half of it; a sample's
        # angle error moves its regressors by dR/dmu.
        mid = 0.5 * (mu[:-1] + mu[1:])
        drot = np.stack(
            [np.stack([-np.sin(mid), np.cos(mid)], -1),
             np.stack([-np.cos(mid), -np.sin(mid)], -1)], -2,
        )  # fmt: skip
        d = -np.einsum("acn,ncj,aj->an", wg, drot, su.h)
        if not level:
            d -= np.einsum("acn,ncj,j->an", wa, drot, su.f_xy)
        zero = np.zeros((wg.shape[0], 1))
        u = 0.5 * (np.concatenate([zero, d], 1) + np.concatenate([d, zero], 1))
        out["encoder"] = res * res / 12.0 * np.sum(u * u, axis=-1)
    sf, mis = model.scale_factor_ppm * 1e-6, model.misalignment_urad * 1e-6
    sf_a, mis_a = model.accel_scale_factor_ppm * 1e-6, model.accel_misalignment_urad * 1e-6
    if sf or mis or (not level and (sf_a or mis_a)):
        var = np.zeros(wg.shape[0])
        for w, true, s_, m_ in ((wg, su.gyro, sf, mis), (wa, su.accel, sf_a, mis_a)):
            sm = np.einsum("acn,anj->acj", w, true)  # sensitivity to the matrix element (c, j)
            var += s_ * s_ * (sm[:, 0, 0] ** 2 + sm[:, 1, 1] ** 2)
            var += m_ * m_ * (sm[:, 0, 1] ** 2 + sm[:, 0, 2] ** 2 + sm[:, 1, 0] ** 2
                              + sm[:, 1, 2] ** 2)  # fmt: skip
        out["misalignment"] = var
    return out


def _spin_prediction(
    model: ErrorModel,
    plan: SpinPlan,
    latitude_deg: float,
    azimuths_deg: tuple[float, ...],
    *,
    warmup_s: float,
    level: bool,
    fs: float,
    pitch_deg: float,
    roll_deg: float,
    bias_step_dph: float,
) -> Prediction:
    """The prediction of a spin: the demodulating solver's first-order weights on every sample
    (:func:`~northfinder.host.spin.heading_weights`) against every error term over the spin's
    own timeline, the drive's heat included; the deterministic terms (drift, table ripple and
    wobble, periodic encoder error, a level solver on a tilted instrument) through the solver
    itself."""
    limit = MAX_TILT_DEG - 1e-6
    tilt = (math.radians(min(max(pitch_deg, -limit), limit)),
            math.radians(min(max(roll_deg, -limit), limit)))  # fmt: skip
    az = np.asarray(azimuths_deg, dtype=float)
    su = _spin_setup(model, plan, latitude_deg, az, warmup_s, level, fs, tilt)
    gyro_ch, accel_ch = _channels(model)
    step = bias_step_dph * DPH
    parts: dict[str, NDArray[np.float64]] = {}

    def add(name: str, var: NDArray[np.float64]) -> None:
        parts[name] = parts.get(name, np.zeros(az.size)) + var

    for w, ch, is_gyro in ((su.wg, gyro_ch, True), (su.wa, accel_ch, False)):
        if not is_gyro and level:
            continue
        causes = _spin_channel_vars(w, ch, model, su.t_on, fs, step if is_gyro else 0.0)
        heat = _spin_heat_var(w, ch, model.table, plan.rate_dps, fs)
        if heat is not None:
            causes["spin_heat"] = heat
        for cause, var in causes.items():
            name = "tilt" if not is_gyro and cause in ("white", "slow_noise") else cause
            add(name, var.sum(axis=-1))  # x and y
    det = _spin_deterministic(su, model, plan, latitude_deg, az, level, bool(pitch_deg or roll_deg))
    drift_g = None if model.drift_rps is None else np.asarray(model.drift_rps(su.t_on), float)
    drift_a = (
        None
        if model.accel_drift_mps2 is None or level
        else np.asarray(model.accel_drift_mps2(su.t_on), float)
    )
    if drift_g is not None or drift_a is not None or np.any(np.abs(det) > 1e-9):
        lin = det.copy()
        if drift_g is not None:
            lin += np.einsum("acn,nc->a", su.wg, drift_g)
        if drift_a is not None:
            lin += np.einsum("acn,nc->a", su.wa, drift_a)
        add("drift", lin * lin)
    for name, var in _spin_table_vars(su, model, level).items():
        add(name, var)
    parts.setdefault("white", np.zeros(az.size))
    mean_parts = {k: float(np.mean(v)) for k, v in parts.items()}
    total = sum(mean_parts.values())
    return Prediction(
        sigma_deg=math.degrees(angle_rms(math.sqrt(max(total, 0.0)))),
        bound_deg=math.degrees(math.sqrt(mean_parts["white"])),
        plan_time_s=plan_time_s(plan, model.table),
        parts_deg={k: math.degrees(math.sqrt(max(v, 0.0))) for k, v in mean_parts.items()},
    )
