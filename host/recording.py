"""Recordings of raw windows: written by ``northfinder record``, solved by ``northfinder solve``.

Two formats carry the same content.

CSV (``.csv``)
    Comment lines ``# key = value`` first (``format = northfinder-recording``, ``version = 1``,
    ``latitude_deg``, ``sample_rate_hz``, and anything else known, e.g. the simulated truth), then
    one header line and one row per sample with the columns of :data:`COLUMNS`:

    ======================  =====================================================
    ``window``              0-based window index
    ``commanded_deg``       table angle ordered for the window, deg
    ``counter``             device sample counter (consecutive within a window)
    ``time_s``              device time of the sample, s
    ``gyro_x_dph`` .. z     gyro, mean rate over the sample interval, deg/h
    ``accel_x_mps2`` .. z   accelerometer, mean specific force, m/s^2
    ``table_deg``           encoder angle, deg
    ``temperature_c``       sensor temperature, degC
    ``validity``            validity bits (protocol.md 4.5)
    ======================  =====================================================

NPZ (``.npz``)
    Arrays named after the columns (``gyro_dph`` and ``accel_mps2`` as (n, 3)), concatenated over
    windows, and ``meta_json``: the same metadata as a JSON string (the column layout). An NPZ
    still being written, or cut off while it was, holds each window's arrays instead, as
    ``w0/commanded_deg`` (one number), ``w0/counter``, ``w0/time_s``, ... ``w0/validity``, then
    ``w1/...`` (the window layout); the reader joins them. Both layouts are ``version = 1``.

Written as they arrive
    :class:`RecordingWriter` writes each window as soon as it is measured: a CSV's rows are
    appended and flushed to disk window by window; an NPZ's window is appended to the archive
    (its arrays, then the archive's directory again), so the file is a whole NPZ after every
    window and nothing is written twice, and as the run ends (complete or interrupted) the
    windows are written once more in the column layout, to a temporary file that replaces it:
    time linear in the samples. An existing file of the name (an
    earlier recording) is never touched until the new recording is complete: the windows go to
    ``run.partial.csv`` beside ``run.csv``, which replaces it at the end; a run that ends early
    (an interruption, an error, a full disk) leaves the earlier file as it was and its windows in
    the partial file. Without an earlier file the windows go to the name given. So a failed write
    never destroys a file, and an interrupted run keeps every complete window. The metadata key
    ``status`` says how the recording ended: ``"recording"`` (written while the windows arrive; a
    recording that still reads so was cut off: power, SIGKILL, a full disk), ``"interrupted"`` or
    ``"complete"``; a CSV's head holds it once, written over in place as the run ends, and a
    comment line after the samples the number of ``windows``. A recording without ``status``
    (written before this key) counts as complete. :attr:`Recording.partial` names what is missing.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.constants import Validity
from northfinder.driver.protocol.units import DPH
from northfinder.host.errors import OutputError, RecordingError

__all__ = [
    "COLUMNS",
    "FORMAT",
    "SAMPLE_ARRAYS",
    "VERSION",
    "RecordedWindow",
    "Recording",
    "RecordingError",
    "RecordingWriter",
    "summarise_csv",
    "summarise_npz",
    "summarise_recording",
]

FORMAT = "northfinder-recording"
VERSION = 1
COLUMNS = (
    "window",
    "commanded_deg",
    "counter",
    "time_s",
    "gyro_x_dph",
    "gyro_y_dph",
    "gyro_z_dph",
    "accel_x_mps2",
    "accel_y_mps2",
    "accel_z_mps2",
    "table_deg",
    "temperature_c",
    "validity",
)


#: Per-sample arrays of a window, in the order of :class:`RecordedWindow`'s fields.
SAMPLE_ARRAYS = (
    "counter",
    "time_s",
    "gyro_dph",
    "accel_mps2",
    "table_deg",
    "temperature_c",
    "validity",
)


@dataclass(frozen=True)
class RecordedWindow:
    """One window of raw samples (the same fields the procedure reads from a live window)."""

    commanded_deg: float
    counter: NDArray[np.int64]
    time_s: NDArray[np.float64]
    gyro_dph: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    table_deg: NDArray[np.float64]
    temperature_c: NDArray[np.float64]
    validity: NDArray[np.uint8]

    @property
    def gaps(self) -> list[tuple[int, int]]:
        """(first missing counter, count) for every jump in the counter."""
        d = np.diff(self.counter)
        return [(int(self.counter[i] + 1), int(d[i] - 1)) for i in np.flatnonzero(d != 1)]

    @property
    def missing(self) -> int:
        return sum(max(c, 0) for _, c in self.gaps)

    @classmethod
    def from_window(cls, window: Any, commanded_deg: float) -> RecordedWindow:
        """Copy the sample arrays of a live window (anything with those attributes)."""
        fields = {name: _kept(getattr(window, name)) for name in SAMPLE_ARRAYS}
        fields["validity"] = fields["validity"].astype(np.uint8, copy=False)
        return cls(float(commanded_deg), **fields)


def _kept(a: Any) -> NDArray[Any]:
    """``a`` itself when nothing can change it (a read-only array owning its data, as a live
    window's are), else a copy: a recording of hours holds no second copy of its samples."""
    if isinstance(a, np.ndarray) and a.flags.owndata and not a.flags.writeable:
        return a
    return np.array(a)


@dataclass(frozen=True)
class Recording:
    windows: tuple[RecordedWindow, ...]
    meta: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_batch(
        cls, batch: Any, run: int, latitude_deg: float, *, temperature_c: float = 20.0
    ) -> Recording:
        """Run ``run`` of a many-runs batch (anything with the arrays of the simulator's
        ``BatchWindows``) as the recorder writes it: consecutive counters from each window's
        start, the encoder angle and ``temperature_c`` held over the window, every sample
        valid (gyro and accelerometer)."""
        fs = float(batch.sample_rate_hz)
        n = batch.gyro_rps.shape[2]
        windows = []
        for p, angle in enumerate(batch.commanded_deg):
            counter = round(batch.window_start_s[p] * fs) + np.arange(n)
            windows.append(
                RecordedWindow(
                    float(angle),
                    counter,
                    (counter + 1) / fs,
                    batch.gyro_rps[run, p] / DPH,
                    np.array(batch.accel_mps2[run, p]),
                    np.full(n, batch.table_deg[run, p]),
                    np.full(n, temperature_c),
                    np.full(n, Validity.GYRO_VALID | Validity.ACCEL_VALID, dtype=np.uint8),
                )
            )
        return cls(tuple(windows), {"latitude_deg": latitude_deg, "sample_rate_hz": fs})

    def save(self, path: str | Path) -> None:
        """Write as CSV or NPZ, chosen by the file name's ending: to a temporary file beside it,
        which then replaces ``path`` at once (a failed write leaves an existing file as it was).

        Raises
        ------
        RecordingError
            The name ends in neither .csv nor .npz.
        OutputError
            The file cannot be written.
        """
        p = _recording_path(path)
        meta = {"format": FORMAT, "version": VERSION, **self.meta}
        meta.setdefault("status", "complete")
        try:
            if p.suffix == ".npz":
                _replace_npz(p, meta, self.windows)
            else:
                with _atomic(p) as fh:
                    _write_csv_head(fh, meta)
                    for i, w in enumerate(self.windows):
                        _write_csv_rows(fh, i, w)
                    _write_csv_tail(fh, len(self.windows))
        except OSError as exc:
            raise OutputError(f"{p}: cannot write ({exc.strerror or exc})") from exc

    @property
    def status(self) -> str:
        """How the recording ended: ``"complete"``, ``"interrupted"`` or ``"recording"``
        (cut off while written); ``"complete"`` for a recording written before the key."""
        return str(self.meta.get("status", "complete"))

    @property
    def planned_windows(self) -> int | None:
        """The number of windows the recording's plan asked for, if it states its plan."""
        plan = self.meta.get("plan")
        positions = plan.get("positions_deg") if isinstance(plan, dict) else None
        return len(positions) if isinstance(positions, list) else None

    @property
    def partial(self) -> str | None:
        """None for a complete recording, else what it holds: ``"interrupted: 3 of 4 windows"``
        (every window it holds is complete)."""
        if self.status == "complete":
            return None
        why = "interrupted" if self.status == "interrupted" else "cut off while recording"
        spin = _spin_plan(self)
        if spin is not None and self.windows:
            n, rate_dps = spin
            have = sum(len(w.counter) + w.missing for w in self.windows)
            return f"{why}: {_ticks_and_turns(have, n, rate_dps, self.meta)}"
        planned = self.planned_windows
        of = f" of {planned}" if planned is not None else ""
        return f"{why}: {len(self.windows)}{of} windows"

    @staticmethod
    def load(path: str | Path, *, min_windows: int = 2) -> Recording:
        """Read a CSV or NPZ recording; every problem is reported with the file and the field.

        ``min_windows``: fewer windows is an error (north finding needs two positions; a static
        recording for calibration may hold one)."""
        p = Path(path)
        if p.suffix not in (".csv", ".npz"):
            raise RecordingError(f"{p}: the file name must end in .csv or .npz")
        _check_readable(p)
        try:
            if p.suffix == ".npz":
                arrays, meta = _read_npz(p)
            else:
                arrays, meta = _read_csv(p)
        except OSError as exc:
            raise RecordingError(f"{p}: cannot read ({exc.strerror or exc})") from exc
        if not isinstance(meta, dict):
            raise RecordingError(
                f"{p}: the metadata (meta_json) must be a table of key = value, got "
                f"{type(meta).__name__}"
            )
        if meta.get("format") != FORMAT:
            raise RecordingError(
                f"{p}: not a northfinder recording (format = {meta.get('format')!r})"
            )
        if meta.get("version") != VERSION:
            raise RecordingError(
                f"{p}: recording version {meta.get('version')!r}; this reader knows {VERSION}"
            )
        check_meta(meta, p)
        windows = _split(arrays, p, min_windows)
        check_rate(windows, float(meta["sample_rate_hz"]), p)
        recording = Recording(windows, meta)
        check_against_plan(recording, p)
        return recording


def check_against_plan(rec: Recording, p: Path | str) -> None:
    """Refuse a recording that does not hold what its own plan and status say: fewer windows
    than planned in a recording that says it is complete, a window shorter than the plan's
    (cut short) or longer, more windows than planned (padded). A recording without a plan
    (written by other tools) is not checked; a partial one (:attr:`Recording.partial`) may hold
    fewer windows, each of them whole.

    Raises
    ------
    RecordingError
        ``truncated: 3 of 4 windows, the last cut short``, ``padded: ...``.
    """
    spin = _spin_plan(rec)
    if spin is not None:
        _check_spin(rec, spin, p)
        return
    plan = rec.meta.get("plan")
    if not isinstance(plan, dict):
        return
    positions, window_s = plan.get("positions_deg"), plan.get("window_s")
    if not isinstance(positions, list) or not _number(window_s) or window_s <= 0:
        return
    planned = len(positions)
    n = round(float(window_s) * float(rec.meta["sample_rate_hz"]))
    have = len(rec.windows)
    sizes = [len(w.counter) + w.missing for w in rec.windows]  # ticks spanned, gaps included
    if have > planned:
        raise RecordingError(f"{p}: padded: {have} windows, its plan has {planned}")
    long = [i for i, k in enumerate(sizes) if k > n]
    if long:
        raise RecordingError(
            f"{p}: padded: window {long[0]} spans {sizes[long[0]]} sample ticks; its plan's "
            f"{window_s:g} s at {rec.meta['sample_rate_hz']:g} Hz make {n}"
        )
    short = [i for i, k in enumerate(sizes) if k < n]
    if short and short != [have - 1]:
        raise RecordingError(
            f"{p}: truncated: window {short[0]} has {sizes[short[0]]} of its {n} samples"
        )
    if short:
        raise RecordingError(
            f"{p}: truncated: {have} of {planned} windows, the last cut short "
            f"({sizes[-1]} of {n} samples)"
        )
    if have < planned and rec.partial is None:
        raise RecordingError(
            f"{p}: truncated: {have} of {planned} windows, though it says it is complete"
        )


def _spin_plan(rec: Recording) -> tuple[int, float] | None:
    """(sample ticks, rate deg/s) a spin recording's ``spin`` entry plans; None for another
    recording or one whose entry does not say."""
    spin = rec.meta.get("spin")
    if not isinstance(spin, dict):
        return None
    rate_dps, spin_s = spin.get("rate_dps"), spin.get("spin_s")
    if not (_number(rate_dps) and _number(spin_s) and spin_s > 0):
        return None
    return round(float(spin_s) * float(rec.meta["sample_rate_hz"])), float(rate_dps)


def _ticks_and_turns(have: int, n: int, rate_dps: float, meta: dict[str, Any]) -> str:
    """``6000 of 12000 samples (-0.50 of -1.00 turns)``."""
    per_tick = rate_dps / float(meta["sample_rate_hz"]) / 360.0
    return f"{have} of {n} samples ({have * per_tick:+.2f} of {n * per_tick:+.2f} turns)"


def _check_spin(rec: Recording, spin: tuple[int, float], p: Path | str) -> None:
    """A spin recording holds one window of its planned ticks; fewer only when it says it is
    partial (interrupted or cut off while recording)."""
    n, rate_dps = spin
    if len(rec.windows) > 1:
        raise RecordingError(f"{p}: padded: {len(rec.windows)} windows; a spin recording has one")
    (w,) = rec.windows
    have = len(w.counter) + w.missing  # ticks spanned, gaps included
    if have > n:
        raise RecordingError(
            f"{p}: padded: the spin spans {have} sample ticks; its {n / float(rec.meta['sample_rate_hz']):g} s "
            f"at {rec.meta['sample_rate_hz']:g} Hz make {n}"
        )
    if have < n and rec.partial is None:
        raise RecordingError(
            f"{p}: truncated: {_ticks_and_turns(have, n, rate_dps, rec.meta)}, though it says "
            "it is complete"
        )


def check_rate(windows: tuple[RecordedWindow, ...], rate_hz: float, p: Path | str) -> None:
    """Refuse a recording whose device time disagrees with its stated ``sample_rate_hz``: the
    solvers and the noise model read the rate, so a wrong one gives a wrong sigma.

    The median step of ``time_s`` between samples whose counters follow each other must be one
    period within 1 %.

    Raises
    ------
    RecordingError
    """
    steps = [np.diff(w.time_s)[np.diff(w.counter) == 1] for w in windows if len(w.counter) > 1]
    dt = np.concatenate(steps) if steps else np.empty(0)
    if len(dt) < 2:
        return
    step = float(np.median(dt))
    if not abs(step * rate_hz - 1.0) <= 0.01:
        seen = f"{1.0 / step:.6g} Hz" if step > 0 else "no time at all"
        raise RecordingError(
            f"{p}: sample_rate_hz = {rate_hz:g}, but time_s advances {step * 1000:.6g} ms from one "
            f"sample counter to the next ({seen}); the rate and the samples disagree"
        )


#: Highest sample rate a recording may state, Hz.
MAX_SAMPLE_RATE_HZ = 100_000.0
#: Largest magnitude of a gyro sample, deg/h (over 270 000 deg/s), of a specific force, m/s^2
#: (about 1000 g), of an encoder angle, deg: beyond them a recording holds no measurement.
SAMPLE_LIMITS = {"gyro_dph": 1e9, "accel_mps2": 1e4, "table_deg": 720.0}
#: Truth fields a recording of a simulated run carries (deg).
TRUTH_FIELDS = ("azimuth_deg", "pitch_deg", "roll_deg")


def _number(value: Any) -> TypeGuard[float]:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def check_meta(meta: dict[str, Any], p: Path | str) -> None:
    """Refuse metadata a solver would misread; the message names the key.

    ``sample_rate_hz`` must be a positive number (at most :data:`MAX_SAMPLE_RATE_HZ`);
    ``latitude_deg``, when present, a number in [-90, 90]; ``truth``, when present, a table of
    finite numbers with at least :data:`TRUTH_FIELDS`; ``plan``, when present, a table.

    Raises
    ------
    RecordingError
    """
    rate = meta.get("sample_rate_hz")
    if not (_number(rate) and 0 < rate <= MAX_SAMPLE_RATE_HZ):
        shown = "missing" if rate is None else f"got {rate!r}"
        raise RecordingError(
            f"{p}: sample_rate_hz must be a number of Hz, more than 0 and at most "
            f"{MAX_SAMPLE_RATE_HZ:g} ({shown})"
        )
    if "latitude_deg" in meta:
        lat = meta["latitude_deg"]
        if not (_number(lat) and -90.0 <= lat <= 90.0):
            raise RecordingError(
                f"{p}: latitude_deg must be a number of deg in [-90, 90], got {lat!r}"
            )
    if "truth" in meta:
        truth = meta["truth"]
        if not isinstance(truth, dict):
            raise RecordingError(f"{p}: truth must be a table of key = value, got {truth!r}")
        for key in TRUTH_FIELDS:
            if not _number(truth.get(key)):
                raise RecordingError(
                    f"{p}: truth {key} must be a finite number of deg, got {truth.get(key)!r}"
                )
    if "plan" in meta and not isinstance(meta["plan"], dict):
        raise RecordingError(f"{p}: plan must be a table of key = value, got {meta['plan']!r}")


def _whole(name: str, values: NDArray[Any], p: Path, lo: float, hi: float) -> NDArray[np.int64]:
    """A column of whole numbers in [lo, hi] as int64, or a RecordingError naming it."""
    v = np.asarray(values)
    if v.dtype.kind in "iu":
        bad = (v < lo) | (v > hi)
    else:
        f = v.astype(np.float64)
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(f) | (f != np.round(f)) | (f < lo) | (f > hi)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise RecordingError(
            f"{p}: {name} of sample {i} is {v.flat[i]!r}; it must be a whole number from "
            f"{lo:g} to {hi:g}"
        )
    return v.astype(np.int64)


def _concat(windows: tuple[RecordedWindow, ...]) -> dict[str, NDArray[Any]]:
    def cat(name: str) -> NDArray[Any]:
        return np.concatenate([getattr(w, name) for w in windows])

    return {
        "window": np.concatenate(
            [np.full(len(w.counter), i, dtype=np.int64) for i, w in enumerate(windows)]
        ),
        "commanded_deg": np.concatenate(
            [np.full(len(w.counter), w.commanded_deg) for w in windows]
        ),
        **{name: cat(name) for name in SAMPLE_ARRAYS},
    }


def _npy_header(fh: Any) -> tuple[tuple[int, ...], bool, np.dtype[Any]]:
    """The shape, Fortran order and dtype of the ``.npy`` array open in ``fh``, read from its
    header (``fh`` is left at the array's data)."""
    version = np.lib.format.read_magic(fh)
    read = (
        np.lib.format.read_array_header_1_0
        if version == (1, 0)
        else np.lib.format.read_array_header_2_0
    )
    shape, fortran, dtype = read(fh)
    return shape, fortran, dtype


def _npz_size(p: Path) -> int:
    """Bytes the arrays of an NPZ file take once loaded, from their headers (a small compressed
    file may hold arrays far larger than itself)."""
    total = 0
    with zipfile.ZipFile(p) as zf:
        for info in zf.infolist():
            with zf.open(info) as fh:
                shape, _, dtype = _npy_header(fh)
                total += math.prod(shape) * dtype.itemsize
    return total


def _read_npz(p: Path) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    try:
        size = _npz_size(p)
    except (ValueError, zipfile.BadZipFile, EOFError, OSError, TypeError):
        size = 0  # np.load below says what is wrong with it
    if size > _MAX_ARRAY_BYTES:
        raise RecordingError(
            f"{p}: its arrays take {size / 2**30:.1f} GiB loaded; a recording holds at most "
            f"{MAX_SAMPLES} samples (split the session)"
        )
    try:
        with np.load(p, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except ValueError as exc:
        if "pickled" in str(exc):  # numpy's advice to load it unsafely is not for a user
            raise RecordingError(
                f"{p}: not a readable NPZ file of arrays (numpy could only unpickle it, and "
                "pickled data is never loaded)"
            ) from exc
        raise RecordingError(f"{p}: not a readable NPZ file ({exc})") from exc
    except (zipfile.BadZipFile, EOFError) as exc:
        cut = _cut_off_arrays(p)
        if cut is None:
            raise RecordingError(f"{p}: not a readable NPZ file ({exc})") from exc
        arrays = cut
    if "meta_json" not in arrays:
        raise RecordingError(f"{p}: no meta_json array; not a northfinder recording")
    if _member(0, "counter") in arrays:
        arrays = _joined(arrays, p)
    try:
        meta = json.loads(str(arrays.pop("meta_json")))
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{p}: meta_json is not JSON ({exc})") from exc
    return arrays, meta


def _cut_off_arrays(p: Path) -> dict[str, NDArray[Any]] | None:
    """The arrays of an NPZ cut off while a window was appended to it (power lost, SIGKILL):
    those of its last whole archive (:class:`_NpzAppender` writes one after every window),
    found from the end of the file; None if it holds none of the window layout."""
    with p.open("rb") as fh:
        for at in _signatures_from_end(fh, _EOCD, _MAX_ARCHIVES_TRIED):
            try:
                with np.load(_Prefix(fh, at + 22), allow_pickle=False) as data:
                    if "meta_json" not in data.files or _member(0, "counter") not in data.files:
                        continue
                    return {k: data[k] for k in data.files}
            except (ValueError, zipfile.BadZipFile, EOFError, OSError):
                continue
    return None


#: The signature of a zip archive's end record, and how many are tried from the end of a file.
_EOCD = b"PK\x05\x06"
_MAX_ARCHIVES_TRIED = 64


def _signatures_from_end(fh: Any, sig: bytes, limit: int) -> Any:
    """Offsets of ``sig`` in the file, the last first (at most ``limit``), read in blocks."""
    end = fh.seek(0, os.SEEK_END)
    pos, found = end, 0
    while pos > 0 and found < limit:
        start = max(0, pos - (1 << 20))
        fh.seek(start)
        block = fh.read(min(end, pos + len(sig) - 1) - start)
        i = block.rfind(sig, 0, pos - start + len(sig) - 1)
        while i >= 0 and found < limit:
            found += 1
            yield start + i
            i = block.rfind(sig, 0, i + len(sig) - 1)
        pos = start


class _Prefix(io.RawIOBase):
    """The first ``size`` bytes of an open file, as a file of their own."""

    def __init__(self, fh: Any, size: int) -> None:
        self._fh, self._size, self._pos = fh, size, 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._pos, os.SEEK_END: self._size}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, b: Any) -> int:
        n = max(0, min(len(b), self._size - self._pos))
        self._fh.seek(self._pos)
        data = self._fh.read(n)
        b[: len(data)] = data
        self._pos += len(data)
        return len(data)


