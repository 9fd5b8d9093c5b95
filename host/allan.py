"""Allan deviation of rate records with confidence intervals, and the IEEE Std 952 noise fit.

The overlapping Allan deviation and its equivalent degrees of freedom (Greenhall's algorithm)
come from ``allantools``. A rate record is the instrument's output: each sample the mean rate
over its interval (any unit; deg/h below), so it is allantools' "frequency" data.

IEEE Std 952 (Annex C) writes the Allan variance of a gyro as a sum of independent terms,

    sigma^2(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2,

quantisation Q (rate x s: the angle quantum / sqrt(12)), angle random walk N (rate x sqrt(s)),
bias instability B (rate; the flat floor is 0.664 B), rate random walk K (rate / sqrt(s)) and
rate ramp R (rate / s). :func:`fit_ieee952` fits the non-negative coefficients by weighted least
squares on the variance, each point weighted by its variance 2 sigma^4 / edf at the model (the
edf for the noise type that dominates the model there), iterated to convergence. The Allan
variances at neighbouring tau are correlated, which this weighting ignores, so the coefficient
uncertainties from the fit alone are too small: the variances are scaled by the number of
cluster times per octave (values within an octave share most of their data) and by the residual
chi-squared per degree of freedom when that exceeds one. A term counts as *resolved* when it is
at least three times its uncertainty and supplies most of the model variance at some cluster
time where the curve has ten or more degrees of freedom; otherwise :attr:`NoiseFit.upper` gives the largest value the
measured curve's 95 % upper bound allows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import allantools
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls
from scipy.stats import chi2

from northfinder.host.errors import HostConfigError

__all__ = [
    "TERMS",
    "AllanCurve",
    "NoiseFit",
    "allan_curve",
    "allan_deviation",
    "fit_ieee952",
    "pool_curves",
]

#: The IEEE 952 terms, in the order of :attr:`NoiseFit.coefficients`.
TERMS = ("quantisation", "arw", "bias_instability", "rrw", "rate_ramp")
#: Noise-type exponent alpha (frequency PSD ~ f^alpha) of each term, for the edf; the ramp is no
#: power law and takes the steepest type the estimator allows.
_ALPHA = {"quantisation": 2, "arw": 0, "bias_instability": -1, "rrw": -2, "rate_ramp": -2}
_FLOOR = 2.0 * math.log(2.0) / math.pi


def _basis(taus: NDArray[np.float64]) -> NDArray[np.float64]:
    """Allan variance of each term at unit coefficient, (k, 5)."""
    t = np.asarray(taus, dtype=float)
    return np.stack([3.0 / t**2, 1.0 / t, np.full_like(t, _FLOOR), t / 3.0, t**2 / 2.0], axis=-1)


def _check_record(y: NDArray[np.float64], sample_rate_hz: float) -> None:
    if y.shape[0] < 3:
        raise HostConfigError(
            f"rate: need at least 3 samples for an Allan deviation, got {y.shape[0]}"
        )
    if not math.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
        raise HostConfigError(f"sample_rate_hz: must be positive, got {sample_rate_hz!r}")
    if not np.all(np.isfinite(y)):
        raise HostConfigError("rate: contains non-finite samples")


def _cluster_sizes(n: int, sample_rate_hz: float, taus_s: ArrayLike | None, per_decade: int):
    if taus_s is None:
        top = max(n // 9, 1)
        return np.unique(np.round(np.logspace(0, math.log10(top), per_decade * 8)).astype(int))[
            : None if top > 1 else 1
        ]
    ms = np.unique(np.round(np.asarray(taus_s, dtype=float) * sample_rate_hz).astype(int))
    if ms.size == 0 or ms.min() < 1 or 2 * ms.max() >= n:
        raise HostConfigError(
            f"taus_s: each must span at least one sample and at most a third of the "
            f"{n / sample_rate_hz:g} s record"
        )
    return ms


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
    _check_record(y, sample_rate_hz)
    ms = _cluster_sizes(y.shape[0], sample_rate_hz, taus_s, 10)
    flat = y.reshape(y.shape[0], -1)
    out = np.empty((ms.size, flat.shape[1]))
    for j in range(flat.shape[1]):
        _, dev, _, _ = allantools.oadev(
            flat[:, j], rate=sample_rate_hz, data_type="freq", taus=ms / sample_rate_hz
        )
        out[:, j] = dev
    return ms / sample_rate_hz, out.reshape((ms.size, *y.shape[1:]))


@dataclass(frozen=True)
class AllanCurve:
    """An overlapping Allan deviation with what its confidence intervals need.

    Attributes
    ----------
    taus_s : (k,) float
        Cluster times, s.
    adev : (k,) float
        Allan deviation, unit of the rate.
    terms : (k,) int
        Number of overlapping second differences behind each value.
    samples : (k,) int
        Samples of the records behind each value (for the edf).
    clusters : (k,) int
        Cluster size in samples.
    records : (k,) int
        Independent records behind each value (those long enough for its cluster time).
    """

    taus_s: NDArray[np.float64]
    adev: NDArray[np.float64]
    terms: NDArray[np.int64]
    samples: NDArray[np.int64] = field(repr=False)
    clusters: NDArray[np.int64] = field(repr=False)
    records: NDArray[np.int64] = field(repr=False)

    @property
    def segments(self) -> int:
        """Records pooled into the curve (those behind its shortest cluster time)."""
        return int(self.records[0])

    def edf(self, alpha: ArrayLike = 0) -> NDArray[np.float64]:
        """Equivalent degrees of freedom of each value for the noise types ``alpha`` (one or one
        per value), summed over the pooled records (taken as of their mean length)."""
        al = np.broadcast_to(np.asarray(alpha), self.taus_s.shape)
        per = np.array(
            [
                allantools.edf_greenhall(
                    alpha=int(a), d=2, m=int(m), N=int(n // r), overlapping=True
                )
                for a, m, n, r in zip(al, self.clusters, self.samples, self.records, strict=True)
            ]
        )
        return per * self.records

    def interval(
        self, level: float = 0.6826894921370859, alpha: ArrayLike = 0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lower and upper bounds of the deviation at confidence ``level`` (chi-squared with the
        edf of noise types ``alpha``)."""
        edf = self.edf(alpha)
        lo = np.sqrt(edf / chi2.ppf(0.5 + level / 2.0, edf)) * self.adev
        hi = np.sqrt(edf / chi2.ppf(0.5 - level / 2.0, edf)) * self.adev
        return lo, hi


