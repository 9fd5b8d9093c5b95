"""Heading kernels on arrays of runs, and the vectorised solvers built on them.

Every kernel works on arrays with a leading run axis (shape ``(R, ...)``); the scalar solvers of
:mod:`northfinder.host.heading` call the same kernels with one run and add what a single solution
needs (input checks, errors, a propagated sigma). Conventions are those of
:mod:`northfinder.host.heading`: azimuth of body x clockwise from true north, table angles
right-handed about up, specific force (a level unit reads +g on z). Angles inside the kernels are
radians; the public solvers take degrees. Gyro means may be in any unit as long as the Earth-rate
components passed in are in the same unit; accelerometer means likewise with gravity.

Excessive tilt has one behaviour everywhere: the scalar solvers raise
:class:`~northfinder.host.errors.TiltError`; the vectorised solvers return NaN for that run (and
the accuracy study counts those runs). A tilt is excessive when pitch or roll exceeds
:data:`MAX_SOLVER_TILT_DEG`, or when the accelerometer means contradict gravity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.units import (
    MAX_LATITUDE_DEG,
    OMEGA_IE,
    check_latitude_deg,
    normal_gravity,
)
from northfinder.host.errors import LatitudeError

__all__ = [
    "MAX_LATITUDE_DEG",
    "MAX_SOLVER_TILT_DEG",
    "MIN_MU_SEPARATION_DEG",
    "Eq14",
    "HeadingFit",
    "bias_design",
    "earth_rate_body",
    "eq14",
    "f0_from_two_positions",
    "fit_heading",
    "fit_tilt",
    "latitude_rad",
    "lstsq",
    "solve_least_squares_batch",
    "solve_two_position_batch",
    "table_rotation",
    "tilt_from_f0",
    "tilt_within_limit",
]

#: The table angle must differ from 0 (mod 360) by at least this much. The Earth-rate difference
#: between the positions is 2 Omega_H sin(mu/2): at 5 deg it is 23 times smaller than at 180 deg.
MIN_MU_SEPARATION_DEG = 5.0
#: Largest pitch or roll the heading solvers accept. The equations are exact at any tilt, but beyond this a north
#: finder is outside its levelling range and the accelerometer model (no cross-coupling, no
#: misalignment) stops being credible.
MAX_SOLVER_TILT_DEG = 15.0

Array = NDArray[np.float64]


def latitude_rad(latitude_deg: float | None, purpose: str) -> float:
    """Check a latitude for north finding and return it in rad.

    Raises
    ------
    LatitudeError
        Missing (the message names ``purpose``), not a finite number, outside [-90, 90] deg, or
        beyond +-:data:`MAX_LATITUDE_DEG`.
    """
    if latitude_deg is None:
        raise LatitudeError(f"latitude_deg is required for {purpose}")
    return math.radians(check_latitude_deg(latitude_deg, LatitudeError))


def table_rotation(mu_rad: ArrayLike) -> Array:
    """Horizontal block of C_m^m1 for table angles ``mu_rad``, shape ``(..., 2, 2)``."""
    mu = np.asarray(mu_rad, dtype=float)
    c, s = np.cos(mu), np.sin(mu)
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)


# ----------------------------------------------------------------------------------------------
# Tilt
# ----------------------------------------------------------------------------------------------


def tilt_from_f0(fx0: ArrayLike, fy0: ArrayLike, g: float) -> tuple[Array, Array]:
    """Pitch and roll (rad) from the horizontal specific force at table angle 0.

    A level body frame sees f = g (-sin theta, cos theta sin gamma, cos theta cos gamma). Where a
    component exceeds gravity the tilt is undefined: that run's pitch (or roll) is NaN.
    """
    s_theta = -np.asarray(fx0, dtype=float) / g
    theta = np.arcsin(np.where(np.abs(s_theta) < 1.0, s_theta, np.nan))
    s_gamma = np.asarray(fy0, dtype=float) / (g * np.cos(theta))
    gamma = np.arcsin(np.where(np.abs(s_gamma) < 1.0, s_gamma, np.nan))
    return theta, gamma


def f0_from_two_positions(
    accel0: ArrayLike, accel1: ArrayLike, mu_rad: ArrayLike
) -> tuple[Array, Array]:
    """Horizontal specific force at table angle 0 from two positions, bias-free (paper eqs. 12, 13).

    With S = g sin(theta), C = g cos(theta) sin(gamma) and d = f(0) - f(mu):
    -dfx = (1 - cos mu) S + sin mu C and dfy = -sin mu S + (1 - cos mu) C; the result is
    (-S, C), the input of :func:`tilt_from_f0`.

    Parameters
    ----------
    accel0, accel1 : array_like, shape (..., 2) or (..., 3)
        Accelerometer means at the two positions.
    mu_rad : array_like, shape (...)
        Table angle between the positions, rad.
    """
    a0 = np.asarray(accel0, dtype=float)
    a1 = np.asarray(accel1, dtype=float)
    mu = np.asarray(mu_rad, dtype=float)
    c, s = np.cos(mu), np.sin(mu)
    dfx, dfy = a0[..., 0] - a1[..., 0], a0[..., 1] - a1[..., 1]
    det = 2.0 * (1.0 - c)
    s_pitch = ((1.0 - c) * -dfx - s * dfy) / det
    c_roll = (s * -dfx + (1.0 - c) * dfy) / det
    return -s_pitch, c_roll


def tilt_within_limit(theta: ArrayLike, gamma: ArrayLike) -> NDArray[np.bool_]:
    """True where pitch and roll (rad) are defined and within +-:data:`MAX_SOLVER_TILT_DEG`."""
    t = np.abs(np.degrees(np.asarray(theta, dtype=float)))
    r = np.abs(np.degrees(np.asarray(gamma, dtype=float)))
    return (t <= MAX_SOLVER_TILT_DEG) & (r <= MAX_SOLVER_TILT_DEG)


# ----------------------------------------------------------------------------------------------
# Two positions
# ----------------------------------------------------------------------------------------------


class Eq14(NamedTuple):
    """Paper eq. 14 for a set of runs: alpha = atan2(num, den).

    ``num = n1 dwx + n2 dwy + n0`` and ``den = d1 dwx + d2 dwy + d0`` with dw = w(0) - w(mu);
    ``n`` and ``d`` hold (n1, n2, n0) and (d1, d2, d0) along their last axis.
    """

    num: Array
    den: Array
    n: Array
    d: Array

    @property
    def alpha(self) -> Array:
        """The model's counter-clockwise angle, rad."""
        return np.arctan2(self.num, self.den)


