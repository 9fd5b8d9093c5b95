"""Every row of docs/cli.md's exit-status table taken by a command that ends with it: the
statuses of the work (0 to 3) in this process, the signals' (130, 143, 129) by real signals
to a real ``northfinder`` process."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from clirun import run_cli

from northfinder.host.recording import SAMPLE_ARRAYS, RecordedWindow, Recording

DOC = Path(__file__).resolve().parents[1] / "docs" / "cli.md"
FAST = ["--sim", "--warmup", "0", "--seed", "2", "--window", "1"]


def documented_statuses() -> set[int]:
    text = DOC.read_text()
    table = text.split("## Exit status", 1)[1].split("\n\n", 2)[1]
    return {int(m) for m in re.findall(r"^\| (\d+) \|", table, flags=re.M)}


def _recording(tmp_path: Path) -> Path:
    path = tmp_path / "run.npz"
    code, _, err = run_cli("record", str(path), *FAST)
    assert code == 0, err
    return path


def _work_status(status: int, tmp_path: Path) -> tuple[int, str]:
    """Run the case of ``status``; its exit status and stderr."""
    if status == 0:
        code, out, err = run_cli("find", *FAST)
        assert "azimuth" in out
        return code, err
    if status == 1:  # measured data unusable: a window with ticks missing
        rec = Recording.load(_recording(tmp_path))
        w = rec.windows[1]
        keep = [i for i in range(len(w.counter)) if i != 50]
        gappy = RecordedWindow(w.commanded_deg, *(getattr(w, a)[keep] for a in SAMPLE_ARRAYS))
        path = tmp_path / "gappy.npz"
        Recording((rec.windows[0], gappy, *rec.windows[2:]), rec.meta).save(path)
        code, _, err = run_cli("solve", str(path))
        assert "missing 1 samples" in err
        return code, err
    if status == 2:  # the request is wrong
        code, _, err = run_cli("find", "--sim", "--window", "0")
        assert "argument --window" in err
        return code, err
    if status == 3:  # a heading whose windows disagree: the wrong latitude
        code, out, err = run_cli("solve", str(_recording(tmp_path)), "--latitude", "70")
        assert "CONSISTENCY CHECK FAILED" in out
        return code, err
    if status == 4:  # accept: a datasheet line the record is too short to decide
        ds = tmp_path / "datasheet.toml"
        ds.write_text("[gyro]\nbias_instability_dph = 0.01\n")
        code, out, err = run_cli(
            "accept", "--datasheet", str(ds), "--sim", "--seed", "3", "--static-s", "30",
            "-o", str(tmp_path / "acc"),
        )  # fmt: skip
        assert "NOT RESOLVED" in out
        return code, err
    raise AssertionError(f"no case for status {status}")


SIGNALS = {130: signal.SIGINT, 143: signal.SIGTERM, 129: signal.SIGHUP}


def test_every_documented_status_has_a_case_here():
    assert documented_statuses() == {0, 1, 2, 3, 4, *SIGNALS}


@pytest.mark.parametrize("status", [0, 1, 2, 3, 4])
def test_the_work_ends_with_its_documented_status(status, tmp_path):
    code, err = _work_status(status, tmp_path)
    assert code == status, err
    if status:
        assert len([x for x in err.splitlines() if "error" in x]) <= 1


@pytest.mark.realtime(alone=False)
@pytest.mark.parametrize("status", sorted(SIGNALS))
def test_a_signal_ends_with_its_documented_status(status):
    signum = SIGNALS[status]
    argv = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())",
            "find", "--sim", "--warmup", "0", "--speed", "5", "--window", "60"]  # fmt: skip
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        for line in proc.stderr:  # the first window is being measured: 12 s of wall time
            if line.startswith("find: acquire"):
                break
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == status, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("northfinder find: interrupted"), last
    if signum != signal.SIGINT:
        assert signum.name in last
