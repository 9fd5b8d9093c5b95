"""North finding on a continuously turning table (rotation modulation).

The table turns at a constant rate (protocol 1.1 SPIN). Seen by the horizontal gyros, the
horizontal Earth rate is a sinusoid in the table angle whose phase is the heading, while their
constant biases (and slow drift) stay at zero frequency:

    w_x(mu) =  cos(mu) h_x + sin(mu) h_y + b_x (+ d_x t)
    w_y(mu) = -sin(mu) h_x + cos(mu) h_y + b_y (+ d_y t)

with ``h = h(alpha, pitch, roll)`` the Earth rate in the body frame at table angle 0
(:func:`~northfinder.host.kernels.earth_rate_body`). Every sample is the mean over its interval,
so the regressors are the means of cos and sin over the angles the interval swept (from the
previous sample's encoder angle to this one's: exact for a constant rate within the interval).
The accelerometers give the tilt the same way (``f(mu) = R(mu) f0 + b_a``), and the heading follows
by least squares over all samples with the kernels of the multi-position solver
(:func:`~northfinder.host.kernels.fit_tilt`, :func:`~northfinder.host.kernels.fit_heading`).

Conventions are those of :mod:`northfinder.host.heading`: the azimuth is that of body x at table
angle 0, clockwise from true north; table angles counter-clockwise seen from above.

Sigma. The heading's first-order weights on every sample (gyro and accelerometer, both axes) are
computed from the fit; the reported ``sigma_deg`` is the white-noise sigma (residual scatter
through those weights) unless a batch estimate (the weighted residuals summed over :data:`BATCHES`
consecutive stretches, which also holds when the noise is correlated over less than a stretch)
exceeds it beyond its own scatter (:func:`reported_sigma`). The consistency check solves the first and the second half of the samples
separately and asks them to agree within three sigma of their difference; when they do not, the
reported sigma is scaled by their disagreement (``sigma_scale``).

The white-noise bound is :func:`northfinder.host.accuracy.spin_bound_deg`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.constants import VALIDITY_SPIN_UNFIT, VALIDITY_STEADY_RATE
from northfinder.driver.protocol.units import DPH, OMEGA_IE, normal_gravity
from northfinder.host.errors import GeometryError, InputError, TiltError
from northfinder.host.kernels import (
    MAX_SOLVER_TILT_DEG,
    azimuths_of_rotated,
    bias_design,
    earth_rate_body,
    fit_heading,
    fit_tilt,
    latitude_rad,
    tilt_from_f0,
    tilt_within_limit,
)

__all__ = [
    "BATCHES",
    "MIN_SWEEP_DEG",
    "SpinSamples",
    "SpinSolution",
    "amplitude_pinv",
    "fitted_rates",
    "heading_weights",
    "interval_rotation",
    "nuisance_design",
    "solve_spin",
    "solve_spin_batch",
    "spin_samples",
    "spin_weights_level",
]

Array = NDArray[np.float64]

#: Consecutive stretches the batch estimate of sigma sums the weighted residuals over.
BATCHES = 16
#: How far the batch estimate's square must exceed the white one's before it is reported: the
#: 95 % point of chi-square with BATCHES - 1 degrees of freedom over BATCHES - 1 (under white
#: noise the ratio of the two is that distribution's, so 5 % of white runs report the batch).
BATCH_EXCESS = 24.99579013972863 / 15.0


def reported_sigma(white_deg: float, batch_deg: float) -> float:
    """The sigma a spin solution reports, deg: the batch estimate where the residuals show
    correlated noise (its square beyond :data:`BATCH_EXCESS` times the white one's), else the
    white-noise sigma. (The larger of the two would run about 7 % high under white noise.)"""
    return batch_deg if batch_deg * batch_deg > BATCH_EXCESS * white_deg * white_deg else white_deg


#: A spin solution needs the table to sweep at least this much, deg (the sinusoid must show).
MIN_SWEEP_DEG = 90.0


def interval_rotation(mu0_rad: ArrayLike, mu1_rad: ArrayLike) -> Array:
    """Mean of the table rotation C_m^m1 (horizontal block) over each interval, (..., 2, 2).

    The angle runs linearly from ``mu0`` to ``mu1`` (rad, continuous: ``mu1 - mu0`` is the turn
    swept, not taken modulo a turn); where they are equal it is the rotation at that angle.
    """
    a0 = np.asarray(mu0_rad, dtype=float)
    a1 = np.asarray(mu1_rad, dtype=float)
    d = a1 - a0
    turning = np.abs(d) > 1e-9
    safe = np.where(turning, d, 1.0)
    c = np.where(turning, (np.sin(a1) - np.sin(a0)) / safe, np.cos(0.5 * (a0 + a1)))
    s = np.where(turning, -(np.cos(a1) - np.cos(a0)) / safe, np.sin(0.5 * (a0 + a1)))
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)


def nuisance_design(time_s: ArrayLike, drift: bool = False) -> Array:
    """Nuisance design of the spin fit, (R, 2N, k): a constant bias per axis (k = 2), and with
    ``drift`` a linear drift per axis (k = 4) in time centred on the record and in units of its
    length (so the coefficients stay well scaled)."""
    t = np.atleast_2d(np.asarray(time_s, dtype=float))
    r_count, n = t.shape
    base = bias_design(r_count, n)
    if not drift:
        return base
    mid = 0.5 * (t[:, :1] + t[:, -1:])
    span = np.maximum(t[:, -1:] - t[:, :1], 1e-9)
    x = np.repeat((t - mid) / span, 2, axis=1)  # (R, 2N)
    return np.concatenate([base, base * x[..., None]], axis=-1)


def _alpha_from_u(u: Array, theta: Array, gamma: Array, omega_n: float, omega_u: float) -> Array:
    """The heading (rad) from the fitted body Earth rate ``u`` (..., 2) given the tilt, by the
    closed form :func:`~northfinder.host.kernels.fit_heading` starts from."""
    st, ct, sg, cg = np.sin(theta), np.cos(theta), np.sin(gamma), np.cos(gamma)
    u0 = (u[..., 0] + omega_u * st) / (omega_n * ct)
    u1 = -((u[..., 1] - omega_u * ct * sg) - omega_n * st * sg * u0) / (omega_n * cg)
    return np.arctan2(u1, u0)


def amplitude_pinv(rot: Array, nuisance: Array) -> Array:
    """Rows of the least-squares pseudo-inverse that map the samples (rows x, y of each in turn)
    to the sinusoid's amplitudes (u or f0) with the nuisance terms estimated, (2, 2N)."""
    n = rot.shape[0]
    design = np.concatenate([rot.reshape(2 * n, 2), nuisance], axis=-1)
    out: Array = np.linalg.solve(design.T @ design, design.T)[:2]
    return out


def heading_weights(
    rot: Array,
    nuisance: Array,
    alpha: float,
    theta: float,
    gamma: float,
    omega_n: float,
    omega_u: float,
    g: float,
    *,
    pinv: Array | None = None,
) -> tuple[Array, Array]:
    """First-order weights of the heading on every gyro and accelerometer sample of one run.

    ``alpha_hat - alpha = c_g . e_g + c_a . e_a`` for small errors ``e`` of the samples (rows x,
    y of each sample in turn), with the nuisance terms estimated.

    Parameters
    ----------
    rot : ndarray, shape (N, 2, 2)
        :func:`interval_rotation` of every sample.
    nuisance : ndarray, shape (2N, k)
        :func:`nuisance_design` of the run (the same for both sensors).
    alpha, theta, gamma : float
        Heading, pitch and roll at which to linearise, rad.
    omega_n, omega_u : float
        Horizontal and vertical Earth rate, rad/s.
    g : float
        Gravity, m/s^2.

    pinv : ndarray, shape (2, 2N), optional
        :func:`amplitude_pinv` of ``rot`` and ``nuisance``, when it is at hand (it does not
        depend on the heading or the tilt).

    Returns
    -------
    c_g : ndarray, shape (2N,)
        rad per rad/s of gyro error.
    c_a : ndarray, shape (2N,)
        rad per m/s^2 of accelerometer error.
    """
    if pinv is None:
        pinv = amplitude_pinv(rot, nuisance)
    h, _ = earth_rate_body(alpha, theta, gamma, omega_n, omega_u)
    f0 = np.array([-g * math.sin(theta), g * math.cos(theta) * math.sin(gamma)])
    eps = 1e-7

    def d_alpha(du: Array, th: float, ga: float) -> float:
        d = float(_alpha_from_u(h + du, np.asarray(th), np.asarray(ga), omega_n, omega_u) - alpha)
        return (d + math.pi) % (2.0 * math.pi) - math.pi  # alpha may be given beyond +-pi

    scale = omega_n * eps
    grad_u = np.array([d_alpha(np.array([scale, 0.0]), theta, gamma),
                       d_alpha(np.array([0.0, scale]), theta, gamma)]) / scale  # fmt: skip
    grad_tilt = np.array([d_alpha(np.zeros(2), theta + eps, gamma),
                          d_alpha(np.zeros(2), theta, gamma + eps)]) / eps  # fmt: skip
    # d(theta, gamma) / d f0, by differences of the levelling kernel.
    df = g * eps
    jac = np.empty((2, 2))
    base = np.array(tilt_from_f0(f0[0], f0[1], g), dtype=float)
    for k in range(2):
        f = f0.copy()
        f[k] += df
        jac[:, k] = (np.array(tilt_from_f0(f[0], f[1], g), dtype=float) - base) / df
    c_g = grad_u @ pinv
    c_a = (grad_tilt @ jac) @ pinv
    return c_g, c_a


@dataclass(frozen=True)
class SpinSamples:
    """Angle-tagged samples of a spin, ready for :func:`solve_spin`.

    Attributes
    ----------
    gyro_rps, accel_mps2 : ndarray, shape (N, 3)
        Sample means (x, y, z), rad/s and m/s^2.
    mu0_rad, mu1_rad : ndarray, shape (N,)
        Continuous table angle at the start and the end of each sample interval, rad.
    time_s : ndarray, shape (N,)
        End of each sample interval, s.
    dropped : int
        Samples left out: not at the steady rate, unfit, or without the sample before them.
    """

    gyro_rps: Array
    accel_mps2: Array
    mu0_rad: Array
    mu1_rad: Array
    time_s: Array
    dropped: int = 0

    @property
    def n(self) -> int:
        return len(self.time_s)

    @property
    def sweep_deg(self) -> float:
        """Angle the table turned over the samples, deg (signed)."""
        return math.degrees(float(np.sum(self.mu1_rad - self.mu0_rad))) if self.n else 0.0

    @property
    def rate_dps(self) -> float:
        """Mean table rate over the samples, deg/s."""
        span = float(self.time_s[-1] - self.time_s[0]) if self.n > 1 else 0.0
        steps = np.diff(self.time_s)
        dt = float(np.median(steps)) if steps.size else 0.0
        return self.sweep_deg / (span + dt) if span + dt > 0 else 0.0


def spin_samples(
    gyro_dph: ArrayLike,
    accel_mps2: ArrayLike,
    table_deg: ArrayLike,
    counter: ArrayLike,
    sample_rate_hz: float,
    validity: ArrayLike | None = None,
) -> SpinSamples:
    """The samples of a spin recording a spin solution can use, with the angle each swept.

    A sample is used when it was taken at the steady rate (validity pair TABLE_MOVING |
    TABLE_SETTLING, bits 4..7 clear; every sample when ``validity`` is None) and the sample
    before it arrived (its angle is where this one's interval began).

    Parameters
    ----------
    gyro_dph : array_like, shape (N, 3)
        Gyro means, deg/h (as :class:`~northfinder.driver.window.Window` holds them).
    accel_mps2 : array_like, shape (N, 3)
    table_deg : array_like, shape (N,)
        Encoder angle at the end of each sample, [0, 360) deg.
    counter : array_like, shape (N,)
        Sample counters (consecutive, gaps where samples are missing).
    sample_rate_hz : float
    validity : array_like, shape (N,), optional
    """
    g = np.asarray(gyro_dph, dtype=float) * DPH
    a = np.asarray(accel_mps2, dtype=float)
    ang = np.asarray(table_deg, dtype=float)
    cnt = np.asarray(counter, dtype=np.int64)
    n = len(cnt)
    if not (g.shape[0] == a.shape[0] == ang.shape[0] == n):
        raise InputError("gyro, accel, table angle and counter must have one row per sample")
    fit = np.ones(n, dtype=bool)
    if validity is not None:
        v = np.asarray(validity, dtype=np.int64)
        fit = ((v & int(VALIDITY_STEADY_RATE)) == int(VALIDITY_STEADY_RATE)) & (
            (v & int(VALIDITY_SPIN_UNFIT)) == 0
        )
    # Each used sample needs its predecessor (fit or not: only its angle is used).
    has_prev = np.zeros(n, dtype=bool)
    has_prev[1:] = np.diff(cnt) == 1
    use = fit & has_prev
    idx = np.flatnonzero(use)
    # What each sample swept is the (short) step from its predecessor's angle; only the angles
    # of each interval enter the regressors, so no angle needs unwrapping across the record.
    step = np.radians((ang[idx] - ang[idx - 1] + 180.0) % 360.0 - 180.0)
    mu1 = np.radians(ang[idx])
    mu0 = mu1 - step
    return SpinSamples(
        gyro_rps=g[idx],
        accel_mps2=a[idx],
        mu0_rad=mu0,
        mu1_rad=mu1,
        time_s=cnt[idx].astype(float) / float(sample_rate_hz),
        dropped=int(n - idx.size),
    )


def solve_spin_batch(
    gyro_rps: ArrayLike,
    accel_mps2: ArrayLike | None,
    mu0_rad: ArrayLike,
    mu1_rad: ArrayLike,
    *,
    latitude_deg: float,
    time_s: ArrayLike | None = None,
    drift: bool = False,
    max_iterations: int = 50,
) -> Array:
    """Azimuths of many spin runs at once (the Monte Carlo's solver).

    Parameters
    ----------
    gyro_rps : array_like, shape (R, N, 2) or (R, N, 3)
        Gyro sample means, rad/s.
    accel_mps2 : array_like, shape (R, N, 2) or (R, N, 3), or None
        Accelerometer sample means, m/s^2; None: the instrument is taken as level.
    mu0_rad, mu1_rad : array_like, shape (R, N) or (N,)
        Continuous table angle at the start and end of each sample, rad.
    latitude_deg : float
    time_s : array_like, shape (R, N) or (N,), optional
        Sample times, s (needed with ``drift``).
    drift : bool
        Also fit a linear drift of each gyro and accelerometer.

    Returns
    -------
    ndarray, shape (R,)
        Azimuth of body x at table angle 0, [0, 360) deg; NaN for a run whose tilt is excessive
        or whose fit did not converge.
    """
    w = np.asarray(gyro_rps, dtype=float)[..., :2]
    r_count, n = w.shape[:2]
    mu0 = np.broadcast_to(np.asarray(mu0_rad, dtype=float), (r_count, n))
    mu1 = np.broadcast_to(np.asarray(mu1_rad, dtype=float), (r_count, n))
    lat = latitude_rad(latitude_deg, "the spin solution")
    rot = interval_rotation(mu0, mu1)
    if drift:
        if time_s is None:
            raise InputError("time_s is needed to fit a drift")
        nuisance = nuisance_design(np.broadcast_to(np.asarray(time_s, float), (r_count, n)), True)
    else:
        nuisance = None

    return azimuths_of_rotated(
        w, rot, lat, accel_mps2, max_iterations=max_iterations, nuisance=nuisance
    )


@dataclass(frozen=True)
class SpinSolution:
    """The heading from a spin and how far to trust it.

    Attributes
    ----------
    azimuth_deg : float
        Azimuth of body x at table angle 0, clockwise from true north, [0, 360) deg.
    sigma_deg : float
        1 sigma, deg: ``sigma_batch_deg`` where it exceeds ``sigma_white_deg`` beyond its
        scatter, else ``sigma_white_deg`` (:func:`reported_sigma`); times ``sigma_scale``.
    sigma_white_deg, sigma_batch_deg : float
        White-noise sigma from the residual scatter; batch estimate over :data:`BATCHES`
        stretches (see the module docstring).
    pitch_deg, roll_deg : float
    gyro_bias_dph : tuple of float
        Nuisance coefficients of the gyro fit, deg/h: (b_x, b_y) and with drift (d_x, d_y), the
        drift over the whole record.
    residual_dph : tuple of float
        RMS residual of the x and y gyros, deg/h.
    samples, dropped : int
    duration_s, sweep_deg, rate_dps : float
        Span of the samples, angle turned (signed), mean rate.
    halves_deg : tuple of float
        Azimuths of the first and the second half alone.
    halves_sigma_deg : tuple of float
    consistent : bool
        Whether the halves agree within three sigma of their difference.
    drift : bool
    sigma_scale : float
        1, or when the halves disagree the ratio of their difference to its sigma (the square
        root of chi2 for one degree of freedom), already applied to ``sigma_deg``: a heading its
        halves cannot vouch for does not keep a sigma they contradict.
    """

    azimuth_deg: float
    sigma_deg: float
    sigma_white_deg: float
    sigma_batch_deg: float
    pitch_deg: float
    roll_deg: float
    gyro_bias_dph: tuple[float, ...]
    residual_dph: tuple[float, float]
    samples: int
    dropped: int
    duration_s: float
    sweep_deg: float
    rate_dps: float
    halves_deg: tuple[float, float] | None
    halves_sigma_deg: tuple[float, float] | None
    consistent: bool | None
    drift: bool
    sigma_scale: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        out = dict(self.__dict__)
        for k, v in out.items():
            if isinstance(v, tuple):
                out[k] = list(v)
        return out


def _solve_one(
    data: SpinSamples, lat: float, drift: bool
) -> tuple[float, float, float, float, float, tuple[float, ...], tuple[float, float]]:
    """(azimuth deg, sigma white deg, sigma batch deg, pitch rad, roll rad, nuisance, rms)."""
    n = data.n
    rot = interval_rotation(data.mu0_rad, data.mu1_rad)  # (N, 2, 2)
    nuisance = nuisance_design(data.time_s, drift)  # (1, 2N, k)
    g = float(normal_gravity(lat))
    on, ou = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    f = data.accel_mps2[None, :, :2]
    theta, gamma, _, res_a, _ = fit_tilt(f, rot[None], g, nuisance=nuisance)
    if not (np.isfinite(theta[0]) and np.isfinite(gamma[0])):
        raise TiltError("the accelerometer means contradict gravity: no tilt can explain them")
    if not tilt_within_limit(theta, gamma)[0]:
        raise TiltError(
            f"pitch {math.degrees(theta[0]):.2f} deg, roll {math.degrees(gamma[0]):.2f} deg: "
            f"beyond the +-{MAX_SOLVER_TILT_DEG:g} deg a north finder levels within"
        )
    w = data.gyro_rps[None, :, :2]
    fit = fit_heading(w, rot[None], theta, gamma, on, ou, nuisance=nuisance)
    if not fit.converged[0]:
        raise GeometryError("the spin fit did not converge: is the Earth rate in the samples?")
    alpha, th, ga = float(fit.alpha[0]), float(theta[0]), float(gamma[0])
    h, _ = earth_rate_body(alpha, th, ga, on, ou)
    res_g = (
        w[0].reshape(2 * n)
        - np.einsum("nij,j->ni", rot, h).reshape(2 * n)
        - nuisance[0] @ fit.bias[0]
    )
    c_g, c_a = heading_weights(rot, nuisance[0], alpha, th, ga, on, ou, g)
    k = nuisance.shape[-1]
    dof = max(2 * n - 2 - k, 1)
    s_g2 = float(res_g @ res_g) / dof
    ra = res_a[0]
    s_a2 = float(ra @ ra) / dof
    white = math.sqrt(s_g2 * float(c_g @ c_g) + s_a2 * float(c_a @ c_a))
    z = c_g * res_g + c_a * ra
    parts = np.array_split(z.reshape(n, 2).sum(axis=1), min(BATCHES, n))
    zb = np.array([p.sum() for p in parts])
    kb = len(zb)
    batch = math.sqrt(float(zb @ zb) * kb / max(kb - 1, 1))
    rms = res_g.reshape(n, 2)
    rms_dph = tuple(float(x) / DPH for x in np.sqrt(np.mean(rms * rms, axis=0)))
    return (
        float(np.mod(-math.degrees(alpha), 360.0)),
        math.degrees(white),
        math.degrees(batch),
        th,
        ga,
        tuple(float(b) / DPH for b in fit.bias[0]),
        (rms_dph[0], rms_dph[1]),
    )


def _subset(data: SpinSamples, sel: slice) -> SpinSamples:
    return SpinSamples(
        data.gyro_rps[sel], data.accel_mps2[sel], data.mu0_rad[sel], data.mu1_rad[sel],
        data.time_s[sel],
    )  # fmt: skip


def solve_spin(data: SpinSamples, *, latitude_deg: float, drift: bool = False) -> SpinSolution:
    """Heading, tilt, sigma and the halves' consistency from the samples of one spin.

    Raises
    ------
    GeometryError
        Too few samples, or the table swept less than :data:`MIN_SWEEP_DEG` (half of it for
        each half; the halves are then not judged).
    TiltError
        Tilt beyond the levelling range.
    LatitudeError
        Latitude missing or out of range.
    """
    lat = latitude_rad(latitude_deg, "the spin solution")
    if data.n < 16:
        raise GeometryError(f"{data.n} usable spin samples: at least 16 are needed")
    if abs(data.sweep_deg) < MIN_SWEEP_DEG:
        raise GeometryError(
            f"the table turned {data.sweep_deg:+.1f} deg over the samples: a spin solution needs "
            f"at least {MIN_SWEEP_DEG:g} deg (better whole turns)"
        )
    az, white, batch, th, ga, bias, rms = _solve_one(data, lat, drift)
    halves: tuple[float, float] | None = None
    halves_sigma: tuple[float, float] | None = None
    consistent: bool | None = None
    scale = 1.0
    half = data.n // 2
    first, second = _subset(data, slice(0, half)), _subset(data, slice(half, None))
    if min(abs(first.sweep_deg), abs(second.sweep_deg)) >= MIN_SWEEP_DEG and half >= 16:
        a1 = _solve_one(first, lat, drift)
        a2 = _solve_one(second, lat, drift)
        s1, s2 = reported_sigma(a1[1], a1[2]), reported_sigma(a2[1], a2[2])
        halves, halves_sigma = (a1[0], a2[0]), (s1, s2)
        diff = (a1[0] - a2[0] + 180.0) % 360.0 - 180.0
        consistent = abs(diff) <= 3.0 * math.hypot(s1, s2)
        if not consistent:
            scale = abs(diff) / math.hypot(s1, s2)
    span = float(data.time_s[-1] - data.time_s[0]) if data.n > 1 else 0.0
    dt = float(np.median(np.diff(data.time_s))) if data.n > 1 else 0.0
    return SpinSolution(
        azimuth_deg=az,
        sigma_deg=reported_sigma(white, batch) * scale,
        sigma_white_deg=white,
        sigma_batch_deg=batch,
        pitch_deg=math.degrees(th),
        roll_deg=math.degrees(ga),
        gyro_bias_dph=bias,
        residual_dph=rms,
        samples=data.n,
        dropped=data.dropped,
        duration_s=span + dt,
        sweep_deg=data.sweep_deg,
        rate_dps=data.rate_dps,
        halves_deg=halves,
        halves_sigma_deg=halves_sigma,
        consistent=consistent,
        drift=drift,
        sigma_scale=scale,
    )


def fitted_rates(
    data: SpinSamples, solution: SpinSolution, latitude_deg: float
) -> tuple[Array, Array, Array]:
    """The spin fit on its own samples (what ``find --spin --plot`` draws), rad/s.

    Returns
    -------
    model : ndarray, shape (N, 2)
        The fitted x and y gyro means, ``R(mu) h + b`` (+ the drift when it was fitted).
    demodulated : ndarray, shape (N, 2)
        Each sample's x and y gyro less the fitted bias (and drift), turned back to table angle
        0 (``R(mu)^-1 (w - b)``): the Earth rate ``h`` plus noise, the same at every table angle
        when the model holds (a once-per-turn error shows as a ripple in it).
    h : ndarray, shape (2,)
        The fitted Earth rate on the x and y gyros at table angle 0.
    """
    lat = latitude_rad(latitude_deg, "the spin solution")
    on, ou = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    alpha = -math.radians(solution.azimuth_deg)
    h, _ = earth_rate_body(
        alpha, math.radians(solution.pitch_deg), math.radians(solution.roll_deg), on, ou
    )
    rot = interval_rotation(data.mu0_rad, data.mu1_rad)  # (N, 2, 2)
    nuisance = nuisance_design(data.time_s, solution.drift)[0]  # (2N, k)
    bias = (nuisance @ (np.asarray(solution.gyro_bias_dph, dtype=float) * DPH)).reshape(data.n, 2)
    model = np.einsum("nij,j->ni", rot, h) + bias
    # The interval means of the rotation are rotations scaled by |sinc| <= 1: the inverse is
    # the transpose over the determinant.
    det = rot[:, 0, 0] * rot[:, 1, 1] - rot[:, 0, 1] * rot[:, 1, 0]
    demodulated = np.einsum("nji,nj->ni", rot, data.gyro_rps[:, :2] - bias) / det[:, None]
    return model, demodulated, np.asarray(h, dtype=float)


def spin_weights_level(
    mu0_rad: Sequence[float] | Array,
    mu1_rad: Sequence[float] | Array,
    time_s: Sequence[float] | Array,
    latitude_deg: float,
    drift: bool = False,
    azimuth_deg: float = 0.0,
) -> tuple[Array, Array]:
    """:func:`heading_weights` of a level instrument at ``azimuth_deg`` (for the bound)."""
    lat = latitude_rad(latitude_deg, "the spin bound")
    rot = interval_rotation(np.asarray(mu0_rad, float), np.asarray(mu1_rad, float))
    nuisance = nuisance_design(np.asarray(time_s, float), drift)[0]
    return heading_weights(
        rot,
        nuisance,
        -math.radians(azimuth_deg),
        0.0,
        0.0,
        OMEGA_IE * math.cos(lat),
        OMEGA_IE * math.sin(lat),
        float(normal_gravity(lat)),
    )
