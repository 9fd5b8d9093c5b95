"""Acquisition windows: consecutive sample ticks in physical units, and the state machine that
collects them.

:class:`WindowCollector` is pure: it is fed, in arrival order, the samples and tick losses a
transport delivers and decides which ticks belong to the window, which are missing, and when the
window is complete. It has no thread and no clock; :class:`~northfinder.driver.device.Device` feeds
it from its reader thread's queue and watches the deadlines. :class:`Window` is what it returns.

Counters: the device's 32-bit sample counter wraps; a window continues it past 2**32 (int64), so
its counters increase strictly and differences are exact.

Memory: samples travel as raw counts in numpy columns (:class:`SampleColumns`, about 43 bytes a
sample), never one Python object per sample held: :class:`SampleInbox` turns what the reader
receives into columns a few hundred samples at a time, and the collector copies the window's rows
into columns preallocated for the whole window. A window of any length costs its arrays.
"""

from __future__ import annotations

import dataclasses
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Any, Literal

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

__all__ = ["CountScales", "OnGap", "SampleColumns", "SampleInbox", "Window", "WindowCollector"]

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


_U32 = 0xFFFF_FFFF


@dataclass(frozen=True, slots=True)
class SampleColumns:
    """Samples as received, one row each, in raw counts (the wire's own sizes).

    Attributes
    ----------
    counter : ndarray, shape (n,), int64
        The 32-bit sample counter as received (wrapping).
    gyro, accel : ndarray, shape (n, 3), int32
        Counts of each axis.
    angle : ndarray, shape (n,), uint32
    temperature : ndarray, shape (n,), int16
    validity : ndarray, shape (n,), uint8
    arrival_s : ndarray, shape (n,), float64
        Wall-clock time each sample was received.
    """

    counter: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    angle: np.ndarray
    temperature: np.ndarray
    validity: np.ndarray
    arrival_s: np.ndarray

    def __len__(self) -> int:
        return len(self.counter)

    @classmethod
    def empty(cls, n: int) -> SampleColumns:
        """Columns for ``n`` rows, not yet written (pages are taken as rows are written)."""
        return cls(
            np.empty(n, np.int64),
            np.empty((n, 3), np.int32),
            np.empty((n, 3), np.int32),
            np.empty(n, np.uint32),
            np.empty(n, np.int16),
            np.empty(n, np.uint8),
            np.empty(n, np.float64),
        )

    @classmethod
    def of(cls, samples: list[Sample], arrivals: list[float]) -> SampleColumns:
        """The columns of decoded samples received at wall times ``arrivals``."""
        n = len(samples)
        return cls(
            np.fromiter([s.counter for s in samples], np.int64, n),
            np.array([s.gyro for s in samples], np.int32).reshape(n, 3),
            np.array([s.accel for s in samples], np.int32).reshape(n, 3),
            np.fromiter([s.angle for s in samples], np.uint32, n),
            np.fromiter([s.temperature for s in samples], np.int16, n),
            np.fromiter([int(s.validity) for s in samples], np.uint8, n),
            np.array(arrivals, np.float64),
        )

    @classmethod
    def concat(cls, blocks: list[SampleColumns]) -> SampleColumns:
        """The rows of ``blocks`` one after the other."""
        if len(blocks) == 1:
            return blocks[0]
        if not blocks:
            return cls.empty(0)
        return cls(*(np.concatenate([getattr(b, name) for b in blocks]) for name in _COLUMNS))

    def put(self, at: int, src: SampleColumns, start: int, stop: int) -> None:
        """Copy rows ``start:stop`` of ``src`` to rows from ``at`` on."""
        end = at + stop - start
        for name in _COLUMNS:
            getattr(self, name)[at:end] = getattr(src, name)[start:stop]


#: What a released column of a collector is (:meth:`WindowCollector.take_window`).
_RELEASED = np.empty((0, 3), np.int32)
_RELEASED.setflags(write=False)

