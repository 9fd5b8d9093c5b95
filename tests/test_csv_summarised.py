"""A CSV recording is read window by window in one pass (``summarise_csv``): each window handed
on once its rows are parsed and then dropped, so that ``solve`` and ``calibrate`` of hours hold
one window's samples. The windows are those the whole reader gives, array for array; the
results the same to the last digit; a partial recording says what it holds as before; a file the
whole reader refuses is left to it (its one message, its exit status); memory measured with
tracemalloc (numpy's buffers traced too)."""

from __future__ import annotations

import gc
import json
import shutil
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from clirun import run_cli
from seeded import saved, seeded_windows, solved_both_ways

import northfinder.cli.solve as solve
import northfinder.host.calibrate.readers as readers
from northfinder.host import recording
from northfinder.host.calibrate import calibrate, read_runs
from northfinder.host.calibrate.readers import window_fit
from northfinder.host.recording import (
    SAMPLE_ARRAYS,
    RecordedWindow,
    Recording,
    RecordingWriter,
    summarise_csv,
    summarise_recording,
)

RATE_HZ = 200.0
PLAN = {"positions_deg": [0, 90, 180, 270], "window_s": 10.0}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A seeded simulated record of six windows with moves between them, as CSV."""
    path = tmp_path_factory.mktemp("rec") / "run.csv"
    code, _, err = run_cli("record", "--sim", "--seed", "3", "--warmup", "0", "--window", "20",
                           "--positions", "0,90,180,270,0,90", str(path))  # fmt: skip
    assert code == 0, err
    return path


def _windows(windows: int, n: int) -> list[RecordedWindow]:
    return seeded_windows(windows, n, 0)


def _csv(path: Path, windows: int, n: int = 2000, **meta: Any) -> Path:
    return saved(path, _windows(windows, n), meta)


def _kept(w: RecordedWindow, rate_hz: float) -> tuple[RecordedWindow, float]:
    return w, rate_hz


def test_the_windows_handed_on_are_those_of_the_whole_reader(recorded, tmp_path):
    for path in (recorded, _csv(tmp_path / "rec.csv", 5)):
        got = summarise_recording(path, _kept)
        assert got is not None  # read window by window, not left to the whole reader
        pairs, meta, partial = got
        whole = Recording.load(path)
        assert meta == whole.meta and partial is None
        assert len(pairs) == len(whole.windows) >= 5
        for (w, rate), held in zip(pairs, whole.windows, strict=True):
            assert rate == whole.meta["sample_rate_hz"] and w.commanded_deg == held.commanded_deg
            for name in SAMPLE_ARRAYS:
                a, b = getattr(w, name), getattr(held, name)
                # the same numbers in the same layout: the same sums to the last digit
                assert a.dtype == b.dtype and a.strides == b.strides, name
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "options", [[], ["--denoise", "hampel"], ["--latitude", "40"], ["--solver", "least-squares"]]
)
def test_a_csv_solved_window_by_window_gives_the_result_of_every_window_held(
    recorded, tmp_path, monkeypatch, options
):
    for path in (recorded, _csv(tmp_path / "rec.csv", 8)):
        assert summarise_csv(path, solve.summariser("none", False)) is not None
        streamed, held = solved_both_ways(path, monkeypatch, *options)
        assert streamed == held and streamed[0] in (0, 3)  # 3: inconsistent at a wrong latitude
        assert "azimuth_deg" in streamed[1]


def test_calibration_of_a_csv_reduced_as_read_is_that_of_the_windows_held(recorded):
    fitted = read_runs([recorded], fitted=True)
    assert fitted[0].windows == () and len(fitted[0].fits) == 6  # reduced as read
    held = read_runs([recorded])
    assert len(held[0].windows) == 6
    assert fitted[0].meta == held[0].meta
    assert calibrate(fitted).to_json_dict() == calibrate(held).to_json_dict()
    assert calibrate(fitted).report() == calibrate(held).report()


def test_calibrate_through_the_cli_is_the_same_either_way(recorded, monkeypatch):
    streamed = run_cli("calibrate", str(recorded), "--json")
    monkeypatch.setattr(readers, "summarise_recording", lambda *_: None)
    held = run_cli("calibrate", str(recorded), "--json")
    assert streamed[0] == 0, streamed[2]
    drop = lambda text: {k: v for k, v in json.loads(text).items() if k != "created_utc"}  # noqa: E731
    assert drop(streamed[1]) == drop(held[1])


def test_an_interrupted_and_a_cut_off_csv_say_what_they_hold(tmp_path, monkeypatch):
    meta = {"latitude_deg": 34.0, "sample_rate_hz": RATE_HZ, "plan": PLAN}
    writer = RecordingWriter(tmp_path / "run.csv", meta)
    for w in _windows(3, 2000):
        writer.add(w)
    cut = tmp_path / "cut.csv"
    shutil.copy(writer.work, cut)  # as a power cut leaves it: no tail, "recording"
    writer.close("interrupted")
    for path, why in ((tmp_path / "run.csv", "interrupted"), (cut, "cut off while recording")):
        got = summarise_csv(path, solve.summariser("none", False))
        assert got is not None
        assert got[2] == Recording.load(path).partial == f"{why}: 3 of 4 windows"
        streamed, held = solved_both_ways(path, monkeypatch)
        assert streamed == held and streamed[0] in (0, 3)  # 3: inconsistent (random samples)
        assert streamed[1]["source"]["partial"] == f"{why}: 3 of 4 windows"


def _edited(path: Path, out: Path, edit: Any) -> Path:
    """``path`` with its sample rows (its head and tail kept) as ``edit(rows)`` gives them."""
    lines = path.read_text().splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if not line.startswith("#")) + 1
    tail = next(i for i in range(len(lines), 0, -1) if not lines[i - 1].startswith("#"))
    out.write_text("".join(lines[:head] + edit(lines[head:tail]) + lines[tail:]))
    return out


def _cell(rows: list[str], row: int, column: int, value: str) -> list[str]:
    cells = rows[row].rstrip("\r\n").split(",")
    cells[column] = value
    return [*rows[:row], ",".join(cells) + "\r\n", *rows[row + 1 :]]


N = 500  # samples a window of the files edited
BAD = {
    "not a number": (lambda r: _cell(r, N + 7, 5, "abc"), "line 514: column 'gyro_y_dph' is missing or not a number"),
    "NaN": (lambda r: _cell(r, 2 * N + 3, 8, "nan"), "array 'accel_mps2' holds NaN or infinite values"),
    "a row cut short": (lambda r: [*r[:-1], r[-1][:20] + "\r\n"], "is missing or not a number"),
    "windows mixed": (lambda r: [*r[:10], *r[11 : 2 * N], r[10], *r[2 * N :]], "window 0: the counter does not increase"),
    "counter going back": (lambda r: _cell(r, N + 9, 2, "1"), "window 1: the counter does not increase"),
    "counter not whole": (lambda r: _cell(r, 5, 2, "5.5"), "counter of sample 5 is"),
    "validity over 255": (lambda r: _cell(r, 3 * N + 1, 12, "256"), "validity of sample 1501 is"),
    "two commanded angles": (lambda r: _cell(r, 2 * N + 1, 1, "7.0"), "window 2 has more than one commanded angle"),
    "a gyro beyond any": (lambda r: _cell(r, 9, 4, "2e9"), "array 'gyro_dph' holds values beyond"),
}  # fmt: skip
META = {
    "a rate of none": ("# sample_rate_hz = -5.0\n", None, "sample_rate_hz must be a number of Hz"),
    "a tail with a latitude beyond": (None, "# latitude_deg = 100\n", "latitude_deg must be a number"),
    "a tail with another rate": (None, "# sample_rate_hz = 400.0\n", "the rate and the samples disagree"),
    "a tail not JSON": (None, "# status = interrupted\n", None),
}  # fmt: skip


def _same_either_way(
    path: Path, monkeypatch: pytest.MonkeyPatch, left: bool = True
) -> tuple[int, str, str]:
    """Exit status and messages of ``solve`` and ``calibrate``, the same read either way;
    ``left``: the window-by-window reader leaves the file to the whole reader."""
    got = summarise_csv(path, solve.summariser("none", False))
    assert (got is None) == left
    streamed, held = solved_both_ways(path, monkeypatch)
    assert streamed == held
    calibrated = []
    for patched in (False, True):
        with monkeypatch.context() as m:
            if patched:
                m.setattr(readers, "summarise_recording", lambda *_: None)
            calibrated.append(run_cli("calibrate", str(path)))
    assert calibrated[0] == calibrated[1]
    return streamed[0], streamed[2], calibrated[0][2]


@pytest.mark.parametrize("kind", BAD)
def test_a_bad_csv_gets_the_whole_readers_message_and_exit_status(tmp_path, monkeypatch, kind):
    good = _csv(tmp_path / "good.csv", 4, N)
    assert summarise_csv(good, solve.summariser("none", False)) is not None
    edit, message = BAD[kind]
    code, err, cal_err = _same_either_way(_edited(good, tmp_path / "bad.csv", edit), monkeypatch)
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert message in cal_err, cal_err


@pytest.mark.parametrize("kind", META)
def test_bad_metadata_in_the_head_or_the_tail_is_left_to_the_whole_reader(
    tmp_path, monkeypatch, kind
):
    head, tail, message = META[kind]
    path = _csv(tmp_path / "rec.csv", 4, N)
    lines = path.read_text().splitlines(keepends=True)
    if head is not None:
        key = head.split("=")[0]
        lines = [head if line.startswith(key) else line for line in lines]
    if tail is not None:
        lines.append(tail)
    path.write_text("".join(lines))
    code, err, _ = _same_either_way(path, monkeypatch, left=message is not None)
    if message is None:  # a tail line not JSON is passed over, by either reader
        assert code in (0, 3), err
    else:
        assert code == 2 and err.count("\n") == 1 and message in err, err


def test_windows_stored_out_of_order_are_left_to_the_whole_reader(tmp_path, monkeypatch):
    good = _csv(tmp_path / "good.csv", 4, N)
    swapped = _edited(good, tmp_path / "swapped.csv", lambda r: [*r[:N], *r[2 * N : 3 * N],
                                                                  *r[N : 2 * N], *r[3 * N :]])  # fmt: skip
    code, err, _ = _same_either_way(swapped, monkeypatch)
    assert code in (0, 3), err  # the whole reader picks each window's rows out
    azimuth = [solved_both_ways(p, monkeypatch)[0][1]["azimuth_deg"] for p in (swapped, good)]
    assert azimuth[0] == azimuth[1]  # the same windows


def _peak(read: Any, path: Path) -> int:
    gc.collect()
    tracemalloc.start()
    try:
        got = read(path)
        _, top = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert got is not None  # read window by window, not left to the whole reader
    return top


def test_a_csv_of_four_times_the_windows_holds_one_window_at_a_time(tmp_path, monkeypatch):
    """Six windows more cost a fraction of one window read window by window; read whole (the
    control: the measure sees them) they cost their rows, parsed and joined."""
    # Blocks of rows that fit a window a whole number of times: every window then costs the
    # same, whichever windows a reading holds when its peak is taken.
    monkeypatch.setattr(recording, "_CSV_BLOCK_ROWS", 512)
    n = 4 * 512
    few, many = _csv(tmp_path / "few.csv", 2, n), _csv(tmp_path / "many.csv", 8, n)
    summarise = solve.summariser("none", False)
    readers_ = {"streamed": lambda p: summarise_csv(p, summarise), "whole": Recording.load}
    _peak(readers_["streamed"], few)  # the first reading imports and caches what later ones use
    grown = {k: _peak(read, many) - _peak(read, few) for k, read in readers_.items()}
    one_window = 8 * 13 * n  # its rows as float64, bytes
    assert grown["streamed"] < one_window / 2, (grown, one_window)
    assert grown["whole"] > 6 * one_window, (grown, one_window)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_one_window_recording_is_read_and_reduced_once(tmp_path, monkeypatch, suffix):
    """``calibrate`` takes a recording of one window (a still record): the window-by-window
    reader reduces it as it reads it, once, to the whole reader's result; ``solve`` refuses it
    with the whole reader's message either way."""
    path = saved(tmp_path / f"one{suffix}", seeded_windows(1, 4000, 5))
    fits = []

    def counted(w: RecordedWindow, rate_hz: float) -> Any:
        fits.append(len(w.counter))
        return window_fit(w, rate_hz)

    monkeypatch.setattr(readers, "window_fit", counted)
    fitted = read_runs([path], fitted=True)
    assert fits == [4000]  # read and reduced once
    held = read_runs([path])
    assert calibrate(fitted).to_json_dict() == calibrate(held).to_json_dict()
    streamed, whole = solved_both_ways(path, monkeypatch)
    assert streamed == whole and streamed[0] == 2
    assert "1 window(s); north finding needs at least two positions" in streamed[2]
