"""Static alignment without table rotation: Sage-Husa adaptive Kalman filter (10 states).

A strapdown gyro + accelerometer triad at rest finds north by gyrocompassing: an analytic coarse
alignment from the mean specific force and Earth rate, then a Kalman filter that watches the
velocity computed by the strapdown mechanisation (truly zero) and estimates the misalignment.

Frames
------
The filter works in **East-North-Up** (as the source paper does), with states

    x = (dV_E, dV_N, phi_E, phi_N, phi_U, bias_ax, bias_ay, eps_x, eps_y, eps_z)

(m/s, rad, m/s^2, rad/s): velocity errors, misalignment of the computed navigation frame
(C_b^n' = (I - [phi x]) C_b^n), accelerometer biases of body x and y and gyro biases of body
x, y, z. The body frame is the instrument's (x reference axis, y left, z up); inputs are body
rates and specific force in that frame. The results are converted to the project's conventions:
azimuth of body x clockwise from north, pitch and roll as in C_n^b of the North-West-Up frame.

Filter
------
Error model (static, omega_in = omega_ie = Omega (0, cos L, sin L) in ENU, f^n = (0, 0, g)):
dV' = f^n x phi - 2 omega_ie x dV + C_b^n bias_a,  phi' = -omega_ie x phi - C_b^n eps
(+ the small dV/R terms). Discrete with Phi = exp(F dt). The observation is the horizontal
velocity of the mechanisation. The measurement noise R is adapted (Sage-Husa):

    R_{k+1} = (1 - d_k) R_k + d_k (v v^T - H P_{k+1,k} H^T),  d_k = (1 - b) / (1 - b^(k+1))

with forgetting factor b = 0.95. Attitude and velocity estimates are fed back into the
mechanisation after every update (closed loop); the bias estimates stay in the state.

Settings of the source paper, and how they are read here:

- P0 = diag((0.1 m/s)^2 x2, (1 deg)^2 x3, (0.1 mg)^2 x2, (0.1 deg/h)^2 x3).
- Q printed as diag((0.05 deg/h)^2 x3, (50 ug)^2 x2, 0 x5): the order in print does not follow
  the state order; read as accelerometer white noise (50 ug)^2 on the two velocity states and
  gyro white noise (0.05 deg/h)^2 on the three attitude states, biases constant. The values are
  taken as spectral densities (per Hz: 50 ug/sqrt(Hz), 0.05 deg/h/sqrt(Hz)) and discretised as
  Q dt.
- R0 = diag((0.01 m/s)^2 x2), b = 0.95.

The Sage-Husa estimate can lose positive definiteness (the velocity of a resting instrument has
almost no measurement noise); its diagonal is kept at or above ``r_floor``. The covariance update
uses the Joseph form for the same reason.

Disturbances (seed 001: an engine running, people on the vehicle) put far more noise into the
gyro and accelerometer records than the paper's Q, which describes the sensors alone. The Sage-
Husa R absorbs what reaches the innovations, but the covariance of the azimuth stays at the
quiet value, and its error grows by an order of magnitude: 0.44 deg claimed against several
degrees. So the filter reads the record's own noise density (the Allan deviation of the block
means at :data:`NOISE_TAU_S`, where a folded vibration line has averaged out and impulses have
not) and, where it exceeds the settings, uses it for Q and for the coarse azimuth's initial
uncertainty (``KalmanSettings.measured_noise``); the result then says that it is not the quiet
model's (``consistent`` False, with ``notes``). Predicted sigmas come from P: with gyro biases
unobservable at rest, the azimuth sigma settles near the combination of the P0 terms
sigma(phi_U) and sigma(eps_E) / (Omega cos L), about 0.45 deg at 40 deg latitude with the
paper's values. That P0 treats the initial azimuth error as independent of the east gyro bias,
but the coarse alignment's error *is* mostly eps_E / (Omega cos L); so when the biases are as
large as P0 says, the predicted sigma is about 10 % optimistic (0.45 instead of 0.50 deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.units import DEG, DPH, G0, OMEGA_IE, normal_gravity
from northfinder.host.allan import allan_deviation
from northfinder.host.errors import AlignmentError, InputError
from northfinder.host.kernels import latitude_rad

__all__ = [
    "ALIGNMENT_STATES",
    "NOISE_RATIO_LIMIT",
    "NOISE_TAU_S",
    "PAPER_SETTINGS",
    "R_RATIO_LIMIT",
    "AlignmentResult",
    "KalmanSettings",
    "coarse_alignment",
    "measured_noise_density",
    "sage_husa_alignment",
]

#: State names in filter order (ENU).
ALIGNMENT_STATES: tuple[str, ...] = (
    "dV_E",
    "dV_N",
    "phi_E",
    "phi_N",
    "phi_U",
    "bias_ax",
    "bias_ay",
    "eps_x",
    "eps_y",
    "eps_z",
)

_EARTH_RADIUS = 6378137.0
#: ENU -> NWU: N = y_enu, W = -x_enu, U = z_enu.
_NWU_FROM_ENU = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class KalmanSettings:
    """Initial covariance, noise densities and adaptation of the alignment filter (SI units).

    Attributes
    ----------
    p0_sigma : tuple of 10 float
        1-sigma of the initial state, filter order (m/s, rad, m/s^2, rad/s).
    accel_noise_density : float
        Accelerometer white noise on the velocity states, m/s^2/sqrt(Hz).
    gyro_noise_density : float
        Gyro white noise on the attitude states, rad/s/sqrt(Hz).
    r0_sigma : float
        Initial 1-sigma of the velocity observation, m/s.
    forgetting : float
        Sage-Husa forgetting factor b, 0 < b < 1.
    adaptive : bool
        False runs a conventional Kalman filter with R fixed at R0.
    r_floor_sigma : float
        Lower bound on the adapted observation 1-sigma, m/s.
    measured_noise : bool
        Raise the noise densities, and the initial azimuth uncertainty they imply, to what the
        record itself shows when that is more (see :func:`sage_husa_alignment`); False runs the
        filter with the settings as they are.
    """

    p0_sigma: tuple[float, ...] = (
        0.1,
        0.1,
        1.0 * DEG,
        1.0 * DEG,
        1.0 * DEG,
        0.1e-3 * G0,
        0.1e-3 * G0,
        0.1 * DPH,
        0.1 * DPH,
        0.1 * DPH,
    )
    accel_noise_density: float = 50e-6 * G0
    gyro_noise_density: float = 0.05 * DPH
    r0_sigma: float = 0.01
    forgetting: float = 0.95
    adaptive: bool = True
    r_floor_sigma: float = 1e-3
    measured_noise: bool = True


#: The source paper's settings.
PAPER_SETTINGS = KalmanSettings()


@dataclass(frozen=True)
class AlignmentResult:
    """Result of a static alignment.

    Attributes
    ----------
    azimuth_deg : float
        Azimuth of body x, clockwise from true north, [0, 360) deg.
    pitch_deg, roll_deg : float
        Attitude in the project's convention (z-y-x from North-West-Up), deg.
    sigma_deg : float
        Predicted 1-sigma of the azimuth (from the filter covariance of phi_U), deg.
    level_sigma_deg : tuple of float
        Predicted 1-sigma of the tilt about east and north, deg.
    gyro_bias : ndarray, shape (3,)
        Estimated gyro biases of body x, y, z, rad/s.
    accel_bias : ndarray, shape (2,)
        Estimated accelerometer biases of body x, y, m/s^2.
    coarse_azimuth_deg : float
        Azimuth of the analytic coarse alignment the filter started from, deg.
    times_s : ndarray, shape (K,)
        Time of each filter step from the start of the record, s.
    azimuth_history_deg, sigma_history_deg : ndarray, shape (K,)
        Azimuth and its predicted sigma after each step, deg.
    gyro_noise_density, accel_noise_density : float
        Noise densities the filter used (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)): the settings', or
        the record's own when larger.
    noise_ratio : tuple of float
        The record's gyro and accelerometer noise over the settings' (1 when quiet).
    consistent : bool
        False when the record is noisier than the settings by more than
        :data:`NOISE_RATIO_LIMIT` or the adapted measurement noise ends far above its floor:
        disturbances the filter's model does not describe. ``sigma_deg`` then covers the noise
        that was measured, but the result cannot be vouched for as the model's.
    notes : tuple of str
        Why ``consistent`` is False, in words.
    """

    azimuth_deg: float
    pitch_deg: float
    roll_deg: float
    sigma_deg: float
    level_sigma_deg: tuple[float, float]
    gyro_bias: NDArray[np.float64] = field(repr=False)
    accel_bias: NDArray[np.float64] = field(repr=False)
    coarse_azimuth_deg: float = field(repr=False)
    times_s: NDArray[np.float64] = field(repr=False)
    azimuth_history_deg: NDArray[np.float64] = field(repr=False)
    sigma_history_deg: NDArray[np.float64] = field(repr=False)
    gyro_noise_density: float = field(default=math.nan, repr=False)
    accel_noise_density: float = field(default=math.nan, repr=False)
    noise_ratio: tuple[float, float] = (1.0, 1.0)
    consistent: bool = True
    notes: tuple[str, ...] = ()


#: Cluster time at which the record's own noise density is read, s.
NOISE_TAU_S = 5.0
#: Record noise over the settings' beyond which a result is flagged as not the model's.
NOISE_RATIO_LIMIT = 3.0
#: Adapted measurement noise over its floor (1-sigma) beyond which the same holds.
R_RATIO_LIMIT = 3.0


def measured_noise_density(
    blocks: NDArray[np.float64], dt: float, tau_s: float = NOISE_TAU_S
) -> float:
    """White-noise density (unit/sqrt(Hz)) of block means ``blocks`` (K, axes) spaced ``dt`` s
    apart, averaged over the axes: ``sigma_A(tau) sqrt(tau)`` at the cluster time ``tau_s``.

    What matters to an alignment that averages for minutes is the noise at long times: a
    vibration line folded into the blocks averages out by a few seconds, impulses and white
    noise do not, and a slow drift has not yet risen there.
    """
    tau = min(tau_s, dt * (blocks.shape[0] // 3))
    taus, adev = allan_deviation(blocks, 1.0 / dt, [tau])
    return math.sqrt(float(np.mean(np.square(adev))) * float(taus[0]))


def _skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rotation(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """exp([v x]) by Rodrigues' formula (exactly orthonormal)."""
    angle = float(np.linalg.norm(v))
    k = _skew(v)
    if angle < 1e-12:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + math.sin(angle) / angle * k + (1.0 - math.cos(angle)) / angle**2 * (k @ k)


