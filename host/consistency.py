"""Do the windows of a run agree with each other within their noise? A chi-square test.

A plan with redundant windows (more equations than unknowns: three or more positions, for example
0, 180, 180, 0 or 0, 90, 180, 270) over-determines the heading fit
``w_i = R(mu_i) h(alpha) + b`` (x and y gyro means of N windows: 2N equations for the heading and
two biases). What the fit leaves over must then be noise: with the windows' own noise
the weighted residual sum of squares is a chi-square with ``2N - 3`` degrees of freedom. A bias
step between windows, a drift, a table standing at another angle than its encoder says, or a
disturbance beyond the noise leaves more, and the test says so instead of letting a wrong heading
look right. Two positions leave one equation over (the size of the Earth rate), which cannot see
a bias step between the windows: such a plan is reported as not checked.

The test
--------
Each window's noise comes from its batch means (:func:`northfinder.host.procedure.batch_sem`,
19 degrees of freedom per axis). The per-sample variance of each axis is pooled over the windows
(windows of one run share one sensor), so the weights of the test are estimated with
``nu = 19 N`` degrees of freedom and the statistic ``T = sum (r / s)^2`` is referred to the
F distribution: ``T / dof ~ F(dof, nu)`` under white noise, where a known noise would give a
chi-square. The false-alarm rate is :data:`FALSE_ALARM` (1 %); ``tests/test_consistency.py``
checks it by Monte Carlo, and the test's power against a bias step.

When it fails
-------------
The residuals are compared with the patterns the usual causes leave (each a few extra columns of
the fit, tested by the drop in chi-square they give): a linear drift of the gyro biases, a bias
step between two consecutive windows, and a table angle error at one window. Every pattern that
leaves a remainder passing at a tenth of the false-alarm rate is listed, the one that explains
most first, with the shift of the azimuth that fitting it gives (what the heading would move by if
it were the cause). With few windows several patterns often explain the same
residuals: the list says which are possible, not which one happened. The sigma of an
inconsistent result is scaled by the Birge ratio ``sqrt(T / dof)``, so that it reflects the
scatter the windows show, and the result carries the warning.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.units import DPH, OMEGA_IE
from northfinder.host.heading import solve_multi_position
from northfinder.host.kernels import earth_rate_body, table_rotation

#: How every result whose consistency check failed begins its warning (text, JSON notes, plot
#: title): find's windows and a spin's halves alike (exit 3).
FAILED_MARKER = "CONSISTENCY CHECK FAILED"

__all__ = [
    "FALSE_ALARM",
    "NOISE_FLOOR_DPH",
    "ConsistencyCheck",
    "Explanation",
    "check_windows",
    "pooled_sem",
]

#: False-alarm rate of the test under white noise.
FALSE_ALARM = 0.01
#: A cause explains the residuals when what is left passes at this level (a tenth of the
#: false-alarm rate: the remainder is noise, which alone fails the 1 % test once in 100 runs).
EXPLAINED = FALSE_ALARM / 10
#: Smallest noise of a window mean the test assumes, deg/h: the resolution of the window means
#: and encoder angles (1e-6 deg of 12 deg/h is 2e-7 deg/h), so noise-free simulated windows are not
#: failed for their rounding. Any real gyro's window noise is far above it (paper-prototype:
#: 0.0035 deg/h per 10 s window).
NOISE_FLOOR_DPH = 1e-5
#: Degrees of freedom of one window's noise estimate per axis (20 batch means).
BATCH_DOF = 19


@dataclass(frozen=True)
class Explanation:
    """A cause that would account for the residuals.

    Attributes
    ----------
    kind : str
        ``drift``, ``bias step`` or ``table angle``.
    label : str
        What exactly, e.g. ``bias step between windows 2 and 3``.
    chi2_removed : float
        How much of the chi-square it accounts for.
    p_value : float
        p-value of what is left once it is fitted (it explains the residuals when this is at
        least a tenth of the false-alarm rate, :data:`EXPLAINED`).
    azimuth_shift_deg : float
        Change of the azimuth if it is fitted too, deg (linearised).
    """

    kind: str
    label: str
    chi2_removed: float
    p_value: float
    azimuth_shift_deg: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class ConsistencyCheck:
    """The outcome of :func:`check_windows`.

    ``checked`` False means the plan could not be checked (``reason`` says why); then
    ``consistent`` is None. Otherwise ``chi2`` with ``dof`` degrees of freedom (noise estimated
    with ``noise_dof``), its ``p_value``, ``consistent`` (p >= ``false_alarm``), the Birge ratio
    ``sigma_scale`` applied to the result's sigma when inconsistent, and the ``explanations``.
    """

    checked: bool
    reason: str = ""
    chi2: float | None = None
    dof: int = 0
    noise_dof: int = 0
    p_value: float | None = None
    false_alarm: float = FALSE_ALARM
    consistent: bool | None = None
    sigma_scale: float = 1.0
    explanations: tuple[Explanation, ...] = field(default=())
    #: Where a user-given latitude may be the cause of a failed check ("" when the latitude is
    #: the simulated truth's): the fit takes the Earth rate of that latitude as known.
    latitude_hint: str = ""

    def summary(self) -> str:
        """One line for people."""
        if not self.checked:
            return f"consistency not checked: {self.reason}"
        head = (
            f"chi2 {self.chi2:.1f} for {self.dof} dof, p = {self.p_value:.2g} "
            f"(false-alarm rate {self.false_alarm:g})"
        )
        if self.consistent:
            return f"consistency check passed: the windows agree within their noise ({head})"
        causes = "; ".join(
            f"{e.label} (fitting it shifts the azimuth by {_shift(e.azimuth_shift_deg)} deg)"
            for e in self.explanations
        )
        return (
            f"{FAILED_MARKER}: the windows disagree beyond their noise ({head}); the "
            f"azimuth may be wrong by more than its noise: sigma scaled x{self.sigma_scale:.2f}; "
            + (
                f"possible causes: {causes}"
                if causes
                else "no single drift, step or table angle error explains it"
            )
            + (f"; or a wrong latitude: {self.latitude_hint}" if self.latitude_hint else "")
        )

    def to_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in self.__dict__.items() if k not in ("explanations", "latitude_hint")}
        out["explanations"] = [e.to_dict() for e in self.explanations]
        out["summary"] = self.summary()
        return out


def _shift(deg: float) -> str:
    """A signed shift with four decimals; one that rounds to zero is written 0.0000, unsigned."""
    text = f"{deg:+.4f}"
    return "0.0000" if float(text) == 0.0 else text


def pooled_sem(sem: NDArray[np.float64], samples: Sequence[int]) -> NDArray[np.float64]:
    """Standard error of each window mean from the per-sample variance of each axis pooled over
    the windows (windows of one run share one sensor), shape of ``sem``.

    Each window's own estimate rests on 20 batch means (19 degrees of freedom: +-16 % in the
    standard error); weighting a fit by such estimates adds error of its own (a bias step that
    a symmetric plan cancels leaks into the heading through unequal weights). The pooled
    estimate has 19 N degrees of freedom.
    """
    sem = np.asarray(sem, dtype=float)
    counts = np.asarray(samples, dtype=float)[:, None]
    per_sample = np.mean(sem**2 * counts, axis=0)
    out: NDArray[np.float64] = np.sqrt(per_sample[None, :] / counts)
    return out


def _not_checked(n: int) -> ConsistencyCheck:
    return ConsistencyCheck(
        checked=False,
        reason=(
            f"{n} positions leave no redundancy (a bias step or drift between the windows would "
            "go unseen); measure redundant positions, e.g. 0,180,180,0"
        ),
    )


def check_windows(
    mu_deg: Sequence[float],
    gyro_dph: NDArray[np.float64],
    gyro_sem_dph: NDArray[np.float64],
    samples: Sequence[int],
    latitude_deg: float,
    *,
    accel_mps2: NDArray[np.float64] | None = None,
    accel_sem_mps2: NDArray[np.float64] | None = None,
    time_s: Sequence[float | None] | None = None,
    false_alarm: float = FALSE_ALARM,
) -> ConsistencyCheck:
    """Test the gyro window means of one run against their noise.

    Parameters
    ----------
    mu_deg : sequence of float, length N
        Encoder angle of each window, deg.
    gyro_dph : ndarray, shape (N, 2) or (N, 3)
        Gyro window means, deg/h (z unused).
    gyro_sem_dph : ndarray, shape (N, 2) or (N, 3)
        Their standard errors from batch means, deg/h.
    samples : sequence of int
        Samples per window (to pool the per-sample variance).
    latitude_deg : float
    accel_mps2, accel_sem_mps2 : ndarray, shape (N, 3), optional
        Accelerometer means and standard errors, for the tilt of the fit.
    time_s : sequence of float, optional
        Mid time of each window, s (device time), for the drift pattern.
    false_alarm : float
        Probability of failing a run of white noise.

    Returns
    -------
    ConsistencyCheck
    """
    n = len(mu_deg)
    dof = 2 * n - 3
    if n < 3:
        return _not_checked(n)
    mu = np.asarray(mu_deg, dtype=float)
    gyro = np.asarray(gyro_dph, dtype=float)[:, :2]
    sem = np.asarray(gyro_sem_dph, dtype=float)[:, :2]
    s = np.maximum(pooled_sem(sem, samples), NOISE_FLOOR_DPH)
    fit = solve_multi_position(
        gyro, mu, latitude_deg=latitude_deg, accel_means=accel_mps2, rate_unit="deg/h",
        gyro_noise=s,
        accel_noise=None if accel_sem_mps2 is None else np.maximum(accel_sem_mps2[:, :2], 1e-12),
    )  # fmt: skip
    w = (1.0 / s).ravel()
    r = fit.gyro_residuals.ravel() * w
    chi2 = float(r @ r)
    noise_dof = BATCH_DOF * n
    # The F distribution's survival function from scipy.special, imported here: scipy.stats
    # would add half a second to every find.
    from scipy.special import fdtrc

    p = float(fdtrc(dof, noise_dof, chi2 / dof))
    consistent = p >= false_alarm
    if consistent:
        return ConsistencyCheck(True, "", chi2, dof, noise_dof, p, false_alarm, True, 1.0)

    lat = math.radians(latitude_deg)
    omega_n, omega_u = OMEGA_IE * math.cos(lat) / DPH, OMEGA_IE * math.sin(lat) / DPH
    alpha = -math.radians(fit.azimuth_deg)
    theta, gamma = math.radians(fit.pitch_deg), math.radians(fit.roll_deg)
    h, dh = earth_rate_body(alpha, theta, gamma, omega_n, omega_u)
    rot = table_rotation(np.radians(mu))
    jac = np.zeros((2 * n, 3))
    jac[:, 0] = np.einsum("nij,j->ni", rot, dh[:, 0]).ravel()
    jac[:, 1:] = np.tile(np.eye(2), (n, 1))
    jac *= w[:, None]
    explanations = []
    for kind, label, cols in _patterns(mu, rot, h, time_s):
        e = cols * w[:, None]
        full = np.hstack([jac, e])
        coef, *_ = np.linalg.lstsq(full, r, rcond=None)
        rank = np.linalg.matrix_rank(full) - 3
        if rank < 1:
            continue
        left = float(np.sum((r - full @ coef) ** 2))
        dof_left = dof - rank
        p_left = 1.0 if dof_left < 1 else float(fdtrc(dof_left, noise_dof, left / dof_left))
        if p_left >= false_alarm * (EXPLAINED / FALSE_ALARM):
            explanations.append(
                Explanation(kind, label, chi2 - left, p_left, -math.degrees(float(coef[0])))
            )
    explanations.sort(key=lambda e: -e.chi2_removed)
    return ConsistencyCheck(
        True, "", chi2, dof, noise_dof, p, false_alarm, False,
        max(1.0, math.sqrt(chi2 / dof)), tuple(explanations),
    )  # fmt: skip


def _patterns(
    mu: NDArray[np.float64],
    rot: NDArray[np.float64],
    h: NDArray[np.float64],
    time_s: Sequence[float | None] | None,
) -> list[tuple[str, str, NDArray[np.float64]]]:
    """(kind, label, columns (2N, k)) of each cause tested, in model units (deg/h per unit)."""
    n = len(mu)
    out = []
    if time_s is not None and all(t is not None for t in time_s):
        t = np.asarray(time_s, dtype=float)
        t = (t - t.mean()) / 3600.0  # deg/h per hour
        cols = np.zeros((2 * n, 2))
        cols[0::2, 0] = t
        cols[1::2, 1] = t
        out.append(("drift", "a linear drift of the gyro biases", cols))
    for k in range(1, n):
        cols = np.zeros((2 * n, 2))
        cols[2 * k :: 2, 0] = 1.0
        cols[2 * k + 1 :: 2, 1] = 1.0
        out.append(("bias step", f"a bias step between windows {k} and {k + 1}", cols))
    # d/dmu of R(mu) h: R'(mu) = [[-s, c], [-c, -s]].
    for i in range(n):
        c, sn = rot[i, 0, 0], rot[i, 0, 1]
        d = np.array([[-sn, c], [-c, -sn]]) @ h
        cols = np.zeros((2 * n, 1))
        cols[2 * i : 2 * i + 2, 0] = np.radians(d)  # per deg of table angle
        out.append(("table angle", f"a table angle error at window {i + 1}", cols))
    return out