def allan_curve(
    rate: ArrayLike,
    sample_rate_hz: float,
    taus_s: ArrayLike | None = None,
    *,
    per_decade: int = 8,
) -> AllanCurve:
    """The overlapping Allan deviation of one rate record (1-D), with its term counts.

    ``taus_s`` as in :func:`allan_deviation`; by default ``per_decade`` values per decade from
    one sample to a ninth of the record.
    """
    y = np.asarray(rate, dtype=float)
    if y.ndim != 1:
        raise HostConfigError(f"rate: expected one axis of samples, got shape {y.shape}")
    _check_record(y, sample_rate_hz)
    ms = _cluster_sizes(y.size, sample_rate_hz, taus_s, per_decade)
    taus, dev, _, n = allantools.oadev(
        y, rate=sample_rate_hz, data_type="freq", taus=ms / sample_rate_hz
    )
    m = np.round(np.asarray(taus) * sample_rate_hz).astype(np.int64)
    return AllanCurve(
        taus_s=np.asarray(taus, dtype=float),
        adev=np.asarray(dev, dtype=float),
        terms=np.asarray(n, dtype=np.int64),
        samples=np.full(m.size, y.size, dtype=np.int64),
        clusters=m,
        records=np.ones(m.size, dtype=np.int64),
    )


def pool_curves(curves: Sequence[AllanCurve]) -> AllanCurve:
    """One curve from independent records of one sensor axis: the Allan variance at each
    cluster size averaged over the records that reach it, weighted by their term counts (long
    records carry the long cluster times alone, with the degrees of freedom they have).

    The records must share the sample rate (cluster sizes are matched in samples).
    """
    if not curves:
        raise HostConfigError("curves: need at least one Allan curve to pool")
    tau0 = {round(float(c.taus_s[0] / c.clusters[0]), 12) for c in curves}
    if len(tau0) > 1:
        raise HostConfigError("curves: records at different sample rates cannot be pooled")
    ms = np.unique(np.concatenate([c.clusters for c in curves]))
    var = np.zeros(ms.size)
    terms = np.zeros(ms.size, dtype=np.int64)
    samples = np.zeros(ms.size, dtype=np.int64)
    count = np.zeros(ms.size, dtype=np.int64)
    for c in curves:
        idx = np.searchsorted(ms, c.clusters)
        var[idx] += c.terms * c.adev**2
        terms[idx] += c.terms
        samples[idx] += c.samples
        count[idx] += 1
    t = float(curves[0].taus_s[0] / curves[0].clusters[0])
    return AllanCurve(
        taus_s=ms * t,
        adev=np.sqrt(var / terms),
        terms=terms,
        samples=samples,
        clusters=ms,
        records=count,
    )


