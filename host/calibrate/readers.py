"""Recordings as calibration input: every format the project reads, behind one reader table.

A reader turns one file into a :class:`RecordedRun`: the windows of one power-on in time order,
each the project's :class:`~northfinder.host.recording.RecordedWindow` (gyro in deg/h,
accelerometer in m/s^2, device times, table angles, validity bits). :data:`READERS` maps a file
name's ending to its reader; a new format plugs in with :func:`register_reader` and nothing else
changes. Read today: northfinder recordings (``.csv``, ``.npz``) and CAN logs in python-can's
formats (``.log``, ``.asc``, ``.blf``, ``.db``, ``.trc``, ``.mf4``, python-can's ``.csv`` told
from a recording by its header, and ``.gz`` of the text formats), whose windows
:func:`northfinder.host.canlog.read_can_log` rebuilds from the frame stream.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.units import UG
from northfinder.host.allan import AllanCurve, allan_curve
from northfinder.host.canlog import ReadProgress, is_can_log, read_can_log
from northfinder.host.errors import RecordingError
from northfinder.host.procedure import unfit_samples
from northfinder.host.recording import RecordedWindow, Recording, summarise_recording

__all__ = [
    "AXES",
    "READERS",
    "RecordedRun",
    "WindowFit",
    "good_stretches",
    "read_runs",
    "register_reader",
    "window_fit",
]

#: Channels in order: gyro x, y, z (deg/h), accelerometer x, y, z (ug).
AXES = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
#: Shortest stretch of good samples used for the Allan deviation.
MIN_PIECE_SAMPLES = 64
#: Samples of each window compared, gyro and accelerometer, to tell a recording given twice.
FINGERPRINT_SAMPLES = 256


def good_stretches(window: RecordedWindow, min_samples: int = 1) -> list[slice]:
    """Runs of consecutive good samples of a window (usable for north finding by the
    procedure's rule, :func:`~northfinder.host.procedure.unfit_samples`; no counter gap) of at
    least ``min_samples``, as slices."""
    good = ~unfit_samples(window.validity)
    breaks = np.flatnonzero(np.diff(window.counter) != 1) + 1
    out = []
    for seg in np.split(np.arange(len(window.counter)), breaks):
        g = good[seg]
        # Split each gap-free stretch again at bad samples.
        edges = np.flatnonzero(np.diff(np.concatenate([[0], g.astype(np.int8), [0]])))
        for lo, hi in zip(edges[::2], edges[1::2], strict=True):
            if hi - lo >= min_samples:
                out.append(slice(int(seg[lo]), int(seg[hi - 1]) + 1))
    return out


@dataclass(frozen=True)
class RecordedRun:
    """The windows of one recording (one power-on), in time order.

    Attributes
    ----------
    source : str
        Where it came from (the file name).
    sample_rate_hz : float
        Sample rate, Hz.
    windows : tuple of RecordedWindow
        The project's window of raw samples (:class:`northfinder.host.recording.RecordedWindow`:
        gyro in deg/h, accelerometer in m/s^2, device times, encoder angles, validity bits).
    latitude_deg : float or None
        Latitude, if the recording states it.
    meta : dict
        Whatever else the recording states.
    """

    source: str
    sample_rate_hz: float
    windows: tuple[RecordedWindow, ...]
    latitude_deg: float | None = None
    meta: dict[str, Any] = field(default_factory=dict, repr=False)
    #: The windows reduced as they were read (``read_runs(..., fitted=True)``); :attr:`windows`
    #: is then empty.
    fits: tuple[WindowFit, ...] = field(default=(), repr=False)

    def window_fits(self) -> tuple[WindowFit, ...]:
        """What calibration takes of each window: :attr:`fits`, or made from :attr:`windows`."""
        if self.fits or not self.windows:
            return self.fits
        return tuple(window_fit(w, self.sample_rate_hz) for w in self.windows)


@dataclass(frozen=True)
class WindowFit:
    """What calibration takes of one window (:func:`window_fit`), made as the window is read so
    that its samples can be dropped.

    Of the stages of :func:`~northfinder.host.calibrate.core.calibrate`, only the Allan
    deviation needs samples together: those of one good stretch (consecutive good samples) of
    one channel, as float64 (gyro deg/h, accelerometer ug), for the time it is computed. The
    rest are sums: each stretch's slope, the window's means for the between-position fit, and a
    fingerprint to tell a recording given twice.

    Attributes
    ----------
    commanded_deg : float
    start_s : float
        Device time of the first sample, s (the windows of a recording are put in time order).
    samples : int
    pieces : tuple
        For each stretch of at least ``MIN_PIECE_SAMPLES`` good samples, for each channel of
        :data:`AXES`: its Allan curve, the slope of its samples over time and the slope's weight.
    piece_samples : tuple of int
        Samples of each stretch.
    means : tuple or None
        Over the window's good samples: the x and y gyro means (deg/h), the mean encoder angle
        (deg), the device time one sample before the first (s) and of the last; None without
        good samples.
    fingerprint : tuple
        A digest of the counters and validity bits, and :data:`FINGERPRINT_SAMPLES` samples of
        the gyro and accelerometer spread over the window.
    """

    commanded_deg: float
    start_s: float
    samples: int
    pieces: tuple[tuple[tuple[AllanCurve, float, float], ...], ...]
    piece_samples: tuple[int, ...]
    means: tuple[NDArray[np.float64], float, float, float] | None
    fingerprint: tuple[bytes, NDArray[np.float64]] = field(repr=False)


def _slope(y: NDArray[np.float64], t: NDArray[np.float64]) -> tuple[float, float]:
    """Least-squares slope of y over t and its weight (sum of (t - mean)^2)."""
    tc = t - t.mean()
    w = float(tc @ tc)
    return (float(tc @ (y - y.mean())) / w if w > 0 else 0.0), w


def window_fit(w: RecordedWindow, sample_rate_hz: float) -> WindowFit:
    """What calibration takes of window ``w`` (:class:`WindowFit`)."""
    fs = sample_rate_hz
    pieces, sizes = [], []
    for s in good_stretches(w, MIN_PIECE_SAMPLES):
        per_channel = []
        for ch in range(len(AXES)):
            y = w.gyro_dph[s, ch] if ch < 3 else w.accel_mps2[s, ch - 3] / UG
            per_channel.append((allan_curve(y, fs), *_slope(y, w.time_s[s])))
        pieces.append(tuple(per_channel))
        sizes.append(s.stop - s.start)
    means = None
    good = good_stretches(w)
    if good:
        idx = np.concatenate([np.arange(s.start, s.stop) for s in good])
        means = (
            w.gyro_dph[idx, :2].mean(axis=0), float(np.mean(w.table_deg[idx])),
            w.time_s[idx[0]] - 1.0 / fs, w.time_s[idx[-1]],
        )  # fmt: skip
    n = len(w.counter)
    digest = hashlib.sha256(np.ascontiguousarray(w.counter, dtype=np.int64).tobytes())
    digest.update(np.ascontiguousarray(w.validity, dtype=np.uint8).tobytes())
    at = np.unique(np.linspace(0, n - 1, min(n, FINGERPRINT_SAMPLES)).astype(np.int64))
    seen = np.hstack([w.gyro_dph[at], w.accel_mps2[at]]) if n else np.empty((0, 6))
    return WindowFit(
        float(w.commanded_deg), float(w.time_s[0]) if n else math.nan, n, tuple(pieces),
        tuple(sizes), means, (digest.digest(), seen),
    )  # fmt: skip


#: File-name ending -> reader.
READERS: dict[str, Callable[[Path], RecordedRun]] = {}


def register_reader(suffix: str, reader: Callable[[Path], RecordedRun]) -> None:
    """Make ``read_runs`` read files ending in ``suffix`` (``".asc"``, say) with ``reader``."""
    if not suffix.startswith("."):
        raise RecordingError(f"reader suffix: must start with '.', got {suffix!r}")
    READERS[suffix.lower()] = reader


def _read_northfinder(path: Path) -> RecordedRun:
    rec = Recording.load(path, min_windows=1)
    rate = rec.meta.get("sample_rate_hz")
    if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
        raise RecordingError(f"{path}: no sample_rate_hz in the metadata (got {rate!r})")
    lat = rec.meta.get("latitude_deg")
    latitude = float(lat) if isinstance(lat, int | float) and math.isfinite(lat) else None
    windows = rec.windows
    order = np.argsort([w.time_s[0] for w in windows], kind="stable")
    return RecordedRun(str(path), float(rate), tuple(windows[i] for i in order), latitude, rec.meta)


def _read_can_log(
    path: Path, progress: ReadProgress | None = None, *, fitted: bool = False
) -> RecordedRun:
    session = read_can_log(
        path, min_windows=1, progress=progress, summarise=window_fit if fitted else None
    )
    gaps = [n for n in session.notes if "missing" in n]
    meta: dict[str, Any] = {"notes": list(session.notes), "gaps": gaps}
    if session.identity is not None:
        meta["device"] = session.recording().meta.get("device")
    return RecordedRun(
        str(path), session.sample_rate_hz, session.windows, None, meta, session.summaries
    )


def _read_csv(path: Path) -> RecordedRun:
    return _read_can_log(path) if is_can_log(path) else _read_northfinder(path)


def _read_gz(path: Path) -> RecordedRun:
    if not is_can_log(path):
        raise RecordingError(f"{path}: a .gz file is read as a compressed CAN log (run.log.gz)")
    return _read_can_log(path)


register_reader(".csv", _read_csv)
register_reader(".npz", _read_northfinder)
for _suffix in (".log", ".asc", ".blf", ".db", ".trc", ".mf4"):
    register_reader(_suffix, _read_can_log)
register_reader(".gz", _read_gz)


def read_runs(
    paths: Sequence[str | Path],
    progress: Callable[[Path], ReadProgress | None] | None = None,
    *,
    fitted: bool = False,
) -> list[RecordedRun]:
    """Read every file, one run each, by the reader its ending names; a CAN log's reading is
    told to ``progress(path)`` when that gives a callback
    (:func:`~northfinder.host.canlog.read_can_log`'s ``progress``).

    ``fitted``: each window is reduced to what calibration takes of it (:func:`window_fit`) and
    its samples dropped: :attr:`RecordedRun.fits` instead of :attr:`RecordedRun.windows`, in
    memory one window's samples at a time (CAN logs, NPZ and CSV recordings are read window by
    window; a file of another reader is read whole, then reduced).

    Raises
    ------
    RecordingError
        No files, a format no reader knows (the message lists those known), the reader's own
        error naming the file and what is wrong, or the same recording given twice (the same
        file, a copy, or the same samples in another format): each recording must be an
        independent power-on, and a repeated one would count its noise twice and overstate
        the confidence of every term fitted.
    """
    if not paths:
        raise RecordingError("recordings: give at least one file")
    runs = []
    for p in map(Path, paths):
        reader = READERS.get(p.suffix.lower())
        if reader is None:
            raise RecordingError(
                f"{p}: no reader for {p.suffix or 'files without an ending'!r}; readable: "
                f"{', '.join(sorted(READERS))}"
            )
        told = progress(p) if progress is not None else None
        if fitted:
            runs.append(_fitted(p, reader, told))
        else:
            runs.append(_read_can_log(p, told) if told is not None and is_can_log(p) else reader(p))
    _check_distinct(paths, runs)
    return runs


def _fitted(
    p: Path, reader: Callable[[Path], RecordedRun], progress: ReadProgress | None
) -> RecordedRun:
    """The run of ``p`` with its windows reduced (:func:`window_fit`) as they are read."""
    if is_can_log(p):
        return _read_can_log(p, progress, fitted=True)
    got = summarise_recording(p, window_fit)  # None for another format
    if got is not None:
        fits, meta, _ = got
        lat = meta.get("latitude_deg")
        latitude = float(lat) if isinstance(lat, int | float) and math.isfinite(lat) else None
        order = np.argsort([f.start_s for f in fits], kind="stable")
        rate = float(meta["sample_rate_hz"])
        return RecordedRun(str(p), rate, (), latitude, meta, tuple(fits[i] for i in order))
    run = reader(p)
    fits = tuple(window_fit(w, run.sample_rate_hz) for w in run.windows)
    return dataclasses.replace(run, windows=(), fits=fits)


def _check_distinct(paths: Sequence[str | Path], runs: list[RecordedRun]) -> None:
    names = list(map(str, paths))
    for j, run in enumerate(runs):
        first = next((names[i] for i in range(j) if same_session(runs[i], run)), None)
        if first is None:
            continue
        name = names[j]
        same = (
            "is the same file as"
            if Path(name).resolve() == Path(first).resolve()
            else "holds the same samples as"
        )
        raise RecordingError(
            f"{name}: {same} {first}; each recording must be a separate power-on "
            "(a repeated one would be counted as independent data)"
        )


#: Sample values of one session written in two formats (a recording's CSV or NPZ, a CAN log's
#: counts scaled back) agree to this, relative and absolute (deg/h, m/s^2); two power-ons never do.
SAME_SESSION_RTOL = 1e-6
SAME_SESSION_ATOL = 1e-6


def same_session(a: RecordedRun, b: RecordedRun) -> bool:
    """Whether two runs hold the same session: the same windows of the same sample counters and
    validity, with gyro and accelerometer samples equal within :data:`SAME_SESSION_RTOL` (a
    recording and a CAN log of one run differ in the last digits, as floats written and read
    in another way do). Runs read ``fitted`` are compared on their windows' fingerprints
    (:class:`WindowFit`): the counters and validity bits, and samples spread over each window."""
    if a.fits or b.fits:
        return _same_fits(a.window_fits(), b.window_fits())
    if len(a.windows) != len(b.windows):
        return False
    for wa, wb in zip(a.windows, b.windows, strict=True):
        if not (
            np.array_equal(wa.counter, wb.counter) and np.array_equal(wa.validity, wb.validity)
        ):
            return False
        for x, y in ((wa.gyro_dph, wb.gyro_dph), (wa.accel_mps2, wb.accel_mps2)):
            if not np.allclose(x, y, rtol=SAME_SESSION_RTOL, atol=SAME_SESSION_ATOL):
                return False
    return True


def _same_fits(a: Sequence[WindowFit], b: Sequence[WindowFit]) -> bool:
    if len(a) != len(b):
        return False
    for fa, fb in zip(a, b, strict=True):
        if fa.fingerprint[0] != fb.fingerprint[0] or fa.samples != fb.samples:
            return False
        x, y = fa.fingerprint[1], fb.fingerprint[1]
        if not np.allclose(x, y, rtol=SAME_SESSION_RTOL, atol=SAME_SESSION_ATOL):
            return False
    return True
