"""Sage-Husa static alignment on simulated resting data."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from northfinder.firmware_sim.earth import OMEGA_IE, alpha_from_azimuth, body_rates, mat_nb
from northfinder.host.align import (
    ALIGNMENT_STATES,
    PAPER_SETTINGS,
    KalmanSettings,
    coarse_alignment,
    sage_husa_alignment,
)
from northfinder.host.errors import AlignmentError, InputError, LatitudeError

FS_HZ = 200.0
LATITUDE_DEG = 39.804  # the source paper's site
DEG_PER_H = math.pi / 180.0 / 3600.0
G0 = 9.80665


def resting_record(
    rng: np.random.Generator,
    azimuth_deg: float,
    pitch_deg: float,
    roll_deg: float,
    *,
    duration_s: float = 300.0,
    gyro_bias: np.ndarray | None = None,
    accel_bias: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Gyro (rad/s) and accelerometer (m/s^2) samples of a resting triad with white noise.

    Noise as the filter's Q assumes: 0.05 deg/h/sqrt(Hz) and 50 ug/sqrt(Hz), i.e. per sample at
    200 Hz those densities times sqrt(200 Hz).
    """
    n = int(duration_s * FS_HZ)
    omega_b, f_b = body_rates(azimuth_deg, pitch_deg, roll_deg, LATITUDE_DEG)
    gyro_sigma = 0.05 * DEG_PER_H * math.sqrt(FS_HZ)
    accel_sigma = 50e-6 * G0 * math.sqrt(FS_HZ)
    gyro = omega_b + rng.normal(0.0, gyro_sigma, (n, 3))
    accel = f_b + rng.normal(0.0, accel_sigma, (n, 3))
    if gyro_bias is not None:
        gyro += gyro_bias
    if accel_bias is not None:
        accel += accel_bias
    return gyro, accel