def _joined(arrays: dict[str, NDArray[Any]], p: Path) -> dict[str, NDArray[Any]]:
    """The column arrays of an NPZ written window by window (a recording cut off while it was
    written: :class:`_NpzAppender`), its windows' arrays joined."""
    count = sum(1 for k in arrays if k.endswith("/counter"))
    parts: dict[str, list[NDArray[Any]]] = {name: [] for name in ("window", *_WINDOW_MEMBERS)}
    for i in range(count):
        for name in _WINDOW_MEMBERS:
            if _member(i, name) not in arrays:
                raise RecordingError(f"{p}: missing array {_member(i, name)!r}")
            parts[name].append(arrays.pop(_member(i, name)))
        n = len(parts["counter"][-1])
        if parts["commanded_deg"][-1].shape != ():
            raise RecordingError(f"{p}: array {_member(i, 'commanded_deg')!r} must be one number")
        parts["commanded_deg"][-1] = np.full(n, parts["commanded_deg"][-1])
        parts["window"].append(np.full(n, i, dtype=np.int64))
    try:
        joined = {name: np.concatenate(a) for name, a in parts.items()}
    except ValueError as exc:  # windows whose arrays differ in shape
        raise RecordingError(f"{p}: the windows' arrays do not fit together ({exc})") from exc
    return {**arrays, **joined}


