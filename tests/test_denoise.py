"""Denoising functions against their definitions."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import pywt
from numpy.testing import assert_allclose, assert_array_equal

from northfinder.host.denoise import (
    METHODS,
    THRESHOLD_MODES,
    denoise,
    detrend_average_points,
    five_point_smooth,
    forced_denoise,
    hampel,
    mad_sigma,
    moving_average,
    outlier_mask,
    threshold,
    universal_threshold,
    wavelet_denoise,
)
from northfinder.host.errors import DenoiseError, HostConfigError, InputError

# ---------------------------------------------------------------------------------------------
# Threshold functions
# ---------------------------------------------------------------------------------------------


def test_hard_and_soft_thresholds_at_chosen_points() -> None:
    w = np.array([-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 1.0000001, 3.0])
    assert_array_equal(threshold(w, 1.0, "hard"), [-3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0000001, 3.0])
    assert_allclose(threshold(w, 1.0, "soft"), [-2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-7, 2.0])


def test_two_parameter_threshold_properties() -> None:
    lam = 2.0
    for alpha, beta in ((0.05, 4), (0.1, 6), (0.2, 5)):
        # Definition and the value alpha*w at |w| = lambda.
        w = np.array([-5.0, -lam, -1.0, 0.0, 1.0, lam, 3.0])
        with np.errstate(divide="ignore"):
            expected = np.where(w == 0.0, 0.0, w * alpha ** ((lam / np.abs(w)) ** beta))
        assert_allclose(threshold(w, lam, "2p", alpha=alpha, beta=beta), expected, rtol=1e-15)
        assert_allclose(
            threshold([lam, -lam], lam, "2p", alpha=alpha, beta=beta), [alpha * lam, -alpha * lam]
        )
        # Continuous everywhere (no jump at lambda, unlike hard).
        eps = 1e-9
        below, above = threshold([lam - eps, lam + eps], lam, "2p", alpha=alpha, beta=beta)
        assert abs(above - below) < 1e-6
        # Asymptote w_hat = w: the gap itself goes to zero for beta >= 2.
        big = np.array([1e2, 1e3, 1e4])
        gap = big - threshold(big, lam, "2p", alpha=alpha, beta=beta)
        assert np.all(np.diff(gap) < 0.0) and gap[-1] < 1e-6
        # Odd function, and zero (without warnings) at and near w = 0.
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            tiny = threshold([1e-300, -1e-300, 0.0], lam, "2p", alpha=alpha, beta=beta)
        assert_array_equal(tiny, 0.0)
    # Tends to the hard threshold as beta grows.
    w = np.array([0.5, 1.5, 1.9, 2.1, 2.5, 4.0])
    close = threshold(w, lam, "2p", alpha=0.1, beta=400)
    assert_allclose(close, threshold(w, lam, "hard"), atol=1e-6)


def test_reconstructed_003_threshold_properties() -> None:
    lam, mu, beta = 1.5, 0.2, 2.0
    w = np.array([-1.4, 0.0, 1.0, 1.49])
    assert_array_equal(threshold(w, lam, "003", mu=mu, beta=beta), 0.0)
    # Continuous at lambda: zero there, like soft.
    assert_allclose(threshold([lam, -lam], lam, "003", mu=mu, beta=beta), 0.0, atol=1e-15)
    # A chosen point: w = lambda + 1 -> u = 1 - exp(-mu), w_hat = w - lambda exp(-beta mu).
    assert_allclose(
        threshold(lam + 1.0, lam, "003", mu=mu, beta=beta), lam + 1.0 - lam * math.exp(-beta * mu)
    )
    assert_allclose(
        threshold(-(lam + 1.0), lam, "003", mu=mu, beta=beta),
        -(lam + 1.0) + lam * math.exp(-beta * mu),
    )
    # Unbiased for large |w|: w_hat = w exactly once exp underflows.
    assert_allclose(
        threshold([50.0, -50.0], lam, "003", mu=mu, beta=beta), [50.0, -50.0], rtol=1e-15
    )
    # Between soft (at lambda) and identity (far away), monotone increasing.
    grid = np.linspace(lam, 20.0, 2000)
    out = threshold(grid, lam, "003", mu=mu, beta=beta)
    assert np.all(np.diff(out) > 0.0)
    assert np.all(out >= threshold(grid, lam, "soft") - 1e-12) and np.all(out <= grid + 1e-12)


def test_threshold_mode_is_checked_against_the_table() -> None:
    with pytest.raises(HostConfigError, match=r"'hard', 'soft', '2p', '003'"):
        threshold([1.0], 1.0, "garrote")
    assert set(THRESHOLD_MODES) == {"hard", "soft", "2p", "003"}
    with pytest.raises(HostConfigError, match="alpha"):
        threshold([1.0], 1.0, "2p", alpha=1.5)
    with pytest.raises(HostConfigError, match="value"):
        threshold([1.0], -1.0, "soft")


def test_mad_noise_estimate_and_universal_threshold() -> None:
    rng = np.random.default_rng(11)
    noise = rng.normal(0.0, 2.5, (3, 100_000))
    assert_allclose(mad_sigma(noise, axis=-1)[:, 0], 2.5, rtol=0.02)
    assert mad_sigma(noise, axis=-1).shape == (3, 1)
    assert_allclose(mad_sigma(noise.T, axis=0)[0], mad_sigma(noise, axis=-1)[:, 0])
    assert_allclose(universal_threshold(2.0, 2000), 2.0 * math.sqrt(2.0 * math.log(2000)))


# ---------------------------------------------------------------------------------------------
# Wavelet denoising
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["hard", "soft", "2p", "003"])
def test_wavelet_denoise_keeps_constants_and_window_means(mode: str) -> None:
    rng = np.random.default_rng(3)
    n = 2048  # a multiple of 2**level: the periodised transform is exactly orthogonal
    x = 4.2e-5 + rng.normal(0.0, 1e-6, n)
    y = wavelet_denoise(x, mode)
    assert y.shape == x.shape
    assert_allclose(y.mean(), x.mean(), rtol=0.0, atol=1e-18)
    assert y.std() < 0.5 * x.std()  # white noise mostly removed
    assert_allclose(wavelet_denoise(np.full(n, 3.0), mode), 3.0, rtol=1e-12)


def test_wavelet_denoise_zero_threshold_is_perfect_reconstruction() -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(size=1000)
    assert_allclose(wavelet_denoise(x, "hard", value=0.0), x, atol=1e-12)
    assert_allclose(wavelet_denoise(x, "soft", value=0.0, extension="symmetric"), x, atol=1e-12)


def test_wavelet_denoise_uses_universal_threshold_from_finest_details() -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=1024)
    coeffs = pywt.wavedec(x, "db4", mode="periodization", level=4)
    lam = np.median(np.abs(coeffs[-1])) / 0.6745 * math.sqrt(2.0 * math.log(1024))
    expected = pywt.waverec(
        [coeffs[0]] + [pywt.threshold(d, lam, "soft") for d in coeffs[1:]],
        "db4",
        mode="periodization",
    )
    assert_allclose(wavelet_denoise(x, "soft"), expected, atol=1e-12)


def test_wavelet_denoise_axis_handling() -> None:
    rng = np.random.default_rng(6)
    x = rng.normal(size=(3, 2, 1000)) * np.array([1.0, 10.0, 100.0])[:, None, None]
    along_last = wavelet_denoise(x, "2p", alpha=0.05, beta=4)
    along_first = wavelet_denoise(np.moveaxis(x, -1, 0), "2p", alpha=0.05, beta=4, axis=0)
    assert_allclose(np.moveaxis(along_first, 0, -1), along_last, atol=1e-12)
    # Each channel has its own threshold: channel k equals the 1-D result.
    assert_allclose(
        along_last[2, 1], wavelet_denoise(x[2, 1], "2p", alpha=0.05, beta=4), atol=1e-12
    )
    odd = wavelet_denoise(rng.normal(size=999), "hard")
    assert odd.shape == (999,)


def test_forced_denoise_keeps_a_pure_approximation_band_signal() -> None:
    n, level = 1024, 5
    wav = pywt.Wavelet("sym4")
    template = pywt.wavedec(np.zeros(n), wav, mode="periodization", level=level)
    approx = np.linspace(-1.0, 2.0, template[0].size) ** 3  # monotone: the median keeps it
    signal = pywt.waverec(
        [approx] + [np.zeros_like(d) for d in template[1:]], wav, mode="periodization"
    )
    assert_allclose(forced_denoise(signal), signal, atol=1e-12)
    # Adding any detail-band content is removed completely.
    rng = np.random.default_rng(8)
    details = [rng.normal(size=d.size) for d in template[1:]]
    noisy = pywt.waverec([np.zeros_like(approx), *details], wav, mode="periodization")
    assert_allclose(forced_denoise(signal + noisy), signal, atol=1e-12)
    # An impulse of a few samples is removed by the median on the approximation coefficients,
    # but survives the low-pass alone.
    spiky = signal.copy()
    spiky[500:504] += 50.0
    low_pass_only = np.abs(forced_denoise(spiky, median_window=None) - signal).max()
    with_median = np.abs(forced_denoise(spiky) - signal).max()
    assert low_pass_only > 1.0 and with_median < 0.05 * low_pass_only


def test_forced_denoise_axis_and_errors() -> None:
    rng = np.random.default_rng(9)
    x = rng.normal(size=(2048, 3))
    assert_allclose(forced_denoise(x, axis=0)[:, 1], forced_denoise(x[:, 1]), atol=1e-12)
    with pytest.raises(DenoiseError, match="too deep"):
        forced_denoise(rng.normal(size=100))
    with pytest.raises(HostConfigError, match="odd"):
        forced_denoise(x, axis=0, median_window=10)
    with pytest.raises(HostConfigError, match="wavelet"):
        wavelet_denoise(x[:, 0], wavelet="db99")
    with pytest.raises(HostConfigError, match="'periodization'"):
        wavelet_denoise(x[:, 0], extension="mirror")
    with pytest.raises(InputError, match="non-finite"):
        wavelet_denoise(np.array([1.0, np.nan] * 512))
    with pytest.raises(InputError, match="axis"):
        wavelet_denoise(x, axis=2)


# ---------------------------------------------------------------------------------------------
# Time-domain methods
# ---------------------------------------------------------------------------------------------


def test_five_point_smoother_reproduces_quadratics_including_ends() -> None:
    t = np.arange(40, dtype=float)
    quadratic = 3.0 - 0.5 * t + 0.02 * t**2
    assert_allclose(five_point_smooth(quadratic), quadratic, rtol=1e-13, atol=1e-12)
    # The coefficients: response to a unit impulse at each of the first and last samples.
    n = 9
    impulses = np.eye(n)
    response = five_point_smooth(impulses, axis=-1)  # row k: response to an impulse at k
    assert_allclose(response[:, 0] * 35.0, [31, 9, -3, -5, 3, 0, 0, 0, 0], atol=1e-12)
    assert_allclose(response[:, 1] * 35.0, [9, 13, 12, 6, -5, 0, 0, 0, 0], atol=1e-12)
    assert_allclose(response[:, 4] * 35.0, [0, 0, -3, 12, 17, 12, -3, 0, 0], atol=1e-12)
    assert_allclose(response[:, -2] * 35.0, [0, 0, 0, 0, -5, 6, 12, 13, 9], atol=1e-12)
    assert_allclose(response[:, -1] * 35.0, [0, 0, 0, 0, 3, -5, -3, 9, 31], atol=1e-12)
    # Axis handling.
    block = np.stack([quadratic, 2.0 * quadratic], axis=0)
    assert_allclose(five_point_smooth(block.T, axis=0).T, block, atol=1e-12)
    with pytest.raises(DenoiseError, match="at least 5"):
        five_point_smooth([1.0, 2.0, 3.0, 4.0])


def test_detrender_removes_lines_and_keeps_the_mean() -> None:
    rng = np.random.default_rng(12)
    for n in (1499, 1500, 1501, 3000, 4321):
        t = np.arange(n, dtype=float)
        line = 7.0 + 0.003 * t
        assert_allclose(detrend_average_points(line, segment=n + 10), line.mean(), rtol=1e-12)
        x = rng.normal(size=n) + line
        y = detrend_average_points(x)
        assert_allclose(y.mean(), x.mean(), rtol=0.0, atol=1e-12)
    # Piecewise: a slope that changes at the segment boundaries is removed segment by segment,
    # and every segment keeps its own mean.
    n = 4500
    t = np.arange(n, dtype=float)
    slopes = np.repeat([1e-3, -2e-3, 4e-3], 1500)
    x = np.cumsum(slopes)
    y = detrend_average_points(x)
    for k in range(3):
        seg = slice(1500 * k, 1500 * (k + 1))
        assert_allclose(y[seg], x[seg].mean(), rtol=0.0, atol=1e-9)
    assert_allclose(detrend_average_points(np.stack([x, -x]), axis=1)[1], -y, atol=1e-12)
    assert t.size == n


def test_moving_average_removes_a_full_period_disturbance() -> None:
    period = 25
    t = np.arange(1000)
    disturbance = np.sin(2.0 * np.pi * t / period) + 0.3 * np.cos(4.0 * np.pi * t / period)
    x = 1.5 + disturbance
    assert_allclose(moving_average(x, period, edges="valid"), 1.5, atol=1e-12)
    assert moving_average(x, period, edges="valid").shape == (1000 - period + 1,)
    same = moving_average(x, period)
    assert same.shape == x.shape
    assert_allclose(same[period:-period], 1.5, atol=1e-12)
    assert_allclose(moving_average([1.0, 2.0, 3.0, 4.0], 3), [1.5, 2.0, 3.0, 3.5])
    assert_allclose(moving_average(np.stack([x, x]).T, period, axis=0)[:, 1], same)
    with pytest.raises(HostConfigError, match="'shrink', 'valid'"):
        moving_average(x, 5, edges="wrap")
    with pytest.raises(DenoiseError, match="exceeds"):
        moving_average(x[:10], 11)


def test_hampel_replaces_impulses_and_leaves_clean_samples() -> None:
    t = np.arange(400, dtype=float)
    clean = 0.01 * t + 2.0
    x = clean.copy()
    spikes = [50, 51, 200, 333]
    x[spikes] += [40.0, 35.0, -60.0, 25.0]
    mask = outlier_mask(x)
    assert_array_equal(np.flatnonzero(mask), spikes)
    # Outliers become their window median (on a ramp, a neighbour's value); the rest is untouched.
    y = hampel(x)
    assert_array_equal(y[~mask], clean[~mask])
    assert_allclose(y[spikes], clean[spikes], atol=0.025)
    assert_array_equal(hampel(np.stack([x, clean]).T, axis=0)[:, 0], y)
    with pytest.raises(HostConfigError, match="odd"):
        hampel(x, window=20)


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------


def test_registry_names_and_every_method_keeps_shape() -> None:
    assert set(METHODS) == {
        "none",
        "wavelet-hard",
        "wavelet-soft",
        "wavelet-2p",
        "wavelet-003",
        "forced-median",
        "five-point",
        "detrend",
        "moving-average",
        "hampel",
    }
    rng = np.random.default_rng(13)
    x = 1e-4 + rng.normal(0.0, 1e-6, (3, 2000))  # 10 s at 200 Hz, three gyros
    for name, method in METHODS.items():
        options = {"window": 20} if name == "moving-average" else {}
        y = denoise(x, name, axis=-1, **options)
        assert y.shape == x.shape, name
        assert_allclose(y.mean(axis=-1), x.mean(axis=-1), rtol=1e-3, err_msg=name)
        assert_allclose(method.func(x.T, axis=0, **options).T, y, atol=1e-15, err_msg=name)
        assert method.name == name and method.description
    assert_array_equal(denoise(x, "none"), x)


def test_registry_errors_name_the_choices() -> None:
    with pytest.raises(HostConfigError, match=r"'none', 'wavelet-hard'.*'hampel'"):
        denoise([1.0, 2.0], "kalman")
    with pytest.raises(HostConfigError, match="window="):
        denoise(np.ones(100), "moving-average")
    with pytest.raises(HostConfigError, match="bad options"):
        denoise(np.ones(100), "five-point", alpha=0.1)


def test_the_extension_modes_are_pywavelets_own():
    import pywt

    from northfinder.host.denoise import EXTENSIONS

    assert tuple(pywt.Modes.modes) == EXTENSIONS