def _enu_to_attitude(c_bn: NDArray[np.float64]) -> tuple[float, float, float]:
    """(azimuth deg, pitch deg, roll deg) of the project's convention from C_b^n in ENU."""
    c_nb = (_NWU_FROM_ENU @ c_bn).T  # C_n^b with n = North-West-Up
    alpha = math.atan2(c_nb[0, 1], c_nb[0, 0])
    pitch = math.atan2(-c_nb[0, 2], math.hypot(c_nb[1, 2], c_nb[2, 2]))
    roll = math.atan2(c_nb[1, 2], c_nb[2, 2])
    return (-math.degrees(alpha)) % 360.0, math.degrees(pitch), math.degrees(roll)


def coarse_alignment(
    gyro_mean: ArrayLike, accel_mean: ArrayLike
) -> tuple[NDArray[np.float64], float, float, float]:
    """Analytic alignment from mean body rate and specific force (instrument at rest).

    Up is along the specific force, east along omega x up, north = up x east.

    Parameters
    ----------
    gyro_mean : array_like, shape (3,)
        Mean body rate, rad/s.
    accel_mean : array_like, shape (3,)
        Mean specific force, m/s^2.

    Returns
    -------
    c_bn : ndarray, shape (3, 3)
        C_b^n with n = East-North-Up.
    azimuth_deg, pitch_deg, roll_deg : float
        The same attitude in the project's convention.
    """
    w = np.asarray(gyro_mean, dtype=float)
    f = np.asarray(accel_mean, dtype=float)
    up = f / np.linalg.norm(f)
    east = np.cross(w, up)
    norm = np.linalg.norm(east)
    if norm == 0.0 or not math.isfinite(norm):
        raise AlignmentError("coarse alignment: the Earth rate is parallel to gravity or zero")
    east /= norm
    north = np.cross(up, east)
    c_bn = np.stack([east, north, up])
    return (c_bn, *_enu_to_attitude(c_bn))


