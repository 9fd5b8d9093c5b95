"""The north-finding procedure on a device: wait for warm-up, rotate, settle, acquire, check, solve.

The procedure talks to anything with the driver's :class:`~northfinder.driver.device.Device` methods it uses
(``status``, ``get_config``, ``rotate_to``, ``acquire``, ``stop_streaming``), so it runs the same on
the simulator and on a real unit. It uses the encoder angles the device reports, never the
commanded ones.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.constants import VALIDITY_UNFIT, ConfigKey, DeviceState, Validity
from northfinder.host.denoise import METHODS, denoise
from northfinder.host.errors import HostConfigError, HostError
from northfinder.host.heading import (
    MIN_MU_SEPARATION_DEG,
    MultiPositionSolution,
    solve_multi_position,
    solve_two_position,
)

#: Largest span of the encoder during a window before the window counts as moved, deg.
MAX_ENCODER_SPAN_DEG = 0.01
#: Batches used to estimate the standard error of a window mean (robust to correlated noise).
N_BATCHES = 20
#: Validity bits that make a sample unusable for north finding (protocol.md 4.5).
BAD_BITS = VALIDITY_UNFIT
METHOD_CHOICES = ("auto", "two-position", "least-squares")


class QualityError(HostError):
    """A window is unusable: the table moved, samples are flagged bad, or data are missing."""


class WindowLike(Protocol):
    # Read-only, as the driver's frozen Window has them.
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
    def missing(self) -> int: ...


class DeviceLike(Protocol):
    def status(self) -> Any: ...
    def get_config(self, key: ConfigKey) -> int: ...
    def rotate_to(
        self, angle_deg: float, *, wait: bool = True, timeout: float | None = None
    ) -> Any: ...
    def acquire(
        self, seconds: float, *, on_gap: Literal["raise", "report"] = "raise"
    ) -> WindowLike: ...
    def stop_streaming(self) -> None: ...


@dataclass(frozen=True)
class Plan:
    """What to measure: table angles (any, deg), window length and extra settle time (s).

    ``settle_s`` is waited after the device reports READY (the device has its own settle time);
    ``denoise`` names a method of :data:`northfinder.host.denoise.METHODS`; ``method`` picks the solver:
    ``two-position`` (seed 000, exactly two positions), ``least-squares`` (any number), or ``auto``.
    """

    positions_deg: tuple[float, ...] = (0.0, 180.0)
    window_s: float = 10.0
    settle_s: float = 0.0
    denoise: str = "none"
    method: str = "auto"

    def __post_init__(self) -> None:
        if len(self.positions_deg) < 2:
            raise HostConfigError(
                f"positions: need at least two table angles, got {list(self.positions_deg)}"
            )
        for p in self.positions_deg:
            if not math.isfinite(p):
                raise HostConfigError(f"positions: {p!r} is not a finite angle")
        wrapped = [p % 360.0 for p in self.positions_deg]
        spread = max(
            min(abs(a - b) % 360.0, 360.0 - abs(a - b) % 360.0) for a in wrapped for b in wrapped
        )
        if spread < MIN_MU_SEPARATION_DEG:
            raise HostConfigError(
                f"positions: {list(self.positions_deg)} lie within {MIN_MU_SEPARATION_DEG} deg of each "
                "other; the Earth rate differences vanish and no heading can be found"
            )
        if not (math.isfinite(self.window_s) and 0.5 <= self.window_s <= 3600):
            raise HostConfigError(f"window: must be 0.5 to 3600 s, got {self.window_s}")
        if not (math.isfinite(self.settle_s) and 0 <= self.settle_s <= 600):
            raise HostConfigError(f"settle: must be 0 to 600 s, got {self.settle_s}")
        if self.denoise not in METHODS:
            raise HostConfigError(
                f"denoise: unknown method {self.denoise!r}; choose from {', '.join(METHODS)}"
            )
        if self.method not in METHOD_CHOICES:
            raise HostConfigError(
                f"method: unknown {self.method!r}; choose from {', '.join(METHOD_CHOICES)}"
            )
        if self.method == "two-position" and len(self.positions_deg) != 2:
            raise HostConfigError("method two-position needs exactly two positions")

    @property
    def solver(self) -> str:
        if self.method == "auto":
            return "two-position" if len(self.positions_deg) == 2 else "least-squares"
        return self.method


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

    def to_dict(self) -> dict[str, Any]:
        return {
            "azimuth_deg": self.azimuth_deg,
            "sigma_deg": self.sigma_deg,
            "pitch_deg": self.pitch_deg,
            "roll_deg": self.roll_deg,
            "method": self.method,
            "denoise": self.denoise,
            "latitude_deg": self.latitude_deg,
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
                    "notes": list(w.notes),
                }
                for w in self.windows
            ],
            "pairwise_azimuth_deg": list(self.pairwise_deg),
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class Progress:
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


def summarise_window(
    window: WindowLike, commanded_deg: float, denoise_method: str
) -> PositionWindow:
    """Check one window and reduce it to means and standard errors.

    Raises
    ------
    QualityError
        Samples flagged moving/settling/saturated/warming/fault, the encoder moved, or samples
        are missing.
    """
    n = len(window.counter)
    if n < 2 * N_BATCHES:
        raise QualityError(f"window at {commanded_deg:g} deg has only {n} samples")
    if window.missing:
        raise QualityError(f"window at {commanded_deg:g} deg is missing {window.missing} samples")
    bad = (np.asarray(window.validity, dtype=np.uint8) & int(BAD_BITS)) != 0
    if bad.any():
        flags = Validity(int(np.bitwise_or.reduce(np.asarray(window.validity)[bad])))
        raise QualityError(
            f"window at {commanded_deg:g} deg: {int(bad.sum())} of {n} samples flagged {flags!r}"
        )
    enc = np.asarray(window.table_deg, dtype=float)
    unwrapped = np.degrees(np.unwrap(np.radians(enc)))
    span = float(np.ptp(unwrapped))
    if span > MAX_ENCODER_SPAN_DEG:
        raise QualityError(
            f"the table moved {span:.4f} deg during the window at {commanded_deg:g} deg"
        )
    encoder = float(np.mean(unwrapped)) % 360.0
    gyro = np.asarray(window.gyro_dph, dtype=float)
    accel = np.asarray(window.accel_mps2, dtype=float)
    clean_g = denoise(gyro, denoise_method, axis=0) if denoise_method != "none" else gyro
    clean_a = denoise(accel, denoise_method, axis=0) if denoise_method != "none" else accel
    med = np.median(gyro, axis=0)
    mad = 1.4826 * np.median(np.abs(gyro - med), axis=0)
    outliers = int(np.sum(np.any(np.abs(gyro - med) > 8.0 * np.maximum(mad, 1e-12), axis=1)))
    notes = []
    if outliers > 0.005 * n:
        notes.append(
            f"{outliers} impulsive samples (vibration or shock); consider --denoise hampel"
        )
    return PositionWindow(
        commanded_deg=float(commanded_deg),
        encoder_deg=encoder,
        samples=n,
        gyro_dph=tuple(float(v) for v in clean_g.mean(axis=0)),  # type: ignore[arg-type]
        gyro_raw_dph=tuple(float(v) for v in gyro.mean(axis=0)),  # type: ignore[arg-type]
        gyro_sem_dph=tuple(float(v) for v in batch_sem(clean_g)),  # type: ignore[arg-type]
        accel_mps2=tuple(float(v) for v in clean_a.mean(axis=0)),  # type: ignore[arg-type]
        accel_sem_mps2=tuple(float(v) for v in batch_sem(clean_a)),  # type: ignore[arg-type]
        outliers=outliers,
        notes=tuple(notes),
    )


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


def solve_windows(
    windows: Sequence[PositionWindow], latitude_deg: float, plan: Plan
) -> tuple[float, float | None, float, float, tuple[float, ...]]:
    """Heading, sigma, pitch, roll and pairwise azimuths from summarised windows."""
    mu = np.array([w.encoder_deg for w in windows])
    gyro = np.array([w.gyro_dph for w in windows])
    accel = np.array([w.accel_mps2 for w in windows])
    # Floors far below any sensor's noise keep noise-free (simulated ideal) windows well posed.
    g_sem = np.maximum(np.array([w.gyro_sem_dph for w in windows])[:, :2], 1e-9)
    a_sem = np.maximum(np.array([w.accel_sem_mps2 for w in windows])[:, :2], 1e-12)
    pairwise: list[float] = []
    for i in range(len(windows) - 1):
        d = (mu[i + 1] - mu[i]) % 360.0
        if MIN_MU_SEPARATION_DEG <= d <= 360.0 - MIN_MU_SEPARATION_DEG:
            s = solve_two_position(
                gyro[i], gyro[i + 1], d, accel0=accel[i], accel1=accel[i + 1],
                latitude_deg=latitude_deg, rate_unit="deg/h",
            )  # fmt: skip
            pairwise.append(base_attitude(s.azimuth_deg, s.pitch_deg, s.roll_deg, float(mu[i]))[0])
    if plan.solver == "two-position":
        d = float((mu[1] - mu[0]) % 360.0)
        s = solve_two_position(
            gyro[0], gyro[1], d, accel0=accel[0], accel1=accel[1], latitude_deg=latitude_deg,
            rate_unit="deg/h", gyro_noise=g_sem, accel_noise=a_sem,
        )  # fmt: skip
        azimuth, pitch, roll = base_attitude(s.azimuth_deg, s.pitch_deg, s.roll_deg, float(mu[0]))
        return azimuth, s.sigma_deg, pitch, roll, tuple(pairwise)
    m: MultiPositionSolution = solve_multi_position(
        gyro, mu, latitude_deg=latitude_deg, accel_means=accel, rate_unit="deg/h",
        gyro_noise=g_sem, accel_noise=a_sem,
    )  # fmt: skip
    return m.azimuth_deg % 360.0, m.sigma_deg, m.pitch_deg, m.roll_deg, tuple(pairwise)


def _state_name(status: Any) -> str:
    state = getattr(status, "state", status)
    return DeviceState(int(state)).name


def find_north(
    device: DeviceLike,
    plan: Plan,
    latitude_deg: float,
    *,
    warmup_timeout_s: float = 600.0,
    progress: Callable[[Progress], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[FindResult, list[Any]]:
    """Run the plan on ``device`` and solve; return the result and the raw windows.

    Raises
    ------
    HostError
        Warm-up did not end in time, the device is in FAULT, or a window failed its checks.
    DriverError
        From the driver: refusals, timeouts, lost link, stream gaps.
    """
    report = progress or (lambda p: None)
    n = len(plan.positions_deg)
    rate_dps = device.get_config(ConfigKey.TABLE_MAX_RATE_MDPS) / 1000.0
    settle_dev = device.get_config(ConfigKey.SETTLE_TIME_MS) / 1000.0

    def seconds_left(i: int, here: float | None) -> float:
        left, angle = 0.0, here
        for p in plan.positions_deg[i:]:
            if angle is not None:
                d = abs((p - angle + 180.0) % 360.0 - 180.0)
                left += d / max(rate_dps, 1e-6) + settle_dev
            angle = p
            left += plan.settle_s + plan.window_s
        return left

    deadline = time.monotonic() + warmup_timeout_s
    while True:
        status = device.status()
        state = _state_name(status)
        if state == "READY":
            break
        if state == "FAULT":
            raise HostError(
                f"the device is in FAULT (faults {getattr(status, 'faults', '?')!r}); reset it"
            )
        if time.monotonic() > deadline:
            raise HostError(
                f"the device did not become READY within {warmup_timeout_s:g} s (state {state})"
            )
        report(Progress("warm-up", 0, n, _angle(status), None))
        sleep(0.05)
    windows: list[PositionWindow] = []
    raw: list[Any] = []
    notes: list[str] = []
    here = _angle(device.status())
    for i, target in enumerate(plan.positions_deg):
        report(Progress("rotate", i + 1, n, here, seconds_left(i, here)))
        device.rotate_to(target % 360.0, wait=True)
        if plan.settle_s:
            report(
                Progress("settle", i + 1, n, target % 360.0, seconds_left(i, None) - plan.window_s)
            )
            sleep(plan.settle_s)
        report(Progress("acquire", i + 1, n, target % 360.0, seconds_left(i, None) - plan.settle_s))
        window = device.acquire(plan.window_s, on_gap="raise")
        device.stop_streaming()
        raw.append(window)
        summary = summarise_window(window, target, plan.denoise)
        windows.append(summary)
        notes += [f"position {i + 1}: {note}" for note in summary.notes]
        here = summary.encoder_deg
    report(Progress("solve", n, n, here, 0.0))
    azimuth, sigma, pitch, roll, pairwise = solve_windows(windows, latitude_deg, plan)
    report(Progress("done", n, n, here, 0.0))
    result = FindResult(
        azimuth_deg=azimuth,
        sigma_deg=sigma,
        pitch_deg=pitch,
        roll_deg=roll,
        method=plan.solver,
        denoise=plan.denoise,
        latitude_deg=latitude_deg,
        windows=tuple(windows),
        pairwise_deg=pairwise if n > 2 else (),
        notes=tuple(notes),
    )
    return result, raw


def _angle(status: Any) -> float | None:
    angle = getattr(status, "angle_deg", None)
    if angle is None and getattr(status, "angle", None) is not None:
        angle = status.angle * 1e-6
    return None if angle is None else float(angle)