def prior_biases(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Biases drawn from the filter's P0: 0.1 deg/h per gyro, 0.1 mg per horizontal accelerometer."""
    gyro_bias = rng.normal(0.0, 0.1 * DEG_PER_H, 3)
    accel_bias = np.append(rng.normal(0.0, 0.1e-3 * G0, 2), 0.0)
    return gyro_bias, accel_bias


def angle_error_deg(a: float, b: float) -> float:
    return (a - b + 180.0) % 360.0 - 180.0


def test_coarse_alignment_matches_the_project_conventions() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        az, pitch, roll = rng.uniform(0.0, 360.0), *rng.uniform(-10.0, 10.0, 2)
        omega_b, f_b = body_rates(az, pitch, roll, rng.uniform(-80.0, 80.0))
        c_bn, az_c, pitch_c, roll_c = coarse_alignment(omega_b, f_b)
        assert abs(angle_error_deg(az_c, az)) < 1e-9
        assert_allclose([pitch_c, roll_c], [pitch, roll], atol=1e-9)
        # C_b^n maps the body's specific force to (0, 0, g) in East-North-Up.
        assert_allclose(c_bn @ f_b, [0.0, 0.0, float(np.linalg.norm(f_b))], atol=1e-12)
        assert_allclose(c_bn @ c_bn.T, np.eye(3), atol=1e-12)


def test_alignment_noise_only_converges_within_predicted_sigma() -> None:
    rng = np.random.default_rng(2024)
    az, pitch, roll = 123.4, 2.5, -4.0
    gyro, accel = resting_record(rng, az, pitch, roll)
    result = sage_husa_alignment(gyro, accel, FS_HZ, LATITUDE_DEG)
    error = angle_error_deg(result.azimuth_deg, az)
    assert abs(error) < result.sigma_deg
    # Without biases only the white noise limits it: far better than the prior-limited sigma.
    assert abs(error) < 0.1
    assert_allclose([result.pitch_deg, result.roll_deg], [pitch, roll], atol=0.005)
    assert 0.0 <= result.azimuth_deg < 360.0
    # The sigma settles at the P0 combination of phi_U and eps_E / (Omega cos L).
    phi_u = 1.0
    eps_e = math.degrees(0.1 * DEG_PER_H / (OMEGA_IE * math.cos(math.radians(LATITUDE_DEG))))
    floor = math.sqrt(phi_u**2 * eps_e**2 / (phi_u**2 + eps_e**2))
    assert_allclose(result.sigma_deg, floor, rtol=0.02)
    assert result.sigma_history_deg[0] > 0.9 and np.all(np.diff(result.sigma_history_deg) <= 1e-9)
    assert result.times_s.shape == result.azimuth_history_deg.shape
    assert len(ALIGNMENT_STATES) == 10


@pytest.mark.parametrize("seed", [7, 8])
def test_alignment_with_biases_from_the_prior(seed: int) -> None:
    rng = np.random.default_rng(seed)
    az, pitch, roll = rng.uniform(0.0, 360.0), *rng.uniform(-5.0, 5.0, 2)
    gyro_bias, accel_bias = prior_biases(rng)
    gyro, accel = resting_record(
        rng, az, pitch, roll, gyro_bias=gyro_bias, accel_bias=accel_bias, duration_s=200.0
    )
    result = sage_husa_alignment(gyro, accel, FS_HZ, LATITUDE_DEG)
    assert abs(angle_error_deg(result.azimuth_deg, az)) < 3.0 * result.sigma_deg
    tilt_error = max(abs(result.pitch_deg - pitch), abs(result.roll_deg - roll))
    assert tilt_error < 3.0 * max(result.level_sigma_deg)
    # What is physically possible at rest: the east gyro bias over the horizontal Earth rate.
    assert result.sigma_deg < 0.5


def test_conventional_filter_also_converges() -> None:
    rng = np.random.default_rng(77)
    gyro, accel = resting_record(rng, 300.0, -1.0, 1.0, duration_s=120.0)
    fixed = KalmanSettings(adaptive=False)
    result = sage_husa_alignment(gyro, accel, FS_HZ, LATITUDE_DEG, settings=fixed)
    assert abs(angle_error_deg(result.azimuth_deg, 300.0)) < result.sigma_deg
    assert PAPER_SETTINGS.forgetting == 0.95 and PAPER_SETTINGS.adaptive


def test_alignment_input_errors() -> None:
    rng = np.random.default_rng(3)
    gyro, accel = resting_record(rng, 10.0, 0.0, 0.0, duration_s=40.0)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        sage_husa_alignment(gyro[:, :2], accel, FS_HZ, LATITUDE_DEG)
    with pytest.raises(InputError, match="non-finite"):
        bad = gyro.copy()
        bad[5, 1] = np.nan
        sage_husa_alignment(bad, accel, FS_HZ, LATITUDE_DEG)
    with pytest.raises(InputError, match="divide"):
        sage_husa_alignment(gyro, accel, FS_HZ, LATITUDE_DEG, filter_rate_hz=7.0)
    with pytest.raises(InputError, match="too short"):
        sage_husa_alignment(gyro[:4000], accel[:4000], FS_HZ, LATITUDE_DEG)
    with pytest.raises(LatitudeError, match="pole"):
        sage_husa_alignment(gyro, accel, FS_HZ, 89.9)
    with pytest.raises(AlignmentError, match="coarse"):
        coarse_alignment([0.0, 0.0, 1e-4], [0.0, 0.0, 9.8])


def east_bias_limit_deg(
    azimuth_deg: float, pitch_deg: float, roll_deg: float, gyro_bias: np.ndarray
) -> float:
    """Azimuth error forced by the east gyro bias at rest: eps_E / (Omega cos L), deg."""
    c_nb = mat_nb(alpha_from_azimuth(azimuth_deg), math.radians(pitch_deg), math.radians(roll_deg))
    eps_east = -(c_nb.T @ gyro_bias)[1]  # the navigation frame here is North-West-Up
    return math.degrees(eps_east / (OMEGA_IE * math.cos(math.radians(LATITUDE_DEG))))


@pytest.mark.slow
def test_alignment_predicted_sigma_is_honest_over_many_runs() -> None:
    """Biases drawn from P0: the error is the east-bias limit, and its spread the sigma.

    The paper's P0 treats the coarse azimuth error as independent of the east gyro bias, while
    it is mostly that bias over the horizontal Earth rate, so the RMS of error / sigma is
    expected near 1.1 rather than 1.
    """
    ratios, beyond_limit = [], []
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        az, pitch, roll = rng.uniform(0.0, 360.0), *rng.uniform(-5.0, 5.0, 2)
        gyro_bias, accel_bias = prior_biases(rng)
        gyro, accel = resting_record(
            rng, az, pitch, roll, gyro_bias=gyro_bias, accel_bias=accel_bias, duration_s=150.0
        )
        result = sage_husa_alignment(gyro, accel, FS_HZ, LATITUDE_DEG)
        error = angle_error_deg(result.azimuth_deg, az)
        ratios.append(error / result.sigma_deg)
        # A positive east bias turns the solution clockwise: error = -limit.
        beyond_limit.append(error + east_bias_limit_deg(az, pitch, roll, gyro_bias))
    rms = math.sqrt(np.mean(np.square(ratios)))
    assert 0.75 < rms < 1.5, rms
    # What remains is white noise: mostly the accelerometers' (50 ug/sqrt(Hz)), which blur the
    # slow tilt drift Omega_N phi_U that carries the azimuth; about 0.1 deg after 150 s.
    assert math.sqrt(np.mean(np.square(beyond_limit))) < 0.2