def _block_means(data: NDArray[np.float64], block: int) -> NDArray[np.float64]:
    k = data.shape[0] // block
    return data[: k * block].reshape(k, block, data.shape[1]).mean(axis=1)


def sage_husa_alignment(
    gyro: ArrayLike,
    accel: ArrayLike,
    fs_hz: float,
    latitude_deg: float,
    *,
    settings: KalmanSettings = PAPER_SETTINGS,
    filter_rate_hz: float = 10.0,
    coarse_s: float = 20.0,
) -> AlignmentResult:
    """Static alignment of a resting triad by a Sage-Husa adaptive Kalman filter.

    Needs no table rotation: the instrument stays still for the whole record.

    Parameters
    ----------
    gyro : array_like, shape (N, 3)
        Body rates (x, y, z), rad/s, sampled at ``fs_hz``.
    accel : array_like, shape (N, 3)
        Specific force (x, y, z), m/s^2 (z reads about +g when level).
    fs_hz : float
        Sample rate, Hz.
    latitude_deg : float
        Latitude, deg.
    settings : KalmanSettings
        P0, noise densities, R0 and adaptation; default the source paper's.
    filter_rate_hz : float
        Rate of the mechanisation and filter steps; the samples are averaged into blocks of
        ``fs_hz / filter_rate_hz`` (an integer). At rest nothing is lost by this: the averaged
        increments carry the same Earth-rate and gravity information.
    coarse_s : float
        Length of the record's beginning used for the analytic coarse alignment, s.

    Returns
    -------
    AlignmentResult

    Raises
    ------
    InputError
        Wrong shapes, non-finite samples, bad rates, record too short.
    LatitudeError
        Latitude not finite or too close to a pole.
    AlignmentError
        The coarse alignment is undefined or the filter diverges.
    """
    gyro_blocks, accel_blocks, lat, dt, n_coarse = _filter_blocks(
        gyro, accel, fs_hz, latitude_deg, settings, filter_rate_hz, coarse_s
    )
    n_steps = gyro_blocks.shape[0]
    omega_n, omega_u = OMEGA_IE * math.cos(lat), OMEGA_IE * math.sin(lat)
    omega_ie = np.array([0.0, omega_n, omega_u])
    g = float(normal_gravity(lat))
    gravity_n = np.array([0.0, 0.0, -g])
    rot_earth = _rotation(-omega_ie * dt)

    c_bn, coarse_az, _, _ = coarse_alignment(
        gyro_blocks[:n_coarse].mean(axis=0), accel_blocks[:n_coarse].mean(axis=0)
    )

    s = settings
    x = np.zeros(10)
    p, q, r, gyro_density, accel_density, ratio = _filter_noise(
        s, gyro_blocks, accel_blocks, dt, n_coarse, omega_n
    )
    r_floor = s.r_floor_sigma**2
    v = np.zeros(2)

    start = n_coarse
    times = np.arange(start + 1, n_steps + 1, dtype=np.float64) * dt
    az_hist = np.empty(n_steps - start)
    sig_hist = np.empty(n_steps - start)
    for k, i in enumerate(range(start, n_steps)):
        # Mechanisation over one step: attitude by the gyros less Earth rate, velocity by the
        # specific force less gravity and Coriolis (horizontal channels only).
        c_old = c_bn
        c_bn = rot_earth @ c_bn @ _rotation(gyro_blocks[i] * dt)
        f_n = 0.5 * (c_old + c_bn) @ accel_blocks[i] + gravity_n
        coriolis = 2.0 * np.cross(omega_ie, np.array([v[0], v[1], 0.0]))
        v = v + (f_n[:2] - coriolis[:2]) * dt

        phi = _transition(c_bn, omega_n, omega_u, g, lat, dt)
        x, p, r = _kalman_step(x, p, q, r, phi, v, s, k, r_floor)

        # Closed loop: correct the mechanisation, zero the fed-back states.
        c_bn = _rotation(x[2:5]) @ c_bn
        v = v - x[:2]
        x[:5] = 0.0
        if not np.all(np.isfinite(p)):
            raise AlignmentError(f"the filter diverged at t = {times[k]:.1f} s")
        az_hist[k] = _enu_to_attitude(c_bn)[0]
        sig_hist[k] = math.degrees(math.sqrt(p[4, 4]))

    azimuth, pitch, roll = _enu_to_attitude(c_bn)
    notes = _alignment_notes(s, ratio, r, r_floor)
    return AlignmentResult(
        azimuth_deg=azimuth,
        pitch_deg=pitch,
        roll_deg=roll,
        sigma_deg=math.degrees(math.sqrt(p[4, 4])),
        level_sigma_deg=(math.degrees(math.sqrt(p[2, 2])), math.degrees(math.sqrt(p[3, 3]))),
        gyro_bias=x[7:10].copy(),
        accel_bias=x[5:7].copy(),
        coarse_azimuth_deg=coarse_az,
        times_s=times,
        azimuth_history_deg=az_hist,
        sigma_history_deg=sig_hist,
        gyro_noise_density=gyro_density,
        accel_noise_density=accel_density,
        noise_ratio=(float(ratio[0]), float(ratio[1])),
        consistent=not notes,
        notes=tuple(notes),
    )