@dataclass(frozen=True)
class NoiseFit:
    """The IEEE 952 coefficients fitted to an Allan curve (units of the rate ``u``).

    Attributes
    ----------
    coefficients : dict
        ``quantisation`` Q (u s), ``arw`` N (u sqrt(s)), ``bias_instability`` B (u),
        ``rrw`` K (u / sqrt(s)), ``rate_ramp`` R (u / s); 0 where the fit sets a term to zero.
    sigma : dict
        1-sigma of each coefficient from the weighted fit (a lower bound: see the module doc).
    resolved : dict
        Whether the record shows the term (module doc).
    upper : dict
        For an unresolved term, the largest coefficient the curve's 95 % upper bound allows.
    taus_s : (k,) float
        Cluster times fitted, s.
    chi2_per_dof : float
        Weighted residual sum of squares per degree of freedom (about 1 when the model fits).
    """

    coefficients: dict[str, float]
    sigma: dict[str, float]
    resolved: dict[str, bool]
    upper: dict[str, float]
    taus_s: NDArray[np.float64] = field(repr=False)
    chi2_per_dof: float = math.nan

    def adev(self, taus_s: ArrayLike) -> NDArray[np.float64]:
        """The fitted model's Allan deviation at ``taus_s``."""
        c = np.array([self.coefficients[t] for t in TERMS])
        return np.asarray(np.sqrt(_basis(np.asarray(taus_s, dtype=float)) @ (c * c)))

    def term_adev(self, term: str, taus_s: ArrayLike) -> NDArray[np.float64]:
        """One term's Allan deviation at ``taus_s``."""
        i = TERMS.index(term)
        basis = _basis(np.asarray(taus_s, dtype=float))[:, i]
        return np.asarray(np.sqrt(basis) * self.coefficients[term])


def fit_ieee952(
    curve: AllanCurve,
    terms: Sequence[str] = TERMS,
    *,
    iterations: int = 8,
) -> NoiseFit:
    """Fit the IEEE 952 terms ``terms`` to ``curve`` (see the module doc).

    Raises
    ------
    HostConfigError
        An unknown term name, or fewer cluster times than terms.
    """
    unknown = [t for t in terms if t not in TERMS]
    if unknown:
        raise HostConfigError(f"terms: unknown {unknown[0]!r}; choose from {', '.join(TERMS)}")
    use = [TERMS.index(t) for t in terms]
    taus = curve.taus_s
    if taus.size < len(use) + 1:
        raise HostConfigError(
            f"the Allan curve has {taus.size} cluster times; fitting {len(use)} terms needs more "
            "(a longer record)"
        )
    a = _basis(taus)[:, use]
    y = curve.adev**2
    model = y.copy()
    alpha = np.zeros(taus.size)
    coef = np.zeros(len(use))
    edf = curve.edf(alpha)
    for _ in range(iterations):
        w = np.sqrt(edf / 2.0) / np.maximum(model, 1e-300)  # 1 / sd of each variance
        coef, _ = nnls(a * w[:, None], y * w)
        new = a @ coef
        # The noise type of each point is that of the term that dominates the model there.
        parts = a * coef
        dominant = np.argmax(parts, axis=1)
        alpha = np.array([_ALPHA[TERMS[use[d]]] for d in dominant])
        edf = curve.edf(alpha)
        if np.allclose(new, model, rtol=1e-6):
            model = new
            break
        model = np.maximum(new, 1e-300)
    w = np.sqrt(edf / 2.0) / model
    aw = a * w[:, None]
    active = coef > 0
    cov = np.zeros((len(use), len(use)))
    if active.any():
        sub = aw[:, active]
        cov_sub = np.linalg.pinv(sub.T @ sub)
        cov[np.ix_(active, active)] = cov_sub
    resid = (y - model) * w
    dof = max(taus.size - int(active.sum()), 1)
    chi2_dof = float(resid @ resid / dof)
    # Values within an octave of cluster time share most of their data: count them as one.
    per_octave = max(taus.size / max(math.log2(taus[-1] / taus[0]), 1.0), 1.0)
    cov *= max(chi2_dof, 1.0) * per_octave
    _, upper95 = curve.interval(0.95, alpha)
    share = (a * coef) / model[:, None]
    out_c: dict[str, float] = dict.fromkeys(TERMS, 0.0)
    out_s: dict[str, float] = dict.fromkeys(TERMS, math.nan)
    out_r: dict[str, bool] = dict.fromkeys(TERMS, False)
    out_u: dict[str, float] = dict.fromkeys(TERMS, math.nan)
    for j, i in enumerate(use):
        name = TERMS[i]
        c2, var_c2 = coef[j], cov[j, j]
        c = math.sqrt(c2)
        # The fit is in c^2; d(c) = d(c^2) / (2 c).
        sd = math.sqrt(var_c2) / (2.0 * c) if c > 0 else math.nan
        out_c[name] = c
        out_s[name] = sd
        # Dominance counts only where the curve has ten or more degrees of freedom: the last few
        # cluster times of a record have a handful, and a rise there is as often chance.
        dominant = (share[:, j] >= 0.5) & (edf >= 10.0)
        out_r[name] = bool(c > 0 and c2 >= 3.0 * math.sqrt(var_c2) and dominant.any())
        if not out_r[name]:
            out_u[name] = float(np.sqrt(np.min(upper95**2 / a[:, j])))
    return NoiseFit(
        coefficients=out_c,
        sigma=out_s,
        resolved=out_r,
        upper=out_u,
        taus_s=taus,
        chi2_per_dof=chi2_dof,
    )