def eq14(
    gyro0: ArrayLike,
    gyro1: ArrayLike,
    mu_rad: ArrayLike,
    theta: ArrayLike,
    gamma: ArrayLike,
    omega_u: float,
) -> Eq14:
    """Paper eq. 14 from gyro means at two positions; level (theta = gamma = 0) it is eq. 15.

    Parameters
    ----------
    gyro0, gyro1 : array_like, shape (..., 2) or (..., 3)
        Gyro means at the two positions (eq. 15 is unit-free; eq. 14 needs ``omega_u`` in the
        same unit).
    mu_rad, theta, gamma : array_like, shape (...)
        Table angle between the positions, pitch and roll, rad.
    omega_u : float
        Vertical Earth rate in the unit of the gyro means (0 for eq. 15).
    """
    g0 = np.asarray(gyro0, dtype=float)
    g1 = np.asarray(gyro1, dtype=float)
    th = np.asarray(theta, dtype=float)
    ga = np.asarray(gamma, dtype=float)
    mu = np.asarray(mu_rad, dtype=float)
    st, ct, sg, cg = np.sin(th), np.cos(th), np.sin(ga), np.cos(ga)
    c, s = np.cos(mu), np.sin(mu)
    n1 = st * sg + s * ct - c * st * sg
    n2 = -(ct - c * ct - s * st * sg)
    n0 = 2.0 * omega_u * sg * (1.0 - c)
    d1 = -(c - 1.0) * cg
    d2 = s * cg
    d0 = -2.0 * omega_u * st * (c - 1.0) * cg
    dwx, dwy = g0[..., 0] - g1[..., 0], g0[..., 1] - g1[..., 1]
    num = n1 * dwx + n2 * dwy + n0
    den = d1 * dwx + d2 * dwy + d0
    shape = num.shape
    return Eq14(
        num,
        den,
        np.stack([np.broadcast_to(v, shape) for v in (n1, n2, n0)], -1),
        np.stack([np.broadcast_to(v, shape) for v in (d1, d2, d0)], -1),
    )


