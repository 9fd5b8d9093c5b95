"""A CSV recording is read window by window in one pass (``summarise_csv``): each window handed
on once its rows are parsed and then dropped, so that ``solve`` and ``calibrate`` of hours hold
one window's samples. The windows are those the whole reader gives, array for array; the
results the same to the last digit; a partial recording says what it holds as before; a file the
whole reader refuses is left to it (its one message, its exit status); memory measured with
tracemalloc (numpy's buffers traced too)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from clirun import run_cli

import northfinder.cli.solve as solve
import northfinder.host.calibrate.readers as readers
from northfinder.host.calibrate import calibrate, read_runs
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


def _windows(windows: int, n: int, seed: int = 0) -> list[RecordedWindow]:
    rng = np.random.default_rng(seed)
    made = []
    for k in range(windows):
        counter = np.arange(n) + k * 10 * n
        made.append(
            RecordedWindow(
                90.0 * (k % 4), counter, (counter + 1) / RATE_HZ,
                rng.normal([10.0 * (k % 4 - 1.5), 5.0, -8.0], 3.0, (n, 3)),
                rng.normal([0.01, -0.02, 9.8], 1e-3, (n, 3)), np.full(n, 90.0 * (k % 4)),
                np.full(n, 20.0), np.full(n, 3, dtype=np.uint8),
            )
        )  # fmt: skip
    return made


def _csv(path: Path, windows: int, n: int = 2000, **meta: Any) -> Path:
    made = _windows(windows, n)
    Recording(tuple(made), {"latitude_deg": 34.0, "sample_rate_hz": RATE_HZ, **meta}).save(path)
    return path


def _solved_both_ways(path: Path, monkeypatch: pytest.MonkeyPatch, *options: str) -> list[Any]:
    """``solve --json`` read window by window and read whole (every window held)."""
    out = []
    for streamed in (True, False):
        with monkeypatch.context() as m:
            if not streamed:
                m.setattr(solve, "summarise_recording", lambda *_: None)
            code, text, err = run_cli("solve", str(path), "--json", *options)
        doc = json.loads(text) if text else {}
        doc.pop("created_utc", None)
        out.append((code, doc, err))
    return out


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
        streamed, held = _solved_both_ways(path, monkeypatch, *options)
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
        streamed, held = _solved_both_ways(path, monkeypatch)
        assert streamed == held and streamed[0] in (0, 3)  # 3: inconsistent (random samples)
        assert streamed[1]["source"]["partial"] == f"{why}: 3 of 4 windows"
