"""Heading solvers: closed-form data, the paper's prototype tables, errors and accuracy bounds."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose
from numpy.typing import ArrayLike

from northfinder.driver.protocol.units import OMEGA_IE
from northfinder.firmware_sim.earth import (
    alpha_from_azimuth,
    earth_rate_n,
    gravity,
    mat_nb,
    mat_table,
)
from northfinder.host.errors import (
    GeometryError,
    HostConfigError,
    HostError,
    InputError,
    LatitudeError,
    TiltError,
)
from northfinder.host.heading import (
    MAX_SOLVER_TILT_DEG,
    pairwise_azimuths,
    solve_multi_position,
    solve_two_position,
    two_position_bound_deg,
)
from northfinder.host.kernels import solve_least_squares_batch
from northfinder.host.plan import PAPER_SWEEP, PLANS

# The source paper's Table 1: mean outputs (mV) of the x and y gyros of the prototype at table
# angles 0, 30, ..., 210 deg, seven repeated runs (rows), rounded to 1e-5 mV.
TABLE1_X = np.array(
    [
        [-0.12864, -0.12866, -0.09406, -0.03438, 0.03465, 0.09449, 0.12894, 0.12864],
        [-0.12862, -0.12858, -0.09401, -0.03432, 0.03485, 0.09375, 0.12874, 0.12861],
        [-0.12865, -0.12860, -0.09408, -0.03422, 0.03456, 0.09416, 0.12893, 0.12878],
        [-0.12860, -0.12853, -0.09407, -0.03412, 0.03460, 0.09415, 0.12886, 0.12835],
        [-0.12861, -0.12879, -0.09399, -0.03400, 0.03473, 0.09421, 0.12872, 0.12831],
        [-0.12865, -0.12871, -0.09396, -0.03386, 0.03483, 0.09401, 0.12873, 0.12839],
        [-0.12870, -0.12859, -0.09398, -0.03464, 0.03454, 0.09390, 0.12918, 0.12879],
    ]
)
TABLE1_Y = np.array(
    [
        [0.03440, -0.03454, -0.09400, -0.12848, -0.12820, -0.09385, -0.03389, 0.03476],
        [0.03451, -0.03424, -0.09382, -0.12860, -0.12838, -0.09371, -0.03423, 0.03460],
        [0.03448, -0.03453, -0.09396, -0.12861, -0.12859, -0.09373, -0.03408, 0.03457],
        [0.03446, -0.03434, -0.09407, -0.12852, -0.12800, -0.09413, -0.03417, 0.03480],
        [0.03447, -0.03434, -0.09399, -0.12837, -0.12840, -0.09353, -0.03408, 0.03485],
        [0.03452, -0.03433, -0.09404, -0.12816, -0.12844, -0.09376, -0.03398, 0.03494],
        [0.03450, -0.03441, -0.09411, -0.12831, -0.12851, -0.09382, -0.03408, 0.03485],
    ]
)
# The paper's Table 2: azimuth (deg) of each run for mu = 30 ... 210 deg, level formula (eq. 15).
TABLE2_AZIMUTH = np.array(
    [
        [74.97821, 75.07297, 75.05570, 75.12045, 75.11006, 75.15045, 75.07904],
        [75.02843, 75.09493, 75.03340, 75.10375, 75.03231, 75.04583, 75.02010],
        [75.03570, 75.06357, 75.06927, 75.02267, 75.08199, 75.09541, 75.01991],
        [75.05442, 75.03634, 75.10018, 75.13038, 75.00424, 75.07484, 75.07762],
        [74.85261, 75.08572, 75.15588, 75.08270, 75.12490, 75.08265, 75.08550],
        [74.95228, 75.10076, 75.22883, 75.09189, 75.05347, 75.09731, 75.09461],
        [75.09044, 75.10776, 75.01406, 75.03872, 75.03728, 75.10676, 75.07656],
    ]
)


def angle_error_deg(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def closed_form_means(
    azimuth_deg: float, pitch_deg: float, roll_deg: float, latitude_deg: float, mu_deg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free gyro (rad/s) and accelerometer (m/s^2) readings at table angles mu_deg."""
    lat = math.radians(latitude_deg)
    c_nb = mat_nb(alpha_from_azimuth(azimuth_deg), math.radians(pitch_deg), math.radians(roll_deg))
    table = mat_table(np.radians(mu_deg))
    gyro = table @ (c_nb @ earth_rate_n(lat))
    accel = table @ (c_nb @ np.array([0.0, 0.0, gravity(lat)]))
    return gyro, accel