def solve_two_position_batch(
    gyro0: ArrayLike,
    gyro1: ArrayLike,
    mu_deg: ArrayLike,
    *,
    latitude_deg: float,
    accel0: ArrayLike | None = None,
    accel1: ArrayLike | None = None,
) -> Array:
    """Azimuths of many two-position runs (paper eqs. 12-14, or eq. 15 without accelerometers).

    The vectorised form of :func:`northfinder.host.heading.solve_two_position` (rad/s and m/s^2).

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
        Azimuth of body x at the first position, [0, 360) deg; NaN for a run whose tilt is
        excessive (see the module docstring).
    """
    g0 = np.asarray(gyro0, dtype=float)
    g1 = np.asarray(gyro1, dtype=float)
    mu = np.radians(np.broadcast_to(np.asarray(mu_deg, dtype=float), g0.shape[:-1]))
    lat = latitude_rad(latitude_deg, "the solution")
    if accel0 is None or accel1 is None:
        zero = np.zeros(mu.shape)
        return np.mod(-np.degrees(eq14(g0, g1, mu, zero, zero, 0.0).alpha), 360.0)
    g = float(normal_gravity(lat))
    theta, gamma = tilt_from_f0(*f0_from_two_positions(accel0, accel1, mu), g)
    az = np.mod(-np.degrees(eq14(g0, g1, mu, theta, gamma, OMEGA_IE * math.sin(lat)).alpha), 360.0)
    return np.where(tilt_within_limit(theta, gamma), az, np.nan)


# ----------------------------------------------------------------------------------------------
# Least squares
# ----------------------------------------------------------------------------------------------


def lstsq(
    a: Array, b: Array, weights: Array | None = None, *, factor: tuple[Array, Array] | None = None
) -> tuple[Array, Array, Array]:
    """Weighted least squares for stacks of small systems, by QR of the weighted design.

    Parameters
    ----------
    a : ndarray, shape (R, M, P)
        Design matrices.
    b : ndarray, shape (R, M)
        Observations.
    weights : ndarray, shape (R, M) or (M,), optional
        Weight of each equation (1 / sigma); default 1.
    factor : (q, r), optional
        ``numpy.linalg.qr`` of the weighted design, when the caller has it already (one
        factorisation for several right-hand sides of the same design).

    Returns
    -------
    x : ndarray, shape (R, P)
    residuals : ndarray, shape (R, M)
        ``b - a x``, unweighted.
    normal_inv : ndarray, shape (R, P, P)
        (A_w^T A_w)^-1, the covariance of x for unit-weight noise.
    """
    if weights is None:
        bw = b
        q, r = np.linalg.qr(a) if factor is None else factor
    else:
        bw = b * weights
        q, r = np.linalg.qr(a * weights[..., None]) if factor is None else factor
    x = np.linalg.solve(r, np.einsum("rmp,rm->rp", q, bw)[..., None])[..., 0]
    residuals = b - np.einsum("rmp,rp->rm", a, x)
    rinv = np.linalg.inv(r)
    return x, residuals, rinv @ np.swapaxes(rinv, -1, -2)


def earth_rate_body(
    alpha: ArrayLike, theta: ArrayLike, gamma: ArrayLike, omega_n: float, omega_u: float
) -> tuple[Array, Array]:
    """Horizontal Earth rate in the body frame at table angle 0, and its derivatives.

    Returns
    -------
    h : ndarray, shape (..., 2)
        Rate seen by the x and y gyros, in the unit of ``omega_n`` and ``omega_u``.
    jac : ndarray, shape (..., 2, 3)
        dh / d(alpha, theta, gamma).
    """
    a = np.asarray(alpha, dtype=float)
    sa, ca = np.sin(a), np.cos(a)
    th = np.asarray(theta, dtype=float)
    ga = np.asarray(gamma, dtype=float)
    st, ct, sg, cg = np.sin(th), np.cos(th), np.sin(ga), np.cos(ga)
    on, ou = omega_n, omega_u
    h = np.stack([on * ca * ct - ou * st, on * (ca * st * sg - sa * cg) + ou * ct * sg], -1)
    zero = np.zeros(np.broadcast_shapes(a.shape, th.shape, ga.shape))
    jac = np.stack(
        [
            np.stack([-on * sa * ct + zero, -on * ca * st - ou * ct + zero, zero], -1),
            np.stack(
                [
                    -on * (sa * st * sg + ca * cg) + zero,
                    on * ca * ct * sg - ou * st * sg + zero,
                    on * (ca * st * cg + sa * sg) + ou * ct * cg + zero,
                ],
                -1,
            ),
        ],
        -2,
    )
    return h, jac


