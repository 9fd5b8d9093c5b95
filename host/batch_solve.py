"""From window samples to azimuth errors and their statistics, for many runs at once.

The accuracy study (:mod:`northfinder.host.montecarlo`) draws the samples of every window of many
runs; this module reduces them: denoise and average every window (:func:`window_means`), solve
every run with the vectorised solvers of :mod:`northfinder.host.kernels`
(:func:`chunk_errors`), and summarise the errors (:func:`summarize`). Conventions are those of
:mod:`northfinder.host.heading`: azimuth of body x clockwise from true north, table angles
right-handed about up, gyro means in rad/s, accelerometer means (specific force) in m/s^2.

A run whose tilt is beyond :data:`~northfinder.host.kernels.MAX_SOLVER_TILT_DEG` (or whose least-squares
fit does not converge) has no solution: its error is NaN, and :class:`Summary` counts it in
``rejected`` instead of hiding it in the statistics.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.host.denoise import METHODS, denoised_mean
from northfinder.host.errors import InputError, check_choice
from northfinder.host.kernels import (
    MAX_SOLVER_TILT_DEG,
    solve_least_squares_batch,
    solve_two_position_batch,
)
from northfinder.host.plan import resolve_solver

__all__ = [
    "Summary",
    "azimuth_errors",
    "chunk_errors",
    "summarize",
    "summarize_columns",
    "window_means",
]


def window_means(
    samples: ArrayLike,
    method: str = "none",
    *,
    axis: int = -1,
    options: Mapping[str, Any] | None = None,
) -> NDArray[np.float64]:
    """Mean of every window after denoising with a :data:`northfinder.host.denoise.METHODS` method.

    Parameters
    ----------
    samples : array_like
        Samples along ``axis`` (any other axes: runs, positions, channels).
    method : str
        Denoising method name (``none``: the plain mean).
    axis : int
        Sample axis.
    options : mapping, optional
        Passed to the method.

    Returns
    -------
    ndarray
        ``samples`` with ``axis`` reduced.
    """
    check_choice(method, METHODS, "denoise", "method")
    if method == "none":
        return np.mean(np.asarray(samples, dtype=float), axis=axis)
    return denoised_mean(samples, method, axis=axis, **dict(options or {}))


def azimuth_errors(estimate_deg: ArrayLike, truth_deg: ArrayLike) -> NDArray[np.float64]:
    """Estimate minus truth wrapped to [-180, 180) deg."""
    d = np.asarray(estimate_deg, dtype=float) - np.asarray(truth_deg, dtype=float)
    return np.mod(d + 180.0, 360.0) - 180.0


def chunk_errors(
    gyro: NDArray[np.float64],
    accel: NDArray[np.float64] | None,
    angles_deg: ArrayLike,
    truth_azimuth_deg: ArrayLike,
    latitude_deg: float,
    *,
    solver: str = "auto",
    denoise_method: str = "none",
    denoise_options: Mapping[str, Any] | None = None,
    denoise_accel: bool = False,
) -> NDArray[np.float64]:
    """Azimuth errors of a chunk of runs from their window samples.

    Parameters
    ----------
    gyro : ndarray, shape (R, P, n, 3)
        Gyro samples of every window, rad/s (only x and y are used).
    accel : ndarray, shape (R, P, n, 3), or None
        Accelerometer samples, m/s^2; None assumes a level instrument.
    angles_deg : array_like, shape (R, P) or (P,)
        Table angles the solver uses (encoder readings or commanded angles), deg.
    truth_azimuth_deg : array_like, shape (R,)
        True azimuth of each run.
    latitude_deg : float
    solver : str
        A key of :data:`northfinder.host.plan.SOLVERS`.
    denoise_method : str
        A key of :data:`northfinder.host.denoise.METHODS`, applied to every window of gyro x and y.
    denoise_options : mapping, optional
        Options of the method.
    denoise_accel : bool
        Also denoise the accelerometer windows (else their plain means).

    Returns
    -------
    ndarray
        Shape (R,), or (R, P - 1) for ``pairwise``, deg; NaN for a run without a solution.
    """
    if gyro.ndim != 4 or gyro.shape[-1] < 2:
        raise InputError(f"gyro: expected shape (runs, positions, samples, 3), got {gyro.shape}")
    p = gyro.shape[1]
    solver = resolve_solver(solver, p, "solver")
    # Channels first and samples last, (2, R, P, n): the simulator's channel-major memory is then
    # read in order. Means come back as (R, P, 2).
    gm = np.moveaxis(
        window_means(gyro[..., :2].transpose(3, 0, 1, 2), denoise_method, options=denoise_options),
        0,
        -1,
    )
    am = None
    if accel is not None:
        a = accel[..., :2].transpose(3, 0, 1, 2)
        am = np.moveaxis(
            window_means(a, denoise_method, options=denoise_options)
            if denoise_accel
            else a.mean(axis=-1),
            0,
            -1,
        )
    ang = np.broadcast_to(np.asarray(angles_deg, dtype=float), gm.shape[:2])
    truth = np.asarray(truth_azimuth_deg, dtype=float)
    if solver == "least-squares":
        az = solve_least_squares_batch(gm, ang, latitude_deg=latitude_deg, accel_means=am)
        # Azimuth at table angle 0; the truth is the body azimuth, also at table angle 0.
        return azimuth_errors(az, truth)

    def pair(k: int) -> NDArray[np.float64]:
        az = solve_two_position_batch(
            gm[:, 0],
            gm[:, k],
            ang[:, k] - ang[:, 0],
            latitude_deg=latitude_deg,
            accel0=None if am is None else am[:, 0],
            accel1=None if am is None else am[:, k],
        )
        # The two-position solution is the azimuth of body x at the first window's table angle.
        return azimuth_errors(az, truth - ang[:, 0])

    if solver == "two-position":
        return pair(1)
    return np.stack([pair(k) for k in range(1, p)], axis=-1)


@dataclass(frozen=True)
class Summary:
    """Statistics of azimuth errors, deg.

    Attributes
    ----------
    runs : int
        Runs with a solution (the statistics are over these).
    bias_deg, std_deg, rmse_deg, max_abs_deg : float
    rmse_rel_se : float
        Relative standard error of the RMSE (1 / sqrt(2 runs) for Gaussian errors).
    rejected : int
        Runs without a solution (NaN errors): tilt beyond the solvers' limit, or a least-squares
        fit that did not converge.
    """

    runs: int
    bias_deg: float
    std_deg: float
    rmse_deg: float
    max_abs_deg: float
    rmse_rel_se: float
    rejected: int = 0


def _summary(col: NDArray[np.float64]) -> Summary:
    ok = col[np.isfinite(col)]
    rejected = int(col.size - ok.size)
    if ok.size < 2:
        raise InputError(
            f"errors: need at least 2 solved runs, got {ok.size} of {col.size}; {rejected} had "
            f"no solution (tilt beyond +-{MAX_SOLVER_TILT_DEG:g} deg or a fit that did not converge)"
        )
    rmse = float(np.sqrt(np.mean(ok * ok)))
    kurt = float(np.mean(ok**4)) / max(float(np.mean(ok * ok)) ** 2, 1e-300)
    return Summary(
        runs=int(ok.size),
        bias_deg=float(ok.mean()),
        std_deg=float(ok.std(ddof=1)),
        rmse_deg=rmse,
        max_abs_deg=float(np.abs(ok).max()),
        # var(mean e^2) / (4 rmse^4) = (kurtosis - 1) / (4 n) for the squared errors.
        rmse_rel_se=math.sqrt(max(kurt - 1.0, 0.0) / (4.0 * ok.size)),
        rejected=rejected,
    )


def summarize(errors_deg: ArrayLike) -> Summary:
    """Bias, standard deviation, RMSE and largest error of the errors of many runs.

    Parameters
    ----------
    errors_deg : array_like, shape (R,)
        One error per run, deg; NaN for a run without a solution (counted in ``rejected``).

    Raises
    ------
    InputError
        Not one-dimensional, or fewer than two runs with a solution.
    """
    e = np.asarray(errors_deg, dtype=float)
    if e.ndim != 1:
        raise InputError(f"errors: expected shape (runs,), got {e.shape}; see summarize_columns")
    if e.size < 2:
        raise InputError(f"errors: need at least 2 runs, got {e.size}")
    return _summary(e)


def summarize_columns(errors_deg: ArrayLike) -> list[Summary]:
    """:func:`summarize` of every column of errors shaped (runs, solutions), e.g. ``pairwise``."""
    e = np.asarray(errors_deg, dtype=float)
    if e.ndim != 2 or e.shape[0] < 2:
        raise InputError(f"errors: expected shape (runs >= 2, solutions), got {e.shape}")
    return [_summary(col) for col in e.T]
