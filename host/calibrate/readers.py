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

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from northfinder.host.canlog import ReadProgress, is_can_log, read_can_log
from northfinder.host.errors import RecordingError
from northfinder.host.procedure import unfit_samples
from northfinder.host.recording import RecordedWindow, Recording

__all__ = [
    "READERS",
    "RecordedRun",
    "good_stretches",
    "read_runs",
    "register_reader",
]


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


def _read_can_log(path: Path, progress: ReadProgress | None = None) -> RecordedRun:
    session = read_can_log(path, min_windows=1, progress=progress)
    gaps = [n for n in session.notes if "missing" in n]
    meta: dict[str, Any] = {"notes": list(session.notes), "gaps": gaps}
    if session.identity is not None:
        meta["device"] = session.recording().meta.get("device")
    return RecordedRun(str(path), session.sample_rate_hz, session.windows, None, meta)


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
    paths: Sequence[str | Path], progress: Callable[[Path], ReadProgress | None] | None = None
) -> list[RecordedRun]:
    """Read every file, one run each, by the reader its ending names; a CAN log's reading is
    told to ``progress(path)`` when that gives a callback
    (:func:`~northfinder.host.canlog.read_can_log`'s ``progress``).

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
        runs.append(_read_can_log(p, told) if told is not None and is_can_log(p) else reader(p))
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
    return runs


#: Sample values of one session written in two formats (a recording's CSV or NPZ, a CAN log's
#: counts scaled back) agree to this, relative and absolute (deg/h, m/s^2); two power-ons never do.
SAME_SESSION_RTOL = 1e-6
SAME_SESSION_ATOL = 1e-6


def same_session(a: RecordedRun, b: RecordedRun) -> bool:
    """Whether two runs hold the same session: the same windows of the same sample counters and
    validity, with gyro and accelerometer samples equal within :data:`SAME_SESSION_RTOL` (a
    recording and a CAN log of one run differ in the last digits, as floats written and read
    in another way do)."""
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