@dataclass(frozen=True)
class HeadingFit:
    """Result of :func:`fit_heading` for R runs.

    Attributes
    ----------
    alpha : ndarray, shape (R,)
        The model's counter-clockwise angle, rad (azimuth = -alpha mod 360).
    bias : ndarray, shape (R, k)
        x and y gyro biases, in the unit of the means.
    converged : ndarray of bool, shape (R,)
        Whether the last alpha step fell below the tolerance.
    """

    alpha: Array
    bias: Array
    converged: NDArray[np.bool_]


def bias_design(r_count: int, n: int) -> Array:
    """Nuisance design of a constant x and y bias: (R, 2N, 2), rows x, y of each mean in turn."""
    return np.broadcast_to(np.eye(2), (r_count, n, 2, 2)).reshape(r_count, 2 * n, 2)


@dataclass(frozen=True)
class LinearDesign:
    """The unweighted design of ``w_i = R(mu_i) u + nuisance`` and its QR factorisation: the tilt
    and the heading fits of one set of table angles share it."""

    a: Array
    qr: tuple[Array, Array]


def linear_design(rot: Array, nuisance: Array | None = None) -> LinearDesign:
    """:class:`LinearDesign` of the table rotations ``rot`` (R, N, 2, 2) and the nuisance design."""
    a = _linear_design(rot, nuisance)
    q, r = np.linalg.qr(a)
    return LinearDesign(a, (q, r))


def _linear_design(rot: Array, nuisance: Array | None = None) -> Array:
    """Design of w_i = R(mu_i) u + nuisance for every run: (R, N, 2, 2) -> (R, 2N, 2 + k)."""
    r_count, n = rot.shape[:2]
    nu = bias_design(r_count, n) if nuisance is None else nuisance
    return np.concatenate([rot.reshape(r_count, 2 * n, 2), nu], axis=-1)


def fit_tilt(
    accel: Array,
    rot: Array,
    g: float,
    weights: Array | None = None,
    nuisance: Array | None = None,
    *,
    design: LinearDesign | None = None,
) -> tuple[Array, Array, Array, Array, Array]:
    """Tilt and accelerometer biases from ``f_i = R(mu_i) f0 + b_a`` (linear) for every run.

    Parameters
    ----------
    accel : ndarray, shape (R, N, 2)
        Accelerometer means, in the unit of ``g``.
    rot : ndarray, shape (R, N, 2, 2)
        :func:`table_rotation` of the table angles.
    g : float
        Gravity in the unit of the means.
    weights : ndarray, shape (R, 2N), optional
        1 / sigma of each mean (x, y of each position in turn).
    nuisance : ndarray, shape (R, 2N, k), optional
        Design of what else the means hold (default :func:`bias_design`: a constant bias each).
    design : LinearDesign, optional
        :func:`linear_design` of ``rot`` and ``nuisance`` when the caller has it (unweighted fits).

    Returns
    -------
    theta, gamma : ndarray, shape (R,)
        Pitch and roll, rad (NaN where the fit contradicts gravity).
    x : ndarray, shape (R, 2 + k)
        (f0x, f0y, then the nuisance coefficients: bias_x, bias_y by default).
    residuals : ndarray, shape (R, 2N)
    normal_inv : ndarray, shape (R, 4, 4)
        Unit-weight covariance of x.
    """
    r_count, n = accel.shape[:2]
    b = accel.reshape(r_count, 2 * n)
    if design is None or weights is not None:
        x, res, ninv = lstsq(_linear_design(rot, nuisance), b, weights)
    else:
        x, res, ninv = lstsq(design.a, b, factor=design.qr)
    theta, gamma = tilt_from_f0(x[:, 0], x[:, 1], g)
    return theta, gamma, x, res, ninv