_COLUMNS = ("counter", "gyro", "accel", "angle", "temperature", "validity", "arrival_s")
#: Rows a collector reserves at first (about 2.8 MB of columns); it doubles them as they fill.
_INITIAL_ROWS = 1 << 16


class SampleInbox:
    """What a link hands to the window being collected, in arrival order: samples and events.

    Samples go into numpy columns (:class:`SampleColumns`) a chunk at a time, so a window that
    waits long between wake-ups holds no Python object per sample; any other item (a tick loss,
    a restart, a lost link) is an event stamped with the number of samples before it. It has no
    lock: the :class:`~northfinder.driver.device.Device` guards it with its own.

    Parameters
    ----------
    chunk : int
        Decoded samples kept as objects before they are turned into columns.
    """

    def __init__(self, chunk: int = 256) -> None:
        self._chunk = chunk
        self._samples: list[Sample] = []
        self._arrivals: list[float] = []
        self._blocks: list[SampleColumns] = []
        self._events: list[tuple[int, str, Any, float, float]] = []
        self._count = 0  # samples waiting (in blocks and in the chunk)
        self.last_sample_mono = 0.0  # clock time the latest sample was received

    def __len__(self) -> int:
        """Items waiting: samples and events."""
        return self._count + len(self._events)

    def add_sample(self, sample: Sample, mono: float, wall: float) -> None:
        """A sample received at clock time ``mono`` and wall time ``wall``."""
        self._samples.append(sample)
        self._arrivals.append(wall)
        self._count += 1
        self.last_sample_mono = mono
        if len(self._samples) >= self._chunk:
            self._seal()

    def add_event(self, kind: str, item: Any, mono: float, wall: float) -> None:
        """Anything else received (``kind`` names it for the collector)."""
        self._events.append((self._count, kind, item, mono, wall))

    def _seal(self) -> None:
        if self._samples:
            self._blocks.append(SampleColumns.of(self._samples, self._arrivals))
            self._samples, self._arrivals = [], []

    def take(self) -> tuple[SampleColumns, list[tuple[int, str, Any, float, float]]]:
        """Everything waiting, and empty the inbox: the samples' columns, and the events as
        ``(samples_before, kind, item, mono, wall)`` (``samples_before`` indexes the columns)."""
        self._seal()
        block = SampleColumns.concat(self._blocks)
        events = self._events
        self._blocks, self._events, self._count = [], [], 0
        return block, events


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
        # The window keeps at most `requested` samples (distinct ticks of its span): rows for up
        # to _INITIAL_ROWS of them at first, doubled as they fill (a collector of an unbounded
        # span, as a CAN log's reader makes, must not reserve its whole span).
        self._rows = SampleColumns.empty(min(requested, _INITIAL_ROWS))
        self._received = 0
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
        return self._received

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
        c = self._admit(sample.counter)
        if c is not None:
            self._room(1)
            r, m = self._rows, self._received
            r.counter[m] = c
            r.gyro[m] = sample.gyro
            r.accel[m] = sample.accel
            r.angle[m] = sample.angle
            r.temperature[m] = sample.temperature
            r.validity[m] = int(sample.validity)
            r.arrival_s[m] = arrival_s
            self._received = m + 1
        return self.done

    def add_samples(self, block: SampleColumns, start: int = 0, stop: int | None = None) -> bool:
        """Add rows ``start:stop`` of ``block`` in order, as :meth:`add_sample` would one by one,
        but stop after the first row once the window is :attr:`done`; return :attr:`done`.

        Runs of consecutive counters are copied at once; only a row after a gap, a repeat or a
        restart is judged alone.

        Raises
        ------
        StreamGap, DeviceReset
            As :meth:`add_sample`, with the rows before the one at fault added.
        """
        stop = len(block) if stop is None else stop
        raw = block.counter
        # Rows whose counter does not follow the row before by one (each begins a run).
        breaks = (np.flatnonzero(((raw[start + 1 : stop] - raw[start : stop - 1]) & _U32) != 1)
                  + start + 1).tolist()  # fmt: skip
        i = start
        while i < stop:
            run = 0
            if (
                self.first is not None
                and self._expected == self._prev + 1
                and int(raw[i]) == (self._prev_raw + 1) & _U32
            ):
                k = bisect_right(breaks, i)
                run_end = breaks[k] if k < len(breaks) else stop
                run = min(run_end - i, self._end - self._expected)
            if run > 0:
                self._room(run)
                m, c0 = self._received, self._prev + 1
                self._rows.put(m, block, i, i + run)
                self._rows.counter[m : m + run] = np.arange(c0, c0 + run, dtype=np.int64)
                self._received = m + run
                self._prev = self._expected = c0 + run - 1
                self._expected += 1
                self._prev_raw = int(raw[i + run - 1])
                i += run
            else:
                c = self._admit(int(raw[i]))
                if c is not None:
                    self._room(1)
                    m = self._received
                    self._rows.put(m, block, i, i + 1)
                    self._rows.counter[m] = c
                    self._received = m + 1
                i += 1
            if self.done:
                return True
        return self.done

    def _room(self, n: int) -> None:
        """Rows for ``n`` more samples: the columns doubled (at most to ``requested``) when full."""
        need = self._received + n
        if need > len(self._rows):
            grown = SampleColumns.empty(min(max(2 * len(self._rows), need), self.requested))
            grown.put(0, self._rows, 0, self._received)
            self._rows = grown

    def _admit(self, raw: int) -> int | None:
        """Advance over one sample with the 32-bit counter ``raw``: its continued counter if the
        window keeps it, None if not (a repeat, or past the window)."""
        c = raw
        if self.first is None:
            self.first = self._prev = self._expected = c
            self._end = c + self.requested
        else:
            step = counter_diff(c, self._prev_raw)
            if step == 0:
                return None  # a repeated sample
            if step < 0:
                raise DeviceReset(
                    f"the sample counter went back from {self._prev_raw} to {c} after "
                    f"{self.received} of {self.requested} samples: the device restarted"
                )
            c = self._prev = self._prev + step
        self._prev_raw = raw
        if c >= self._end:
            self._gap(self._expected, self._end)
            self._expected = self._end
        elif c >= self._expected:
            self._gap(self._expected, c)
            self._expected = c + 1
            return c
        return None

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
        return self._window(sample_rate_hz, scales, release=False)

    def take_window(self, sample_rate_hz: float, scales: CountScales) -> Window:
        """:meth:`window`, and the collector gives up its raw columns as each is converted (the
        peak of memory is the window's arrays and about half its raw counts); it takes no more
        samples afterwards."""
        return self._window(sample_rate_hz, scales, release=True)

    def _window(self, sample_rate_hz: float, scales: CountScales, *, release: bool) -> Window:
        m = self._received
        r = self._rows
        # Rows are only ever appended: the window shares the columns already in its units
        # (counter, arrival, validity) and converts the others, one new array each.
        converted: dict[str, np.ndarray] = {}
        for name, column, scale in (
            ("gyro_dph", "gyro", scales.gyro_dph),
            ("accel_mps2", "accel", scales.accel_mps2),
            ("table_deg", "angle", scales.angle_deg),
            ("temperature_c", "temperature", scales.temperature_c),
        ):
            raw = getattr(r, column)[:m]
            converted[name] = raw * scale
            if column == "temperature":
                converted[name][raw == TEMPERATURE_NOT_AVAILABLE] = np.nan
            if release:
                del raw
                r = self._rows = dataclasses.replace(r, **{column: _RELEASED})
        counter = r.counter[:m]
        window = Window(
            counter=counter,
            time_s=counter / float(sample_rate_hz),
            arrival_s=r.arrival_s[:m],
            validity=r.validity[:m],
            sample_rate_hz=float(sample_rate_hz),
            requested=self.requested,
            missing=self.missing,
            gaps=tuple(self.gaps),
            **converted,
        )
        for name in _ARRAYS:
            getattr(window, name).setflags(write=False)
        return window
