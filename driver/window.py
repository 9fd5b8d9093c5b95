"""Acquisition windows: consecutive sample ticks in physical units, and the state machine that
collects them.

:class:`WindowCollector` is pure: it is fed, in arrival order, the samples and tick losses a
transport delivers and decides which ticks belong to the window, which are missing, and when the
window is complete. It has no thread and no clock; :class:`~northfinder.driver.device.Device` feeds
it from its reader thread's queue and watches the deadlines. :class:`Window` is what it returns.

Counters: the device's 32-bit sample counter wraps; a window continues it past 2**32 (int64), so
its counters increase strictly and differences are exact.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from northfinder.driver.errors import ArgumentError, DeviceReset, EmptyWindow, StreamGap
from northfinder.driver.protocol.can import TickLoss
from northfinder.driver.protocol.constants import (
    ACCEL_G_PER_COUNT,
    ANGLE_DEG_PER_COUNT,
    GYRO_DPH_PER_COUNT,
    TEMPERATURE_DEGC_PER_COUNT,
    TEMPERATURE_NOT_AVAILABLE,
    VALIDITY_GOOD,
    VALIDITY_UNFIT,
)
from northfinder.driver.protocol.counters import counter_diff
from northfinder.driver.protocol.messages import Identify, Sample
from northfinder.driver.protocol.units import DPH, G0

__all__ = ["CountScales", "OnGap", "Window", "WindowCollector"]

_ARRAYS = (
    "counter",
    "time_s",
    "arrival_s",
    "gyro_dph",
    "accel_mps2",
    "table_deg",
    "temperature_c",
    "validity",
)

OnGap = Literal["raise", "report"]
"""What a missing tick does to a window: raise :class:`StreamGap`, or be reported in it."""


@dataclass(frozen=True, slots=True)
class CountScales:
    """The physical value of one count of each channel (protocol.md 3; a unit reports its own in
    IDENTIFY, :meth:`of`). The defaults are the protocol's."""

    gyro_dph: float = GYRO_DPH_PER_COUNT
    accel_mps2: float = ACCEL_G_PER_COUNT * G0
    angle_deg: float = ANGLE_DEG_PER_COUNT
    temperature_c: float = TEMPERATURE_DEGC_PER_COUNT

    @classmethod
    def of(cls, ident: Identify) -> CountScales:
        """The scales an IDENTIFY reports."""
        return cls(
            ident.gyro_scale.value,
            ident.accel_scale.value * G0,
            ident.angle_scale.value,
            ident.temperature_scale.value,
        )

    def temperature(self, counts: int) -> float:
        """A temperature value in degC; NaN for the protocol's "no reading"."""
        if counts == TEMPERATURE_NOT_AVAILABLE:
            return float("nan")
        return counts * self.temperature_c


