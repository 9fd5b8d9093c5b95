"""Denoising of gyro and accelerometer records before their window means are taken.

Every function is pure: it takes an array-like, works along ``axis`` (samples; default the last)
and returns a new float array of the same shape (except :func:`moving_average` with
``edges="valid"``). Strings that choose a variant (threshold ``mode``, wavelet ``extension``,
method names) are checked against a table, and the error lists the choices.

What the methods can and cannot do for north finding: the Earth-rate signal is the **mean** of
each window. For white noise the plain mean is already the optimal estimate, and wavelet
thresholding keeps the approximation coefficients, so it cannot beat the white-noise bound. The
methods earn their keep against impulses (door slams, footsteps), vibration above a few hertz,
drift and steps. With the default ``extension="periodization"`` the wavelet transform is
orthogonal and every detail coefficient has zero sum, so editing details never moves the window
mean (exactly so when the length is a multiple of 2**level); only the approximation-domain
median filter, the smoothers and the outlier rejection change it.

Sources
-------
- Wavelet threshold denoising with hard, soft and a two-parameter threshold function, db4, four
  levels, universal threshold with a MAD noise estimate (the arbitrary two-position paper, eq. 18).
- Another improved threshold function, db6, eight levels, after a moving average over one
  disturbance period (the gyro-accelerometer vibration paper). Its formula is missing from the
  text; ``"003"`` is a **reconstruction** from the quantities it defines.
- Wavelet "forced" denoising (sym4, five levels, all details set to zero) followed by a median
  filter of window 11 on the approximation coefficients (the FOG SINS alignment paper).
- Five-point quadratic smoothing with its end formulas and piecewise average-point detrending
  (the FOG signal compensation paper).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray

from northfinder.host.errors import DenoiseError, HostConfigError, InputError, check_choice

if TYPE_CHECKING:
    import pywt


def _pywt() -> Any:
    """PyWavelets, imported when a wavelet method first runs (it and scipy take a second to
    import; a command that does not denoise with wavelets does not pay for it)."""
    import pywt

    return pywt


__all__ = [
    "EXTENSIONS",
    "METHODS",
    "MOVING_AVERAGE_EDGES",
    "THRESHOLD_MODES",
    "DenoiseMethod",
    "denoise",
    "denoised_mean",
    "detrend_average_points",
    "five_point_smooth",
    "forced_denoise",
    "hampel",
    "mad_sigma",
    "moving_average",
    "outlier_mask",
    "threshold",
    "universal_threshold",
    "wavelet_denoise",
    "wavelet_denoise_mean",
]

#: Threshold functions by ``mode``.
THRESHOLD_MODES: Mapping[str, str] = {
    "hard": "keep |w| > lambda, zero the rest",
    "soft": "shrink towards zero by lambda",
    "2p": "two-parameter function w * alpha ** ((lambda/|w|) ** beta) (paper eq. 18)",
    "003": "reconstruction: sign(w) (|w| - lambda (1 - u) ** beta), u = 1 - exp(-mu (|w| - lambda)**2)",
}
#: Wavelet signal-extension modes accepted (PyWavelets names).
EXTENSIONS: tuple[str, ...] = (
    "zero", "constant", "symmetric", "periodic", "smooth", "periodization", "reflect",
    "antisymmetric", "antireflect",
)  # fmt: skip
"""PyWavelets' signal extension modes (``pywt.Modes.modes``; a test keeps them the same)."""
#: Edge handling of :func:`moving_average`.
MOVING_AVERAGE_EDGES: Mapping[str, str] = {
    "shrink": "same length; windows are truncated (and re-normalised) at the ends",
    "valid": "only full windows; length n - window + 1",
}
#: 1 / Phi^-1(3/4): turns a median absolute deviation into a Gaussian standard deviation.
_MAD_TO_SIGMA = 1.0 / 0.6745


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------


