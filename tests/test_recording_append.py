"""An NPZ recording written window by window in time linear in the data: each window is appended
once (the file up to it is never written again), the file is a whole archive after every window,
and the run's end writes the column layout every NPZ reader knows, as files written before."""

from __future__ import annotations

import errno
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import northfinder.host.recording as recording
from northfinder.host.errors import OutputError
from northfinder.host.recording import SAMPLE_ARRAYS, RecordedWindow, Recording, RecordingWriter
from tests.clirun import run_cli

#: Written by the recorder before windows were appended (``northfinder record --sim --seed 1
#: --warmup 0 --window 20 old.npz``): the column layout, read as it was.
OLD = Path(__file__).parent / "data" / "recording-v1-seed1.npz"
RATE = 200
N = 300
META: dict[str, Any] = {
    "latitude_deg": 34.0,
    "sample_rate_hz": RATE,
    "plan": {"positions_deg": [0.0, 90.0, 180.0, 270.0], "window_s": N / RATE},
}


def window(k: int) -> RecordedWindow:
    counter = np.arange(N) + k * 1000
    rng = np.random.default_rng(k)
    return RecordedWindow(
        90.0 * k, counter, (counter + 1) / RATE, rng.normal(0.0, 1.0, (N, 3)),
        rng.normal([0.0, 0.0, 9.8], 1e-4, (N, 3)), np.full(N, 90.0 * k), np.full(N, 20.0),
        np.full(N, 3, dtype=np.uint8),
    )  # fmt: skip


def same_windows(a: Recording, b: Recording) -> None:
    assert len(a.windows) == len(b.windows)
    for x, y in zip(a.windows, b.windows, strict=True):
        assert x.commanded_deg == y.commanded_deg
        for name in SAMPLE_ARRAYS:
            got, want = getattr(x, name), getattr(y, name)
            assert got.dtype == want.dtype, name
            np.testing.assert_array_equal(got, want, err_msg=name)


def test_each_window_is_appended_once_and_the_file_is_whole_after_each(tmp_path, monkeypatch):
    path = tmp_path / "run.npz"
    rewrites: list[Path] = []
    real = recording._write_columns

    def counted(p: Path, *args: Any) -> None:
        rewrites.append(p)
        real(p, *args)

    monkeypatch.setattr(recording, "_write_columns", counted)
    writer = RecordingWriter(path, META)
    before = b""
    for k in range(4):
        writer.add(window(k))
        now = path.read_bytes()
        # Nothing written before is written again: the file only grows, by about one window.
        assert now.startswith(before) and len(now) > len(before)
        if k:
            assert len(now) - len(before) < 2 * (len(before) / k)
        before = now
        rec = Recording.load(path, min_windows=1)
        same_windows(rec, Recording(tuple(window(i) for i in range(k + 1))))
        assert rec.status == "recording" and not rewrites
    writer.close("complete")
    assert rewrites == [path]  # the column layout, written once as the run ends
    with zipfile.ZipFile(path) as zf:
        assert sorted(zf.namelist()) == sorted(
            f"{n}.npy" for n in ("meta_json", "window", "commanded_deg", *SAMPLE_ARRAYS)
        )
    rec = Recording.load(path)
    assert rec.partial is None
    same_windows(rec, Recording(tuple(window(i) for i in range(4))))


def test_a_window_whose_write_fails_is_cut_off_and_the_earlier_ones_stay(tmp_path, monkeypatch):
    path = tmp_path / "run.npz"
    writer = RecordingWriter(path, META)
    writer.add(window(0))
    writer.add(window(1))
    good = path.read_bytes()
    real = recording._NpzAppender._put

    def full_at_gyro(self, name, a):
        if name.endswith("gyro_dph"):
            raise OSError(errno.ENOSPC, "No space left on device")
        real(self, name, a)

    monkeypatch.setattr(recording._NpzAppender, "_put", full_at_gyro)
    writer.add(window(2))  # its counter and time were written before the disk filled
    monkeypatch.undo()
    assert path.read_bytes() == good
    with pytest.raises(OutputError, match="2 complete window"):
        writer.close()
    rec = Recording.load(path)
    assert rec.partial == "cut off while recording: 2 of 4 windows"
    same_windows(rec, Recording(tuple(window(i) for i in range(2))))


def test_a_recording_written_before_loads_as_it_did(tmp_path):
    """The same seeded record, written now, holds the very arrays of the file written before
    windows were appended, and both solve alike."""
    new = tmp_path / "new.npz"
    code, _, err = run_cli(
        "record", "--sim", "--seed", "1", "--warmup", "0", "--window", "20", str(new)
    )
    assert code == 0, err
    with np.load(OLD) as old_arrays, np.load(new) as new_arrays:
        assert sorted(old_arrays.files) == sorted(new_arrays.files)
        for name in old_arrays.files:
            if name != "meta_json":
                assert old_arrays[name].dtype == new_arrays[name].dtype, name
                np.testing.assert_array_equal(old_arrays[name], new_arrays[name], err_msg=name)
    old, rec = Recording.load(OLD), Recording.load(new)
    same_windows(old, rec)
    assert old.status == rec.status == "complete"
    solved = [json.loads(run_cli("solve", str(p), "--json")[1]) for p in (OLD, new)]
    for key in ("azimuth_deg", "sigma_deg", "pitch_deg", "roll_deg"):
        assert solved[0][key] == solved[1][key], key


@pytest.mark.parametrize("padding", [0, 70_000])
def test_a_recording_cut_off_while_a_window_was_appended_keeps_the_windows_before(
    tmp_path, padding
):
    """Power lost or SIGKILL while window 3 was written: the file ends with part of it (and,
    padded, with more than zipfile searches for an archive's end)."""
    path = tmp_path / "run.npz"
    writer = RecordingWriter(path, META)
    for k in range(2):
        writer.add(window(k))
    whole = path.read_bytes()
    writer.add(window(2))
    three = path.read_bytes()
    writer.close("interrupted")
    path.write_bytes(three[: (len(whole) + len(three)) // 2] + bytes(padding))
    if padding:
        with pytest.raises(zipfile.BadZipFile):
            zipfile.ZipFile(path)
    rec = Recording.load(path)
    assert rec.partial == "cut off while recording: 2 of 4 windows"
    same_windows(rec, Recording(tuple(window(i) for i in range(2))))
    path.write_bytes(b"PK\x03\x04" + bytes(300_000))  # no archive at all
    with pytest.raises(recording.RecordingError, match="not a readable NPZ file"):
        Recording.load(path)