#: Largest recording read, bytes (a day of 200 Hz samples in CSV is about 2 GB; beyond this the
#: reader would exhaust memory rather than say what is wrong).
MAX_RECORDING_BYTES = 4 << 30


def _check_readable(p: Path) -> None:
    """Refuse what is no regular file (a FIFO would block, a device never end) or is larger
    than :data:`MAX_RECORDING_BYTES`."""
    import stat

    try:
        st = p.stat()
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read ({exc.strerror or exc})") from exc
    if not stat.S_ISREG(st.st_mode):
        raise RecordingError(f"{p}: not a regular file (a folder, a FIFO or a device)")
    if st.st_size > MAX_RECORDING_BYTES:
        raise RecordingError(
            f"{p}: {st.st_size / 2**30:.1f} GiB; recordings up to {MAX_RECORDING_BYTES >> 30} GiB "
            "are read (split a longer session)"
        )


def _recording_path(path: str | Path) -> Path:
    p = Path(path)
    if p.suffix not in (".csv", ".npz"):
        raise RecordingError(f"{p}: the file name must end in .csv or .npz")
    return p


def _temporary_beside(p: Path) -> tuple[int, str]:
    """A new temporary file in ``p``'s directory (so that ``os.replace`` is atomic), with the
    permissions a file created in place would get (mkstemp makes it private)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent or ".")
    try:
        mode = os.stat(p).st_mode & 0o777
    except OSError:
        umask = os.umask(0o022)
        os.umask(umask)
        mode = 0o666 & ~umask
    with contextlib.suppress(OSError):
        os.fchmod(fd, mode)
    return fd, tmp


@contextlib.contextmanager
def _atomic(p: Path, mode: str = "w") -> Any:
    """A temporary file beside ``p`` that replaces ``p`` once written and flushed to disk; on
    any error it is removed and ``p`` is left as it was."""
    fd, tmp = _temporary_beside(p)
    try:
        with os.fdopen(fd, mode, newline="" if "b" not in mode else None) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _replace_npz(p: Path, meta: dict[str, Any], windows: tuple[RecordedWindow, ...]) -> None:
    # The arrays of np.savez_compressed, written column by column and window by window: the
    # windows are never joined in memory (a copy of the whole run at every window).
    def piece(i: int, name: str) -> NDArray[Any]:
        w = windows[i]
        if name == "window":
            return np.full(len(w.counter), i, dtype=np.int64)
        if name == "commanded_deg":
            return np.full(len(w.counter), w.commanded_deg)
        return np.asarray(getattr(w, name))

    _write_columns(p, meta, [len(w.counter) for w in windows], piece)


def _write_columns(
    p: Path, meta: dict[str, Any], sizes: list[int], piece: Callable[[int, str], NDArray[Any]]
) -> None:
    """Write the NPZ of the column layout (one array a column, every window in turn) to a
    temporary file that then replaces ``p``; ``piece(i, name)`` gives window ``i``'s part of
    column ``name`` (``sizes[i]`` rows), asked for one at a time."""
    with _atomic(p, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("meta_json.npy", "w", force_zip64=True) as out:
            np.lib.format.write_array(out, np.array(json.dumps(meta)), allow_pickle=False)
        for name in ("window", "commanded_deg", *SAMPLE_ARRAYS):
            like = piece(0, name) if sizes else np.empty(0)
            dtype, shape = like.dtype, (sum(sizes), *like.shape[1:])
            del like  # asked for again below: one window's column in memory at a time
            header = {
                "descr": np.lib.format.dtype_to_descr(dtype),
                "fortran_order": False,
                "shape": shape,
            }
            with zf.open(f"{name}.npy", "w", force_zip64=True) as out:
                np.lib.format.write_array_header_1_0(out, header)
                for i in range(len(sizes)):
                    a = np.ascontiguousarray(piece(i, name), dtype=dtype)
                    flat = a.reshape(-1).view(np.uint8)
                    for k in range(0, len(flat), _NPZ_CHUNK_BYTES):
                        out.write(flat[k : k + _NPZ_CHUNK_BYTES].data)
                    del a, flat


#: Bytes handed to the compressor at a time while an NPZ is written.
_NPZ_CHUNK_BYTES = 1 << 22


def _write_csv_head(fh: Any, meta: dict[str, Any]) -> int:
    """Write the comment lines and the column header; return the byte offset of the ``status``
    value, which is padded so that any final status can be written over it in place."""
    at = -1
    written = 0
    for k, v in meta.items():
        value = json.dumps(v)
        if k == "status":
            at = written + len(f"# {k} = ".encode())
            value = value.ljust(_STATUS_WIDTH)
        line = f"# {k} = {value}\n"
        fh.write(line)
        written += len(line.encode())
    csv.writer(fh).writerow(COLUMNS)
    return at


#: Characters of the ``status`` value in a CSV's head: the longest status, quoted.
_STATUS_WIDTH = max(len(json.dumps(s)) for s in ("recording", "interrupted", "complete"))


def _write_csv_rows(fh: Any, i: int, w: RecordedWindow) -> None:
    # Formatted and written a block of rows at a time (a window of hours is never held as
    # text). A window cut off part way (an interruption, a full disk) is cut off the file by
    # the writer, which truncates it to the end of the last complete window.
    for start in range(0, len(w.counter), _CSV_BLOCK_ROWS):
        stop = min(start + _CSV_BLOCK_ROWS, len(w.counter))
        text = io.StringIO()
        writer = csv.writer(text)
        for j in range(start, stop):
            writer.writerow(
                [i, f"{w.commanded_deg:.6f}", int(w.counter[j]), f"{w.time_s[j]:.6f}"]
                + [repr(float(v)) for v in w.gyro_dph[j]]
                + [repr(float(v)) for v in w.accel_mps2[j]]
                + [f"{w.table_deg[j]:.6f}", f"{w.temperature_c[j]:.2f}", int(w.validity[j])]
            )
        fh.write(text.getvalue())


def _write_csv_tail(fh: Any, windows: int) -> None:
    fh.write(f"# windows = {windows}\n")


def partial_name(p: Path) -> Path:
    """Where the windows of a new recording go while an earlier file of the same name is kept:
    ``run.partial.csv`` beside ``run.csv`` (``run.partial-2.csv``, ... if that is taken)."""
    for k in range(1, 1000):
        tag = ".partial" if k == 1 else f".partial-{k}"
        candidate = p.with_name(f"{p.stem}{tag}{p.suffix}")
        if not os.path.lexists(candidate):
            return candidate
    raise RecordingError(f"{p}: 999 partial recordings beside it; move them away")


def _create(p: Path, mode: int | None) -> int:
    """A new file (never one that exists), with ``mode`` if given."""
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    if mode is not None:
        with contextlib.suppress(OSError):
            os.fchmod(fd, mode)
    return fd


#: Member names of a window in an NPZ being written (``w3/gyro_dph.npy``, ...): its commanded
#: angle (a 0-d array) and its sample arrays.
_WINDOW_MEMBERS = ("commanded_deg", *SAMPLE_ARRAYS)


def _member(i: int, name: str) -> str:
    return f"w{i}/{name}"


class _NpzAppender:
    """An NPZ that grows by whole windows, as :class:`RecordingWriter` writes one.

    Each window's arrays go in as members of their own (:func:`_member`) after those already
    written, and the zip archive's central directory (the list of its members, which ends every
    zip file) is written after them: the file on disk is a whole archive of every window added,
    and no window is written twice. The directories of earlier windows stay in the file,
    unlisted (a few hundred bytes a window). A window whose writing fails is cut off the file
    (:meth:`cut`), which then ends with the last whole archive again.
    """

    def __init__(self, fd: int, meta: dict[str, Any]) -> None:
        self._fh = os.fdopen(fd, "w+b")
        # Any: the archive's directory is written through zipfile's own private method.
        self._zf: Any = zipfile.ZipFile(self._fh, "w", zipfile.ZIP_DEFLATED)
        self.good = 0  # bytes of the file up to the end of its last whole archive
        self.sizes: list[int] = []  # samples of each window written
        self._put("meta_json", np.array(json.dumps(meta)))

    def _put(self, name: str, a: NDArray[Any]) -> None:
        with self._zf.open(f"{name}.npy", "w", force_zip64=True) as out:
            np.lib.format.write_array(out, np.asarray(a), allow_pickle=False)

    def add(self, window: RecordedWindow) -> None:
        i = len(self.sizes)
        self._put(_member(i, "commanded_deg"), np.array(window.commanded_deg))
        for name in SAMPLE_ARRAYS:
            self._put(_member(i, name), np.asarray(getattr(window, name)))
        # zipfile writes the central directory only as it closes the archive; written here
        # after the members (where the next window's members then begin), the file is a
        # whole archive after every window.
        self._zf._write_end_record()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.good = self._fh.tell()
        self._zf.start_dir = self.good
        self._zf._didModify = False  # whole on disk: nothing for zipfile to write as it closes
        self.sizes.append(len(window.counter))

    def cut(self) -> None:
        """Cut what follows the last whole archive off the file."""
        with contextlib.suppress(OSError, ValueError):
            self._fh.truncate(self.good)

    def close(self) -> None:
        """Close the file as it is (its last whole archive: nothing more is written)."""
        self._zf._didModify = False  # every window's archive is on disk already
        self._zf._writing = False
        with contextlib.suppress(OSError, ValueError):
            self._zf.close()
        with contextlib.suppress(OSError, ValueError):
            self._fh.close()


def _consolidate(work: Path, meta: dict[str, Any], sizes: list[int]) -> None:
    """Write the windows of an NPZ written window by window (:class:`_NpzAppender`) again in
    the column layout, with ``meta``, in place of it: one pass, one window's column at a time
    in memory."""
    with zipfile.ZipFile(work) as src:

        def piece(i: int, name: str) -> NDArray[Any]:
            if name == "window":
                return np.full(sizes[i], i, dtype=np.int64)
            with src.open(_member(i, name) + ".npy") as fh:
                a = np.lib.format.read_array(fh, allow_pickle=False)
            return np.full(sizes[i], float(a)) if name == "commanded_deg" else a

        _write_columns(work, meta, sizes, piece)


class RecordingWriter:
    """Writes a recording window by window, as the windows are measured (module docstring).

    Where there is no file of that name, the windows go to it at once. An existing file (an
    earlier recording) is never touched until the new one is complete: the windows go to
    :attr:`work`, ``run.partial.csv`` beside ``run.csv``, which replaces the earlier file when
    the run closes ``"complete"``; a run that ends early leaves both.

    ``add`` never raises for a failed write: the first error is kept (:attr:`error`), later
    windows are counted but not written, and :meth:`close` raises it, so that a run goes on to
    its result and the caller reports the result first, then the error.

    Parameters
    ----------
    path : str or Path
        The recording, .csv or .npz.
    meta : dict
        Its metadata (``latitude_deg``, ``sample_rate_hz``, ``plan``, ...).
    keep_windows : bool
        Also keep each window added in :attr:`windows` (False: the file is the only copy).

    Raises
    ------
    RecordingError
        The name ends in neither .csv nor .npz.
    """

    def __init__(
        self, path: str | Path, meta: dict[str, Any], *, keep_windows: bool = True
    ) -> None:
        self.path = _recording_path(path)
        self.meta = {"format": FORMAT, "version": VERSION, **meta, "status": "recording"}
        #: The windows added, in memory (none when made with ``keep_windows=False``: a run of
        #: hours then holds one window at a time, the file the only copy).
        self.windows: list[RecordedWindow] = []
        self.keep_windows = keep_windows
        #: The samples of each window added (:attr:`written` of them written).
        self.sizes: list[int] = []
        self.written = 0
        self.error: OutputError | None = None
        #: An earlier file of the name, kept until the new recording is complete.
        self.replaces = os.path.lexists(self.path)
        self._mode: int | None = None
        if self.replaces:
            with contextlib.suppress(OSError):
                self._mode = os.stat(self.path).st_mode & 0o777
        #: The file the windows are written to (:attr:`path` itself when nothing is replaced).
        self.work = partial_name(self.path) if self.replaces else self.path
        self._fh: Any = None
        self._npz: _NpzAppender | None = None
        self._created = False
        self._good = 0  # bytes of the CSV up to the end of its last complete window
        self._status_at = -1  # byte offset of the CSV's status value
        self._closed = False

    def add(self, window: RecordedWindow) -> None:
        """Write one more window (flushed to disk before this returns)."""
        if self.keep_windows:
            self.windows.append(window)
        self.sizes.append(len(window.counter))
        if self.error is not None or self._closed:
            return
        try:
            if self.path.suffix == ".npz":
                self._write_npz(window)
            else:
                self._append_csv(len(self.sizes) - 1, window)
            self.written = len(self.sizes)
        except OSError as exc:
            self._failed(exc)

    def _write_npz(self, window: RecordedWindow) -> None:
        if self._npz is None:
            fd = _create(self.work, self._mode)  # the name is this run's from now on
            self._created = True
            self._npz = _NpzAppender(fd, self.meta)
        try:
            self._npz.add(window)
        except BaseException:
            self._npz.cut()  # the file ends with the windows written whole
            raise

    def _append_csv(self, i: int, window: RecordedWindow) -> None:
        if self._fh is None:
            fd = _create(self.work, self._mode)
            self._created = True
            self._fh = os.fdopen(fd, "w", newline="")
            self._status_at = _write_csv_head(self._fh, self.meta)
            self._fh.flush()
            self._good = self._fh.tell()
        try:
            _write_csv_rows(self._fh, i, window)
        except BaseException:
            # Written a block at a time: the rows of a window cut off go (the file ends with
            # complete windows).
            with contextlib.suppress(OSError, ValueError):
                self._fh.flush()
                self._fh.truncate(self._good)
                self._fh.seek(self._good)
            raise
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._good = self._fh.tell()

    @property
    def where(self) -> str:
        """Where the windows written are, for the line that ends a run early."""
        if not self.replaces:
            return str(self.work)
        return f"{self.work} ({self.path}, the earlier recording, left as it was)"

    def _failed(self, exc: OSError) -> None:
        if self.written:
            kept = f"; {self.written} complete window(s) kept in {self.where}"
        else:
            kept = f"; {self.path} left as it was" if self.replaces else ""
        self.error = OutputError(f"{self.path}: cannot write ({exc.strerror or exc}){kept}")
        self.error.__cause__ = exc
        if self._fh is not None:
            # Cut a half-written window off: the file ends with complete windows.
            with contextlib.suppress(OSError, ValueError):
                self._fh.flush()
            with contextlib.suppress(OSError, ValueError):
                self._fh.truncate(self._good)
        if not self.written and self._created:
            if self._npz is not None:
                self._npz.close()
                self._npz = None
            if self._fh is not None:
                with contextlib.suppress(OSError, ValueError):
                    self._fh.close()
                self._fh = None
            with contextlib.suppress(OSError):
                os.unlink(self.work)
            self._created = False

    def close(self, status: str = "complete") -> None:
        """State how the recording ended (``"complete"`` or ``"interrupted"``) and close it.
        Complete, it replaces an earlier file of its name; ended early, it stays at
        :attr:`work` beside the earlier file. Without a window written, nothing is written.

        Raises
        ------
        OutputError
            A write failed (the message says how many complete windows are kept, and where).
        """
        if self._closed:
            if self.error is not None:
                raise self.error
            return
        self._closed = True
        self.meta["status"] = status
        try:
            if self.error is None and self.written:
                if self._npz is not None:
                    # The windows in the column layout every reader of an NPZ knows, with the
                    # final status: written once, as the run ends.
                    self._npz.close()
                    _consolidate(self.work, self.meta, self._npz.sizes[: self.written])
                else:
                    # A window cut off by an interruption (an exception raised while it was
                    # being written) is cut off the file: it ends with complete windows.
                    self._fh.seek(self._good)
                    self._fh.truncate()
                    _write_csv_tail(self._fh, self.written)
                    self._fh.flush()
                    value = json.dumps(status).ljust(_STATUS_WIDTH).encode()
                    os.pwrite(self._fh.fileno(), value, self._status_at)
                    os.fsync(self._fh.fileno())
                if status == "complete" and self.work != self.path:
                    os.replace(self.work, self.path)
                    self.work = self.path
        except OSError as exc:
            self._failed(exc)
        finally:
            if self._fh is not None:
                with contextlib.suppress(OSError, ValueError):
                    self._fh.close()
            if self._npz is not None:
                self._npz.close()
        if self.error is not None:
            raise self.error


#: Most samples a recording may hold (about 29 hours at 200 Hz; 1.1 GB as numbers in memory),
#: and most windows (a plan takes at most 64 positions; calibrations a handful): a file beyond
#: either is refused while it is read, before it fills the memory.
MAX_SAMPLES = 20_000_000
MAX_WINDOWS = 1024
#: Rows parsed into one block of numbers at a time (the text is never held whole).
_CSV_BLOCK_ROWS = 4096
#: Largest NPZ arrays loaded: MAX_SAMPLES samples of 13 numbers, and the metadata.
_MAX_ARRAY_BYTES = MAX_SAMPLES * 13 * 8 + (16 << 20)


def _read_csv(p: Path) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    with p.open(errors="replace", newline="") as fh:
        meta, idx, first_row = _read_csv_head(fh, p)
        blocks = list(_csv_blocks(fh, p, idx, meta, first_row))
    if not blocks:
        raise RecordingError(f"{p}: no samples")
    a = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
    return _csv_columns(a), meta


def _read_csv_head(fh: Any, p: Path) -> tuple[dict[str, Any], list[int], int]:
    """The metadata of a CSV recording's comment lines, where each column of :data:`COLUMNS`
    is in a row, and the line number of the first row after the header."""
    meta: dict[str, Any] = {}
    lineno = 0
    line = ""
    for line in fh:
        lineno += 1
        if not line.startswith("#"):
            break
        key, sep, value = line[1:].rstrip("\r\n").partition("=")
        if sep:
            try:
                meta[key.strip()] = json.loads(value.strip())
            except json.JSONDecodeError:
                raise RecordingError(
                    f"{p}: line {lineno}: metadata value is not JSON: {value.strip()!r}"
                ) from None
    else:
        line = ""
    header = next(csv.reader([line]), None) if line.strip() else None
    if header is None:
        raise RecordingError(f"{p}: no header line")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise RecordingError(
            f"{p}: missing column {missing[0]!r}; columns are {', '.join(COLUMNS)}"
        )
    return meta, [header.index(c) for c in COLUMNS], lineno + 1


def _csv_blocks(
    fh: Any, p: Path, idx: list[int], meta: dict[str, Any], first_row: int
) -> Iterator[NDArray[np.float64]]:
    """The rows after a CSV recording's header as blocks of at most :data:`_CSV_BLOCK_ROWS`
    rows of numbers, the columns in the order of :data:`COLUMNS`; comment lines (the tail: how
    the recording ended) go to ``meta`` as they are read."""
    rows: list[list[float]] = []
    count = 0
    windows: set[float] = set()
    for lineno, row in enumerate(csv.reader(fh), start=first_row):
        if not row:
            continue
        if row[0].startswith("#"):  # the tail: how the recording ended
            key, sep, value = ",".join(row)[1:].partition("=")
            with contextlib.suppress(json.JSONDecodeError):
                if sep:
                    meta[key.strip()] = json.loads(value.strip())
            continue
        try:
            values = [float(row[k]) for k in idx]
        except (ValueError, IndexError):
            bad = next(
                (COLUMNS[n] for n, k in enumerate(idx) if k >= len(row) or not _is_number(row[k])),
                "?",
            )
            raise RecordingError(
                f"{p}: line {lineno}: column {bad!r} is missing or not a number"
            ) from None
        if values[0] not in windows:
            windows.add(values[0])
            if len(windows) > MAX_WINDOWS:
                raise RecordingError(
                    f"{p}: line {lineno}: more than {MAX_WINDOWS} windows; a recording holds "
                    "at most that many (split the session)"
                )
        count += 1
        if count > MAX_SAMPLES:
            raise RecordingError(
                f"{p}: line {lineno}: more than {MAX_SAMPLES} samples; a recording holds at "
                "most that many (split the session)"
            )
        rows.append(values)
        if len(rows) >= _CSV_BLOCK_ROWS:
            block = np.array(rows, dtype=np.float64)
            rows = []  # its numbers as objects go before the block is handed on
            yield block
            del block
    if rows:
        yield np.array(rows, dtype=np.float64)


def _csv_columns(a: NDArray[np.float64]) -> dict[str, NDArray[Any]]:
    """The arrays of rows of a CSV recording (views of ``a``, one row a sample). Whole-number
    columns stay floats here: :func:`_split` checks and converts them."""
    return {
        "window": a[:, 0],
        "commanded_deg": a[:, 1],
        "counter": a[:, 2],
        "time_s": a[:, 3],
        "gyro_dph": a[:, 4:7],
        "accel_mps2": a[:, 7:10],
        "table_deg": a[:, 10],
        "temperature_c": a[:, 11],
        "validity": a[:, 12],
    }


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _split(
    arrays: dict[str, NDArray[Any]], p: Path, min_windows: int = 2
) -> tuple[RecordedWindow, ...]:
    needed = ("window", "commanded_deg", *SAMPLE_ARRAYS)
    for name in needed:
        if name not in arrays:
            raise RecordingError(f"{p}: missing array {name!r}")
    n = len(arrays["window"])
    if n > MAX_SAMPLES:
        raise RecordingError(
            f"{p}: {n} samples; a recording holds at most {MAX_SAMPLES} (split the session)"
        )
    for name in needed:
        shape = (n, 3) if name in ("gyro_dph", "accel_mps2") else (n,)
        if arrays[name].shape != shape:
            raise RecordingError(
                f"{p}: array {name!r} has shape {arrays[name].shape}, expected {shape}"
            )
        if arrays[name].dtype.kind not in "iuf":
            raise RecordingError(f"{p}: array {name!r} must hold numbers, got {arrays[name].dtype}")
        if arrays[name].dtype.kind == "f" and arrays[name].dtype.itemsize < 4:
            # Half precision keeps three significant digits (a counter stops at 2048, a gyro
            # reading of 100 deg/h is 0.06 deg/h coarse): never a recording's own data.
            raise RecordingError(
                f"{p}: array {name!r} is {arrays[name].dtype} (half precision, 3 significant "
                "digits): too coarse for a recording; store it as float32 or float64"
            )
        if arrays[name].dtype.kind == "f" and not np.all(np.isfinite(arrays[name])):
            raise RecordingError(f"{p}: array {name!r} holds NaN or infinite values")
        limit = SAMPLE_LIMITS.get(name)
        if limit is not None and np.any(np.abs(arrays[name]) > limit):
            raise RecordingError(
                f"{p}: array {name!r} holds values beyond +-{limit:g}, which no instrument reads"
            )
    # Whole-number columns: checked, never truncated (a NaN counter is no counter).
    window_index = _whole("window", arrays["window"], p, 0, 1e6)
    counter = _whole("counter", arrays["counter"], p, 0, 2.0**53)
    validity = _whole("validity", arrays["validity"], p, 0, 255).astype(np.uint8)
    numbers = np.unique(window_index)
    if len(numbers) > MAX_WINDOWS:
        raise RecordingError(
            f"{p}: {len(numbers)} windows; a recording holds at most {MAX_WINDOWS} (split the "
            "session)"
        )
    # A recording's windows are stored one after the other: each is then a slice of the arrays
    # read (no copy of a recording of hours); rows of windows mixed are picked out.
    stored_in_order = bool(np.all(window_index[1:] >= window_index[:-1]))
    bounds = np.searchsorted(
        window_index, np.append(numbers, numbers[-1] + 1) if len(numbers) else numbers
    )
    windows = []
    for k, w in enumerate(numbers):
        sel: Any = (
            slice(int(bounds[k]), int(bounds[k + 1])) if stored_in_order else window_index == w
        )
        commanded = arrays["commanded_deg"][sel]
        if not math.isfinite(float(commanded[0])) or np.ptp(commanded) != 0:
            raise RecordingError(f"{p}: window {int(w)} has more than one commanded angle")
        fields = {name: arrays[name][sel] for name in SAMPLE_ARRAYS}
        fields["counter"] = counter[sel]
        fields["validity"] = validity[sel]
        if np.any(np.diff(fields["counter"]) <= 0):
            raise RecordingError(
                f"{p}: window {int(w)}: the counter does not increase sample by sample"
            )
        windows.append(RecordedWindow(float(commanded[0]), **fields))
    if len(windows) < min_windows:
        need = (
            "north finding needs at least two positions"
            if min_windows == 2
            else f"need at least {min_windows}"
        )
        raise RecordingError(f"{p}: {len(windows)} window(s); {need}")
    return tuple(windows)


class _Doubt(Exception):
    """A recording the window-by-window reader leaves to :meth:`Recording.load` (another
    layout, or anything it would refuse or cannot vouch for: the whole reader says what)."""


def summarise_recording(path: str | Path, summarise: Callable[[RecordedWindow, float], Any]) -> Any:
    """:func:`summarise_npz` or :func:`summarise_csv` by the file name's ending; None for
    another ending (the whole reader says what is wrong)."""
    suffix = Path(path).suffix
    if suffix == ".npz":
        return summarise_npz(path, summarise)
    if suffix == ".csv":
        return summarise_csv(path, summarise)
    return None


def summarise_npz(path: str | Path, summarise: Callable[[RecordedWindow, float], Any]) -> Any:
    """Read an NPZ recording of the column layout window by window, each window handed to
    ``summarise(window, sample_rate_hz)`` as it is read and then dropped: memory is one
    window's arrays and what ``summarise`` returns, whatever the number of windows.

    Returns ``(summaries, meta, partial)`` (:attr:`Recording.partial`), or None where
    :meth:`Recording.load` must read the file whole: a recording it would refuse (so that its
    one message names what is wrong), a spin recording, windows not stored one after the
    other, the window layout, a sample rate the samples might not bear out (the check then
    needs every step). Where it returns, the windows are those
    :meth:`Recording.load` gives, checked as it checks them.
    """
    p = Path(path)
    try:
        if p.suffix != ".npz":
            raise _Doubt
        _check_readable(p)
        if _npz_size(p) > _MAX_ARRAY_BYTES:
            raise _Doubt
        with zipfile.ZipFile(p) as zf:
            return _summarise_columns(p, zf, summarise)
    except (_Doubt, RecordingError, OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError):
        return None


def summarise_csv(path: str | Path, summarise: Callable[[RecordedWindow, float], Any]) -> Any:
    """Read a CSV recording window by window in one pass, its rows parsed a block at a time,
    each window handed to ``summarise(window, sample_rate_hz)`` once its rows are read and then
    dropped: memory is one window's arrays and what ``summarise`` returns.

    Returns what :func:`summarise_npz` returns, the metadata with the CSV's tail (how the
    recording ended) as :meth:`Recording.load` reads it; None where :meth:`Recording.load` must
    read the file whole: as for an NPZ, and windows not numbered 0, 1, 2, ... one after the
    other, or a tail that changes the sample rate.
    """
    p = Path(path)
    try:
        if p.suffix != ".csv":
            raise _Doubt
        _check_readable(p)
        with p.open(errors="replace", newline="") as fh:
            meta, idx, first_row = _read_csv_head(fh, p)
            _known(meta, p)
            windows = _csv_windows(_csv_blocks(fh, p, idx, meta, first_row))
            return _summarised(p, meta, windows, summarise)
    except (_Doubt, RecordingError, OSError, ValueError, csv.Error):
        return None


def _known(meta: Any, p: Path) -> None:
    """Metadata the window-by-window readers take as :meth:`Recording.load` would (else
    :class:`_Doubt`, or the RecordingError of :func:`check_meta`)."""
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or "spin" in meta:
        raise _Doubt
    if meta.get("version") != VERSION:
        raise _Doubt
    check_meta(meta, p)


def _summarised(
    p: Path,
    meta: dict[str, Any],
    windows: Iterator[RecordedWindow],
    summarise: Callable[[RecordedWindow, float], Any],
) -> tuple[list[Any], dict[str, Any], str | None]:
    """The windows summarised one at a time, and the checks :meth:`Recording.load` makes of
    them together (the rate, the plan) from counts and each window's ends."""
    rate_hz = float(meta["sample_rate_hz"])
    summaries: list[Any] = []
    stubs: list[RecordedWindow] = []
    rate = _RateCount(rate_hz)
    for w in windows:
        if len(stubs) >= MAX_WINDOWS:
            raise _Doubt
        rate.add(w)
        # What the plan check reads of a window: its first and last counters (ticks spanned).
        stubs.append(RecordedWindow(w.commanded_deg, **_stub(w)))
        summaries.append(summarise(w, rate_hz))
        del w
    # Read to its end, a CSV's metadata holds its tail: checked again as the whole reader does.
    _known(meta, p)
    if float(meta["sample_rate_hz"]) != rate_hz or not stubs:
        raise _Doubt
    rate.check()
    stub = Recording(tuple(stubs), meta)
    check_against_plan(stub, p)
    return summaries, meta, stub.partial


