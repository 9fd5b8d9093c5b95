"""Recordings written as they arrive and replaced atomically; a failed write never destroys a file
nor hides a result; readers check a recording against its own plan and status."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from northfinder.cli import main
from northfinder.cli.exits import EXIT_INCONSISTENT
from northfinder.host.errors import OutputError
from northfinder.host.recording import RecordedWindow, Recording, RecordingError, RecordingWriter

RATE = 200
N = 400  # 2 s windows


def window(k: int, angle: float) -> RecordedWindow:
    counter = np.arange(N) + k * 10_000
    rng = np.random.default_rng(k)
    return RecordedWindow(
        angle, counter, (counter + 1) / RATE, rng.normal(0.0, 1.0, (N, 3)),
        rng.normal([0.0, 0.0, 9.8], 1e-4, (N, 3)), np.full(N, angle), np.full(N, 20.0),
        np.full(N, 3, dtype=np.uint8),
    )  # fmt: skip


META: dict[str, Any] = {
    "latitude_deg": 34.0,
    "sample_rate_hz": RATE,
    "plan": {"positions_deg": [0.0, 180.0, 180.0, 0.0], "window_s": 2.0},
}
ANGLES = META["plan"]["positions_deg"]


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_windows_are_on_disk_as_they_arrive_and_an_interrupted_recording_says_so(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    writer = RecordingWriter(path, META)
    for k in range(2):
        writer.add(window(k, ANGLES[k]))
        # Readable after every window, before any close: a run cut off here keeps them.
        rec = Recording.load(path, min_windows=1)
        assert len(rec.windows) == k + 1
    assert Recording.load(path).partial == "cut off while recording: 2 of 4 windows"
    writer.add(window(2, ANGLES[2]))
    writer.close("interrupted")
    rec = Recording.load(path)
    assert rec.partial == "interrupted: 3 of 4 windows"
    np.testing.assert_array_equal(rec.windows[2].counter, window(2, 0).counter)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_failed_first_write_leaves_an_existing_file_as_it_was(tmp_path, suffix, monkeypatch):
    path = tmp_path / f"run{suffix}"
    good = Recording(tuple(window(k, a) for k, a in enumerate(ANGLES)), dict(META))
    good.save(path)
    before = path.read_bytes()

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    writer = RecordingWriter(path, META)
    writer.add(window(0, 0.0))
    with pytest.raises(OutputError):
        good.save(path)  # save() too writes beside it and replaces it only when written
    monkeypatch.undo()
    with pytest.raises(OutputError, match="No space left on device"):
        writer.close()
    assert path.read_bytes() == before
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_write_that_fails_mid_window_keeps_the_complete_windows(tmp_path, monkeypatch):
    path = tmp_path / "run.csv"
    writer = RecordingWriter(path, META)
    writer.add(window(0, 0.0))
    writer.add(window(1, 180.0))
    import northfinder.host.recording as recording

    real = recording._write_csv_rows

    def half_then_full(fh, i, w):
        real(
            fh,
            i,
            RecordedWindow(
                w.commanded_deg, *(getattr(w, n)[: N // 2] for n in recording.SAMPLE_ARRAYS)
            ),
        )
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording, "_write_csv_rows", half_then_full)
    writer.add(window(2, 180.0))
    with pytest.raises(OutputError, match="2 complete window"):
        writer.close()
    rec = Recording.load(path)
    assert len(rec.windows) == 2 and rec.partial == "cut off while recording: 2 of 4 windows"


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (as root), else skipped."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)])
    if done.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)


FIND = ["--sim", "--warmup", "0", "--seed", "3", "--sensor", "ideal", "--window", "2"]


def test_find_on_a_full_disk_prints_the_heading_then_the_error(tiny_disk, capsys):
    status = main(["find", *FIND, "--record", str(tiny_disk / "run.csv")])
    out, err = capsys.readouterr()
    assert status == 1
    assert "azimuth" in out.lower()
    last = err.strip().splitlines()[-1]  # after the progress lines, one error line
    assert last.startswith("northfinder find: error: ") and "No space left on device" in last


def test_find_with_a_can_log_that_fails_prints_the_heading_then_the_error(tiny_disk, capsys):
    status = main(["find", *FIND, "--can-log", str(tiny_disk / "run.log")])
    out, err = capsys.readouterr()
    assert status == 1
    assert "azimuth" in out.lower()
    assert "CAN log" in err and "incomplete" in err


def test_find_record_write_failure_never_hides_the_result(tmp_path, capsys, monkeypatch):
    import northfinder.host.recording as recording

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recording, "_write_csv_rows", full)
    status = main(["find", *FIND, "--record", str(tmp_path / "run.csv"), "--json"])
    out, err = capsys.readouterr()
    assert status == 1
    assert json.loads(out)["azimuth_deg"] is not None
    last = err.strip().splitlines()[-1]
    assert last.startswith("northfinder find: error: ") and "No space left" in last


@pytest.mark.realtime(alone=False)
@pytest.mark.parametrize("earlier", [False, True], ids=["new", "over-an-earlier-file"])
def test_an_interrupted_record_keeps_its_complete_windows_and_solve_says_so(tmp_path, earlier):
    target = tmp_path / "run.csv"
    if earlier:
        target.write_text("an earlier recording")
    path = tmp_path / "run.partial.csv" if earlier else target  # where the windows go
    argv = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())",
            "record", str(target), "--sim", "--speed", "20", "--warmup", "0", "--window", "2",
            "--positions", "0,60,120,180,240,300"]  # fmt: skip
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            # The third window has begun on disk, so the first two are whole (each window is
            # written in one call, in order; one seen half-written may still be cut off by the
            # signal). Three windows remain, so a late signal still finds the run going.
            if path.exists() and "\n2," in path.read_text():
                break
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "marked interrupted" in err and f"windows in {path}" in err
    if earlier:
        assert target.read_text() == "an earlier recording"
        assert f"({target}, the earlier recording, left as it was)" in err
    rec = Recording.load(path)
    assert rec.partial is not None and rec.partial.startswith("interrupted: ")
    assert 2 <= len(rec.windows) < 6
    done = subprocess.run(
        [*argv[:3], "solve", str(path)], capture_output=True, text=True, timeout=60
    )
    # Three or more windows are checked against each other, and a sound recording fails that
    # check at its false-alarm rate (1 %): exit 3 with the warning, the heading printed. A seed
    # would not fix the samples: a paced simulator's noise follows the wall clock.
    assert done.returncode == 0 or (
        done.returncode == EXIT_INCONSISTENT and "CONSISTENCY CHECK FAILED" in done.stdout
    ), done.stderr
    assert f"partial recording (interrupted: {len(rec.windows)} of 6 windows)" in done.stdout


def _cut_csv(src: Path, dst: Path, keep_rows: int) -> None:
    lines = src.read_text().splitlines(keepends=True)
    head = [x for x in lines if x.startswith("#") and "status" not in x and "windows =" not in x]
    body = [x for x in lines if not x.startswith("#")]
    dst.write_text("".join(head + body[: 1 + keep_rows]))


def test_a_csv_cut_at_a_line_end_is_named_truncated(tmp_path):
    full = tmp_path / "full.csv"
    Recording(tuple(window(k, a) for k, a in enumerate(ANGLES)), dict(META)).save(full)
    old_style = tmp_path / "cut.csv"  # no status lines: as written before they existed
    _cut_csv(full, old_style, 3 * N - 200)
    with pytest.raises(RecordingError, match=r"truncated: 3 of 4 windows, the last cut short"):
        Recording.load(old_style)
    three = tmp_path / "three.csv"
    _cut_csv(full, three, 3 * N)
    with pytest.raises(RecordingError, match=r"truncated: 3 of 4 windows, though it says"):
        Recording.load(three)
    # calibrate reads with the same rules
    from northfinder.host.calibrate.readers import read_runs

    with pytest.raises(RecordingError, match="truncated"):
        read_runs([old_style])


def test_a_padded_recording_is_named(tmp_path):
    meta = {**META, "plan": {"positions_deg": [0.0, 180.0], "window_s": 2.0}}
    path = tmp_path / "padded.npz"
    Recording(tuple(window(k, a) for k, a in enumerate(ANGLES[:3])), meta).save(path)
    with pytest.raises(RecordingError, match="padded: 3 windows, its plan has 2"):
        Recording.load(path)


def test_calibrates_duplicate_guard_sees_one_session_in_two_formats(tmp_path):
    from northfinder.host.calibrate.readers import read_runs

    windows = tuple(window(k, a) for k, a in enumerate(ANGLES))
    npz = tmp_path / "run.npz"
    Recording(windows, dict(META)).save(npz)
    # The same session as another tool would write it: floats that differ in the last digits.
    nudged = tuple(
        RecordedWindow(
            w.commanded_deg, w.counter, w.time_s, w.gyro_dph * (1 + 1e-13), w.accel_mps2 + 1e-15,
            w.table_deg, w.temperature_c, w.validity,
        )
        for w in windows
    )  # fmt: skip
    csv = tmp_path / "run.csv"
    Recording(nudged, dict(META)).save(csv)
    with pytest.raises(RecordingError, match="holds the same samples as"):
        read_runs([npz, csv])
    other = tmp_path / "other.csv"  # another power-on
    Recording(tuple(window(k + 10, a) for k, a in enumerate(ANGLES)), dict(META)).save(other)
    assert len(read_runs([npz, other])) == 2


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_new_recording_replaces_an_earlier_one_only_when_complete(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    old = Recording(tuple(window(k + 7, a) for k, a in enumerate(ANGLES)), dict(META))
    old.save(path)
    before = path.read_bytes()
    writer = RecordingWriter(path, META)
    assert writer.work == tmp_path / f"run.partial{suffix}"
    for k in range(3):
        writer.add(window(k, ANGLES[k]))
        assert path.read_bytes() == before  # never touched while the run lasts
        assert len(Recording.load(writer.work, min_windows=1).windows) == k + 1
    writer.add(window(3, ANGLES[3]))
    writer.close("complete")
    rec = Recording.load(path)
    assert rec.partial is None and len(rec.windows) == 4
    np.testing.assert_array_equal(rec.windows[3].counter, window(3, 0).counter)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"run{suffix}"]


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_an_interrupted_recording_leaves_an_earlier_one_and_stays_beside_it(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    Recording(tuple(window(k + 7, a) for k, a in enumerate(ANGLES)), dict(META)).save(path)
    before = path.read_bytes()
    (tmp_path / f"run.partial{suffix}").write_text("an earlier partial run")  # kept too
    writer = RecordingWriter(path, META)
    assert writer.work == tmp_path / f"run.partial-2{suffix}"
    for k in range(2):
        writer.add(window(k, ANGLES[k]))
    writer.close("interrupted")
    assert path.read_bytes() == before
    assert (tmp_path / f"run.partial{suffix}").read_text() == "an earlier partial run"
    assert Recording.load(writer.work).partial == "interrupted: 2 of 4 windows"
    assert str(writer.work) in writer.where and "left as it was" in writer.where


def test_a_csv_recording_states_its_status_once(tmp_path):
    path = tmp_path / "run.csv"
    for status in ("complete", "interrupted"):
        writer = RecordingWriter(path, META)
        for k in range(4 if status == "complete" else 2):
            writer.add(window(k, ANGLES[k]))
        writer.close(status)
        lines = [x for x in writer.work.read_text().splitlines() if x.startswith("# status")]
        assert len(lines) == 1 and json.loads(lines[0].split("=", 1)[1]) == status
        assert Recording.load(writer.work).status == status
    Recording(tuple(window(k, a) for k, a in enumerate(ANGLES)), dict(META)).save(path)
    assert path.read_text().count("# status") == 1
    writer = RecordingWriter(tmp_path / "cut.csv", META)
    writer.add(window(0, 0.0))  # never closed: cut off (power, SIGKILL)
    assert (tmp_path / "cut.csv").read_text().count("# status") == 1
    assert Recording.load(tmp_path / "cut.csv", min_windows=1).status == "recording"


def _sized_disk(tmp_path: Path, free: int) -> Path:
    """A tmpfs (as root, else skipped) with ``free`` bytes beyond what tmp_path/old.* take."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    used = sum(-(-p.stat().st_size // 4096) * 4096 for p in tmp_path.glob("old.*"))
    mount = tmp_path / "tiny"
    mount.mkdir()
    size = used + free
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)])
    if done.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    return mount


