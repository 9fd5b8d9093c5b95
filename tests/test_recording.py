"""Recordings: CSV and NPZ round trips, offline solving, and clear errors for bad files."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from northfinder.cli.solve import solve_recording
from northfinder.firmware_sim.batch import simulate_windows
from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.procedure import QualityError
from northfinder.host.recording import SAMPLE_ARRAYS, RecordedWindow, Recording, RecordingError

DPH = math.pi / 180 / 3600
TRUTH = Truth(azimuth_deg=251.3, latitude_deg=34.0, pitch_deg=2.5, roll_deg=-1.0)


def simulated_recording(positions=(0.0, 90.0), spec_name="ideal", seed=0) -> Recording:
    spec = load_spec(spec_name).with_values(
        {"gyro.bias_dph": [2.0, -3.0, 1.0], "accel.bias_ug": [300.0, -200.0, 0.0]}
    )
    ins = Instrument(spec, TRUTH, np.random.default_rng(seed))
    windows = []
    for p in positions:
        end = ins.table.move_to(ins.time_s, p)
        ins.advance(end - ins.time_s + spec.table.settle_s)
        b = ins.advance(10.0)
        windows.append(
            RecordedWindow(
                p,
                b.counter,
                b.time_s,
                b.gyro_rps / DPH,
                b.accel_mps2,
                b.table_deg,
                b.temperature_c,
                np.full(len(b), 3, dtype=np.uint8),
            )
        )
    return Recording(
        tuple(windows),
        {"latitude_deg": TRUTH.latitude_deg, "sample_rate_hz": 200, "truth": TRUTH.__dict__},
    )


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip_and_offline_solve(tmp_path, suffix):
    rec = simulated_recording()
    path = tmp_path / f"rec{suffix}"
    rec.save(path)
    back = Recording.load(path)
    assert back.meta["latitude_deg"] == 34.0 and back.meta["truth"]["azimuth_deg"] == 251.3
    for a, b in zip(rec.windows, back.windows, strict=True):
        np.testing.assert_array_equal(a.counter, b.counter)
        np.testing.assert_allclose(a.gyro_dph, b.gyro_dph, rtol=0, atol=0)
        np.testing.assert_allclose(a.table_deg, b.table_deg, atol=1e-6)
    result = solve_recording(back, None, "none", "auto")
    assert result.azimuth_deg == pytest.approx(TRUTH.azimuth_deg, abs=1e-6)
    assert result.pitch_deg == pytest.approx(TRUTH.pitch_deg, abs=1e-6)
    assert result.roll_deg == pytest.approx(TRUTH.roll_deg, abs=1e-6)


def test_multi_position_recording_solves_by_least_squares(tmp_path):
    rec = simulated_recording(positions=(10.0, 100.0, 190.0, 280.0), spec_name="nav-fog", seed=3)
    result = solve_recording(rec, None, "none", "auto")
    assert result.method == "least-squares" and len(result.pairwise_deg) == 3
    err = (result.azimuth_deg - TRUTH.azimuth_deg + 180) % 360 - 180
    assert result.sigma_deg is not None
    assert abs(err) < 5 * result.sigma_deg


def test_solve_cli_prints_json(tmp_path):
    path = tmp_path / "rec.npz"
    simulated_recording().save(path)
    out = subprocess.run(
        [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())", "solve", str(path), "--json"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    data = json.loads(out.stdout)
    assert abs(data["error_deg"]) < 1e-6 and len(data["windows"]) == 2


def test_a_run_of_the_batch_generator_saves_as_a_recording(tmp_path):
    """What calibration studies write: one power-on of the many-runs generator as a file."""
    positions = [0.0, 90.0, 180.0]
    batch = simulate_windows(
        load_spec("ideal"), TRUTH, positions, 2.0, n_runs=2, rng=np.random.default_rng(1),
        sample_rate_hz=50.0, warmup_s=0.0,
    )  # fmt: skip
    path = tmp_path / "run.npz"
    Recording.from_batch(batch, 1, TRUTH.latitude_deg).save(path)
    back = Recording.load(path)
    assert back.meta["sample_rate_hz"] == 50.0 and back.meta["latitude_deg"] == 34.0
    assert [w.commanded_deg for w in back.windows] == positions
    for p, w in enumerate(back.windows):
        first = round(batch.window_start_s[p] * 50.0)
        np.testing.assert_array_equal(w.counter, np.arange(first, first + 100))
        np.testing.assert_allclose(w.gyro_dph * DPH, batch.gyro_rps[1, p], rtol=1e-15, atol=0)
        assert w.missing == 0 and set(w.validity) == {3}
    result = solve_recording(back, None, "none", "auto")
    assert result.azimuth_deg == pytest.approx(batch.azimuth_deg[1], abs=1e-6)
    assert result.pitch_deg == pytest.approx(TRUTH.pitch_deg, abs=1e-6)


def test_a_gap_in_a_recording_is_reported(tmp_path):
    rec = simulated_recording()
    w = rec.windows[1]
    keep = np.r_[0:500, 510 : len(w.counter)]
    holed = RecordedWindow(
        w.commanded_deg, *(np.asarray(getattr(w, f))[keep] for f in SAMPLE_ARRAYS)
    )
    assert holed.gaps == [(int(w.counter[500]), 10)] and holed.missing == 10
    with pytest.raises(QualityError, match="missing 10 samples"):
        solve_recording(Recording((rec.windows[0], holed), rec.meta), None, "none", "auto")


def test_bad_recordings_name_what_is_wrong(tmp_path):
    rec = simulated_recording()
    good = tmp_path / "good.csv"
    rec.save(good)
    lines = good.read_text().splitlines()
    h = next(i for i, line in enumerate(lines) if not line.startswith("#"))  # the header line
    cases = {
        "wrong.txt": ("x", "must end in .csv or .npz"),
        "nocol.csv": (
            "\n".join([*lines[:h], lines[h].replace("gyro_y_dph", "gyro_q"), *lines[h + 1 :]]),
            "missing column 'gyro_y_dph'",
        ),
        "text.csv": (
            "\n".join(
                [
                    *lines[: h + 2],
                    lines[h + 2].replace(lines[h + 2].split(",")[5], "abc", 1),
                    *lines[h + 3 :],
                ]
            ),
            "not a number",
        ),
        "empty.csv": ("", "no header line"),
        "foreign.csv": (
            "\n".join(['# format = "other"', *lines[1:]]),
            "not a northfinder recording",
        ),
        "version.csv": (
            "\n".join([lines[0], "# version = 99", *lines[2:]]),
            "recording version 99",
        ),
        "onewin.csv": (
            "\n".join(line for line in lines if not line.startswith("1,")),
            "needs at least two positions",
        ),
    }
    for name, (content, message) in cases.items():
        p = tmp_path / name
        p.write_text(content)
        with pytest.raises(RecordingError, match=message):
            Recording.load(p)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(RecordingError, match="not a readable NPZ"):
        Recording.load(junk)
    with pytest.raises(RecordingError, match="cannot read"):
        Recording.load(tmp_path / "missing.csv")


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_stated_rate_the_samples_contradict_is_refused(tmp_path, suffix):
    rec = simulated_recording()
    fs = rec.meta["sample_rate_hz"]
    good = tmp_path / f"good{suffix}"
    rec.save(good)
    assert Recording.load(good).meta["sample_rate_hz"] == fs
    wrong = Recording(rec.windows, {**rec.meta, "sample_rate_hz": fs / 2})
    path = tmp_path / f"wrong{suffix}"
    wrong.save(path)
    with pytest.raises(
        RecordingError, match=rf"sample_rate_hz = {fs / 2:g}, but time_s advances 5 ms"
    ):
        Recording.load(path)
