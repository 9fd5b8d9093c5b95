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
    windows, and ``meta_json``: the same metadata as a JSON string.
"""

from __future__ import annotations

import csv
import io
import json
import math
import zipfile
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
        fields = {name: np.array(getattr(window, name)) for name in SAMPLE_ARRAYS}
        fields["validity"] = fields["validity"].astype(np.uint8)
        return cls(float(commanded_deg), **fields)


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
        """Write as CSV or NPZ, chosen by the file name's ending."""
        p = Path(path)
        meta = {"format": FORMAT, "version": VERSION, **self.meta}
        try:
            if p.suffix == ".npz":
                payload: dict[str, Any] = {
                    "meta_json": np.array(json.dumps(meta)),
                    **_concat(self.windows),
                }
                np.savez_compressed(p, **payload)
            elif p.suffix == ".csv":
                with p.open("w", newline="") as fh:
                    for k, v in meta.items():
                        fh.write(f"# {k} = {json.dumps(v)}\n")
                    writer = csv.writer(fh)
                    writer.writerow(COLUMNS)
                    for i, w in enumerate(self.windows):
                        for j in range(len(w.counter)):
                            writer.writerow(
                                [
                                    i,
                                    f"{w.commanded_deg:.6f}",
                                    int(w.counter[j]),
                                    f"{w.time_s[j]:.6f}",
                                ]
                                + [repr(float(v)) for v in w.gyro_dph[j]]
                                + [repr(float(v)) for v in w.accel_mps2[j]]
                                + [
                                    f"{w.table_deg[j]:.6f}",
                                    f"{w.temperature_c[j]:.2f}",
                                    int(w.validity[j]),
                                ]
                            )
            else:
                raise RecordingError(f"{p}: the file name must end in .csv or .npz")
        except OSError as exc:
            raise OutputError(f"{p}: cannot write ({exc.strerror})") from exc

    @staticmethod
    def load(path: str | Path, *, min_windows: int = 2) -> Recording:
        """Read a CSV or NPZ recording; every problem is reported with the file and the field.

        ``min_windows``: fewer windows is an error (north finding needs two positions; a static
        recording for calibration may hold one)."""
        p = Path(path)
        if p.suffix not in (".csv", ".npz"):
            raise RecordingError(f"{p}: the file name must end in .csv or .npz")
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
        return Recording(windows, meta)


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


def _read_npz(p: Path) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    try:
        with np.load(p, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise RecordingError(f"{p}: not a readable NPZ file ({exc})") from exc
    if "meta_json" not in arrays:
        raise RecordingError(f"{p}: no meta_json array; not a northfinder recording")
    try:
        meta = json.loads(str(arrays.pop("meta_json")))
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{p}: meta_json is not JSON ({exc})") from exc
    return arrays, meta


def _read_csv(p: Path) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    text = p.read_text(errors="replace")
    meta: dict[str, Any] = {}
    lines = text.splitlines()
    body_start = 0
    for i, line in enumerate(lines):
        if not line.startswith("#"):
            body_start = i
            break
        key, sep, value = line[1:].partition("=")
        if sep:
            try:
                meta[key.strip()] = json.loads(value.strip())
            except json.JSONDecodeError:
                raise RecordingError(
                    f"{p}: line {i + 1}: metadata value is not JSON: {value.strip()!r}"
                ) from None
    else:
        body_start = len(lines)
    reader = csv.reader(io.StringIO("\n".join(lines[body_start:])))
    header = next(reader, None)
    if header is None:
        raise RecordingError(f"{p}: no header line")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise RecordingError(
            f"{p}: missing column {missing[0]!r}; columns are {', '.join(COLUMNS)}"
        )
    idx = [header.index(c) for c in COLUMNS]
    rows = []
    for lineno, row in enumerate(reader, start=body_start + 2):
        if not row:
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
        rows.append(values)
    if not rows:
        raise RecordingError(f"{p}: no samples")
    a = np.array(rows)
    arrays = {  # whole-number columns stay floats here: _split checks and converts them
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
    return arrays, meta


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
    for name in needed:
        shape = (n, 3) if name in ("gyro_dph", "accel_mps2") else (n,)
        if arrays[name].shape != shape:
            raise RecordingError(
                f"{p}: array {name!r} has shape {arrays[name].shape}, expected {shape}"
            )
        if arrays[name].dtype.kind not in "iuf":
            raise RecordingError(f"{p}: array {name!r} must hold numbers, got {arrays[name].dtype}")
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
    windows = []
    for w in np.unique(window_index):
        sel = window_index == w
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