def fit_heading(
    gyro: Array,
    rot: Array,
    theta: Array,
    gamma: Array,
    omega_n: float,
    omega_u: float,
    weights: Array | None = None,
    *,
    max_iterations: int = 50,
    tolerance: float = 1e-12,
    nuisance: Array | None = None,
    design: LinearDesign | None = None,
) -> HeadingFit:
    """Heading and gyro biases of every run: least squares of ``w_i = R(mu_i) h(alpha) + b``.

    Only alpha enters non-linearly, so the biases are projected out (for a given alpha they are
    a linear fit) and alpha is found by Newton's method on the projected cost, starting from the
    unconstrained linear fit ``w_i = R(mu_i) u + b`` (alpha from u given the tilt). Newton, not
    Gauss-Newton: with noise comparable to the Earth rate (MEMS gyros) Gauss-Newton's step
    overshoots and oscillates about the minimum; the residual term of the curvature removes that
    (where that curvature is not positive, far from a minimum, the Gauss-Newton step is taken).
    A run has converged when its alpha step is below ``tolerance`` rad; converged runs are no
    longer changed.

    The cost and its derivatives are quadratic forms in the 2-vector h(alpha) (with P the
    projection that removes the nuisance terms, X the weighted rotations, y the weighted means:
    e = P (y - X h)), so the means enter once, through G = (P X)^T (P X) and c = (P X)^T y, and
    each Newton step costs the same whatever the number of means (a spin fits every sample).

    Parameters
    ----------
    gyro : ndarray, shape (R, N, 2)
        x and y gyro means, in the unit of ``omega_n``.
    rot : ndarray, shape (R, N, 2, 2)
        :func:`table_rotation` of the table angles.
    theta, gamma : ndarray, shape (R,)
        Pitch and roll, rad (finite).
    omega_n, omega_u : float
        Horizontal and vertical Earth rate in the unit of the gyro means.
    weights : ndarray, shape (R, 2N), optional
        1 / sigma of each mean.
    max_iterations : int
        Newton steps at most.
    tolerance : float
        Convergence threshold on the alpha step, rad.
    nuisance : ndarray, shape (R, 2N, k), optional
        Design of what else the means hold (default :func:`bias_design`: a constant bias each);
        the fit's ``bias`` then holds its k coefficients.
    design : LinearDesign, optional
        :func:`linear_design` of ``rot`` and ``nuisance`` when the caller has it (unweighted fits).
    """
    r_count, n = gyro.shape[:2]
    w = np.ones((r_count, 2 * n)) if weights is None else np.broadcast_to(weights, (r_count, 2 * n))
    if design is None or weights is not None:
        x_lin, _, _ = lstsq(_linear_design(rot, nuisance), gyro.reshape(r_count, 2 * n), weights)
    else:
        x_lin, _, _ = lstsq(design.a, gyro.reshape(r_count, 2 * n), factor=design.qr)
    st, ct, sg, cg = np.sin(theta), np.cos(theta), np.sin(gamma), np.cos(gamma)
    # h = M (cos a, sin a) + c0 with M = [[on ct, 0], [on st sg, -on cg]]: solve for (cos a, sin a).
    c0 = np.stack([-omega_u * st, omega_u * ct * sg], -1)
    u0 = (x_lin[:, 0] - c0[:, 0]) / (omega_n * ct)
    u1 = -((x_lin[:, 1] - c0[:, 1]) - omega_n * st * sg * u0) / (omega_n * cg)
    alpha = np.arctan2(u1, u0)
    # Weighted bias design B (R, 2N, 2) and the projection P v = v - B (B^T B)^-1 B^T v.
    nu = bias_design(r_count, n) if nuisance is None else nuisance
    b_w = nu * w[..., None]
    b_wt = np.swapaxes(b_w, 1, 2)  # (R, k, 2N)
    b_normal = b_wt @ b_w  # (R, k, k)

    def nuisance_fit(v: Array) -> Array:
        """(B^T B)^-1 B^T v, (R, k)."""
        return np.linalg.solve(b_normal, (b_wt @ v[..., None]))[..., 0]

    def project(v: Array) -> Array:
        return v - (b_w @ nuisance_fit(v)[..., None])[..., 0]

    def weighted(v: Array) -> Array:
        return v.reshape(r_count, 2 * n) * w

    # e = P (y - X h): slope d1.e = dh.(c - G h), Gauss-Newton curvature d1.d1 = dh.G dh, and
    # the residual term d2.e with d2 = P X (c0 - h) (h'' = c0 - h).
    x_w = rot.reshape(r_count, 2 * n, 2) * w[..., None]  # X, (R, 2N, 2)
    px = np.stack([project(x_w[..., 0]), project(x_w[..., 1])], -1)  # P X
    gram = np.einsum("rmi,rmj->rij", px, px)  # G, (R, 2, 2)
    corr = np.einsum("rmi,rm->ri", px, weighted(gyro))  # c, (R, 2)
    converged = np.zeros(r_count, dtype=bool)
    for _ in range(int(max_iterations)):
        h, dh = earth_rate_body(alpha, theta, gamma, omega_n, omega_u)
        d = dh[..., 0]
        fit = corr - np.einsum("rij,rj->ri", gram, h)  # X^T P e
        slope = np.sum(d * fit, axis=1)
        curv_gn = np.einsum("ri,rij,rj->r", d, gram, d)
        curv = curv_gn - np.sum((c0 - h) * fit, axis=1)
        step = slope / np.where(curv > 0.0, curv, curv_gn)
        active = ~converged
        alpha = np.where(active, alpha + step, alpha)
        converged |= np.abs(step) < tolerance
        if converged.all():
            break
    h, _ = earth_rate_body(alpha, theta, gamma, omega_n, omega_u)
    bias = nuisance_fit(weighted(gyro - np.einsum("rnij,rj->rni", rot, h)))
    return HeadingFit(alpha, bias, converged)