def _csv_windows(blocks: Iterator[NDArray[np.float64]]) -> Iterator[RecordedWindow]:
    """The windows of a CSV recording's blocks of rows, each once its last row is read: the
    window column must read 0, 1, 2, ... one after the other (else :class:`_Doubt`)."""
    pieces: list[NDArray[np.float64]] = []
    current = 0.0
    for block in blocks:
        column = block[:, 0]
        starts = np.flatnonzero(column[1:] != column[:-1]) + 1
        at = 0
        for j in (*starts.tolist(), len(block)):
            if j == at:
                continue
            v = float(column[at])
            if v != current:
                if v != current + 1 or not pieces:
                    raise _Doubt  # windows not 0, 1, 2, ... one after the other
                yield _csv_window(pieces)
                pieces, current = [], v
            pieces.append(block[at:j])
            at = j
        del block, column
    if pieces:
        yield _csv_window(pieces)


def _csv_window(pieces: list[NDArray[np.float64]]) -> RecordedWindow:
    """One window of a CSV recording from its rows (``pieces``, emptied), checked as
    :func:`_split` checks it (its arrays views of one array of rows, as the whole reader's
    are)."""
    a = np.empty((sum(len(x) for x in pieces), len(COLUMNS)))
    at = 0
    pieces.reverse()
    while pieces:  # each block of rows dropped once copied: the window is in memory once
        x = pieces.pop()
        a[at : at + len(x)] = x
        at += len(x)
        del x
    columns = _csv_columns(a)
    del columns["window"]
    return _checked_window(columns)


