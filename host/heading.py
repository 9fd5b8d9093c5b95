"""Heading solvers of the gyro north finder: two-position and multi-position least squares.

Conventions (the same as the instrument's)
------------------------------------------
Frames
    Navigation frame n is North-West-Up. Body frame b: x is the reference axis, y points left,
    z up. ``alpha`` rotates n into b about up, counter-clockwise seen from above; then pitch
    ``theta`` about y and roll ``gamma`` about x (z-y-x order, C_n^b as in the source paper).
Azimuth
    Every result reports the **azimuth of body x, clockwise from true north**, in [0, 360) deg:
    ``azimuth = -alpha mod 360``.
Table
    ``mu`` turns the sensors about body z, positive right-handed about up (counter-clockwise seen
    from above); the sensors then read through C_m^m1 = [[cos mu, sin mu, 0], [-sin mu, cos mu, 0],
    [0, 0, 1]].
Sensors
    Gyros read ``C_m^m1 C_n^b omega_ie_n`` + bias, omega_ie_n = Omega (cos lat, 0, sin lat).
    Accelerometers read specific force ``C_m^m1 C_n^b (0, 0, +g)`` + bias (level: z reads +g).
    The paper's eqs. 3, 4, 8, 9 use the opposite sign (a = -f); the levelling below is written for
    specific force.
Kernels
    The arithmetic lives once, in :mod:`northfinder.host.kernels` (arrays of many runs); the
    functions here solve one run with it and add input checks, clear errors and a propagated
    sigma. Excessive tilt raises :class:`~northfinder.host.errors.TiltError` here; the
    vectorised solvers give NaN for that run instead.
Units
    Gyro window means may be in any one unit, named by ``rate_unit`` (a key of
    :data:`RATE_UNITS` or the size of one unit in rad/s); the Earth rate is converted into that
    unit. Accelerometer means likewise with ``accel_unit`` (:data:`ACCEL_UNITS`, or m/s^2 per unit).
    Noise levels (``gyro_noise``, ``accel_noise``) are 1-sigma of the **window means** in the same
    units. Angles in the public API are degrees.

The paper's prototype data
--------------------------
The source paper's Tables 1 and 2 (mean gyro outputs at eight positions 30 deg apart and the
azimuths it computed from them) fit this model exactly once two conventions are mapped: its table
turned clockwise seen from above (pass ``mu = -30, -60, ...``), and the azimuth it reports is that
of the body y axis, i.e. ``paper azimuth = azimuth - 90 deg`` (y points 90 deg counter-clockwise
of x). With the table's x and y rows taken as our x and y gyros, Table 2 is reproduced to the
rounding of Table 1 (largest difference 0.006 deg; see ``tests/test_heading.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.units import (
    DPH,
    DPS,
    G0,
    OMEGA_IE,
    UG,
    finite_float,
    normal_gravity,
)
from northfinder.host.accuracy import bound_deg
from northfinder.host.errors import GeometryError, HostConfigError, InputError, TiltError
from northfinder.host.kernels import (
    MAX_LATITUDE_DEG,
    MAX_SOLVER_TILT_DEG,
    MIN_MU_SEPARATION_DEG,
    earth_rate_body,
    eq14,
    f0_from_two_positions,
    fit_heading,
    fit_tilt,
    latitude_rad,
    table_rotation,
    tilt_from_f0,
    tilt_within_limit,
)
from northfinder.host.plan import PAPER_SWEEP, Plan

__all__ = [
    "ACCEL_UNITS",
    "MAX_LATITUDE_DEG",
    "MAX_SOLVER_TILT_DEG",
    "MIN_MU_SEPARATION_DEG",
    "RATE_UNITS",
    "HeadingSolution",
    "MultiPositionSolution",
    "pairwise_azimuths",
    "solve_multi_position",
    "solve_two_position",
    "two_position_bound_deg",
]

#: Gyro units accepted by name: size of one unit in rad/s.
RATE_UNITS: Mapping[str, float] = {
    "rad/s": 1.0,
    "mrad/s": 1e-3,
    "urad/s": 1e-6,
    "deg/s": DPS,
    "deg/h": DPH,
}
#: Accelerometer units accepted by name: size of one unit in m/s^2.
ACCEL_UNITS: Mapping[str, float] = {
    "m/s^2": 1.0,
    "g": G0,
    "mg": G0 * 1e-3,
    "ug": UG,
}


# ----------------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HeadingSolution:
    """Result of a two-position heading solution.

    Attributes
    ----------
    azimuth_deg : float
        Azimuth of body x at the first position, clockwise from true north, in [0, 360) deg.
    pitch_deg, roll_deg : float
        Tilt used by the solution, deg: from the accelerometers, or 0 when level was assumed.
    mu_deg : float
        Table angle between the two positions, deg, as given.
    sigma_deg : float or None
        1-sigma azimuth error from the given noise of the window means (linear propagation),
        deg; None when no noise level was given. Systematic errors (a level assumption on a
        tilted instrument, table indexing, scale factors) are not included.
    levelled : bool
        True when the tilt came from the accelerometers (paper eq. 14), False when the
        instrument was assumed level (eq. 15).
    """

    azimuth_deg: float
    pitch_deg: float
    roll_deg: float
    mu_deg: float
    sigma_deg: float | None
    levelled: bool


@dataclass(frozen=True)
class MultiPositionSolution:
    """Result of the multi-position least-squares heading fit.

    Attributes
    ----------
    azimuth_deg : float
        Azimuth of body x at table angle 0, clockwise from true north, [0, 360) deg.
    pitch_deg, roll_deg : float
        Tilt, deg: estimated from the accelerometers, or the known values passed in.
    sigma_deg : float or None
        1-sigma azimuth, deg (None when neither noise levels nor redundant data allow one).
    mu_deg : tuple of float
        Table angles of the positions, deg, as given.
    gyro_bias : ndarray, shape (2,)
        Estimated x and y gyro biases, in ``rate_unit``.
    accel_bias : ndarray, shape (2,), or None
        Estimated x and y accelerometer biases in ``accel_unit`` (None without accelerometers).
    parameter_names : tuple of str
        Names of the estimated parameters, in the order of ``covariance``: ``alpha`` (rad, the
        model's counter-clockwise angle, so var(azimuth) = var(alpha)), ``gyro_bias_x``,
        ``gyro_bias_y`` (rate unit), then with accelerometers ``pitch``, ``roll`` (rad),
        ``accel_bias_x``, ``accel_bias_y`` (accel unit).
    covariance : ndarray, shape (P, P), or None
        Covariance of those parameters.
    gyro_residuals : ndarray, shape (N, 2)
        Measured minus fitted gyro means, rate unit.
    accel_residuals : ndarray, shape (N, 2), or None
        Measured minus fitted accelerometer means, accel unit.
    """

    azimuth_deg: float
    pitch_deg: float
    roll_deg: float
    sigma_deg: float | None
    mu_deg: tuple[float, ...]
    gyro_bias: NDArray[np.float64] = field(repr=False)
    accel_bias: NDArray[np.float64] | None = field(repr=False)
    parameter_names: tuple[str, ...] = field(repr=False)
    covariance: NDArray[np.float64] | None = field(repr=False)
    gyro_residuals: NDArray[np.float64] = field(repr=False)
    accel_residuals: NDArray[np.float64] | None = field(repr=False)


# ----------------------------------------------------------------------------------------------
# Checks and helpers
# ----------------------------------------------------------------------------------------------


def heading_text(azimuth_deg: float, digits: int) -> str:
    """``azimuth_deg`` printed with ``digits`` decimals in [0, 360): a heading that rounds up to
    360 is written as 0 (``359.99996`` -> ``0.0000``), as a compass and NMEA's HDT read it."""
    text = f"{azimuth_deg % 360.0:.{digits}f}"
    return f"{0.0:.{digits}f}" if float(text) >= 360.0 else text


def _unit_scale(unit: str | float, table: Mapping[str, float], field_name: str) -> float:
    if isinstance(unit, str):
        try:
            return table[unit]
        except KeyError:
            choices = ", ".join(repr(k) for k in table)
            raise HostConfigError(
                f"{field_name}: unknown unit {unit!r}; choose one of {choices} "
                "or give the size of one unit as a number"
            ) from None
    value = float(unit)
    if not math.isfinite(value) or value <= 0.0:
        raise HostConfigError(f"{field_name}: must be a positive finite number, got {unit!r}")
    return value


def _vector(name: str, value: ArrayLike, *, lead: tuple[int, ...] = ()) -> NDArray[np.float64]:
    """Return ``value`` as float array of shape ``lead + (2,)`` or ``lead + (3,)`` (x, y[, z])."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: must be numeric, got {value!r}") from exc
    if arr.shape[:-1] != lead or arr.ndim != len(lead) + 1 or arr.shape[-1] not in (2, 3):
        want = " x ".join(str(n) for n in lead)
        want = f"({want}, 2) or ({want}, 3)" if lead else "(2,) or (3,)"
        raise InputError(f"{name}: expected shape {want} (x, y[, z] means), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains non-finite values: {arr.tolist()}")
    return arr


def _noise(
    name: str, value: ArrayLike | None, shape: tuple[int, int]
) -> NDArray[np.float64] | None:
    """Broadcast a 1-sigma noise level to ``shape`` (positions, axes x/y); None stays None."""
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 1 and arr.shape[0] == shape[0]:
            arr = arr[:, None]  # one level per position, both axes
        out = np.broadcast_to(arr, shape).astype(float)
    except (TypeError, ValueError) as exc:
        raise InputError(
            f"{name}: must be a scalar, one value per position, or shape {shape} "
            f"(positions, x/y), got {np.shape(value)}"
        ) from exc
    if not np.all(np.isfinite(out)) or np.any(out < 0.0):
        raise InputError(f"{name}: must be finite and non-negative, got {out.tolist()}")
    return out


def _check_mu(mu_deg: float, name: str = "mu_deg") -> float:
    mu = finite_float(mu_deg, InputError, name)
    wrapped = mu % 360.0
    separation = min(wrapped, 360.0 - wrapped)
    if separation < MIN_MU_SEPARATION_DEG:
        raise GeometryError(
            f"{name} = {mu} deg: the table angle must differ from 0 and 360 deg by at least "
            f"{MIN_MU_SEPARATION_DEG} deg (it is {separation:.3g} deg away); the Earth-rate "
            "difference 2*Omega_H*sin(mu/2) vanishes there"
        )
    return mu


def _check_tilt(pitch: float, roll: float, source: str) -> None:
    for label, ok in (
        ("pitch", tilt_within_limit(pitch, 0.0)),
        ("roll", tilt_within_limit(0.0, roll)),
    ):
        if not ok:
            value = math.degrees(pitch if label == "pitch" else roll)
            raise TiltError(
                f"{label} {value:.3f} deg ({source}) exceeds the limit of "
                f"+-{MAX_SOLVER_TILT_DEG} deg: level the instrument first"
            )


def _tilt(fx0: float, fy0: float, g: float, source: str) -> tuple[float, float]:
    """Pitch and roll (rad) from the horizontal specific force at table angle 0, or TiltError."""
    theta, gamma = tilt_from_f0(fx0, fy0, g)
    for value, f in ((theta, fx0), (gamma, fy0)):
        if math.isnan(value):
            raise TiltError(
                f"{source}: horizontal specific force {f:.6g} exceeds gravity {g:.6g} "
                "(check accel_unit and the accelerometer means)"
            )
    return float(theta), float(gamma)


# ----------------------------------------------------------------------------------------------
# Two positions
# ----------------------------------------------------------------------------------------------


def _level_two_position(
    a0: NDArray[np.float64], a1: NDArray[np.float64], mu: float, g: float
) -> tuple[float, float]:
    """Bias-free pitch and roll (rad) from two positions (paper eqs. 12, 13), or TiltError."""
    fx0, fy0 = f0_from_two_positions(a0, a1, mu)
    return _tilt(float(fx0), float(fy0), g, "accelerometer levelling")


def _alpha_two_position(
    g0: NDArray[np.float64],
    g1: NDArray[np.float64],
    mu: float,
    theta: float,
    gamma: float,
    omega_u: float,
) -> tuple[float, NDArray[np.float64]]:
    """Model angle alpha (rad) by eq. 14 (eq. 15 when level) and d alpha / d(g0x, g0y, g1x, g1y)."""
    e = eq14(g0, g1, mu, theta, gamma, omega_u)
    num, den = float(e.num), float(e.den)
    r2 = num * num + den * den
    if r2 == 0.0:
        raise GeometryError("the gyro differences are zero: no Earth rate was measured")
    (n1, n2, _), (d1, d2, _) = e.n.tolist(), e.d.tolist()
    dx = (den * n1 - num * d1) / r2
    dy = (den * n2 - num * d2) / r2
    return math.atan2(num, den), np.array([dx, dy, -dx, -dy])


def solve_two_position(
    gyro0: ArrayLike,
    gyro1: ArrayLike,
    mu_deg: float,
    *,
    accel0: ArrayLike | None = None,
    accel1: ArrayLike | None = None,
    latitude_deg: float | None = None,
    rate_unit: str | float = "rad/s",
    accel_unit: str | float = "m/s^2",
    gyro_noise: ArrayLike | None = None,
    accel_noise: ArrayLike | None = None,
) -> HeadingSolution:
    """Azimuth from window means at two table positions (the paper's arbitrary two-position method).

    Differencing the two positions cancels constant gyro and accelerometer biases. With
    accelerometer means the tilt comes from eqs. 12 and 13 (for specific force) and the azimuth
    from eq. 14, which needs the vertical Earth rate and so the latitude; without them the
    instrument is taken as level and eq. 15 is used. Both are evaluated with atan2.

    Parameters
    ----------
    gyro0, gyro1 : array_like, shape (2,) or (3,)
        Mean gyro outputs (x, y[, z]) at the first position and after turning the table by
        ``mu_deg``, in ``rate_unit``. The z gyro is not used.
    mu_deg : float
        Table angle from the first to the second position, deg, right-handed about up. Any value
        at least :data:`MIN_MU_SEPARATION_DEG` away from 0 (mod 360), negative or above 180.
    accel0, accel1 : array_like, shape (2,) or (3,), optional
        Mean accelerometer outputs (specific force) at the two positions, in ``accel_unit``.
        Give both or neither.
    latitude_deg : float, optional
        Geodetic latitude, deg. Required with accelerometers (eq. 14 and gravity); without them it
        is only checked.
    rate_unit : str or float
        Unit of the gyro means and ``gyro_noise``: a key of :data:`RATE_UNITS` or the size of one
        unit in rad/s. It only matters with accelerometers (the Earth rate enters eq. 14); eq. 15
        is unit-free, so raw outputs (counts, mV) are fine for a level instrument.
    accel_unit : str or float
        Unit of the accelerometer means: a key of :data:`ACCEL_UNITS` or m/s^2 per unit.
    gyro_noise : float or array_like, optional
        1-sigma noise of each gyro window mean, in ``rate_unit``: a scalar, one value per position
        (shape (2,)) or per position and axis (shape (2, 2)). For white noise of angle random
        walk N over a window of t seconds this is N / sqrt(t).
    accel_noise : float or array_like, optional
        1-sigma noise of each accelerometer window mean, in ``accel_unit``, shaped like
        ``gyro_noise``; ignored without accelerometers, taken as zero when omitted.

    Returns
    -------
    HeadingSolution
        Azimuth of body x at the first position; ``sigma_deg`` when a noise level was given.

    Raises
    ------
    InputError
        Wrong shapes, non-finite values, only one accelerometer mean, bad noise levels.
    GeometryError
        ``mu_deg`` within :data:`MIN_MU_SEPARATION_DEG` of 0 or 360 deg, or no Earth rate seen.
    LatitudeError
        Latitude missing (with accelerometers), not finite, or beyond +-:data:`MAX_LATITUDE_DEG`.
    TiltError
        Pitch or roll beyond +-:data:`MAX_SOLVER_TILT_DEG`, or accelerometer means inconsistent with g.
    HostConfigError
        Unknown unit.

    Notes
    -----
    For white noise with equal noise s on all four gyro means and a level instrument,
    ``sigma = s / (sqrt(2) Omega_H |sin(mu/2)|)`` rad, i.e. N / (Omega_H |sin(mu/2)| sqrt(T))
    with T the total dwell (see :func:`two_position_bound_deg`).
    """
    g0 = _vector("gyro0", gyro0)
    g1 = _vector("gyro1", gyro1)
    mu_in = _check_mu(mu_deg)
    mu = math.radians(mu_in)
    rate_scale = _unit_scale(rate_unit, RATE_UNITS, "rate_unit")
    if (accel0 is None) != (accel1 is None):
        raise InputError("accel0 and accel1: give both accelerometer means or neither")
    levelled = accel0 is not None
    if levelled:
        lat = latitude_rad(latitude_deg, "levelling with accelerometers (eq. 14)")
    elif latitude_deg is not None:
        lat = latitude_rad(latitude_deg, "the solution")
    gyro_sigma = _noise("gyro_noise", gyro_noise, (2, 2))

    if accel0 is not None and accel1 is not None:
        a0 = _vector("accel0", accel0)
        a1 = _vector("accel1", accel1)
        accel_scale = _unit_scale(accel_unit, ACCEL_UNITS, "accel_unit")
        g = float(normal_gravity(lat)) / accel_scale
        omega_u = OMEGA_IE * math.sin(lat) / rate_scale
        theta, gamma = _level_two_position(a0, a1, mu, g)
        _check_tilt(theta, gamma, "from the accelerometers")
    else:
        theta = gamma = omega_u = 0.0

    alpha, d_alpha = _alpha_two_position(g0, g1, mu, theta, gamma, omega_u)

    sigma_deg: float | None = None
    if gyro_sigma is not None:
        variance = float(np.sum((d_alpha * gyro_sigma.ravel()) ** 2))
        accel_sigma = _noise("accel_noise", accel_noise, (2, 2)) if levelled else None
        if accel_sigma is not None:
            variance += _accel_variance(g0, g1, a0, a1, mu, g, omega_u, accel_sigma)
        sigma_deg = math.degrees(math.sqrt(variance))

    return HeadingSolution(
        azimuth_deg=float(np.mod(-math.degrees(alpha), 360.0)),
        pitch_deg=math.degrees(theta),
        roll_deg=math.degrees(gamma),
        mu_deg=mu_in,
        sigma_deg=sigma_deg,
        levelled=levelled,
    )


def _accel_variance(
    g0: NDArray[np.float64],
    g1: NDArray[np.float64],
    a0: NDArray[np.float64],
    a1: NDArray[np.float64],
    mu: float,
    g: float,
    omega_u: float,
    accel_sigma: NDArray[np.float64],
) -> float:
    """Variance of alpha (rad^2) from accelerometer noise, through the tilt (central differences).

    alpha is smooth in the accelerometer means; a step of 1e-6 g keeps the truncation error of
    the derivative near 1e-12 relative, far below what a 1-sigma figure needs.
    """
    base = np.concatenate([a0[:2], a1[:2]])
    step = 1e-6 * g
    # Rows 2j and 2j + 1 move mean j up and down by one step; all eight are solved at once.
    rows = np.arange(8)
    moved = np.repeat(base[None, :], 8, axis=0)
    moved[rows, rows // 2] += np.where(rows % 2 == 0, step, -step)
    theta, gamma = tilt_from_f0(*f0_from_two_positions(moved[:, :2], moved[:, 2:], mu), g)
    alpha = eq14(g0, g1, mu, theta, gamma, omega_u).alpha
    grad = np.array(
        [math.remainder(alpha[2 * j] - alpha[2 * j + 1], math.tau) for j in range(4)]
    ) / (2.0 * step)
    return float(np.sum((grad * accel_sigma.ravel()) ** 2))


def two_position_bound_deg(
    arw_dpsh: float, total_time_s: float, mu_deg: float, latitude_deg: float
) -> float:
    """Best 1-sigma azimuth of a level two-position run with white gyro noise only, deg.

    sigma = N / (Omega cos(lat) |sin(mu/2)| sqrt(T)), with the angle random walk
    N = arw_dpsh * pi/180 / 60 rad/sqrt(s), both horizontal gyros, and the total dwell T split
    equally over the two positions: the plan bound :func:`northfinder.host.accuracy.bound_deg`
    of the positions (0, mu).

    Parameters
    ----------
    arw_dpsh : float
        Gyro angle random walk, deg/sqrt(h).
    total_time_s : float
        Total recording time over both positions, s.
    mu_deg : float
        Table angle between the positions, deg.
    latitude_deg : float
        Latitude, deg.
    """
    return bound_deg((0.0, _check_mu(mu_deg)), total_time_s / 2.0, arw_dpsh, latitude_deg)


# ----------------------------------------------------------------------------------------------
# Pairwise over a plan
# ----------------------------------------------------------------------------------------------


def pairwise_azimuths(
    gyro_means: ArrayLike,
    plan: Plan | Sequence[float] = PAPER_SWEEP,
    *,
    accel_means: ArrayLike | None = None,
    latitude_deg: float | None = None,
    rate_unit: str | float = "rad/s",
    accel_unit: str | float = "m/s^2",
    gyro_noise: float | None = None,
    accel_noise: float | None = None,
) -> tuple[HeadingSolution, ...]:
    """Two-position azimuths of every position against the first (the paper's Table 2 layout).

    Parameters
    ----------
    gyro_means : array_like, shape (N, 2) or (N, 3)
        Gyro window means at each position of the plan, ``rate_unit``.
    plan : Plan or sequence of float
        The plan, or the N table angles in deg.
    accel_means : array_like, shape (N, 2) or (N, 3), optional
        Accelerometer window means (then ``latitude_deg`` is required).
    latitude_deg, rate_unit, accel_unit
        As for :func:`solve_two_position`.
    gyro_noise, accel_noise : float, optional
        1-sigma noise of every window mean (one value for all positions and axes).

    Returns
    -------
    tuple of HeadingSolution
        N - 1 solutions, pair (0, k) for k = 1 .. N-1, ``mu_deg = angle_k - angle_0``.
    """
    angles = plan.positions_deg if isinstance(plan, Plan) else tuple(plan)
    n = len(angles)
    if n < 2:
        raise GeometryError(f"a plan needs at least 2 positions, got {n}")
    gyro = _vector("gyro_means", gyro_means, lead=(n,))
    accel = None if accel_means is None else _vector("accel_means", accel_means, lead=(n,))
    out = []
    for k in range(1, n):
        out.append(
            solve_two_position(
                gyro[0],
                gyro[k],
                float(angles[k]) - float(angles[0]),
                accel0=None if accel is None else accel[0],
                accel1=None if accel is None else accel[k],
                latitude_deg=latitude_deg,
                rate_unit=rate_unit,
                accel_unit=accel_unit,
                gyro_noise=gyro_noise,
                accel_noise=accel_noise,
            )
        )
    return tuple(out)


# ----------------------------------------------------------------------------------------------
# Multi-position least squares
# ----------------------------------------------------------------------------------------------


def _posterior_scale(
    residuals: NDArray[np.float64], n_params: int, sigma: NDArray[np.float64] | None
) -> float | None:
    """Variance factor: 1 with known noise, the residual estimate with redundancy, else None."""
    if sigma is not None:
        return 1.0
    dof = residuals.size - n_params
    if dof <= 0:
        return None
    return float(residuals @ residuals) / dof


def solve_multi_position(
    gyro_means: ArrayLike,
    mu_deg: ArrayLike,
    *,
    latitude_deg: float,
    accel_means: ArrayLike | None = None,
    pitch_deg: float = 0.0,
    roll_deg: float = 0.0,
    rate_unit: str | float = "rad/s",
    accel_unit: str | float = "m/s^2",
    gyro_noise: ArrayLike | None = None,
    accel_noise: ArrayLike | None = None,
    max_iterations: int = 50,
) -> MultiPositionSolution:
    """Least-squares azimuth from gyro window means at any set of table angles.

    Model, both horizontal gyros at every position i:
    ``w_i = R(mu_i) h(alpha, pitch, roll) + b``, where R is the horizontal block of C_m^m1,
    h the horizontal Earth rate in the body frame at table angle 0 (its size fixed by the known
    latitude) and b the constant gyro bias. Unknowns: alpha and b; only alpha enters
    non-linearly (the biases are projected out and alpha found by Newton's method, see
    :func:`northfinder.host.kernels.fit_heading`). With accelerometer means the tilt and
    accelerometer biases are estimated first from ``f_i = R(mu_i) f_0 + b_a`` (linear), and
    their covariance is carried into the heading's; without them the tilt is the known
    ``pitch_deg``, ``roll_deg``.

    Parameters
    ----------
    gyro_means : array_like, shape (N, 2) or (N, 3)
        Gyro window means (x, y[, z]) in ``rate_unit``; N >= 2. The z gyro is not used.
    mu_deg : array_like, shape (N,)
        Table angle of each position, deg. At least two must be
        :data:`MIN_MU_SEPARATION_DEG` apart (mod 360).
    latitude_deg : float
        Latitude, deg.
    accel_means : array_like, shape (N, 2) or (N, 3), optional
        Accelerometer window means in ``accel_unit``; then pitch and roll are estimated.
    pitch_deg, roll_deg : float
        Known tilt used without accelerometers, deg.
    rate_unit, accel_unit : str or float
        As for :func:`solve_two_position`.
    gyro_noise : float or array_like, optional
        1-sigma of each gyro window mean (scalar, shape (N,) or (N, 2)), ``rate_unit``. Without
        it the noise is estimated from the residuals when there is redundancy (N >= 3 or more
        equations than unknowns), otherwise no covariance is given.
    accel_noise : float or array_like, optional
        Likewise for the accelerometer means (redundancy needs N >= 3).
    max_iterations : int
        Iteration limit of the heading fit.

    Returns
    -------
    MultiPositionSolution

    Raises
    ------
    InputError, GeometryError, LatitudeError, TiltError, HostConfigError
        As for :func:`solve_two_position`; GeometryError also when fewer than two distinct
        positions are given or the fit does not converge.
    """
    mus_in, gyro, accel, lat, rate_scale, gyro_sigma, accel_sigma = _multi_position_inputs(
        gyro_means, mu_deg, accel_means, latitude_deg, rate_unit, gyro_noise, accel_noise
    )
    n = mus_in.size
    rot = table_rotation(np.radians(mus_in))  # (N, 2, 2)
    omega_n = OMEGA_IE * math.cos(lat) / rate_scale
    omega_u = OMEGA_IE * math.sin(lat) / rate_scale
    theta, gamma, accel_bias, accel_res, tilt_cov = _multi_position_tilt(
        accel, accel_sigma, accel_unit, rot, lat, pitch_deg, roll_deg
    )
    sig_g = None if gyro_sigma is None else gyro_sigma.ravel()
    w = np.ones(2 * n) if sig_g is None else 1.0 / sig_g
    fit = fit_heading(
        gyro[None], rot[None], np.array([theta]), np.array([gamma]), omega_n, omega_u,
        None if sig_g is None else w[None], max_iterations=max_iterations,
    )  # fmt: skip
    if not fit.converged[0]:
        raise GeometryError(
            f"multi-position fit did not converge in {max_iterations} iterations "
            f"(mu_deg = {mus_in.tolist()})"
        )
    alpha, bias = float(fit.alpha[0]), fit.bias[0]
    h, dh = earth_rate_body(alpha, theta, gamma, omega_n, omega_u)
    res_g = (gyro - np.einsum("nij,j->ni", rot, h) - bias).ravel()
    jac = np.empty((2 * n, 3))
    jac[:, 0] = np.einsum("nij,j->ni", rot, dh[:, 0]).ravel()
    jac[:, 1:] = np.tile(np.eye(2), (n, 1))
    jw = jac * w[:, None]
    normal = jw.T @ jw
    # Geometry alone decides separability: extreme weights (noise-free windows) must not.
    if np.linalg.cond(jac.T @ jac) > 1e12:
        raise GeometryError(
            f"mu_deg = {mus_in.tolist()}: the positions do not separate heading from gyro bias"
        )
    ninv_g = np.linalg.inv(normal)
    scale_g = _posterior_scale(res_g * w, 3, sig_g)

    names, cov = _multi_position_covariance(
        scale_g, ninv_g, accel is not None, tilt_cov, rot, dh, jw, w
    )
    return MultiPositionSolution(
        azimuth_deg=float(np.mod(-math.degrees(alpha), 360.0)),
        pitch_deg=math.degrees(theta),
        roll_deg=math.degrees(gamma),
        sigma_deg=None if cov is None else math.degrees(math.sqrt(cov[0, 0])),
        mu_deg=tuple(float(v) for v in mus_in),
        gyro_bias=bias,
        accel_bias=accel_bias,
        parameter_names=tuple(names),
        covariance=cov,
        gyro_residuals=res_g.reshape(n, 2),
        accel_residuals=accel_res,
    )


def _multi_position_inputs(
    gyro_means: ArrayLike,
    mu_deg: ArrayLike,
    accel_means: ArrayLike | None,
    latitude_deg: float,
    rate_unit: str | float,
    gyro_noise: ArrayLike | None,
    accel_noise: ArrayLike | None,
) -> tuple[Any, Any, Any, float, float, Any, Any]:
    """The checked inputs of :func:`solve_multi_position`: table angles (deg), horizontal gyro
    and accelerometer means, latitude (rad), the rate unit's scale and the noise of the means."""
    mus_in = np.asarray(mu_deg, dtype=float)
    if mus_in.ndim != 1 or mus_in.size < 2:
        raise InputError(f"mu_deg: expected shape (N,) with N >= 2, got {mus_in.shape}")
    if not np.all(np.isfinite(mus_in)):
        raise InputError(f"mu_deg: contains non-finite values: {mus_in.tolist()}")
    n = mus_in.size
    gyro = _vector("gyro_means", gyro_means, lead=(n,))[:, :2]
    accel = None if accel_means is None else _vector("accel_means", accel_means, lead=(n,))[:, :2]
    lat = latitude_rad(latitude_deg, "the multi-position fit")
    rate_scale = _unit_scale(rate_unit, RATE_UNITS, "rate_unit")
    gyro_sigma = _noise("gyro_noise", gyro_noise, (n, 2))
    accel_sigma = _noise("accel_noise", accel_noise, (n, 2)) if accel is not None else None
    if gyro_sigma is not None and np.any(gyro_sigma == 0.0):
        raise InputError("gyro_noise: must be positive for a weighted fit")
    if accel_sigma is not None and np.any(accel_sigma == 0.0):
        raise InputError("accel_noise: must be positive for a weighted fit")

    separations = np.abs(np.sin(np.radians(mus_in[:, None] - mus_in[None, :]) / 2.0))
    if separations.max() < math.sin(math.radians(MIN_MU_SEPARATION_DEG) / 2.0):
        raise GeometryError(
            f"mu_deg = {mus_in.tolist()}: at least two positions must be "
            f"{MIN_MU_SEPARATION_DEG} deg apart (mod 360) for the biases to separate from the "
            "Earth rate"
        )
    return mus_in, gyro, accel, lat, rate_scale, gyro_sigma, accel_sigma


def _multi_position_tilt(
    accel: Any,
    accel_sigma: Any,
    accel_unit: str | float,
    rot: Any,
    lat: float,
    pitch_deg: float,
    roll_deg: float,
) -> tuple[float, float, Any, Any, Any]:
    """Pitch and roll (rad) of :func:`solve_multi_position`, with the accelerometer biases,
    residuals and the covariance of (pitch, roll, bias x, bias y) when accelerometer means are
    given; else the known tilt (no biases, no covariance)."""
    n = rot.shape[0]
    # Tilt: linear in (f0x, f0y, bias_x, bias_y); biases cancel only through the rotation.
    tilt_cov = None
    accel_bias = accel_res = None
    if accel is not None:
        accel_scale = _unit_scale(accel_unit, ACCEL_UNITS, "accel_unit")
        g = float(normal_gravity(lat)) / accel_scale
        sig_a = None if accel_sigma is None else accel_sigma.ravel()
        _, _, xa, res_a, ninv_a = fit_tilt(
            accel[None], rot[None], g, None if sig_a is None else 1.0 / sig_a[None]
        )
        theta, gamma = _tilt(float(xa[0, 0]), float(xa[0, 1]), g, "accelerometer fit")
        _check_tilt(theta, gamma, "from the accelerometers")
        accel_bias = xa[0, 2:].copy()
        accel_res = res_a[0].reshape(n, 2)
        scale_a = _posterior_scale(res_a[0] / (1.0 if sig_a is None else sig_a), 4, sig_a)
        # (theta, gamma) from (f0x, f0y): f0x = -g sin(theta), f0y = g cos(theta) sin(gamma).
        st, ct, sg, cg = math.sin(theta), math.cos(theta), math.sin(gamma), math.cos(gamma)
        d_f_d_tilt = np.array([[-g * ct, 0.0], [-g * st * sg, g * ct * cg]])
        d_tilt_d_f = np.linalg.inv(d_f_d_tilt)
        jac_a = np.zeros((4, 4))
        jac_a[:2, :2] = d_tilt_d_f
        jac_a[2:, 2:] = np.eye(2)
        tilt_cov = None if scale_a is None else scale_a * (jac_a @ ninv_a[0] @ jac_a.T)
    else:
        theta, gamma = math.radians(float(pitch_deg)), math.radians(float(roll_deg))
        if not (math.isfinite(theta) and math.isfinite(gamma)):
            raise InputError(f"pitch_deg, roll_deg: must be finite, got {pitch_deg}, {roll_deg}")
        _check_tilt(theta, gamma, "as given")
    return theta, gamma, accel_bias, accel_res, tilt_cov


def _multi_position_covariance(
    scale_g: Any, ninv_g: Any, with_accel: bool, tilt_cov: Any, rot: Any, dh: Any, jw: Any, w: Any
) -> tuple[list[str], NDArray[np.float64] | None]:
    """The names of the solution's parameters and their covariance (None without a noise
    estimate), the tilt's covariance carried into the heading's."""
    n = rot.shape[0]
    names = ["alpha", "gyro_bias_x", "gyro_bias_y"]
    cov: NDArray[np.float64] | None = None
    if scale_g is not None:
        cov = np.asarray(scale_g * ninv_g, dtype=np.float64)
        if with_accel:
            names += ["pitch", "roll", "accel_bias_x", "accel_bias_y"]
            if tilt_cov is None:
                cov = None
            else:
                # Sensitivity of the gyro estimate to the tilt it was computed with.
                jac_t = np.empty((2 * n, 4))
                jac_t[:, :2] = np.einsum("nij,jk->nik", rot, dh[:, 1:]).reshape(2 * n, 2)
                jac_t[:, 2:] = 0.0
                sens = -ninv_g @ (jw.T @ (jac_t * w[:, None]))
                full = np.zeros((7, 7))
                full[:3, :3] = cov + sens @ tilt_cov @ sens.T
                full[:3, 3:] = sens @ tilt_cov
                full[3:, :3] = full[:3, 3:].T
                full[3:, 3:] = tilt_cov
                cov = full
    elif with_accel:
        names += ["pitch", "roll", "accel_bias_x", "accel_bias_y"]
    return names, cov
