"""Spin recordings (``record --spin``) checked against their own spin like stop-and-go ones
against their plan; a spin interrupted by a real signal keeps the samples it received."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from northfinder.cli import main
from northfinder.host.recording import SAMPLE_ARRAYS, RecordedWindow, Recording, RecordingError

COMMON = ["--sim", "--warmup", "0", "--sensor", "nav-fog", "--seed", "4", "--spin", "-6"]


@pytest.fixture(scope="module")
def spin_npz(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("spin") / "spin.npz"
    assert main(["record", str(path), *COMMON]) == 0
    return path


def _cut(rec: Recording, keep: int) -> RecordedWindow:
    (w,) = rec.windows
    return RecordedWindow(w.commanded_deg, *(getattr(w, n)[:keep] for n in SAMPLE_ARRAYS))


def test_half_a_spin_that_says_it_is_complete_is_refused(spin_npz, tmp_path, capsys):
    rec = Recording.load(spin_npz, min_windows=1)
    half = tmp_path / "half.npz"
    Recording((_cut(rec, 6000),), rec.meta).save(half)
    assert main(["solve", str(half)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"northfinder solve: error: {half}: truncated: 6000 of 12000 samples (-0.50 of -1.00 "
        "turns), though it says it is complete"
    )
    # a CSV cut at a line end (a copy that did not finish): its head says complete
    full_csv = tmp_path / "full.csv"
    rec.save(full_csv)
    lines = full_csv.read_text().splitlines(keepends=True)
    cut_csv = tmp_path / "cut.csv"
    cut_csv.write_text("".join(lines[: len(lines) // 2]))
    with pytest.raises(RecordingError, match=r"truncated: \d+ of 12000 samples .*complete"):
        Recording.load(cut_csv, min_windows=1)


def test_a_padded_spin_is_refused(spin_npz, tmp_path):
    rec = Recording.load(spin_npz, min_windows=1)
    two = tmp_path / "two.npz"
    Recording((rec.windows[0], rec.windows[0]), rec.meta).save(two)
    with pytest.raises(RecordingError, match="padded: 2 windows; a spin recording has one"):
        Recording.load(two, min_windows=1)
    (w,) = rec.windows
    longer = RecordedWindow(
        0.0, *(np.concatenate([getattr(w, n), getattr(w, n)[:10]]) for n in SAMPLE_ARRAYS)
    )
    longer = RecordedWindow(0.0, np.arange(12010) + int(w.counter[0]), *(
        getattr(longer, n) for n in SAMPLE_ARRAYS[1:]))  # fmt: skip
    path = tmp_path / "long.npz"
    Recording((longer,), rec.meta).save(path)
    with pytest.raises(RecordingError, match="padded: the spin spans 12010 sample ticks"):
        Recording.load(path, min_windows=1)


def test_a_partial_spin_is_solved_from_what_it_holds_and_says_so(spin_npz, tmp_path, capsys):
    rec = Recording.load(spin_npz, min_windows=1)
    half = tmp_path / "half.npz"
    Recording((_cut(rec, 6000),), {**rec.meta, "status": "interrupted"}).save(half)
    assert main(["solve", str(half)]) == 0
    out = capsys.readouterr().out
    assert "(-0.50 turns, " in out
    note = "partial recording (interrupted: 6000 of 12000 samples (-0.50 of -1.00 turns))"
    assert f"note: {note}: solved from the samples it holds" in out
    assert main(["solve", str(half), "--json"]) == 0
    source = json.loads(capsys.readouterr().out)["source"]
    assert source["partial"] == "interrupted: 6000 of 12000 samples (-0.50 of -1.00 turns)"


RECORD = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())",
          "record"]  # fmt: skip


@pytest.mark.realtime(alone=False)
@pytest.mark.parametrize(("signum", "earlier"), [(signal.SIGINT, False), (signal.SIGTERM, True)])
def test_an_interrupted_spin_keeps_its_samples(tmp_path, signum, earlier):
    path = tmp_path / "spin.csv"
    if earlier:
        path.write_text("an earlier recording")
    # 600 s of spin at 20 times real time: 30 s of wall time, interrupted within a few
    argv = [*RECORD, str(path), *COMMON, "--speed", "20", "--spin-time", "600"]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        for line in proc.stderr:  # the spin is steady and its samples arrive
            if line.startswith("record: acquire"):
                break
        time.sleep(3.0)  # about 60 s of device time: a turn
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signum, err
    kept = path.with_name("spin.partial.csv") if earlier else path
    last = err.strip().splitlines()[-1]
    assert last.startswith("northfinder record: interrupted")
    assert "of 120000 samples" in last and "marked interrupted" in last
    assert f" in {kept}" in last
    if earlier:
        assert path.read_text() == "an earlier recording"
        assert f"({path}, the earlier recording, left as it was)" in last
    rec = Recording.load(kept, min_windows=1)
    assert rec.status == "interrupted" and rec.partial is not None
    have = len(rec.windows[0].counter)
    assert 0 < have < 120000 and f"kept {have} of 120000 samples" in last
    done = subprocess.run([*RECORD[:3], "solve", str(kept)], capture_output=True, text=True,
                          timeout=60)  # fmt: skip
    if have < 3000:  # less than 90 deg (a host starved of CPU): refused, as any short spin
        assert done.returncode == 2 and "needs at least 90 deg" in done.stderr
        return
    assert done.returncode in (0, 3), done.stderr
    assert f"note: partial recording ({rec.partial}): solved from the samples it holds" in (
        done.stdout
    )