def random_case(rng: np.random.Generator) -> tuple[float, float, float, float]:
    return (
        rng.uniform(0.0, 360.0),
        rng.uniform(-5.0, 5.0),
        rng.uniform(-5.0, 5.0),
        rng.uniform(-80.0, 80.0),
    )


# ---------------------------------------------------------------------------------------------
# Closed form
# ---------------------------------------------------------------------------------------------


def test_two_position_closed_form_recovers_azimuth_and_tilt_with_biases() -> None:
    rng = np.random.default_rng(20240601)
    for _ in range(200):
        az, pitch, roll, lat = random_case(rng)
        mu = rng.choice([-1.0, 1.0]) * rng.uniform(10.0, 350.0)  # also > 180 and negative
        gyro, accel = closed_form_means(az, pitch, roll, lat, np.array([0.0, mu]))
        gyro_bias = rng.normal(0.0, 1e-5, 3)  # ~2 deg/h: constant, must cancel
        accel_bias = rng.normal(0.0, 1e-2, 3)  # ~1 mg
        sol = solve_two_position(
            gyro[0] + gyro_bias,
            gyro[1] + gyro_bias,
            mu,
            accel0=accel[0] + accel_bias,
            accel1=accel[1] + accel_bias,
            latitude_deg=lat,
        )
        assert abs(angle_error_deg(sol.azimuth_deg, az)) < 1e-9
        assert_allclose([sol.pitch_deg, sol.roll_deg], [pitch, roll], atol=1e-9)
        assert 0.0 <= sol.azimuth_deg < 360.0
        assert sol.levelled and sol.mu_deg == mu and sol.sigma_deg is None


def test_two_position_level_formula_is_unit_free() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        az, lat = rng.uniform(0.0, 360.0), rng.uniform(-80.0, 80.0)
        mu = rng.uniform(-355.0, 355.0)
        if min(mu % 360.0, 360.0 - mu % 360.0) < 5.0:
            continue
        gyro, _ = closed_form_means(az, 0.0, 0.0, lat, np.array([0.0, mu]))
        counts = gyro * 3.7e7 + 123.0  # arbitrary scale and offset, e.g. raw counts or mV
        sol = solve_two_position(counts[0], counts[1], mu)
        assert abs(angle_error_deg(sol.azimuth_deg, az)) < 1e-9
        assert sol.pitch_deg == 0.0 and sol.roll_deg == 0.0 and not sol.levelled


def test_two_position_rate_and_accel_units_are_honoured() -> None:
    az, pitch, roll, lat, mu = 211.3, 3.0, -4.0, 47.0, 125.0
    gyro, accel = closed_form_means(az, pitch, roll, lat, np.array([0.0, mu]))
    deg_per_h = math.pi / 180.0 / 3600.0
    sol = solve_two_position(
        gyro[0] / deg_per_h,
        gyro[1] / deg_per_h,
        mu,
        accel0=accel[0] / 9.80665,
        accel1=accel[1] / 9.80665,
        latitude_deg=lat,
        rate_unit="deg/h",
        accel_unit="g",
    )
    assert abs(angle_error_deg(sol.azimuth_deg, az)) < 1e-9
    numeric = solve_two_position(
        gyro[0] / 1e-6,
        gyro[1] / 1e-6,
        mu,
        accel0=accel[0],
        accel1=accel[1],
        latitude_deg=lat,
        rate_unit=1e-6,
    )
    assert abs(angle_error_deg(numeric.azimuth_deg, az)) < 1e-9


