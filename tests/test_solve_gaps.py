"""``solve`` of logs and recordings that are not whole: ``--strict`` names the first damaged
line, ``--on-gap report`` solves a window with sample ticks missing from the samples it holds
and names each gap in the result's notes."""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from clirun import run_cli, run_json

from northfinder.host.recording import SAMPLE_ARRAYS, RecordedWindow, Recording


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A candump log of a four-window find, and find's result."""
    path = tmp_path_factory.mktemp("gaps") / "find.log"
    found = run_json("find", "--sim", "--warmup", "0", "--window", "2", "--seed", "21",
                     "--can-log", str(path))  # fmt: skip
    return path, found


def test_strict_names_the_first_damaged_line_even_before_any_window(logged, tmp_path):
    path, _ = logged
    lines = path.read_text().splitlines(keepends=True)
    lines[4:4] = ["this is no frame\n"]
    lines[2000:2000] = ["(1.5) can0 101#ZZ\n"]
    bad = tmp_path / "bad.log"
    bad.write_text("".join(lines))
    code, out, err = run_cli("solve", str(bad), "--latitude", "34", "--strict")
    assert code == 1 and out == ""
    assert err.startswith(f"northfinder solve: error: {bad}:5: damaged line 'this is no frame' (")
    assert err.rstrip().endswith("--strict refuses a log with a damaged line (2 in all)")
    assert len(err.strip().splitlines()) == 1
    code, out, err = run_cli("solve", str(bad), "--latitude", "34")  # skipped, and solved
    assert code == 0 and "skipped 2 damaged line(s)" in err


def _delete_lines(src: Path, dst: Path, share: float, seed: int) -> int:
    rng = random.Random(seed)
    lines = src.read_text().splitlines(keepends=True)
    kept = [line for line in lines if rng.random() >= share]
    dst.write_text("".join(kept))
    return len(lines) - len(kept)


def test_a_log_with_a_thousandth_of_its_lines_missing_is_solved_with_on_gap_report(
    logged, tmp_path
):
    path, found = logged
    holes = tmp_path / "holes.log"
    gone = _delete_lines(path, holes, 0.001, seed=5)
    assert gone >= 4
    code, out, err = run_cli("solve", str(holes), "--latitude", "34", "--window", "2")
    assert code == 1 and out == ""  # every window lost a tick: none is complete
    assert "--on-gap report solves those with sample ticks missing" in err.splitlines()[-1]
    assert "(--on-gap report solves the 4 with sample ticks missing" in err
    code, out, err = run_cli("solve", str(holes), "--latitude", "34", "--window", "2",
                             "--on-gap", "report", "--json")  # fmt: skip
    assert code == 0, err
    doc = json.loads(out)
    assert doc["source"]["windows"] == [1, 2, 3, 4]
    missing = [n for n in doc["notes"] if "sample ticks missing" in n]
    assert len(missing) == 4 and all(" of 400 sample ticks missing" in n for n in missing)
    assert "tick(s) missing from counter" not in err  # in the result's notes, not warned
    assert abs(doc["azimuth_deg"] - found["azimuth_deg"]) < 3 * found["sigma_deg"]
    assert doc["sigma_deg"] == pytest.approx(found["sigma_deg"], rel=0.05)
    code, out, _ = run_cli("solve", str(holes), "--latitude", "34", "--on-gap", "report")
    assert code == 0 and "note: position 1: " in out and "sample ticks missing" in out
    code, _, err = run_cli("solve", str(holes), "--latitude", "34", "--on-gap", "report",
                           "--strict")  # fmt: skip
    assert code == 2 and "--on-gap report: --strict refuses a log with a gap" in err


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    path = tmp_path_factory.mktemp("gaps") / "run.npz"
    code, _, err = run_cli("record", str(path), "--sim", "--warmup", "0", "--window", "2",
                           "--seed", "22")  # fmt: skip
    assert code == 0, err
    return Recording.load(path)


def _gappy_recording(rec: Recording, tmp_path: Path, drop: slice) -> Path:
    """The recording with the ticks ``drop`` of its second window missing."""
    windows = list(rec.windows)
    keep = np.ones(len(windows[1].counter), dtype=bool)
    keep[drop] = False
    windows[1] = RecordedWindow(
        windows[1].commanded_deg, *(getattr(windows[1], a)[keep] for a in SAMPLE_ARRAYS)
    )
    path = tmp_path / "gappy.npz"
    Recording(tuple(windows), rec.meta).save(path)
    return path


def test_a_recording_with_a_gap_is_solved_with_on_gap_report(recorded, tmp_path):
    path = _gappy_recording(recorded, tmp_path, slice(200, 201))
    code, out, err = run_cli("solve", str(path))
    assert code == 1 and out == ""
    assert "window at 180 deg is missing 1 samples (--on-gap report solves it" in err
    code, out, err = run_cli("solve", str(path), "--on-gap", "report")
    assert code == 0, err
    line = "note: position 2: 1 of 400 sample ticks missing (damaged or lost frames); the mean "
    assert line + "is of the samples received\n" in out  # a tick: its mean time stays put


def test_a_long_gap_names_how_far_it_moves_the_windows_mean_time(recorded, tmp_path):
    path = _gappy_recording(recorded, tmp_path, slice(40, 160))  # 0.6 s of 2 s
    code, out, err = run_cli("solve", str(path), "--on-gap", "report")
    assert code == 0, err
    assert "position 2: 120 of 400 sample ticks missing" in out
    assert "the mean is of the samples received, at +0.214 s from the window's middle" in out