def _npy_stream(zf: zipfile.ZipFile, name: str) -> tuple[Any, tuple[int, ...], np.dtype[Any]]:
    """An open member ``name`` of ``zf`` positioned at its data, its shape and dtype."""
    fh = zf.open(f"{name}.npy")
    shape, fortran, dtype = _npy_header(fh)
    if fortran or dtype.hasobject:
        raise _Doubt
    return fh, shape, dtype


def _summarise_columns(
    p: Path, zf: zipfile.ZipFile, summarise: Callable[[RecordedWindow, float], Any]
) -> Any:
    names = zf.namelist()
    if "meta_json.npy" not in names or "window.npy" not in names:
        raise _Doubt  # no recording, or the window layout
    with zf.open("meta_json.npy") as fh:
        meta = json.loads(str(np.lib.format.read_array(fh, allow_pickle=False)))
    _known(meta, p)
    bounds = _window_bounds(zf)
    streams = {}
    for name in ("commanded_deg", *SAMPLE_ARRAYS):
        fh, shape, dtype = _npy_stream(zf, name)
        width = 3 if name in ("gyro_dph", "accel_mps2") else 1
        if shape != ((bounds[-1], 3) if width == 3 else (bounds[-1],)):
            raise _Doubt
        if dtype.kind not in "iuf" or (dtype.kind == "f" and dtype.itemsize < 4):
            raise _Doubt
        if name in ("counter", "validity") and dtype.kind == "f":
            raise _Doubt
        streams[name] = (fh, dtype, width)
    return _summarised(p, meta, _npz_windows(streams, bounds), summarise)