def test_multi_position_closed_form_with_accelerometers() -> None:
    rng = np.random.default_rng(99)
    for n in range(2, 9):
        for _ in range(20):
            az, pitch, roll, lat = random_case(rng)
            first = rng.uniform(-30.0, 30.0)
            # The others anywhere (also beyond +-360), but the second well away from the first.
            others = first + rng.uniform(10.0, 350.0, n - 1) + 360.0 * rng.integers(-1, 2, n - 1)
            mus = np.concatenate([[first], others])
            gyro, accel = closed_form_means(az, pitch, roll, lat, mus)
            gyro_bias, accel_bias = rng.normal(0.0, 1e-5, 3), rng.normal(0.0, 1e-2, 3)
            sol = solve_multi_position(
                gyro + gyro_bias, mus, latitude_deg=lat, accel_means=accel + accel_bias
            )
            assert abs(angle_error_deg(sol.azimuth_deg, az)) < 1e-9
            assert_allclose([sol.pitch_deg, sol.roll_deg], [pitch, roll], atol=1e-9)
            assert_allclose(sol.gyro_bias, gyro_bias[:2], rtol=0.0, atol=1e-15)
            assert sol.accel_bias is not None
            assert_allclose(sol.accel_bias, accel_bias[:2], rtol=0.0, atol=1e-9)
            assert_allclose(sol.gyro_residuals, 0.0, atol=1e-15)


def test_multi_position_closed_form_with_known_tilt_and_level() -> None:
    rng = np.random.default_rng(5)
    for n in (2, 3, 4, 8):
        az, pitch, roll, lat = random_case(rng)
        mus = np.arange(n) * 360.0 / n - 45.0
        gyro, _ = closed_form_means(az, pitch, roll, lat, mus)
        sol = solve_multi_position(
            gyro + 2e-6, mus, latitude_deg=lat, pitch_deg=pitch, roll_deg=roll, gyro_noise=1e-8
        )
        assert abs(angle_error_deg(sol.azimuth_deg, az)) < 1e-9
        assert sol.covariance is not None and sol.covariance.shape == (3, 3)
        assert sol.parameter_names == ("alpha", "gyro_bias_x", "gyro_bias_y")
        gyro_level, _ = closed_form_means(az, 0.0, 0.0, lat, mus)
        level = solve_multi_position(gyro_level, mus, latitude_deg=lat)
        assert abs(angle_error_deg(level.azimuth_deg, az)) < 1e-9


# ---------------------------------------------------------------------------------------------
# The paper's prototype data
# ---------------------------------------------------------------------------------------------


def test_paper_table1_reproduces_table2() -> None:
    """Table 1 through ``solve_two_position`` gives Table 2 to the rounding of Table 1.

    Mapping found: the table rows x and y are our x and y gyros, the paper's table turned
    clockwise seen from above (so mu = -30, -60, ..., -210 deg here), and the paper reports the
    azimuth of the body y axis: Table 2 = (azimuth - 90) mod 360. No other change is needed.

    Table 1 is rounded to 1e-5 mV, so each difference of two means is uncertain by up to 1e-5
    per axis; with the measured Earth-rate amplitude A that moves the angle by at most
    sqrt(2) 1e-5 / (2 A |sin(mu/2)|) rad (about 0.012 deg at mu = 30, 0.003 deg at 180).
    """
    angles = [-a for a in PAPER_SWEEP.positions_deg]
    computed = np.array(
        [
            [
                (s.azimuth_deg - 90.0) % 360.0
                for s in pairwise_azimuths(np.stack([TABLE1_X[run], TABLE1_Y[run]], -1), angles)
            ]
            for run in range(7)
        ]
    )
    amplitude = np.hypot(TABLE1_X, TABLE1_Y).mean()
    mu = np.radians(PAPER_SWEEP.pair_mu_deg())
    rounding = np.degrees(math.sqrt(2.0) * 1e-5 / (2.0 * amplitude * np.abs(np.sin(mu / 2.0))))
    residual = np.abs(angle_error_deg(computed, TABLE2_AZIMUTH))
    assert np.all(residual <= rounding + 1e-5), residual.max(axis=0)
    assert residual.max() < 0.01
    # The paper's root-mean-square errors against its reference azimuth 75.08632 deg (Table 2's
    # last row but one) follow from the reproduced azimuths as well.
    rmse = np.sqrt(np.mean((computed - 75.08632) ** 2, axis=0))
    paper_rmse = [0.11416, 0.02371, 0.07030, 0.03736, 0.04661, 0.03052, 0.03603]
    assert_allclose(rmse, paper_rmse, atol=2e-3)