def _signal(
    x: ArrayLike, axis: int, name: str = "x", *, copy: bool = True
) -> tuple[NDArray[np.float64], int]:
    """Float array of ``x`` (a copy unless ``copy=False``, for callers that never write to it)
    and the normalised axis; refuses scalars and non-finite values."""
    try:
        arr = np.array(x, dtype=float) if copy else np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: must be numeric") from exc
    if arr.ndim == 0:
        raise InputError(f"{name}: must have at least one dimension (samples)")
    if not -arr.ndim <= axis < arr.ndim:
        raise InputError(f"axis {axis} is out of range for {name} with shape {arr.shape}")
    ax = axis % arr.ndim
    # A finite sum has finite terms (NaN and inf propagate); only an overflowing sum needs the
    # element-wise look.
    if not math.isfinite(float(np.sum(arr))) and not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains non-finite values")
    return arr, ax


def _positive_int(value: int, name: str, minimum: int = 1) -> int:
    whole = (
        not isinstance(value, bool)
        and isinstance(value, int | float | np.integer | np.floating)
        and math.isfinite(value)
        and int(value) == value
    )
    if not whole or int(value) < minimum:
        raise HostConfigError(f"{name}: must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _wavelet_named(name: str) -> pywt.Wavelet:
    if name not in _pywt().wavelist(kind="discrete"):
        raise HostConfigError(
            f"wavelet: unknown discrete wavelet {name!r}; see pywt.wavelist(kind='discrete') "
            "(e.g. 'db4', 'db6', 'sym4')"
        )
    return _pywt().Wavelet(name)


def _check_level(n: int, wavelet: pywt.Wavelet, level: int) -> int:
    level = _positive_int(level, "level")
    max_level = _pywt().dwt_max_level(n, wavelet.dec_len)
    if level > max_level:
        raise DenoiseError(
            f"level {level} is too deep for {n} samples with {wavelet.name} "
            f"(at most {max_level}; every coefficient would be dominated by the ends)"
        )
    return level


def _trim(y: NDArray[np.float64], n: int, axis: int) -> NDArray[np.float64]:
    """Cut a reconstruction back to ``n`` samples (waverec pads odd lengths by one)."""
    if y.shape[axis] == n:
        return y
    return np.take(y, np.arange(n), axis=axis)


# ----------------------------------------------------------------------------------------------
# Threshold functions
# ----------------------------------------------------------------------------------------------


def threshold(
    coeffs: ArrayLike,
    value: ArrayLike,
    mode: str = "soft",
    *,
    alpha: float = 0.1,
    beta: float = 6.0,
    mu: float = 0.2,
) -> NDArray[np.float64]:
    """Apply a threshold function element-wise.

    Parameters
    ----------
    coeffs : array_like
        Wavelet coefficients w, any shape.
    value : array_like
        Threshold lambda >= 0, broadcastable to ``coeffs`` (same unit as w).
    mode : {"hard", "soft", "2p", "003"}
        ``hard``: w for |w| > lambda, else 0. ``soft``: sign(w) max(|w| - lambda, 0).
        ``2p`` (two-parameter, paper eq. 18): ``w * alpha ** ((lambda / |w|) ** beta)``, 0 at
        w = 0; continuous and smooth, alpha w at |w| = lambda, tends to w for large |w| (for
        beta >= 2 the gap itself vanishes) and to the hard threshold as beta grows.
        ``003`` (a reconstruction; the source's formula is lost): for |w| >= lambda,
        ``sign(w) (|w| - lambda (1 - u) ** beta)`` with ``u = 1 - exp(-mu (|w| - lambda)**2)``,
        else 0; continuous at lambda (soft-like there) and unbiased for large |w|.
    alpha : float
        Shrink factor of ``2p``, 0 < alpha < 1 (paper: 0.05, 0.1, 0.2).
    beta : float
        Exponent of ``2p`` (paper: positive integers 4, 5, 6) and of ``003`` (source: 2); > 0.
    mu : float
        Rate of ``003``, > 0 (source: 0.2). It has the unit 1/w**2, so the source's value only
        suits coefficients of order one; scale it for other units.

    Returns
    -------
    ndarray
        Thresholded coefficients, shape of ``coeffs``.
    """
    check_choice(mode, THRESHOLD_MODES, "mode")
    w = np.asarray(coeffs, dtype=float)
    lam = np.asarray(value, dtype=float)
    if np.any(~np.isfinite(lam)) or np.any(lam < 0.0):
        raise HostConfigError(f"value: threshold must be finite and >= 0, got {value!r}")
    if mode == "hard":
        return np.where(np.abs(w) > lam, w, 0.0)
    if mode == "soft":
        # sign(w) max(|w| - lambda, 0), in two passes over the coefficients.
        return w - np.clip(w, -lam, lam)
    mag = np.abs(w)
    if not beta > 0.0:
        raise HostConfigError(f"beta: must be > 0, got {beta!r}")
    if mode == "2p":
        if not 0.0 < alpha < 1.0:
            raise HostConfigError(f"alpha: must lie in (0, 1), got {alpha!r}")
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            # (lambda/|w|)**beta overflows to inf for tiny |w|; alpha**inf = 0 is the right limit.
            factor = np.power(alpha, np.power(lam / mag, beta))
        return np.where(mag > 0.0, w * np.nan_to_num(factor, nan=1.0), 0.0)
    if not mu > 0.0:
        raise HostConfigError(f"mu: must be > 0, got {mu!r}")
    excess = mag - lam
    one_minus_u = np.exp(-mu * excess**2)
    return np.where(excess >= 0.0, np.sign(w) * (mag - lam * one_minus_u**beta), 0.0)


def mad_sigma(details: ArrayLike, *, axis: int = -1) -> NDArray[np.float64]:
    """Noise standard deviation from the median absolute value of detail coefficients.

    ``sigma = median(|d|) / 0.6745`` along ``axis`` (kept as a length-1 axis for broadcasting).
    Robust to the few large coefficients that carry signal.
    """
    d, ax = _signal(details, axis, "details", copy=False)
    return _mad_sigma(d, ax)


def _mad_sigma(d: NDArray[np.float64], ax: int) -> NDArray[np.float64]:
    # np.abs makes a new array, so the median may reorder it in place.
    return np.median(np.abs(d), axis=ax, keepdims=True, overwrite_input=True) * _MAD_TO_SIGMA


def universal_threshold(sigma: ArrayLike, n: int) -> NDArray[np.float64]:
    """Universal threshold ``lambda = sigma sqrt(2 ln n)`` for a signal of ``n`` samples."""
    n = _positive_int(n, "n", minimum=2)
    return np.asarray(sigma, dtype=float) * math.sqrt(2.0 * math.log(n))


# ----------------------------------------------------------------------------------------------
# Wavelet methods
# ----------------------------------------------------------------------------------------------


def wavelet_denoise(
    x: ArrayLike,
    mode: str = "soft",
    *,
    wavelet: str = "db4",
    level: int = 4,
    axis: int = -1,
    value: ArrayLike | None = None,
    alpha: float = 0.1,
    beta: float = 6.0,
    mu: float = 0.2,
    extension: str = "periodization",
) -> NDArray[np.float64]:
    """Wavelet threshold denoising.

    Decompose to ``level`` levels, threshold every detail band with one threshold, keep the
    approximation, reconstruct.

    Parameters
    ----------
    x : array_like, shape (..., n, ...)
        Signal, samples along ``axis``.
    mode : {"hard", "soft", "2p", "003"}
        Threshold function, see :func:`threshold`.
    wavelet : str
        Discrete wavelet name (PyWavelets), default db4.
    level : int
        Decomposition depth, default 4; at most ``pywt.dwt_max_level``.
    axis : int
        Sample axis; every other index is an independent channel with its own threshold.
    value : array_like, optional
        Threshold lambda in the unit of x. Default: the universal threshold
        ``sigma sqrt(2 ln n)`` with sigma from :func:`mad_sigma` of the finest details.
    alpha, beta, mu : float
        Parameters of the ``2p`` and ``003`` functions.
    extension : str
        PyWavelets signal extension; default ``periodization`` (orthogonal, mean-preserving).

    Returns
    -------
    ndarray
        Denoised signal, shape of ``x``.
    """
    arr, ax, wav, level = _wavelet_signal(x, mode, wavelet, level, axis, extension)
    return _thresholded(arr, ax, wav, level, extension, mode, value, alpha, beta, mu)


def _wavelet_signal(
    x: ArrayLike, mode: str, wavelet: str, level: int, axis: int, extension: str
) -> tuple[NDArray[np.float64], int, pywt.Wavelet, int]:
    """The checked arguments of :func:`wavelet_denoise`: the signal (not copied: wavedec writes
    only to new arrays), its sample axis, the wavelet and the level."""
    check_choice(mode, THRESHOLD_MODES, "mode")
    check_choice(extension, EXTENSIONS, "extension")
    arr, ax = _signal(x, axis, copy=False)
    wav = _wavelet_named(wavelet)
    return arr, ax, wav, _check_level(arr.shape[ax], wav, level)


def _thresholded(
    arr: NDArray[np.float64],
    ax: int,
    wav: pywt.Wavelet,
    level: int,
    extension: str,
    mode: str,
    value: ArrayLike | None,
    alpha: float,
    beta: float,
    mu: float,
) -> NDArray[np.float64]:
    """Decompose, threshold every detail band, reconstruct (the work of :func:`wavelet_denoise`)."""
    n = arr.shape[ax]
    coeffs = _pywt().wavedec(arr, wav, mode=extension, level=level, axis=ax)
    if value is None:
        lam = universal_threshold(_mad_sigma(coeffs[-1], ax), n)
    else:
        lam = np.asarray(value, dtype=float)
    out = [coeffs[0]] + [threshold(d, lam, mode, alpha=alpha, beta=beta, mu=mu) for d in coeffs[1:]]
    return _trim(_pywt().waverec(out, wav, mode=extension, axis=ax), n, ax)


def _keeps_mean(n: int, wav: pywt.Wavelet, level: int, extension: str) -> bool:
    """True when editing detail coefficients cannot move the mean of the reconstruction.

    With periodization, an orthogonal wavelet and ``n`` a multiple of ``2**level`` the transform
    is an orthogonal matrix W, so ``mean(W^T c) = (W 1)^T c / n``; the details of a constant
    signal are zero (every wavelet filter sums to zero), so only the approximation counts, and
    the mean of the reconstruction is the mean of the signal whatever the details became.
    """
    return extension == "periodization" and bool(wav.orthogonal) and n % 2**level == 0


def wavelet_denoise_mean(
    x: ArrayLike,
    mode: str = "soft",
    *,
    wavelet: str = "db4",
    level: int = 4,
    axis: int = -1,
    value: ArrayLike | None = None,
    alpha: float = 0.1,
    beta: float = 6.0,
    mu: float = 0.2,
    extension: str = "periodization",
) -> NDArray[np.float64]:
    """``mean(wavelet_denoise(x, ...), axis)``: the same number up to rounding, with less work.

    Where thresholding cannot move the mean (:func:`_keeps_mean`: the default periodization
    with an orthogonal wavelet and a length that is a multiple of ``2**level``), it is the
    plain mean of ``x`` and no transform runs; elsewhere the signal is decomposed,
    thresholded and reconstructed. The arguments are checked alike either way. Parameters as
    :func:`wavelet_denoise`; ``axis`` is reduced.
    """
    arr, ax, wav, level = _wavelet_signal(x, mode, wavelet, level, axis, extension)
    if not _keeps_mean(arr.shape[ax], wav, level, extension):
        denoised = _thresholded(arr, ax, wav, level, extension, mode, value, alpha, beta, mu)
        return np.mean(denoised, axis=ax)
    # The options must still be valid: check them on one coefficient.
    threshold(np.ones(1), 0.0 if value is None else value, mode, alpha=alpha, beta=beta, mu=mu)
    return np.mean(arr, axis=ax)


def forced_denoise(
    x: ArrayLike,
    *,
    wavelet: str = "sym4",
    level: int = 5,
    median_window: int | None = 11,
    axis: int = -1,
    extension: str = "periodization",
) -> NDArray[np.float64]:
    """Wavelet "forced" denoising with a median filter in the wavelet domain.

    All detail coefficients are set to zero (a cascade of half-band low-pass filters: with 200 Hz
    sampling and five levels only content below about 3 Hz survives), then a running median of
    ``median_window`` coefficients is applied to the approximation coefficients to remove the
    impulses that survive the low-pass, and the signal is reconstructed.

    Parameters
    ----------
    x : array_like
        Signal, samples along ``axis``.
    wavelet : str
        Default sym4.
    level : int
        Default 5.
    median_window : int or None
        Odd window of the median filter in approximation coefficients (default 11); None or 1
        skips it. The ends repeat the edge coefficient, so monotone runs pass unchanged.
    axis : int
        Sample axis.
    extension : str
        PyWavelets signal extension, default ``periodization``.

    Returns
    -------
    ndarray
        Shape of ``x``.
    """
    check_choice(extension, EXTENSIONS, "extension")
    arr, ax = _signal(x, axis)
    n = arr.shape[ax]
    wav = _wavelet_named(wavelet)
    level = _check_level(n, wav, level)
    coeffs = _pywt().wavedec(arr, wav, mode=extension, level=level, axis=ax)
    approx = coeffs[0]
    if median_window is not None and median_window != 1:
        window = _positive_int(median_window, "median_window")
        if window % 2 == 0:
            raise HostConfigError(f"median_window: must be odd, got {window}")
        if window > approx.shape[ax]:
            raise DenoiseError(
                f"median_window {window} exceeds the {approx.shape[ax]} approximation "
                f"coefficients of {n} samples at level {level}"
            )
        size = [1] * approx.ndim
        size[ax] = window
        from scipy.ndimage import median_filter

        approx = median_filter(approx, size=size, mode="nearest")
    out = [approx] + [np.zeros_like(d) for d in coeffs[1:]]
    return _trim(_pywt().waverec(out, wav, mode=extension, axis=ax), n, ax)


# ----------------------------------------------------------------------------------------------
# Time-domain methods
# ----------------------------------------------------------------------------------------------

_FIVE_POINT_INTERIOR = np.array([-3.0, 12.0, 17.0, 12.0, -3.0]) / 35.0
_FIVE_POINT_FIRST = np.array([31.0, 9.0, -3.0, -5.0, 3.0]) / 35.0
_FIVE_POINT_SECOND = np.array([9.0, 13.0, 12.0, 6.0, -5.0]) / 35.0


def five_point_smooth(x: ArrayLike, *, axis: int = -1) -> NDArray[np.float64]:
    """Five-point quadratic (Savitzky-Golay) smoothing with the least-squares end formulas.

    Interior: ``y_i = (-3 x_{i-2} + 12 x_{i-1} + 17 x_i + 12 x_{i+1} - 3 x_{i+2}) / 35``.
    Ends: ``y_0 = (31 x_0 + 9 x_1 - 3 x_2 - 5 x_3 + 3 x_4) / 35``,
    ``y_1 = (9 x_0 + 13 x_1 + 12 x_2 + 6 x_3 - 5 x_4) / 35`` and their mirror images for the
    last two samples. Every output is the value of the least-squares parabola through five
    neighbours, so quadratics pass unchanged.

    Parameters
    ----------
    x : array_like
        Signal with at least 5 samples along ``axis``.
    axis : int
        Sample axis.

    Returns
    -------
    ndarray
        Shape of ``x``.
    """
    arr, ax = _signal(x, axis)
    n = arr.shape[ax]
    if n < 5:
        raise DenoiseError(f"five-point smoothing needs at least 5 samples, got {n}")
    v = np.moveaxis(arr, ax, -1)
    y = np.empty_like(v)
    windows = sliding_window_view(v, 5, axis=-1)  # (..., n - 4, 5)
    y[..., 2:-2] = windows @ _FIVE_POINT_INTERIOR
    head, tail = v[..., :5], v[..., -5:]
    y[..., 0] = head @ _FIVE_POINT_FIRST
    y[..., 1] = head @ _FIVE_POINT_SECOND
    y[..., -2] = tail @ _FIVE_POINT_SECOND[::-1]
    y[..., -1] = tail @ _FIVE_POINT_FIRST[::-1]
    return np.moveaxis(y, -1, ax)


def detrend_average_points(
    x: ArrayLike, *, segment: int = 1500, axis: int = -1
) -> NDArray[np.float64]:
    """Piecewise average-point detrending that keeps each segment's mean.

    The record is cut into ``round(n / segment)`` (at least one) nearly equal segments. In each,
    the slope is estimated from the means of its two halves, ``K = (P2 - P1) / (m / 2)`` per
    sample (exact for a straight line, also for odd m), and ``K (t - t_mean)`` is removed. The
    source subtracts ``K t``, which would also move the mean; here the mean stays, because the
    Earth-rate signal *is* the window mean.

    Parameters
    ----------
    x : array_like
        Signal, samples along ``axis``.
    segment : int
        Approximate samples per segment (source: about 1500), >= 2.
    axis : int
        Sample axis.

    Returns
    -------
    ndarray
        Shape of ``x``; the mean of every segment (so of the record) is unchanged.
    """
    arr, ax = _signal(x, axis)
    segment = _positive_int(segment, "segment", minimum=2)
    v = np.moveaxis(arr, ax, -1)
    n = v.shape[-1]
    n_seg = max(1, round(n / segment))
    edges = np.linspace(0, n, n_seg + 1).round().astype(int)
    y = v.copy()
    for start, stop in itertools.pairwise(edges):
        m = stop - start
        if m < 2:
            continue
        n1 = (m + 1) // 2
        seg = v[..., start:stop]
        p1 = seg[..., :n1].mean(axis=-1, keepdims=True)
        p2 = seg[..., n1:].mean(axis=-1, keepdims=True)
        slope = (p2 - p1) / (m / 2.0)
        t = np.arange(m) - (m - 1) / 2.0
        y[..., start:stop] = seg - slope * t
    return np.moveaxis(y, -1, ax)


def moving_average(
    x: ArrayLike, window: int, *, axis: int = -1, edges: str = "shrink"
) -> NDArray[np.float64]:
    """Centred moving average over ``window`` samples.

    With the window equal to one period of a periodic disturbance (the source's choice: one
    precession period) that disturbance is removed completely from every full window.

    Parameters
    ----------
    x : array_like
        Signal, samples along ``axis``.
    window : int
        Samples per window, 1 <= window <= n.
    axis : int
        Sample axis.
    edges : {"shrink", "valid"}
        ``shrink`` keeps the length, truncating windows at the ends; ``valid`` returns only full
        windows (n - window + 1 samples).

    Returns
    -------
    ndarray
    """
    check_choice(edges, MOVING_AVERAGE_EDGES, "edges")
    arr, ax = _signal(x, axis)
    v = np.moveaxis(arr, ax, -1)
    n = v.shape[-1]
    window = _positive_int(window, "window")
    if window > n:
        raise DenoiseError(f"moving-average window {window} exceeds the {n} samples")
    csum = np.concatenate([np.zeros((*v.shape[:-1], 1)), np.cumsum(v, axis=-1)], axis=-1)
    if edges == "valid":
        y = (csum[..., window:] - csum[..., :-window]) / window
    else:
        left = window // 2
        idx = np.arange(n)
        lo = np.clip(idx - left, 0, n)
        hi = np.clip(idx - left + window, 0, n)
        y = (csum[..., hi] - csum[..., lo]) / (hi - lo)
    return np.moveaxis(y, -1, ax)


def outlier_mask(
    x: ArrayLike, *, window: int = 21, n_sigmas: float = 3.0, axis: int = -1
) -> NDArray[np.bool_]:
    """Hampel test: True where a sample is more than ``n_sigmas`` robust sigmas off its median.

    The robust sigma is 1.4826 times the median absolute deviation in a centred window of
    ``window`` samples (the ends repeat the edge sample).

    Parameters
    ----------
    x : array_like
        Signal, samples along ``axis``.
    window : int
        Odd window length, >= 3.
    n_sigmas : float
        Rejection threshold, > 0.
    axis : int
        Sample axis.

    Returns
    -------
    ndarray of bool
        Shape of ``x``.
    """
    return _hampel(x, window, n_sigmas, axis)[1]


def hampel(
    x: ArrayLike, *, window: int = 21, n_sigmas: float = 3.0, axis: int = -1
) -> NDArray[np.float64]:
    """Hampel filter: replace outliers (see :func:`outlier_mask`) by their window median.

    Impulses shorter than half the window are removed; everything else passes unchanged.

    Parameters
    ----------
    x : array_like
        Signal, samples along ``axis``.
    window : int
        Odd window length, >= 3 (default 21: 0.1 s at 200 Hz).
    n_sigmas : float
        Rejection threshold in robust sigmas (default 3).
    axis : int
        Sample axis.

    Returns
    -------
    ndarray
        Shape of ``x``.
    """
    return _hampel(x, window, n_sigmas, axis)[0]


def _hampel(
    x: ArrayLike, window: int, n_sigmas: float, axis: int
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    arr, ax = _signal(x, axis)
    window = _positive_int(window, "window", minimum=3)
    if window % 2 == 0:
        raise HostConfigError(f"window: must be odd, got {window}")
    if not (math.isfinite(n_sigmas) and n_sigmas > 0.0):
        raise HostConfigError(f"n_sigmas: must be a positive number, got {n_sigmas!r}")
    v = np.moveaxis(arr, ax, -1)
    half = window // 2
    padded = np.pad(v, [(0, 0)] * (v.ndim - 1) + [(half, half)], mode="edge")
    windows = sliding_window_view(padded, window, axis=-1)  # (..., n, window)
    med = np.median(windows, axis=-1)
    mad = np.median(np.abs(windows - med[..., None]), axis=-1)
    mask = np.abs(v - med) > n_sigmas * 1.4826 * mad
    y = np.where(mask, med, v)
    return np.moveaxis(y, -1, ax), np.moveaxis(mask, -1, ax)


# ----------------------------------------------------------------------------------------------
# Registry
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DenoiseMethod:
    """A named denoising method for the CLI and studies.

    Attributes
    ----------
    name : str
        Registry key.
    func : callable
        ``func(x, *, axis=-1, **options) -> ndarray`` with the source's settings as defaults.
    description : str
        One line for help texts.
    """

    name: str
    func: Callable[..., NDArray[np.float64]]
    description: str
    #: True when ``func`` takes ``mean=True`` and then returns the mean along ``axis`` of what
    #: it would return, computed with less work (the same number up to rounding).
    has_mean: bool = False


def _none(x: ArrayLike, *, axis: int = -1) -> NDArray[np.float64]:
    return _signal(x, axis)[0]


def _wavelet(
    x: ArrayLike, mode: str, *, mean: bool, axis: int, **options: Any
) -> NDArray[np.float64]:
    return (wavelet_denoise_mean if mean else wavelet_denoise)(x, mode, axis=axis, **options)


def _wavelet_hard(
    x: ArrayLike, *, axis: int = -1, mean: bool = False, **options: Any
) -> NDArray[np.float64]:
    return _wavelet(x, "hard", mean=mean, axis=axis, **options)


def _wavelet_soft(
    x: ArrayLike, *, axis: int = -1, mean: bool = False, **options: Any
) -> NDArray[np.float64]:
    return _wavelet(x, "soft", mean=mean, axis=axis, **options)


def _wavelet_2p(
    x: ArrayLike,
    *,
    axis: int = -1,
    mean: bool = False,
    alpha: float = 0.1,
    beta: float = 6.0,
    **options: Any,
) -> NDArray[np.float64]:
    return _wavelet(x, "2p", mean=mean, axis=axis, alpha=alpha, beta=beta, **options)


def _wavelet_003(
    x: ArrayLike,
    *,
    axis: int = -1,
    mean: bool = False,
    wavelet: str = "db6",
    level: int | None = None,
    beta: float = 2.0,
    mu: float = 0.2,
    **options: Any,
) -> NDArray[np.float64]:
    if level is None:
        # The source used 8 levels on long records; a 10 s window at 200 Hz allows 7 with db6.
        n = np.shape(x)[axis] if np.ndim(x) else 0
        level = max(1, min(8, _pywt().dwt_max_level(n, _wavelet_named(wavelet).dec_len)))
    return _wavelet(
        x, "003", mean=mean, axis=axis, wavelet=wavelet, level=level, beta=beta, mu=mu, **options
    )


def _moving_average(
    x: ArrayLike, *, axis: int = -1, window: int | None = None, **options: Any
) -> NDArray[np.float64]:
    if window is None:
        raise HostConfigError(
            "moving-average: give window= (samples in one period of the disturbance)"
        )
    return moving_average(x, window, axis=axis, **options)


#: Methods by name.
METHODS: Mapping[str, DenoiseMethod] = {
    m.name: m
    for m in (
        DenoiseMethod("none", _none, "no processing"),
        DenoiseMethod(
            "wavelet-hard", _wavelet_hard, "db4, 4 levels, universal hard threshold", True
        ),
        DenoiseMethod(
            "wavelet-soft", _wavelet_soft, "db4, 4 levels, universal soft threshold", True
        ),
        DenoiseMethod(
            "wavelet-2p",
            _wavelet_2p,
            "db4, 4 levels, two-parameter threshold alpha=0.1 beta=6",
            True,
        ),
        DenoiseMethod(
            "wavelet-003",
            _wavelet_003,
            "db6, up to 8 levels, reconstructed improved threshold mu=0.2 beta=2",
            True,
        ),
        DenoiseMethod(
            "forced-median",
            forced_denoise,
            "sym4, 5 levels, details zeroed, median of 11 on approximation coefficients",
        ),
        DenoiseMethod("five-point", five_point_smooth, "five-point quadratic smoothing"),
        DenoiseMethod(
            "detrend", detrend_average_points, "piecewise average-point detrending, mean kept"
        ),
        DenoiseMethod(
            "moving-average", _moving_average, "centred moving average over one disturbance period"
        ),
        DenoiseMethod("hampel", hampel, "Hampel outlier replacement (21 samples, 3 sigma)"),
    )
}


def check_denoise(
    method: str, options: Mapping[str, Any], n_samples: int, name: str = "denoise options"
) -> None:
    """Refuse, before any measurement, a method or options that cannot run on windows of
    ``n_samples`` (a bad option name or value, a window or level the samples cannot hold).

    Raises
    ------
    HostConfigError, DenoiseError
        The message names the option; ``name`` (e.g. ``--denoise-option``) leads it.
    """
    try:
        denoise(np.zeros((max(int(n_samples), 1), 1)), method, axis=0, **dict(options))
    except (HostConfigError, DenoiseError) as exc:
        raise type(exc)(f"{name}: {exc}") from exc


def denoise(x: ArrayLike, method: str, *, axis: int = -1, **options: Any) -> NDArray[np.float64]:
    """Apply the registered method ``method`` along ``axis``.

    Parameters
    ----------
    x : array_like
        Signal, samples along ``axis``.
    method : str
        A key of :data:`METHODS`.
    axis : int
        Sample axis.
    **options
        Passed to the method (e.g. ``window=`` for ``moving-average``, ``alpha=`` for
        ``wavelet-2p``).

    Returns
    -------
    ndarray
    """
    entry = METHODS[check_choice(method, METHODS, "method")]
    try:
        return entry.func(x, axis=axis, **options)
    except TypeError as exc:
        raise HostConfigError(f"method {method!r}: bad options {sorted(options)}: {exc}") from exc


def denoised_mean(
    x: ArrayLike, method: str, *, axis: int = -1, **options: Any
) -> NDArray[np.float64]:
    """``mean(denoise(x, method, ...), axis)``: with less work where the method knows how.

    Wavelet thresholding reconstructs linearly, so the mean follows from the thresholded
    coefficients without the reconstruction (:func:`wavelet_denoise_mean`).
    """
    entry = METHODS[check_choice(method, METHODS, "method")]
    if not entry.has_mean:
        return np.mean(denoise(x, method, axis=axis, **options), axis=axis)
    if "mean" in options:
        raise HostConfigError(f"method {method!r}: bad options {sorted(options)}")
    try:
        return entry.func(x, axis=axis, mean=True, **options)
    except TypeError as exc:
        raise HostConfigError(f"method {method!r}: bad options {sorted(options)}: {exc}") from exc