def _npz_windows(streams: dict[str, Any], bounds: list[int]) -> Iterator[RecordedWindow]:
    for k in range(len(bounds) - 1):
        yield _read_window(streams, bounds[k + 1] - bounds[k])
    for fh, _, _ in streams.values():
        if fh.read(1):  # at the end: zipfile checks the member's CRC there, as a load does
            raise _Doubt


def _window_bounds(zf: zipfile.ZipFile) -> list[int]:
    """Row bounds of the windows from the ``window`` column, read in blocks: whole numbers
    0, 1, 2, ... one after the other (anything else is left to the whole reader)."""
    fh, shape, dtype = _npy_stream(zf, "window")
    if len(shape) != 1 or dtype.kind not in "iu" or shape[0] > MAX_SAMPLES:
        raise _Doubt
    bounds, done, prev = [0], 0, -1
    with fh:
        while done < shape[0]:
            rows = min(_STREAM_ROWS, shape[0] - done)
            block = np.frombuffer(_exactly(fh, rows * dtype.itemsize), dtype=dtype)
            for j in np.concatenate(([0], np.flatnonzero(np.diff(block)) + 1)):
                v = int(block[j])
                if v == prev + 1 and prev >= 0:
                    bounds.append(done + int(j))  # the next window begins
                elif not ((v == prev and j == 0) or (v == 0 and prev < 0)):
                    raise _Doubt  # windows not 0, 1, 2, ... one after the other
                prev = v
            done += rows
    bounds.append(shape[0])
    if len(bounds) - 1 > MAX_WINDOWS:
        raise _Doubt
    return bounds