def _kalman_step(
    x: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    r: np.ndarray,
    phi: np.ndarray,
    v: np.ndarray,
    s: KalmanSettings,
    k: int,
    r_floor: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One prediction and update of the error state ``x`` (covariance ``p``) by the transition
    ``phi`` with the horizontal velocity ``v`` as the measurement; the measurement noise ``r``
    adapted (Sage-Husa, step ``k``) when ``s.adaptive``. Returns the new ``x``, ``p``, ``r``."""
    h = np.zeros((2, 10))
    h[0, 0] = h[1, 1] = 1.0
    eye10 = np.eye(10)
    x_pred = phi @ x
    p_pred = phi @ p @ phi.T + q
    innovation = v - h @ x_pred
    hph = h @ p_pred @ h.T
    gain = p_pred @ h.T @ np.linalg.inv(hph + r)
    x = x_pred + gain @ innovation
    ikh = eye10 - gain @ h
    p = ikh @ p_pred @ ikh.T + gain @ r @ gain.T
    if s.adaptive:
        d = (1.0 - s.forgetting) / (1.0 - s.forgetting ** (k + 1))
        r = (1.0 - d) * r + d * (np.outer(innovation, innovation) - hph)
        r = 0.5 * (r + r.T)
        np.fill_diagonal(r, np.maximum(np.diag(r), r_floor))
        if np.linalg.det(r) <= 0.0:
            r = np.diag(np.diag(r))
    return x, p, r


def _filter_blocks(
    gyro: ArrayLike,
    accel: ArrayLike,
    fs_hz: float,
    latitude_deg: float,
    settings: KalmanSettings,
    filter_rate_hz: float,
    coarse_s: float,
) -> tuple[np.ndarray, np.ndarray, float, float, int]:
    """The checked record in block means of the filter's step: gyro and accelerometer blocks,
    the latitude (rad), the step (s) and the steps of the coarse alignment.

    Raises
    ------
    InputError, LatitudeError
        As :func:`sage_husa_alignment`.
    """
    g_b = np.asarray(gyro, dtype=float)
    f_b = np.asarray(accel, dtype=float)
    if g_b.ndim != 2 or g_b.shape[1] != 3 or f_b.shape != g_b.shape:
        raise InputError(
            f"gyro and accel: expected equal shapes (N, 3), got {g_b.shape} and {f_b.shape}"
        )
    if not (np.all(np.isfinite(g_b)) and np.all(np.isfinite(f_b))):
        raise InputError("gyro and accel: contain non-finite samples")
    lat = latitude_rad(latitude_deg, "the alignment")
    if not (math.isfinite(fs_hz) and fs_hz > 0.0):
        raise InputError(f"fs_hz: must be a positive number, got {fs_hz!r}")
    block_f = fs_hz / filter_rate_hz
    block = round(block_f)
    if block < 1 or abs(block - block_f) > 1e-9 * block_f:
        raise InputError(f"filter_rate_hz: {filter_rate_hz} must divide the sample rate {fs_hz} Hz")
    if not 0.0 < settings.forgetting < 1.0:
        raise InputError(f"forgetting factor: must lie in (0, 1), got {settings.forgetting}")
    dt = block / fs_hz
    gyro_blocks = _block_means(g_b, block)
    accel_blocks = _block_means(f_b, block)
    n_steps = gyro_blocks.shape[0]
    n_coarse = max(1, round(coarse_s / dt))
    if n_steps < n_coarse + 10:
        raise InputError(
            f"record too short: {g_b.shape[0] / fs_hz:.3g} s gives {n_steps} filter steps; "
            f"need the {coarse_s} s coarse alignment plus at least 10 steps"
        )
    return gyro_blocks, accel_blocks, lat, dt, n_coarse


def _filter_noise(
    s: KalmanSettings,
    gyro_blocks: np.ndarray,
    accel_blocks: np.ndarray,
    dt: float,
    n_coarse: int,
    omega_n: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float, tuple[float, float]]:
    """The filter's initial covariance P, process noise Q and measurement noise R, the noise
    densities used and the record's noise over the settings' (gyro, accelerometer)."""
    p0 = np.asarray(s.p0_sigma, dtype=float).copy()
    gyro_density, accel_density = s.gyro_noise_density, s.accel_noise_density
    ratio = (
        measured_noise_density(gyro_blocks, dt) / s.gyro_noise_density,
        measured_noise_density(accel_blocks[:, :2], dt) / s.accel_noise_density,
    )
    if s.measured_noise:
        # At rest, what the block means do from one to the next is noise: when the record shows
        # more than the settings (vibration, impulses), the filter's Q must say so, or its
        # covariance claims an accuracy the data cannot give.
        gyro_density *= max(ratio[0], 1.0)
        accel_density *= max(ratio[1], 1.0)
        # The coarse azimuth is the east rate over the horizontal Earth rate: its error from
        # that noise averaged over the coarse span.
        coarse_sigma = gyro_density / math.sqrt(n_coarse * dt) / omega_n
        p0[4] = max(p0[4], coarse_sigma)
    p = np.diag(np.square(p0))
    q = np.diag([accel_density**2] * 2 + [gyro_density**2] * 3 + [0.0] * 5) * dt
    r = np.eye(2) * s.r0_sigma**2
    return p, q, r, gyro_density, accel_density, ratio


def _alignment_notes(
    s: KalmanSettings, ratio: tuple[float, float], r: np.ndarray, r_floor: float
) -> list[str]:
    """What makes the alignment's sigma doubtful: a record noisier than the settings, a
    measurement noise adapted far above its floor."""
    notes = []
    if max(ratio) > NOISE_RATIO_LIMIT:
        notes.append(
            f"the record is noisier than the filter's settings (gyro x{ratio[0]:.3g}, "
            f"accelerometer x{ratio[1]:.3g}): disturbances"
            + ("; the noise used is the record's" if s.measured_noise else "")
        )
    r_ratio = math.sqrt(float(np.max(np.diag(r))) / r_floor)
    if s.adaptive and r_ratio > R_RATIO_LIMIT:
        notes.append(
            f"the adapted measurement noise ends x{r_ratio:.3g} above its floor: the velocity "
            "innovations hold more than the model's noise"
        )
    return notes


def _transition(
    c_bn: NDArray[np.float64], omega_n: float, omega_u: float, g: float, lat: float, dt: float
) -> NDArray[np.float64]:
    """Phi = exp(F dt) of the 10-state ENU error model, by a 4th-order series.

    ||F dt|| is at most about g dt, but F is nearly nilpotent (the chains are eps -> phi -> dV
    and bias -> dV); the neglected 5th-order terms are below 1e-10 of the kept ones at dt = 0.1 s.
    """
    f = np.zeros((10, 10))
    f[0, 1] = 2.0 * omega_u
    f[0, 3] = -g
    f[0, 5:7] = c_bn[0, :2]
    f[1, 0] = -2.0 * omega_u
    f[1, 2] = g
    f[1, 5:7] = c_bn[1, :2]
    f[2, 1] = -1.0 / _EARTH_RADIUS
    f[2, 3] = omega_u
    f[2, 4] = -omega_n
    f[3, 0] = 1.0 / _EARTH_RADIUS
    f[3, 2] = -omega_u
    f[4, 0] = math.tan(lat) / _EARTH_RADIUS
    f[4, 2] = omega_n
    f[2:5, 7:10] = -c_bn
    a = f * dt
    a2 = a @ a
    a3 = a2 @ a
    return np.eye(10) + a + a2 / 2.0 + a3 / 6.0 + (a3 @ a) / 24.0