def test_paper_sweep_plan() -> None:
    assert PLANS["paper-30deg-sweep"] is PAPER_SWEEP
    assert PAPER_SWEEP.positions_deg == (0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0, 210.0)
    assert PAPER_SWEEP.pairs() == tuple((0, k) for k in range(1, 8))
    assert PAPER_SWEEP.pair_mu_deg() == (30.0, 60.0, 90.0, 120.0, 150.0, 180.0, 210.0)
    gyro, accel = closed_form_means(33.0, 1.0, -2.0, 34.0, np.array(PAPER_SWEEP.positions_deg))
    sols = pairwise_azimuths(gyro, PAPER_SWEEP, accel_means=accel, latitude_deg=34.0)
    assert len(sols) == 7
    assert_allclose([s.mu_deg for s in sols], PAPER_SWEEP.pair_mu_deg())
    assert_allclose(angle_error_deg([s.azimuth_deg for s in sols], 33.0), 0.0, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# Accuracy: propagated sigma against the physical bound
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mu", [30.0, 60.0, 90.0, 180.0, 270.0, -60.0])
def test_two_position_sigma_equals_white_noise_bound(mu: float) -> None:
    lat, arw_dpsh, total_s = 34.0, 0.0015, 20.0
    gyro, _ = closed_form_means(75.0, 0.0, 0.0, lat, np.array([0.0, mu]))
    arw = arw_dpsh * math.pi / 180.0 / 60.0
    window_sigma = arw / math.sqrt(total_s / 2.0)
    sol = solve_two_position(gyro[0], gyro[1], mu, gyro_noise=window_sigma)
    bound = two_position_bound_deg(arw_dpsh, total_s, mu, lat)
    assert sol.sigma_deg is not None
    assert_allclose(sol.sigma_deg, bound, rtol=1e-9)
    # The example of the design notes: 2 x 10 s at 34 deg N, mu = 180 -> 0.093 deg.
    assert_allclose(two_position_bound_deg(0.0015, 20.0, 180.0, 34.0), 0.093, atol=1e-3)
    # Two positions through the least-squares fit give the same sigma.
    multi = solve_multi_position(gyro, [0.0, mu], latitude_deg=lat, gyro_noise=window_sigma)
    assert multi.sigma_deg is not None
    assert_allclose(multi.sigma_deg, bound, rtol=1e-6)


def test_accelerometer_noise_adds_to_sigma() -> None:
    gyro, accel = closed_form_means(10.0, 2.0, 3.0, 60.0, np.array([0.0, 90.0]))
    kwargs: dict[str, Any] = {
        "accel0": accel[0],
        "accel1": accel[1],
        "latitude_deg": 60.0,
        "gyro_noise": 1e-8,
    }
    quiet = solve_two_position(gyro[0], gyro[1], 90.0, **kwargs)
    noisy = solve_two_position(gyro[0], gyro[1], 90.0, accel_noise=1e-3, **kwargs)
    assert noisy.sigma_deg is not None and quiet.sigma_deg is not None
    assert noisy.sigma_deg > quiet.sigma_deg > 0.0


# ---------------------------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mu", [0.0, 4.9, -4.9, 355.5, 360.0, 720.0, -360.0])
def test_mu_too_close_to_zero_is_refused(mu: float) -> None:
    gyro, _ = closed_form_means(10.0, 0.0, 0.0, 30.0, np.array([0.0, 90.0]))
    with pytest.raises(GeometryError, match=r"at least 5\.0 deg"):
        solve_two_position(gyro[0], gyro[1], mu)


def test_multi_position_needs_two_distinct_positions() -> None:
    gyro, _ = closed_form_means(10.0, 0.0, 0.0, 30.0, np.array([0.0, 360.0, 1.0]))
    with pytest.raises(GeometryError, match="apart"):
        solve_multi_position(gyro, [0.0, 360.0, 1.0], latitude_deg=30.0)
    with pytest.raises(InputError, match="N >= 2"):
        solve_multi_position(gyro[:1], [0.0], latitude_deg=30.0)


@pytest.mark.parametrize("lat", [89.5, -90.0, 95.0, float("nan")])
def test_latitude_at_a_pole_or_invalid_is_refused(lat: float) -> None:
    gyro, accel = closed_form_means(10.0, 0.0, 0.0, 30.0, np.array([0.0, 90.0]))
    with pytest.raises(LatitudeError, match="latitude_deg"):
        solve_two_position(
            gyro[0], gyro[1], 90.0, accel0=accel[0], accel1=accel[1], latitude_deg=lat
        )
    with pytest.raises(LatitudeError, match="latitude_deg"):
        solve_multi_position(gyro, [0.0, 90.0], latitude_deg=lat)


def test_accelerometers_need_latitude() -> None:
    gyro, accel = closed_form_means(10.0, 0.0, 0.0, 30.0, np.array([0.0, 90.0]))
    with pytest.raises(LatitudeError, match="required"):
        solve_two_position(gyro[0], gyro[1], 90.0, accel0=accel[0], accel1=accel[1])
    with pytest.raises(InputError, match="both"):
        solve_two_position(gyro[0], gyro[1], 90.0, accel0=accel[0], latitude_deg=30.0)


def test_tilt_beyond_limit_is_refused() -> None:
    gyro, accel = closed_form_means(
        10.0, MAX_SOLVER_TILT_DEG + 1.0, 0.0, 30.0, np.array([0.0, 90.0])
    )
    with pytest.raises(TiltError, match=r"pitch .* exceeds the limit of \+-15\.0 deg"):
        solve_two_position(
            gyro[0], gyro[1], 90.0, accel0=accel[0], accel1=accel[1], latitude_deg=30.0
        )
    with pytest.raises(TiltError, match="roll"):
        solve_multi_position(gyro, [0.0, 90.0], latitude_deg=30.0, roll_deg=-20.0)
    with pytest.raises(TiltError, match="exceeds gravity"):
        solve_two_position(
            gyro[0], gyro[1], 90.0, accel0=[30.0, 0.0], accel1=[-30.0, 0.0], latitude_deg=30.0
        )


@pytest.mark.parametrize(
    ("gyro0", "match"),
    [
        ([1.0, float("nan")], "non-finite"),
        ([1.0, float("inf"), 0.0], "non-finite"),
        ([1.0], "shape"),
        ([[1.0, 2.0]], "shape"),
        ([1.0, 2.0, 3.0, 4.0], "shape"),
    ],
)
def test_bad_gyro_means_are_refused(gyro0: list, match: str) -> None:
    with pytest.raises(InputError, match=match):
        solve_two_position(gyro0, [1.0, 2.0], 90.0)


def test_bad_units_and_noise_are_refused() -> None:
    with pytest.raises(HostConfigError, match=r"'rad/s', 'mrad/s'"):
        solve_two_position([1.0, 0.0], [0.0, 1.0], 90.0, rate_unit="furlong/fortnight")
    with pytest.raises(InputError, match="gyro_noise"):
        solve_two_position([1.0, 0.0], [0.0, 1.0], 90.0, gyro_noise=-1.0)
    with pytest.raises(InputError, match="gyro_noise"):
        solve_two_position([1.0, 0.0], [0.0, 1.0], 90.0, gyro_noise=[1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="mu_deg"):
        solve_two_position([1.0, 0.0], [0.0, 1.0], float("nan"))
    # All of them are host errors, so the CLI reports them in one line.
    assert issubclass(InputError, HostError) and issubclass(GeometryError, HostError)


# ---------------------------------------------------------------------------------------------
# Monte Carlo
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_monte_carlo_two_position_rmse_matches_bound() -> None:
    """White noise only: the RMSE of the two-position azimuth is the bound of the design notes.

    The mean of white noise over a window of T/2 s is normal with sigma N / sqrt(T/2), so the
    window means are drawn directly (all runs at once).
    """
    rng = np.random.default_rng(314159)
    lat, arw_dpsh, total_s, az, runs = 34.0, 0.0015, 20.0, 75.0, 4000
    window_sigma = arw_dpsh * math.pi / 180.0 / 60.0 / math.sqrt(total_s / 2.0)
    for mu in (60.0, 90.0, 180.0):
        gyro, _ = closed_form_means(az, 0.0, 0.0, lat, np.array([0.0, mu]))
        means = gyro[None, :, :2] + rng.normal(0.0, window_sigma, (runs, 2, 2))
        azimuths = np.array([solve_two_position(m[0], m[1], mu).azimuth_deg for m in means])
        rmse = math.sqrt(np.mean(angle_error_deg(azimuths, az) ** 2))
        bound = two_position_bound_deg(arw_dpsh, total_s, mu, lat)
        assert abs(rmse / bound - 1.0) < 0.10, (mu, rmse, bound)


@pytest.mark.slow
def test_monte_carlo_predicted_sigmas_with_tilt_and_many_positions() -> None:
    """The propagated sigmas (accelerometer path and least-squares covariance) are honest."""
    rng = np.random.default_rng(2718)
    runs, lat, az, pitch, roll = 3000, 40.0, 300.0, 2.0, -3.0
    gyro_sigma, accel_sigma = 2e-8, 5e-4  # rad/s and m/s^2 per window mean

    gyro, accel = closed_form_means(az, pitch, roll, lat, np.array([0.0, 120.0]))
    g_noise = rng.normal(0.0, gyro_sigma, (runs, 2, 3))
    a_noise = rng.normal(0.0, accel_sigma, (runs, 2, 3))
    kw: dict[str, Any] = {"latitude_deg": lat, "gyro_noise": gyro_sigma, "accel_noise": accel_sigma}
    sols = [
        solve_two_position(g[0], g[1], 120.0, accel0=a[0], accel1=a[1], **kw)
        for g, a in zip(gyro + g_noise, accel + a_noise, strict=True)
    ]
    errors = angle_error_deg([s.azimuth_deg for s in sols], az)
    predicted = float(np.mean([s.sigma_deg for s in sols]))
    assert abs(errors.std() / predicted - 1.0) < 0.10

    mus = np.array([0.0, 90.0, 180.0, 270.0])
    gyro, accel = closed_form_means(az, pitch, roll, lat, mus)
    g_noise = rng.normal(0.0, gyro_sigma, (runs, 4, 3))
    a_noise = rng.normal(0.0, accel_sigma, (runs, 4, 3))
    multi = [
        solve_multi_position(g, mus, accel_means=a, **kw)
        for g, a in zip(gyro + g_noise, accel + a_noise, strict=True)
    ]
    errors = angle_error_deg([s.azimuth_deg for s in multi], az)
    predicted = float(np.mean([s.sigma_deg for s in multi]))
    assert abs(errors.std() / predicted - 1.0) < 0.10


def test_least_squares_finds_the_minimum_when_noise_exceeds_the_earth_rate() -> None:
    """Gyro noise twice the horizontal Earth rate (a MEMS gyro): every fit converges, to the
    least-squares minimum over all headings, and the scalar and vectorised solvers agree. (Plain
    Gauss-Newton oscillates about the minimum for some of these runs.)"""
    rng = np.random.default_rng(42)
    lat, runs = 34.0, 300
    mus = np.array([0.0, 120.0, 240.0])
    omega_h = OMEGA_IE * math.cos(math.radians(lat))
    gyro, _ = closed_form_means(10.0, 0.0, 0.0, lat, mus)
    means = gyro[None, :, :2] + rng.normal(0.0, 2.0 * omega_h, (runs, 3, 2))
    batch = solve_least_squares_batch(means, mus, latitude_deg=lat)
    assert not np.isnan(batch).any()
    # The profiled cost (biases fitted for each heading) on a fine grid of headings.
    alphas = np.radians(np.arange(0.0, 360.0, 0.01))
    h = omega_h * np.stack([np.cos(alphas), -np.sin(alphas)], -1)  # level: h(alpha)
    model = np.einsum("nij,aj->ani", mat_table(np.radians(mus))[:, :2, :2], h)  # (A, N, 2)
    for r in range(runs):
        res = means[r][None] - model
        res -= res.mean(axis=1, keepdims=True)  # the best biases for each heading
        cost = np.sum(res**2, axis=(1, 2))
        best = np.degrees(-alphas[np.argmin(cost)]) % 360.0
        assert abs(angle_error_deg(batch[r], best)) < 0.02
        scalar = solve_multi_position(means[r], mus, latitude_deg=lat)
        assert abs(angle_error_deg(scalar.azimuth_deg, batch[r])) < 1e-9
