"""The north-finding procedure on a device: wait for warm-up, rotate, settle, acquire, check, solve.

The procedure talks to anything with the driver's :class:`~northfinder.driver.device.Device` methods it uses
(``status``, ``get_config``, ``rotate_to``, ``acquire``, ``stop_streaming``), so it runs the same on
the simulator and on a real unit. It uses the encoder angles the device reports, never the
commanded ones.

What it measures is a :class:`~northfinder.host.plan.Plan` (the one plan type of studies and the
planner too). After each move the device settles on its own and reports READY; the procedure then
waits whatever remains of the plan's ``settle_s`` (see :mod:`northfinder.host.plan`). Time is
injected: ``sleep`` and ``clock`` default to the device's own clock (:class:`DeviceLike`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, ParamSpec, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.errors import DeviceFault, DriverTimeout, StreamGap
from northfinder.driver.protocol.constants import (
    VALIDITY_GOOD,
    VALIDITY_UNFIT,
    ConfigKey,
    DeviceState,
    Validity,
)
from northfinder.driver.protocol.motion import shortest_delta_deg
from northfinder.host import spin
from northfinder.host.consistency import ConsistencyCheck, check_windows, pooled_sem
from northfinder.host.denoise import check_denoise, denoise
from northfinder.host.errors import HostConfigError, HostError, QualityError
from northfinder.host.heading import (
    MIN_MU_SEPARATION_DEG,
    MultiPositionSolution,
    solve_multi_position,
    solve_two_position,
)
from northfinder.host.plan import HEADING_SOLVERS, Plan

__all__ = [
    "BAD_BITS",
    "DEFAULT_ON_GAP",
    "MAX_DEVICE_SETTLE_S",
    "MAX_ENCODER_SPAN_DEG",
    "MAX_REMEASURE",
    "METHOD_CHOICES",
    "ON_GAP_CHOICES",
    "READY_TIMEOUT_S",
    "WINDOW_RANGE_S",
    "DeviceClock",
    "DeviceLike",
    "FindProgress",
    "FindResult",
    "Plan",
    "PositionWindow",
    "QualityError",
    "SpinFind",
    "SpinningDeviceLike",
    "WindowsSolution",
    "base_attitude",
    "batch_sem",
    "check_plan_for_device",
    "extra_settle_s",
    "find_north",
    "find_north_spin",
    "result_from_windows",
    "solve_windows",
    "summarise_window",
    "unfit_samples",
    "wait_until_ready",
]

P = ParamSpec("P")
T = TypeVar("T")

#: Largest span of the encoder during a window before the window counts as moved, deg.
MAX_ENCODER_SPAN_DEG = 0.01
#: Batches used to estimate the standard error of a window mean (robust to correlated noise).
N_BATCHES = 20
#: Validity bits that make a sample unusable for north finding (protocol.md 4.5); a sample is
#: also unusable without both GYRO_VALID and ACCEL_VALID (:func:`unfit_samples`).
BAD_BITS = VALIDITY_UNFIT
#: Impulsive samples: farther from the window median than this many robust sigmas (MAD x 1.4826,
#: at least one output step).
OUTLIER_SIGMAS = 8.0
#: What a window with missing sample ticks (a damaged or lost frame) does, in this order. It is
#: measured again, kept with the gap reported in the result, or the run stops.
ON_GAP_CHOICES = ("remeasure", "report", "fail")
#: How often a window is measured again before the run stops (``on_gap="remeasure"``).
MAX_REMEASURE = 3
#: Solvers the procedure offers (a plan's ``pairwise`` is for studies: it gives no one heading).
METHOD_CHOICES = HEADING_SOLVERS
#: Window and settle-time limits of a run on a device, s.
WINDOW_RANGE_S = (0.5, 3600.0)
#: Longest settling a plan may ask of a device after a move, s (a study simulates longer ones).
MAX_DEVICE_SETTLE_S = 600.0
#: Longest wait for READY after the warm-up when none is given, device s.
READY_TIMEOUT_S = 600.0
#: What a window with missing sample ticks gets when nothing is said (see :func:`find_north`).
DEFAULT_ON_GAP = ON_GAP_CHOICES[0]


class WindowLike(Protocol):
    """What the procedure reads from a window (a live one or a recorded one)."""

    @property
    def gyro_dph(self) -> NDArray[np.float64]: ...
    @property
    def accel_mps2(self) -> NDArray[np.float64]: ...
    @property
    def table_deg(self) -> NDArray[np.float64]: ...
    @property
    def validity(self) -> NDArray[np.uint8]: ...
    @property
    def counter(self) -> NDArray[np.int64]: ...
    @property
    def time_s(self) -> NDArray[np.float64]: ...
    @property
    def missing(self) -> int: ...


class DeviceClock(Protocol):
    """The time a device keeps (the driver's :class:`~northfinder.driver.clock.WallClock` or
    :class:`~northfinder.driver.clock.VirtualClock`), s."""

    def now(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


class DeviceLike(Protocol):
    """Everything the procedures use of a device: the driver's
    :class:`~northfinder.driver.device.Device` has it all, and a stand-in in a test needs all of
    it too (no method is looked up by name at run time)."""

    @property
    def clock(self) -> DeviceClock: ...
    @property
    def last_status(self) -> Any: ...
    def status(self) -> Any: ...
    def wait_ready(self, timeout: float = ...) -> Any: ...
    def get_config(self, key: ConfigKey) -> int: ...
    def rotate_to(
        self, angle_deg: float, *, wait: bool = True, timeout: float | None = None
    ) -> Any: ...
    def acquire(
        self, seconds: float, *, on_gap: Literal["raise", "report"] = "raise"
    ) -> WindowLike: ...
    def stop_streaming(self) -> None: ...
    def release_stream(self) -> None: ...
    def leave_at_rest(self) -> Any: ...


class StreamedWindowLike(WindowLike, Protocol):
    """A window a device streamed, with the rate it streamed at (a spin solves against it)."""

    @property
    def sample_rate_hz(self) -> float: ...


class SpinningDeviceLike(DeviceLike, Protocol):
    """A device that can spin its table (protocol 1.1), as :func:`find_north_spin` uses it."""

    def acquire(
        self, seconds: float, *, on_gap: Literal["raise", "report"] = "raise"
    ) -> StreamedWindowLike: ...
    def spin(self, rate_dps: float, *, wait: bool = False, timeout: float | None = None) -> Any: ...
    def stop(self, *, wait: bool = False, timeout: float | None = None) -> Any: ...


def unfit_samples(validity: Any) -> NDArray[np.bool_]:
    """True for every sample north finding must not use (protocol.md 4.5): GYRO_VALID or
    ACCEL_VALID clear, or any of bits 2..7 set."""
    v = np.asarray(validity).astype(np.int64)
    good = int(VALIDITY_GOOD)
    return ((v & good) != good) | ((v & int(BAD_BITS)) != 0)


def check_plan_for_device(plan: Plan) -> None:
    """Refuse what a run on a device cannot do (the plan itself is already valid).

    Raises
    ------
    HostConfigError
        Window outside :data:`WINDOW_RANGE_S`, settle beyond :data:`MAX_DEVICE_SETTLE_S`, or a method
        other than :data:`METHOD_CHOICES` (``pairwise`` gives no single heading).
    """
    lo, hi = WINDOW_RANGE_S
    if not lo <= plan.window_s <= hi:
        raise HostConfigError(f"window: must be {lo:g} to {hi:g} s, got {plan.window_s}")
    if plan.settle_s is not None and plan.settle_s > MAX_DEVICE_SETTLE_S:
        raise HostConfigError(
            f"settle: must be 0 to {MAX_DEVICE_SETTLE_S:g} s, got {plan.settle_s}"
        )
    _check_method(plan)


def _check_method(plan: Plan) -> None:
    if plan.method not in METHOD_CHOICES:
        raise HostConfigError(
            f"method: {plan.method!r} gives no single heading; choose one of "
            f"{', '.join(METHOD_CHOICES)}"
        )


def extra_settle_s(plan: Plan, device_settle_s: float) -> float:
    """What the procedure waits after READY: the rest of the plan's settle time, s."""
    return 0.0 if plan.settle_s is None else max(0.0, plan.settle_s - device_settle_s)