@pytest.fixture
def unmount():
    mounts: list[Path] = []
    yield mounts
    for m in mounts:
        subprocess.run(["umount", "--lazy", str(m)], check=False)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_full_disk_leaves_an_earlier_recording_whole(tmp_path, suffix, unmount):
    """A real full disk (a tmpfs with room for the earlier file and about one new window)."""
    old = Recording(tuple(window(k + 7, a) for k, a in enumerate(ANGLES)), dict(META))
    old.save(tmp_path / f"old{suffix}")
    one = (tmp_path / f"old{suffix}").stat().st_size // 4
    disk = _sized_disk(tmp_path, free=one * 3 // 2 + 8192 if suffix == ".csv" else one * 2 + 4096)
    unmount.append(disk)
    path = disk / f"run{suffix}"
    path.write_bytes((tmp_path / f"old{suffix}").read_bytes())
    writer = RecordingWriter(path, META)
    for k, a in enumerate(ANGLES):
        writer.add(window(k, a))
    assert writer.error is not None and 1 <= writer.written < 4
    with pytest.raises(OutputError, match="No space left on device") as caught:
        writer.close()
    assert f"{writer.written} complete window(s) kept in {disk / f'run.partial{suffix}'}" in str(
        caught.value
    )
    assert "left as it was" in str(caught.value)
    assert path.read_bytes() == (tmp_path / f"old{suffix}").read_bytes()
    kept = Recording.load(disk / f"run.partial{suffix}", min_windows=1)
    assert len(kept.windows) == writer.written and kept.status == "recording"


def test_record_over_a_recording_on_a_full_disk_keeps_it_and_names_the_new_windows(
    tmp_path, capsys, unmount
):
    args = [*FIND[:-1], "1"]  # 1 s windows: about 18 KB of CSV each
    assert main(["record", str(tmp_path / "old.csv"), *args]) == 0
    capsys.readouterr()
    assert main(["solve", str(tmp_path / "old.csv")]) == 0
    solved = capsys.readouterr().out
    disk = _sized_disk(tmp_path, free=28 * 1024)  # the head and one window, not two
    unmount.append(disk)
    path = disk / "run.csv"
    path.write_bytes((tmp_path / "old.csv").read_bytes())
    for command in (["record", str(path)], ["find", "--record", str(path)]):
        status = main([*command, *args, "--seed", "4"])
        out, err = capsys.readouterr()
        assert status == 1, err
        assert ("azimuth" in out) == (command[0] == "find")  # find's heading first
        last = err.strip().splitlines()[-1]
        assert last.startswith(f"northfinder {command[0]}: error: {path}: cannot write (No space")
        assert f"kept in {disk / 'run.partial.csv'} ({path}, the earlier recording, left" in last
        assert main(["solve", str(path)]) == 0
        assert capsys.readouterr().out == solved  # the earlier recording solves as before
        assert Recording.load(disk / "run.partial.csv", min_windows=1).status == "recording"
        (disk / "run.partial.csv").unlink()