def solve_least_squares_batch(
    gyro_means: ArrayLike,
    mu_deg: ArrayLike,
    *,
    latitude_deg: float,
    accel_means: ArrayLike | None = None,
    max_iterations: int = 50,
) -> Array:
    """Azimuths of many multi-position runs by least squares (gyro biases estimated).

    The vectorised form of :func:`northfinder.host.heading.solve_multi_position` with equal
    weights: tilt and accelerometer biases from ``f_i = R(mu_i) f0 + b_a`` (linear), then the
    heading from ``w_i = R(mu_i) h(alpha, tilt) + b`` (:func:`fit_heading`).

    Parameters
    ----------
    gyro_means : array_like, shape (R, N, 2) or (R, N, 3)
        Gyro window means, rad/s.
    mu_deg : array_like, shape (R, N) or (N,)
        Table angles, deg.
    latitude_deg : float
    accel_means : array_like, shape (R, N, 2) or (R, N, 3), optional
        Accelerometer window means, m/s^2; without them the instrument is taken as level.
    max_iterations : int
        Newton steps at most (the start is close: a few usually suffice).

    Returns
    -------
    ndarray, shape (R,)
        Azimuth of body x at table angle 0, [0, 360) deg; NaN for a run whose tilt is excessive
        or whose fit did not converge.
    """
    w = np.asarray(gyro_means, dtype=float)[..., :2]
    r_count, n = w.shape[:2]
    mu = np.radians(np.broadcast_to(np.asarray(mu_deg, dtype=float), (r_count, n)))
    lat = latitude_rad(latitude_deg, "the solution")
    rot = table_rotation(mu)  # (R, N, 2, 2)
    return azimuths_of_rotated(w, rot, lat, accel_means, max_iterations=max_iterations)


def azimuths_of_rotated(
    gyro: Array,
    rot: Array,
    lat_rad: float,
    accel: ArrayLike | None,
    *,
    max_iterations: int = 50,
    nuisance: Array | None = None,
) -> Array:
    """Azimuths of many runs from horizontal gyro readings and the table rotation of each:
    tilt from the accelerometers (level without them), then the heading (:func:`fit_tilt`,
    :func:`fit_heading`). The one tail of the window solver and the spin solver.

    Parameters
    ----------
    gyro : ndarray, shape (R, N, 2)
        Horizontal gyro readings, rad/s.
    rot : ndarray, shape (R, N, 2, 2)
        The table rotation of each reading.
    lat_rad : float
    accel : array_like, shape (R, N, 2) or (R, N, 3), or None
        Accelerometer readings, m/s^2.
    nuisance : ndarray, optional
        Extra columns fitted beside the biases (drift terms).

    Returns
    -------
    ndarray, shape (R,)
        [0, 360) deg; NaN for a run whose tilt is excessive or whose fit did not converge.
    """
    r_count = gyro.shape[0]
    if accel is not None:
        f = np.asarray(accel, dtype=float)[..., :2]
        design = linear_design(rot, nuisance)
        g = float(normal_gravity(lat_rad))
        theta, gamma, _, _, _ = fit_tilt(f, rot, g, nuisance=nuisance, design=design)
        ok = tilt_within_limit(theta, gamma)
        # Rejected runs are solved level (finite numbers throughout) and masked at the end.
        theta, gamma = np.where(ok, theta, 0.0), np.where(ok, gamma, 0.0)
    else:
        design = None
        theta = gamma = np.zeros(r_count)
        ok = np.ones(r_count, dtype=bool)
    fit = fit_heading(
        gyro,
        rot,
        theta,
        gamma,
        OMEGA_IE * math.cos(lat_rad),
        OMEGA_IE * math.sin(lat_rad),
        max_iterations=max_iterations,
        nuisance=nuisance,
        design=design,
    )
    az = np.mod(-np.degrees(fit.alpha), 360.0)
    return np.where(ok & fit.converged, az, np.nan)