@dataclass(frozen=True)
class Window:
    """One acquisition window: consecutive sample ticks, in physical units.

    The window spans ``requested`` ticks of device time from its first sample; the arrays hold
    the samples received (``n = requested - missing`` rows) and ``counter`` shows where any are
    missing. Arrays are read-only.

    Attributes
    ----------
    counter : ndarray, shape (n,), int64
        Sample counter, continued past 2**32 instead of wrapping within a window.
    time_s : ndarray, shape (n,)
        Device time, ``counter / sample_rate_hz`` s (seconds since boot if the rate was never
        changed); differences are exact.
    arrival_s : ndarray, shape (n,)
        Wall-clock time (``time.time()``) at which each sample was received.
    gyro_dph : ndarray, shape (n, 3)
        Mean angular rate over each sample interval, body x, y, z, deg/h.
    accel_mps2 : ndarray, shape (n, 3)
        Mean specific force over each sample interval, body x, y, z, m/s^2.
    table_deg : ndarray, shape (n,)
        Table angle from the encoder, deg in [0, 360).
    temperature_c : ndarray, shape (n,)
        Sensor temperature, degC (NaN: no reading).
    validity : ndarray, shape (n,), uint8
        Validity bits (:class:`~northfinder.driver.protocol.constants.Validity`).
    sample_rate_hz : float
    requested : int
        Ticks the window spans: ``round(seconds * sample_rate_hz)``.
    missing : int
        Ticks in the span that did not arrive whole (lost or incomplete).
    gaps : tuple of (int, int)
        ``(first_counter, count)`` of each run of missing ticks.
    """

    counter: np.ndarray
    time_s: np.ndarray
    arrival_s: np.ndarray
    gyro_dph: np.ndarray
    accel_mps2: np.ndarray
    table_deg: np.ndarray
    temperature_c: np.ndarray
    validity: np.ndarray
    sample_rate_hz: float
    requested: int
    missing: int = 0
    gaps: tuple[tuple[int, int], ...] = field(default_factory=tuple)

    def __len__(self) -> int:
        return len(self.counter)

    @property
    def complete(self) -> bool:
        """True when no tick of the span is missing."""
        return self.missing == 0

    @property
    def duration_s(self) -> float:
        """Device time the window spans, s."""
        return self.requested / self.sample_rate_hz

    @property
    def gyro_rps(self) -> np.ndarray:
        """Angular rate in rad/s, shape (n, 3)."""
        return self.gyro_dph * DPH

    @property
    def valid_mask(self) -> np.ndarray:
        """Samples fit for north finding: gyro and accelerometer valid, no other bit set."""
        v = self.validity
        return ((v & VALIDITY_GOOD) == VALIDITY_GOOD) & ((v & VALIDITY_UNFIT) == 0)

    def mean(self, *, valid_only: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Mean gyro rate (deg/h) and specific force (m/s^2) over the window, each shape (3,).

        Raises
        ------
        EmptyWindow
            No sample to average (none received, or none valid with ``valid_only``); also a
            ``ValueError``.
        """
        keep = self.valid_mask if valid_only else np.ones(len(self), dtype=bool)
        if not np.any(keep):
            raise EmptyWindow(
                "no valid sample in the window (table moving, warming up or in fault?)"
                if valid_only
                else "the window holds no sample"
            )
        return self.gyro_dph[keep].mean(axis=0), self.accel_mps2[keep].mean(axis=0)


class WindowCollector:
    """Collects ``requested`` consecutive sample ticks, starting with the first sample it is given.

    Feed it what the link delivers, in arrival order: :meth:`add_sample` for each whole sample and
    :meth:`add_loss` for each report of ticks that did not arrive whole. Losses before the first
    sample are not the window's. A sample repeating the previous counter is ignored; a sample with
    a counter behind the previous one means the device restarted. The window ends when the tick
    ``first + requested - 1`` arrived or is known to be lost (:attr:`done`); :meth:`window` then
    gives it in physical units.

    Parameters
    ----------
    requested : int
        Ticks the window spans (at least 1).
    on_gap : {"raise", "report"}
        ``"raise"``: the first missing tick raises :class:`~northfinder.driver.errors.StreamGap`.
        ``"report"``: missing ticks are counted in ``missing`` and ``gaps``.

    Raises
    ------
    ArgumentError
        ``requested`` below 1 or an unknown ``on_gap``.
    """

    def __init__(self, requested: int, *, on_gap: OnGap = "raise") -> None:
        if on_gap not in ("raise", "report"):
            raise ArgumentError(f"on_gap={on_gap!r}: choose one of 'raise', 'report'")
        if not (isinstance(requested, int) and requested >= 1):
            raise ArgumentError(f"requested={requested!r}: must be a whole number of ticks >= 1")
        self.requested = requested
        self.on_gap: OnGap = on_gap
        self.samples: list[Sample] = []
        self.counters: list[int] = []
        self.arrivals: list[float] = []
        self.gaps: list[tuple[int, int]] = []
        self.missing = 0
        self.first: int | None = None
        self._prev_raw = 0  # the previous sample's 32-bit counter
        self._prev = 0  # the same, continued past 2**32
        self._expected = 0  # the next tick the window waits for (continued counter)
        self._end = 0  # one past the window's last tick

    @property
    def received(self) -> int:
        """Samples of the window received so far."""
        return len(self.samples)

    @property
    def done(self) -> bool:
        """Whether every tick of the span arrived or is known to be missing."""
        return self.first is not None and self._expected >= self._end

    def add_sample(self, sample: Sample, arrival_s: float) -> bool:
        """Add one sample received at wall time ``arrival_s``; return :attr:`done`.

        Raises
        ------
        StreamGap
            ``on_gap="raise"`` and ticks before this sample are missing.
        DeviceReset
            The counter went back: the device restarted.
        """
        c = sample.counter
        if self.first is None:
            self.first = self._prev = self._expected = c
            self._end = c + self.requested
        else:
            step = counter_diff(c, self._prev_raw)
            if step == 0:
                return self.done  # a repeated sample
            if step < 0:
                raise DeviceReset(
                    f"the sample counter went back from {self._prev_raw} to {c} after "
                    f"{self.received} of {self.requested} samples: the device restarted"
                )
            c = self._prev = self._prev + step
        self._prev_raw = sample.counter
        if c >= self._end:
            self._gap(self._expected, self._end)
            self._expected = self._end
        elif c >= self._expected:
            self._gap(self._expected, c)
            self.samples.append(sample)
            self.counters.append(c)
            self.arrivals.append(arrival_s)
            self._expected = c + 1
        return self.done

    def add_loss(self, loss: TickLoss) -> bool:
        """Add a report of ticks that did not arrive whole; return :attr:`done`.

        Raises
        ------
        StreamGap
            ``on_gap="raise"`` and the loss falls in the window.
        """
        if self.first is None:
            return False  # before the window
        a = self._prev + counter_diff(loss.first_counter, self._prev_raw)
        b = a + loss.count
        if b > self._expected:
            self._gap(self._expected, min(b, self._end))
            self._expected = b
        return self.done

    def _gap(self, a: int, b: int) -> None:
        if b <= a:
            return
        self.gaps.append((a, b - a))
        self.missing += b - a
        if self.on_gap == "raise":
            raise StreamGap(
                f"{b - a} sample tick(s) missing from counter {a} in the window of "
                f"{self.requested} from counter {self.first} ({self.received} received so far): "
                "lost on the link or dropped by the device; pass on_gap='report' to receive the "
                "window with its gaps stated",
                tuple(self.gaps),
                self.missing,
                self.received,
            )

    def window(self, sample_rate_hz: float, scales: CountScales) -> Window:
        """The samples collected so far as a :class:`Window` in physical units.

        Parameters
        ----------
        sample_rate_hz : float
            The device's sample rate, Hz (gives ``time_s``).
        scales : CountScales
            The physical value of one count of each channel.
        """
        samples = self.samples
        m = len(samples)
        gyro = np.array([s.gyro for s in samples], dtype=np.float64).reshape(m, 3)
        accel = np.array([s.accel for s in samples], dtype=np.float64).reshape(m, 3)
        temp_raw = np.array([s.temperature for s in samples], dtype=np.float64)
        temperature = np.where(
            temp_raw == TEMPERATURE_NOT_AVAILABLE, np.nan, temp_raw * scales.temperature_c
        )
        counter = np.array(self.counters, dtype=np.int64)
        window = Window(
            counter=counter,
            time_s=counter / float(sample_rate_hz),
            arrival_s=np.array(self.arrivals, dtype=np.float64),
            gyro_dph=gyro * scales.gyro_dph,
            accel_mps2=accel * scales.accel_mps2,
            table_deg=np.array([s.angle for s in samples], dtype=np.float64) * scales.angle_deg,
            temperature_c=temperature,
            validity=np.array([int(s.validity) for s in samples], dtype=np.uint8),
            sample_rate_hz=float(sample_rate_hz),
            requested=self.requested,
            missing=self.missing,
            gaps=tuple(self.gaps),
        )
        for name in _ARRAYS:
            getattr(window, name).setflags(write=False)
        return window