#: Rows of the window column read at a time by :func:`summarise_npz`.
_STREAM_ROWS = 1 << 20


def _exactly(fh: Any, n: int) -> bytes:
    data = fh.read(n)
    if len(data) != n:
        raise _Doubt  # cut short
    return bytes(data)


def _read_window(streams: dict[str, Any], rows: int) -> RecordedWindow:
    """The next ``rows`` rows of every column, checked as :func:`_split` checks them."""
    fields: dict[str, Any] = {}
    for name, (fh, dtype, width) in streams.items():
        a = np.frombuffer(_exactly(fh, rows * width * dtype.itemsize), dtype=dtype)
        fields[name] = a.reshape(rows, 3) if width == 3 else a
    return _checked_window(fields)


def _checked_window(fields: dict[str, NDArray[Any]]) -> RecordedWindow:
    """A window of its columns (``commanded_deg`` and :data:`SAMPLE_ARRAYS`), checked as
    :func:`_split` checks a window; what it would refuse raises :class:`_Doubt`."""
    for name, a in fields.items():
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise _Doubt
        limit = SAMPLE_LIMITS.get(name)
        if limit is not None and np.any(np.abs(a) > limit):
            raise _Doubt
    commanded = fields.pop("commanded_deg")
    if len(commanded) == 0 or np.ptp(commanded) != 0:
        raise _Doubt
    for name, hi in (("counter", 2.0**53), ("validity", 255)):
        v = fields[name]
        if np.any(v < 0) or np.any(v > hi):
            raise _Doubt
        if v.dtype.kind == "f" and np.any(v != np.round(v)):
            raise _Doubt  # no whole number
    fields["counter"] = fields["counter"].astype(np.int64)
    fields["validity"] = fields["validity"].astype(np.uint8)
    if np.any(np.diff(fields["counter"]) <= 0):
        raise _Doubt
    return RecordedWindow(float(commanded[0]), **fields)


def _stub(w: RecordedWindow) -> dict[str, Any]:
    ends = [0, len(w.counter) - 1] if len(w.counter) > 1 else [0]
    return {name: getattr(w, name)[ends] for name in SAMPLE_ARRAYS}


class _RateCount:
    """:func:`check_rate` from counts, window by window: the median step lies surely inside
    the 1 % band when fewer than half the steps fall outside a band a little narrower on each
    side; else the whole reader decides (and names the step)."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self.n = self.low = self.high = 0

    def add(self, w: RecordedWindow) -> None:
        if len(w.counter) < 2:
            return
        dt = np.diff(w.time_s)[np.diff(w.counter) == 1]
        off = dt * self.rate_hz - 1.0
        self.n += len(dt)
        self.low += int(np.count_nonzero(off < -0.0099))
        self.high += int(np.count_nonzero(off > 0.0099))

    def check(self) -> None:
        if self.n < 2:
            return
        lower, upper = (self.n - 1) // 2, self.n // 2  # the middle steps once sorted
        if self.low > lower or self.high > self.n - 1 - upper:
            raise _Doubt