@dataclass(frozen=True)
class PositionWindow:
    """One window's summary. Rates in deg/h, specific force in m/s^2, angles in deg."""

    commanded_deg: float
    encoder_deg: float
    samples: int
    gyro_dph: tuple[float, float, float]
    gyro_raw_dph: tuple[float, float, float]
    gyro_sem_dph: tuple[float, float, float]
    accel_mps2: tuple[float, float, float]
    accel_sem_mps2: tuple[float, float, float]
    outliers: int
    notes: tuple[str, ...] = ()
    time_s: float | None = None


@dataclass(frozen=True)
class FindResult:
    """The heading and how it was obtained.

    ``azimuth_deg`` is the azimuth of the instrument's reference (encoder zero), clockwise from
    true north; ``sigma_deg`` its 1-sigma estimate from the windows' own noise.
    """

    azimuth_deg: float
    sigma_deg: float | None
    pitch_deg: float
    roll_deg: float
    method: str
    denoise: str
    latitude_deg: float
    windows: tuple[PositionWindow, ...]
    pairwise_deg: tuple[float, ...] = ()
    notes: tuple[str, ...] = field(default=())
    latitude_source: str = ""
    check: ConsistencyCheck | None = None

    @property
    def consistent(self) -> bool | None:
        """True or False when the windows were checked against their noise, None when not."""
        return None if self.check is None else self.check.consistent

    def to_dict(self) -> dict[str, Any]:
        return {
            "azimuth_deg": self.azimuth_deg,
            "sigma_deg": self.sigma_deg,
            "pitch_deg": self.pitch_deg,
            "roll_deg": self.roll_deg,
            "method": self.method,
            "denoise": self.denoise,
            "latitude_deg": self.latitude_deg,
            "latitude_source": self.latitude_source,
            "consistent": self.consistent,
            "check": None if self.check is None else self.check.to_dict(),
            "positions": [w.encoder_deg for w in self.windows],
            "windows": [
                {
                    "commanded_deg": w.commanded_deg,
                    "encoder_deg": w.encoder_deg,
                    "samples": w.samples,
                    "gyro_mean_dph": list(w.gyro_dph),
                    "gyro_raw_mean_dph": list(w.gyro_raw_dph),
                    "gyro_sem_dph": list(w.gyro_sem_dph),
                    "accel_mean_mps2": list(w.accel_mps2),
                    "outliers": w.outliers,
                    "time_s": w.time_s,
                    "notes": list(w.notes),
                }
                for w in self.windows
            ],
            "pairwise_azimuth_deg": list(self.pairwise_deg),
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class FindProgress:
    """Where the procedure is, for a progress display."""

    phase: str  # "warm-up", "rotate", "settle", "acquire", "solve", "done"
    position: int  # 1-based index of the current position (0 before the first)
    positions: int
    table_deg: float | None
    seconds_left: float | None


def batch_sem(x: NDArray[np.float64], n_batches: int = N_BATCHES) -> NDArray[np.float64]:
    """Standard error of the mean along axis 0 from batch means (valid for correlated noise)."""
    n = x.shape[0] // n_batches * n_batches
    if n < n_batches * 2:
        return np.std(x, axis=0, ddof=1) / math.sqrt(max(x.shape[0], 1))
    means = x[:n].reshape(n_batches, -1, *x.shape[1:]).mean(axis=1)
    return np.std(means, axis=0, ddof=1) / math.sqrt(n_batches)


def _triad(v: NDArray[np.float64]) -> tuple[float, float, float]:
    x, y, z = (float(c) for c in v)
    return x, y, z


#: A gap that moves a window's mean time by this share of its length or more is named in the
#: window's note.
GAP_SHIFT_NOTED = 0.01


def summarise_window(
    window: WindowLike,
    commanded_deg: float,
    denoise_method: str,
    denoise_options: Mapping[str, Any] | None = None,
    *,
    allow_gaps: bool = False,
) -> PositionWindow:
    """Check one window and reduce it to means and standard errors.

    ``denoise_method`` (with ``denoise_options``) is applied to the gyro and accelerometer
    samples before their means; the raw gyro mean is kept beside.

    Raises
    ------
    QualityError
        Samples flagged moving/settling/saturated/warming/fault, the encoder moved, or samples
        are missing.
    """
    n = len(window.counter)
    if n < 2 * N_BATCHES:
        raise QualityError(f"window at {commanded_deg:g} deg has only {n} samples")
    gap_note = []
    if window.missing:
        if not allow_gaps:
            raise QualityError(
                f"window at {commanded_deg:g} deg is missing {window.missing} samples "
                "(--on-gap report solves it from the samples received)"
            )
        note = (
            f"{window.missing} of {n + window.missing} sample ticks missing (damaged or lost "
            "frames); the mean is of the samples received"
        )
        t = np.asarray(window.time_s, dtype=np.float64)
        span = float(t[-1] - t[0])
        shift = float(np.mean(t)) - float(t[0] + t[-1]) / 2.0
        if span > 0 and abs(shift) >= GAP_SHIFT_NOTED * span:
            # A long gap moves the time the mean stands for: a drifting bias then moves the
            # mean by drift x shift, which the symmetric plan no longer cancels.
            note += f", at {shift:+.3g} s from the window's middle"
        gap_note.append(note)
    bad = unfit_samples(window.validity)
    if bad.any():
        v = np.asarray(window.validity).astype(np.int64)[bad]
        flags = Validity(int(np.bitwise_or.reduce(v)) & int(BAD_BITS))
        cleared = Validity(int(VALIDITY_GOOD) & ~int(np.bitwise_and.reduce(v)))
        what = " and ".join(
            f"{name} {f!r}" for name, f in (("flagged", flags), ("without", cleared)) if f
        )
        raise QualityError(
            f"window at {commanded_deg:g} deg: {int(bad.sum())} of {n} samples unusable ({what})"
        )
    enc = np.asarray(window.table_deg, dtype=float)
    unwrapped = _unwrap_deg(enc)
    span = float(np.ptp(unwrapped))
    if span > MAX_ENCODER_SPAN_DEG:
        raise QualityError(
            f"the table moved {span:.4f} deg during the window at {commanded_deg:g} deg"
        )
    encoder = float(np.mean(unwrapped)) % 360.0
    gyro = np.asarray(window.gyro_dph, dtype=float)
    accel = np.asarray(window.accel_mps2, dtype=float)
    opts = dict(denoise_options or {})
    clean_g = denoise(gyro, denoise_method, axis=0, **opts) if denoise_method != "none" else gyro
    clean_a = denoise(accel, denoise_method, axis=0, **opts) if denoise_method != "none" else accel
    # Axis by axis: a window of hours takes one column's temporaries at a time, not three.
    med = np.array([np.median(gyro[:, k]) for k in range(3)])
    mad = np.array([np.median(np.abs(gyro[:, k] - med[k])) for k in range(3)])
    # A quantised, nearly noise-free output (the simulated ideal sensor) has a MAD of zero while
    # it toggles between neighbouring steps: the spread is at least one output step.
    spread = np.maximum(1.4826 * mad, _output_step(gyro))
    limit = OUTLIER_SIGMAS * np.maximum(spread, 1e-12)
    impulsive = np.zeros(n, dtype=bool)
    for k in range(3):
        impulsive |= np.abs(gyro[:, k] - med[k]) > limit[k]
    outliers = int(np.sum(impulsive))
    notes = gap_note
    if outliers > 0.005 * n:
        notes.append(
            f"{outliers} impulsive samples (vibration or shock); consider --denoise hampel"
        )
    return PositionWindow(
        commanded_deg=float(commanded_deg),
        encoder_deg=encoder,
        samples=n,
        gyro_dph=_triad(clean_g.mean(axis=0)),
        gyro_raw_dph=_triad(gyro.mean(axis=0)),
        gyro_sem_dph=_triad(batch_sem(clean_g)),
        accel_mps2=_triad(clean_a.mean(axis=0)),
        accel_sem_mps2=_triad(batch_sem(clean_a)),
        outliers=outliers,
        notes=tuple(notes),
        time_s=_mid_time(window),
    )


#: Samples unwrapped at a time by :func:`_unwrap_deg`.
_UNWRAP_BLOCK = 1 << 16


def _unwrap_deg(enc_deg: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.degrees(np.unwrap(np.radians(enc_deg)))`` to the last bit, in three arrays of the
    window's length rather than eight: numpy's steps (its ``unwrap``, period 2 pi) on a block of
    differences at a time, and one running sum of the corrections over the whole window."""
    p = np.radians(enc_deg)
    n = len(p)
    if n < 2:
        return np.degrees(p)
    period = 2 * np.pi
    discont = period / 2
    interval_high = period / 2
    interval_low = -interval_high
    correction = np.empty(n - 1)
    for a in range(0, n - 1, _UNWRAP_BLOCK):
        b = min(a + _UNWRAP_BLOCK, n - 1)
        dd = p[a + 1 : b + 1] - p[a:b]
        ddmod = np.mod(dd - interval_low, period) + interval_low
        np.copyto(ddmod, interval_high, where=(ddmod == interval_low) & (dd > 0))
        ph_correct = ddmod - dd
        np.copyto(ph_correct, 0, where=abs(dd) < discont)
        correction[a:b] = ph_correct
    np.cumsum(correction, out=correction)
    np.add(p[1:], correction, out=p[1:])
    del correction
    return np.degrees(p, out=p)


def _output_step(x: NDArray[np.float64]) -> float:
    """The output's step: the smallest step between distinct values of any column (the axes
    share one count), 0 when every column is constant."""
    steps = [np.diff(np.unique(x[:, k])) for k in range(x.shape[1])]
    positive = [float(s.min()) for s in steps if s.size]
    return min(positive) if positive else 0.0


def _mid_time(window: Any) -> float | None:
    """The time the window's mean stands for: its middle, or with ticks missing the mean time
    of the samples received."""
    t = getattr(window, "time_s", None)
    if t is None or len(t) == 0:
        return None
    if getattr(window, "missing", 0):
        return float(np.mean(t))
    return float((t[0] + t[-1]) / 2.0)


def _mat_nb(alpha: float, theta: float, gamma: float) -> NDArray[np.float64]:
    ca, sa, ct, st, cr, sr = (math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta),
                              math.cos(gamma), math.sin(gamma))  # fmt: skip
    return np.array(
        [
            [ca * ct, sa * ct, -st],
            [ca * st * sr - sa * cr, sa * st * sr + ca * cr, ct * sr],
            [ca * st * cr + sa * sr, sa * st * cr - ca * sr, ct * cr],
        ]
    )


def base_attitude(
    azimuth_deg: float, pitch_deg: float, roll_deg: float, mu0_deg: float
) -> tuple[float, float, float]:
    """Azimuth, pitch and roll of the base from those of the sensor frame at table angle ``mu0``.

    The sensor frame is C_m^m1(mu0) C_n^b; Euler angles do not simply add under tilt, so the
    base attitude is recovered from the direction cosine matrix.
    """
    if mu0_deg % 360.0 == 0.0:
        return azimuth_deg % 360.0, pitch_deg, roll_deg
    m = math.radians(mu0_deg)
    c_table = np.array(
        [[math.cos(m), math.sin(m), 0.0], [-math.sin(m), math.cos(m), 0.0], [0.0, 0.0, 1.0]]
    )
    c_sensor = _mat_nb(-math.radians(azimuth_deg), math.radians(pitch_deg), math.radians(roll_deg))
    c_nb = c_table.T @ c_sensor
    pitch = -math.asin(max(-1.0, min(1.0, c_nb[0, 2])))
    alpha = math.atan2(c_nb[0, 1], c_nb[0, 0])
    roll = math.atan2(c_nb[1, 2], c_nb[2, 2])
    return (-math.degrees(alpha)) % 360.0, math.degrees(pitch), math.degrees(roll)


@dataclass(frozen=True)
class PairSolution:
    """The heading from one pair of consecutive windows (``first`` and ``first + 1``, 0-based)."""

    first: int
    azimuth_deg: float
    sigma_deg: float | None


def pairwise_solutions(
    windows: Sequence[PositionWindow], latitude_deg: float
) -> list[PairSolution]:
    """The two-position heading of every pair of consecutive windows whose table angles differ
    by at least :data:`~northfinder.host.heading.MIN_MU_SEPARATION_DEG`, with its 1-sigma from the
    windows' own noise (the spread of these shows what one pair can tell)."""
    out = []
    for i in range(len(windows) - 1):
        a, b = windows[i], windows[i + 1]
        d = (b.encoder_deg - a.encoder_deg) % 360.0
        if not MIN_MU_SEPARATION_DEG <= d <= 360.0 - MIN_MU_SEPARATION_DEG:
            continue
        g_sem = np.maximum(np.array([a.gyro_sem_dph, b.gyro_sem_dph])[:, :2], 1e-9)
        a_sem = np.maximum(np.array([a.accel_sem_mps2, b.accel_sem_mps2])[:, :2], 1e-12)
        s = solve_two_position(
            a.gyro_dph, b.gyro_dph, d, accel0=a.accel_mps2, accel1=b.accel_mps2,
            latitude_deg=latitude_deg, rate_unit="deg/h", gyro_noise=g_sem, accel_noise=a_sem,
        )  # fmt: skip
        azimuth = base_attitude(s.azimuth_deg, s.pitch_deg, s.roll_deg, a.encoder_deg)[0]
        out.append(PairSolution(i, azimuth, s.sigma_deg))
    return out


@dataclass(frozen=True)
class WindowsSolution:
    """What :func:`solve_windows` finds: the heading and its 1-sigma, the base's tilt and the
    azimuth of each pair of windows (:func:`pairwise_solutions`), deg."""

    azimuth_deg: float
    sigma_deg: float | None
    pitch_deg: float
    roll_deg: float
    pairwise_deg: tuple[float, ...]


def solve_windows(
    windows: Sequence[PositionWindow], latitude_deg: float, plan: Plan
) -> WindowsSolution:
    """Heading, sigma, pitch, roll and pairwise azimuths from summarised windows.

    ``plan.solver`` picks the solver (``pairwise`` is refused: it gives no single heading).
    """
    _check_method(plan)
    mu = np.array([w.encoder_deg for w in windows])
    gyro = np.array([w.gyro_dph for w in windows])
    accel = np.array([w.accel_mps2 for w in windows])
    # Weights from each axis's noise pooled over the windows (consistency.pooled_sem); floors
    # far below any sensor's noise keep noise-free (simulated ideal) windows well posed.
    samples = [w.samples for w in windows]
    g_sem = np.maximum(
        pooled_sem(np.array([w.gyro_sem_dph for w in windows])[:, :2], samples), 1e-9
    )
    a_sem = np.maximum(
        pooled_sem(np.array([w.accel_sem_mps2 for w in windows])[:, :2], samples), 1e-12
    )
    pairwise = [p.azimuth_deg for p in pairwise_solutions(windows, latitude_deg)]
    if plan.solver == "two-position":
        d = float((mu[1] - mu[0]) % 360.0)
        s = solve_two_position(
            gyro[0], gyro[1], d, accel0=accel[0], accel1=accel[1], latitude_deg=latitude_deg,
            rate_unit="deg/h", gyro_noise=g_sem, accel_noise=a_sem,
        )  # fmt: skip
        azimuth, pitch, roll = base_attitude(s.azimuth_deg, s.pitch_deg, s.roll_deg, float(mu[0]))
        return WindowsSolution(azimuth, s.sigma_deg, pitch, roll, tuple(pairwise))
    m: MultiPositionSolution = solve_multi_position(
        gyro, mu, latitude_deg=latitude_deg, accel_means=accel, rate_unit="deg/h",
        gyro_noise=g_sem, accel_noise=a_sem,
    )  # fmt: skip
    return WindowsSolution(
        m.azimuth_deg % 360.0, m.sigma_deg, m.pitch_deg, m.roll_deg, tuple(pairwise)
    )


def result_from_windows(
    windows: Sequence[PositionWindow],
    latitude_deg: float,
    plan: Plan,
    *,
    latitude_source: str = "",
) -> FindResult:
    """Solve summarised windows and check them against their noise (the one way ``find`` and
    ``solve`` reach a result).

    With redundant windows (:mod:`northfinder.host.consistency`) a failed check scales the
    sigma by its Birge ratio and adds the warning to the notes; a plan without redundancy says
    in the notes that it was not checked.
    """
    solved = solve_windows(windows, latitude_deg, plan)
    sigma = solved.sigma_deg
    check = check_windows(
        [w.encoder_deg for w in windows],
        np.array([w.gyro_dph for w in windows]),
        np.array([w.gyro_sem_dph for w in windows]),
        [w.samples for w in windows],
        latitude_deg,
        accel_mps2=np.array([w.accel_mps2 for w in windows]),
        accel_sem_mps2=np.array([w.accel_sem_mps2 for w in windows]),
        time_s=[w.time_s for w in windows],
    )
    if check.consistent is False and latitude_source and "simulated" not in latitude_source:
        # A latitude the user gave can be wrong; the fit takes its Earth rate as known.
        check = dataclasses.replace(
            check,
            latitude_hint=f"{latitude_deg:g} deg (from {latitude_source}); check the site's latitude",
        )
    notes = [f"position {i + 1}: {n}" for i, w in enumerate(windows) for n in w.notes]
    notes.append(check.summary())
    if sigma is not None and check.consistent is False:
        sigma *= check.sigma_scale
    return FindResult(
        azimuth_deg=solved.azimuth_deg,
        sigma_deg=sigma,
        pitch_deg=solved.pitch_deg,
        roll_deg=solved.roll_deg,
        method=plan.solver,
        denoise=plan.denoise,
        latitude_deg=latitude_deg,
        windows=tuple(windows),
        pairwise_deg=solved.pairwise_deg if len(windows) > 2 else (),
        notes=tuple(notes),
        latitude_source=latitude_source,
        check=check,
    )


def _state_name(status: Any) -> str:
    state = getattr(status, "state", status)
    return DeviceState(int(state)).name


#: How often the procedure asks for the status while the device warms up, s.
WARMUP_POLL_S = 0.5


def wait_until_ready(
    device: DeviceLike,
    warmup_timeout_s: float,
    on_wait: Callable[[Any], None] | None = None,
    *,
    clock: Callable[[], float] | None = None,
) -> None:
    """Wait until ``device`` is READY (its warm-up over), calling ``on_wait`` with the status at
    every poll; raise :class:`HostError` on FAULT or after ``warmup_timeout_s`` (by ``clock``,
    default the device's own). The device's heartbeats are waited for on its own clock
    (:meth:`~northfinder.driver.device.Device.wait_ready`)."""
    report = on_wait or (lambda status: None)
    now: Callable[[], float] = clock or device.clock.now
    deadline = now() + warmup_timeout_s
    # A device that reports its status by itself (heartbeats, protocol.md 6) is watched, not
    # asked: one GET_STATUS first, then the heartbeats until READY, with a progress report every
    # WARMUP_POLL_S.
    status = device.status()
    while True:
        state = _state_name(status)
        if state == "READY":
            break
        if state == "FAULT":
            raise HostError(
                f"the device is in FAULT (faults {getattr(status, 'faults', '?')!r}); reset it "
                "(northfinder reset, or Device.reset())"
            )
        if now() > deadline:
            raise HostError(
                f"the device did not become READY within {warmup_timeout_s:g} s (state {state})"
            )
        report(status)
        try:
            status = device.wait_ready(timeout=WARMUP_POLL_S)
        except DeviceFault:
            status = device.status()  # FAULT: reported below, as when asked
        except DriverTimeout:
            status = device.last_status or device.status()


def _at_rest_on_error(procedure: Callable[P, T]) -> Callable[P, T]:
    """However ``procedure`` ends early (an error, a lost link, Ctrl-C, an exception in a
    callback of the caller's): leave the device at rest (its ``leave_at_rest``: STOP a move or
    spin and STREAM_STOP a stream this host started, each repeated until answered) before the
    exception goes on, whatever the caller then does with the device."""

    @functools.wraps(procedure)
    def run(*args: P.args, **kwargs: P.kwargs) -> T:
        try:
            return procedure(*args, **kwargs)
        except BaseException:
            device = args[0] if args else kwargs["device"]
            device.leave_at_rest()  # type: ignore[attr-defined]
            raise

    return run


@_at_rest_on_error
def find_north(
    device: DeviceLike,
    plan: Plan,
    latitude_deg: float,
    *,
    warmup_timeout_s: float = READY_TIMEOUT_S,
    progress: Callable[[FindProgress], None] | None = None,
    sleep: Callable[[float], None] | None = None,
    clock: Callable[[], float] | None = None,
    latitude_source: str = "",
    on_window: Callable[[int, Any], None] | None = None,
    on_gap: str = DEFAULT_ON_GAP,
    keep_windows: bool = True,
) -> tuple[FindResult, list[Any]]:
    """Run the plan on ``device`` and solve; return the result and the raw windows (none when
    ``keep_windows`` is false).

    Parameters
    ----------
    device : DeviceLike
        The instrument (a driver :class:`~northfinder.driver.device.Device` or alike).
    plan : Plan
        Positions, window, settle time, denoising and solver (``auto``, ``two-position`` or
        ``least-squares``).
    latitude_deg : float
        Latitude of the site, deg.
    warmup_timeout_s : float
        Longest wait for READY, s (by ``clock``).
    progress : callable, optional
        Called with a :class:`FindProgress` at every phase.
    sleep, clock : callable
        How to wait and what time it is, s (default: the device's own clock, ``device.clock``,
        so that a device in virtual time is waited for in virtual time).
    latitude_source : str
        Where the latitude came from, stated in the result.
    on_window : callable, optional
        Called with the 0-based index and the raw window as soon as each window is measured
        (before its checks), e.g. to write it to disk while the run goes on.
    on_gap : {"remeasure", "report", "fail"}
        A window with missing sample ticks (a damaged or lost frame): measure it again (up to
        :data:`MAX_REMEASURE` times, then stop), keep it and state the gap in the result's
        notes, or stop the run (:class:`~northfinder.driver.errors.StreamGap`).
    keep_windows : bool
        Keep each raw window to return it. False: each window goes to ``on_window``, is
        summarised and dropped, so that memory does not grow with the plan's length.

    Raises
    ------
    HostError
        Warm-up did not end in time, the device is in FAULT, a window failed its checks, or the
        plan asks what a device cannot do (:func:`check_plan_for_device`).
    DriverError
        From the driver: refusals, timeouts, lost link, stream gaps.
    """
    check_plan_for_device(plan)
    report = progress or (lambda p: None)
    pause = sleep or device.clock.sleep
    timing = _PlanTiming.of(device, plan)
    n = len(plan.positions_deg)
    wait_until_ready(
        device, warmup_timeout_s, lambda st: report(FindProgress("warm-up", 0, n, _angle(st), None)),
        clock=clock,
    )  # fmt: skip
    windows: list[PositionWindow] = []
    raw: list[Any] = []
    here = _angle(device.status())
    for i, target in enumerate(plan.positions_deg):
        report(FindProgress("rotate", i + 1, n, here, timing.seconds_left(i, here)))
        device.rotate_to(target % 360.0, wait=True)
        if timing.extra_s:
            left = timing.seconds_left(i, None) - plan.window_s
            report(FindProgress("settle", i + 1, n, target % 360.0, left))
            pause(timing.extra_s)
        left = timing.seconds_left(i, None) - timing.extra_s
        report(FindProgress("acquire", i + 1, n, target % 360.0, left))
        window, summary = _measure_window(device, plan, target, on_gap)
        if keep_windows:
            raw.append(window)
        if on_window is not None:
            on_window(i, window)
        windows.append(summary())
        here = windows[-1].encoder_deg
    report(FindProgress("solve", n, n, here, 0.0))
    result = result_from_windows(windows, latitude_deg, plan, latitude_source=latitude_source)
    report(FindProgress("done", n, n, here, 0.0))
    return result, raw


@dataclass(frozen=True)
class _PlanTiming:
    """What a plan takes on a device: the table's rate limit (deg/s), the device's own
    settling and the plan's extra settling after each move (s)."""

    plan: Plan
    rate_dps: float
    device_settle_s: float
    extra_s: float

    @classmethod
    def of(cls, device: DeviceLike, plan: Plan) -> _PlanTiming:
        """The device's rates and settling; a denoising method the windows cannot take is
        refused now, not after the measurement."""
        rate_dps = device.get_config(ConfigKey.TABLE_MAX_RATE_MDPS) / 1000.0
        settle_dev = device.get_config(ConfigKey.SETTLE_TIME_MS) / 1000.0
        n_samples = round(plan.window_s * device.get_config(ConfigKey.SAMPLE_RATE_HZ))
        check_denoise(plan.denoise, dict(plan.denoise_options), n_samples, "denoise")
        return cls(plan, rate_dps, settle_dev, extra_settle_s(plan, settle_dev))

    def seconds_left(self, i: int, here: float | None) -> float:
        """Device seconds from position ``i`` (the table at ``here``; None: there) to the end."""
        left, angle = 0.0, here
        for p in self.plan.positions_deg[i:]:
            if angle is not None:
                d = abs(shortest_delta_deg(angle, p))
                left += d / max(self.rate_dps, 1e-6) + self.device_settle_s
            angle = p
            left += self.extra_s + self.plan.window_s
        return left


def _measure_window(
    device: DeviceLike, plan: Plan, target: float, on_gap: str
) -> tuple[Any, Callable[[], PositionWindow]]:
    """Acquire the window at ``target`` (by ``on_gap``) and stop the stream; the raw window
    and how to summarise it (after the caller has handed the raw window on)."""
    window, remeasured = _acquire(device, plan.window_s, on_gap)
    # Stop the stream between windows, but only one this host started (another host on the
    # bus may be using it). A window complete in hand is kept when the stop's reply does not
    # come (the next window starts with the next sample whether the stream ran on or not).
    notes = []
    try:
        device.release_stream()
    except DriverTimeout as exc:
        notes.append(f"STREAM_STOP unanswered after the window ({exc})")
    if remeasured:
        notes.append(f"measured again {remeasured} time(s): sample ticks were missing")

    def summary() -> PositionWindow:
        s = summarise_window(
            window, target, plan.denoise, dict(plan.denoise_options),
            allow_gaps=on_gap == "report",
        )  # fmt: skip
        return dataclasses.replace(s, notes=(*s.notes, *notes)) if notes else s

    return window, summary


def _acquire(device: DeviceLike, window_s: float, on_gap: str) -> tuple[Any, int]:
    """One window by ``on_gap`` (see :func:`find_north`); the window and how often it was
    measured again."""
    if on_gap not in ON_GAP_CHOICES:
        raise HostConfigError(f"on_gap: {on_gap!r}; choose one of {', '.join(ON_GAP_CHOICES)}")
    if on_gap == "report":
        return device.acquire(window_s, on_gap="report"), 0
    for attempt in range(MAX_REMEASURE + 1):
        try:
            return device.acquire(window_s, on_gap="raise"), attempt
        except StreamGap:
            if on_gap == "fail" or attempt == MAX_REMEASURE:
                raise
    raise AssertionError("unreachable")  # pragma: no cover


def _angle(status: Any) -> float | None:
    angle = getattr(status, "angle_deg", None)
    if angle is None and getattr(status, "angle", None) is not None:
        angle = status.angle * 1e-6
    return None if angle is None else float(angle)


@dataclass(frozen=True)
class SpinFind:
    """What :func:`find_north_spin` gives: the solution and the raw window of the spin."""

    solution: spin.SpinSolution
    window: Any
    latitude_deg: float
    latitude_source: str = ""


@_at_rest_on_error
def find_north_spin(
    device: SpinningDeviceLike,
    rate_dps: float,
    spin_s: float,
    latitude_deg: float,
    *,
    drift: bool = False,
    warmup_timeout_s: float = READY_TIMEOUT_S,
    latitude_source: str = "",
    progress: Callable[[FindProgress], None] | None = None,
) -> SpinFind:
    """Find north with ``device`` turning at a constant rate: wait for READY, SPIN, acquire
    ``spin_s`` seconds of steady-rate samples, STOP (and wait for READY), solve.

    Parameters
    ----------
    device : Device
        A driver :class:`~northfinder.driver.device.Device` (protocol 1.1).
    rate_dps : float
        Table rate, deg/s, either sign, within the table's rate limit.
    spin_s : float
        Seconds of samples at the steady rate; whole turns (``360 / |rate|`` s each) are best.
    latitude_deg : float
    drift : bool
        Also fit a linear gyro and accelerometer drift.
    warmup_timeout_s : float
        Longest wait for READY, device seconds.
    progress : callable, optional
        Called with a :class:`FindProgress` as each phase begins (``spin``: the table speeds up,
        ``acquire``, ``solve``).

    Raises
    ------
    HostError
        Warm-up did not end in time, FAULT, or the spin gave too few usable samples. An error
        or interruption during the spin carries the samples received so far as
        ``partial_window`` (:meth:`~northfinder.driver.device.Device.acquire`).
    DriverError
        From the driver: refusals (protocol 1.0 units have no SPIN), timeouts, lost link.
    """
    spin.latitude_rad(latitude_deg, "the spin solution")
    wait_until_ready(device, warmup_timeout_s)
    report = progress or (lambda p: None)
    report(FindProgress("spin", 0, 0, None, spin_s))
    device.spin(rate_dps, wait=True)
    report(FindProgress("acquire", 0, 0, None, spin_s))
    window = device.acquire(spin_s, on_gap="report")
    device.stop(wait=True)
    device.stop_streaming()
    report(FindProgress("solve", 0, 0, None, 0.0))
    data = spin.spin_samples(
        window.gyro_dph, window.accel_mps2, window.table_deg, window.counter,
        window.sample_rate_hz, window.validity,
    )  # fmt: skip
    return SpinFind(
        spin.solve_spin(data, latitude_deg=latitude_deg, drift=drift),
        window,
        latitude_deg,
        latitude_source,
    )
