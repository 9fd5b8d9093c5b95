"""Allan deviation of rate records, used to read ARW, bias instability and rate random walk."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.host.errors import HostConfigError


def allan_deviation(
    rate: ArrayLike, sample_rate_hz: float, taus_s: ArrayLike | None = None, *, axis: int = 0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Overlapping Allan deviation of a rate record.

    Parameters
    ----------
    rate : array_like
        Rate samples (any unit), equally spaced along ``axis``.
    sample_rate_hz : float
        Sample rate, Hz.
    taus_s : array_like, optional
        Cluster times, s. Default: about 10 per decade from one sample to a ninth of the record.
        Each is rounded to a whole number of samples; duplicates are removed.
    axis : int
        Time axis of ``rate``.

    Returns
    -------
    taus : (k,) ndarray
        The cluster times used, s.
    adev : ndarray
        Allan deviation in the unit of ``rate``, shape ``(k, ...)`` with the other axes of ``rate``.
    """
    y = np.moveaxis(np.asarray(rate, dtype=float), axis, 0)
    n = y.shape[0]
    if n < 3:
        raise HostConfigError(f"rate: need at least 3 samples for an Allan deviation, got {n}")
    if not np.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
        raise HostConfigError(f"sample_rate_hz: must be positive, got {sample_rate_hz!r}")
    if taus_s is None:
        ms = np.unique(np.round(np.logspace(0, np.log10(max(n // 9, 1)), 10 * 8)).astype(int))
    else:
        ms = np.unique(np.round(np.asarray(taus_s, dtype=float) * sample_rate_hz).astype(int))
        if ms.size == 0 or ms.min() < 1 or 2 * ms.max() >= n:
            raise HostConfigError(
                f"taus_s: each must span at least one sample and at most a third of the "
                f"{n / sample_rate_hz:g} s record"
            )
    tau0 = 1.0 / sample_rate_hz
    theta = np.concatenate([np.zeros((1, *y.shape[1:])), np.cumsum(y, axis=0)]) * tau0
    out = np.empty((ms.size, *y.shape[1:]))
    for i, m in enumerate(ms):
        d = theta[2 * m :] - 2.0 * theta[m:-m] + theta[: -2 * m]
        out[i] = np.sqrt(np.mean(d * d, axis=0) / 2.0) / (m * tau0)
    return ms * tau0, out
