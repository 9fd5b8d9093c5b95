"""Reading a CAN log in one pass: its windows' arrays and a bounded rest, never an object per
frame or per sample, never the file (measured with tracemalloc, numpy's buffers traced too, on
logs of 20 000 and 200 000 frames written by python-can's writers); sample frames decoded
together give what the driver's receiver and collector give one by one, and a seeded find's
log solves to the same heading to the last digit either way. No clock is read.
"""

from __future__ import annotations

import gc
import io
import os
import re
import tracemalloc
from pathlib import Path

import can
import numpy as np
import pytest
from clirun import run_cli, run_json

import northfinder.cli.logprogress as logprogress
import northfinder.host.canlog as canlog
from northfinder.cli.dump import lines_go_to_a_file
from northfinder.driver.protocol import Sample, Validity
from northfinder.driver.protocol.can import CanReceiver, TickLoss, encode_can
from northfinder.driver.protocol.messages import RotateTo, StreamStart, StreamStop
from northfinder.driver.window import CountScales, WindowCollector
from northfinder.host.canlog import read_can_log

NODE = 1
RATE_HZ = 200.0


def _write_log(path: Path, frames: int) -> int:
    """A two-window session of about ``frames`` frames (four a sample); its samples."""
    ticks = frames // 8  # two windows of four frames a tick
    counter = 1000
    t = 1_700_000_000.0
    samples = 0
    with can.Logger(str(path)) as log:

        def send(message: object, at: float) -> None:
            for f in encode_can(message, NODE):  # type: ignore[arg-type]
                log.on_message_received(
                    can.Message(
                        timestamp=at,
                        arbitration_id=f.arbitration_id,
                        data=f.data,
                        is_extended_id=False,
                    )
                )

        for seq, angle in enumerate((0, 90_000_000)):
            send(RotateTo(2 * seq, angle), t)
            send(StreamStart(2 * seq + 1), t)
            for k in range(ticks):
                s = Sample(
                    counter, (k + 100_000 * (1 - seq), -k + 100_000 * seq, 3 * k),
                    (1, 2, 1_000_000 - k), angle, 2500,
                    Validity.GYRO_VALID | Validity.ACCEL_VALID,
                )  # fmt: skip
                send(s, t + k / RATE_HZ)
                counter += 1
                samples += 1
            t += ticks / RATE_HZ
            send(StreamStop(2 * seq + 2), t)
            counter += 50  # ticks while the table moves, not streamed
    return samples


def _peak(path: Path, skip_damaged: bool) -> tuple[int, int]:
    """tracemalloc's peak while reading the log, and the bytes of the windows' arrays."""
    gc.collect()
    tracemalloc.start()
    try:
        session = read_can_log(path, skip_damaged=skip_damaged)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    arrays = sum(
        getattr(w, name).nbytes
        for w in session.windows
        for name in ("counter", "time_s", "gyro_dph", "accel_mps2", "table_deg",
                     "temperature_c", "validity")
    )  # fmt: skip
    return peak, arrays


@pytest.mark.parametrize(
    ("suffix", "skip_damaged"),
    [(".asc", True), (".blf", False)],
)
def test_reading_a_log_ten_times_longer_grows_by_its_arrays_only(tmp_path, suffix, skip_damaged):
    small, large = tmp_path / f"small{suffix}", tmp_path / f"large{suffix}"
    n_small = _write_log(small, 20_000)
    n_large = _write_log(large, 200_000)
    assert large.stat().st_size > 5 * small.stat().st_size
    peak_small, arrays_small = _peak(small, skip_damaged)
    peak_large, arrays_large = _peak(large, skip_damaged)
    per_sample = (arrays_large - arrays_small) / (n_large - n_small)
    assert per_sample == pytest.approx(81, abs=1)  # the recorded window's arrays, bytes a sample
    growth = peak_large - peak_small
    # The arrays, plus the samples' raw counts (39 bytes a sample) held while they are turned
    # into them, one window at a time, with the growing arrays' spare room: at most 1.5 x.
    # A Python object kept per frame or sample (hundreds of bytes each), or the file held
    # whole, is far beyond it.
    assert growth <= 1.5 * (arrays_large - arrays_small), (growth, arrays_large - arrays_small)


def test_a_window_read_in_arrays_holds_the_samples_as_written(tmp_path):
    path = tmp_path / "run.blf"
    n = _write_log(path, 2_000)
    session = read_can_log(path)
    assert [len(w.counter) for w in session.windows] == [n // 2, n // 2]
    first, second = session.windows
    # No STATUS_COUNTERS in this log: counters are known from the ticks (modulo 256).
    assert first.counter[0] == 1000 % 256
    assert (np.diff(first.counter) == 1).all() and (np.diff(second.counter) == 1).all()
    k = n // 2 - 1
    assert second.gyro_dph[k, 2] == pytest.approx(3 * k * 1e-4)
    assert second.accel_mps2[k, 0] == pytest.approx(1e-6 * 9.80665)
    assert second.table_deg[0] == pytest.approx(90.0)
    assert second.commanded_deg == pytest.approx(90.0)
    assert first.temperature_c[0] == pytest.approx(25.0)


def _irregular_log(path: Path, rng: np.random.Generator) -> list[can.Message]:
    """Two windows of whole ticks in a device's order, with now and then a tick's frames in
    another order, a frame lost, a tick lost, a frame repeated, a tick begun twice, and another
    device's frame every 25 ticks (runs of sample frames end there)."""
    msgs: list[can.Message] = []
    t = 100.0

    def send(message: object) -> list[can.Message]:
        return [
            can.Message(
                timestamp=t, arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False
            )
            for f in encode_can(message, NODE)  # type: ignore[arg-type]
        ]

    counter = 77
    for seq, angle in enumerate((0, 180_000_000)):
        msgs += send(RotateTo(2 * seq, angle))
        msgs += send(StreamStart(2 * seq + 1))
        for k in range(6000):
            g, a = rng.integers(-(2**31), 2**31, 3), rng.integers(-(2**23), 2**23, 3)
            s = Sample(
                counter, (int(g[0]), int(g[1]), int(g[2])), (int(a[0]), int(a[1]), int(a[2])), angle,
                int(rng.integers(-32768, 32768)), Validity(int(rng.integers(0, 256))),
            )  # fmt: skip
            frames = send(s)
            r = rng.random()
            if r < 0.002:
                frames = frames[::-1]
            elif r < 0.004:
                del frames[int(rng.integers(0, 4))]
            elif r < 0.005:
                frames = []
            elif r < 0.006:
                frames.insert(2, frames[1])
            elif r < 0.007:  # a tick's first frames, another frame, then the tick whole
                frames = [*frames[:2], can.Message(timestamp=t, arbitration_id=0x7E5), *frames]
            msgs += frames
            if k % 25 == 24:  # another device's frame on the bus, as a heartbeat comes between
                msgs.append(can.Message(timestamp=t, arbitration_id=0x7E5, data=b"\x01"))
            counter += 1
            t += 1 / RATE_HZ
        msgs += send(StreamStop(2 * seq + 2))
        counter += 321
    with can.Logger(str(path)) as log:
        for m in msgs:
            log.on_message_received(m)
    return msgs


def _one_by_one(msgs: list[can.Message], requested: int) -> list[tuple[np.ndarray, ...]]:
    """The windows as the driver's receiver and collector give them, frame by frame."""
    receiver = CanReceiver(node_id=NODE)
    windows: list[WindowCollector] = []
    current: WindowCollector | None = None
    for m in msgs:
        for item in receiver.feed(m.arbitration_id, bytes(m.data)):
            if isinstance(item, Sample | TickLoss) and current is not None and not current.done:
                if isinstance(item, Sample):
                    current.add_sample(item, 0.0)
                else:
                    current.add_loss(item)
            elif isinstance(item, StreamStart):
                receiver.ticks.restart()
                current = WindowCollector(requested, on_gap="report")
                windows.append(current)
            elif isinstance(item, RotateTo | StreamStop):
                current = None if isinstance(item, RotateTo) else current
    out: list[tuple[np.ndarray, ...]] = []
    for c in windows:
        w = c.window(RATE_HZ, CountScales())
        out.append((w.counter, w.gyro_dph, w.accel_mps2, w.table_deg, w.temperature_c,
                    w.validity, np.array(w.gaps).reshape(-1, 2)))  # fmt: skip
    return out


@pytest.mark.parametrize("window_s", [None, 17.3])
def test_samples_decoded_together_are_those_the_driver_decodes_one_by_one(tmp_path, window_s):
    path = tmp_path / "irregular.blf"
    msgs = _irregular_log(path, np.random.default_rng(5))
    session = read_can_log(path, window_s=window_s)
    requested = 1 << 40 if window_s is None else round(window_s * RATE_HZ)
    expected = _one_by_one(msgs, requested)
    assert len(session.windows) == len(expected) == 2
    for i, (w, (counter, gyro, accel, table, temp, validity, gaps)) in enumerate(
        zip(session.windows, expected, strict=True), start=1
    ):
        assert len(w.counter) > 1000
        np.testing.assert_array_equal(w.counter, counter)
        np.testing.assert_array_equal(w.gyro_dph, gyro)
        np.testing.assert_array_equal(w.accel_mps2, accel)
        np.testing.assert_array_equal(w.table_deg, table)
        np.testing.assert_array_equal(w.temperature_c, temp)
        np.testing.assert_array_equal(w.validity, validity)
        np.testing.assert_array_equal(w.time_s, counter / RATE_HZ)
        # Every kind of flaw is in the log: the gaps reported as the driver reports them.
        noted = [
            tuple(int(x) for x in re.findall(r"(\d+) tick\(s\) missing from counter (\d+)", n)[0])
            for n in session.notes
            if n.startswith(f"window {i} (") and "tick(s) missing" in n
        ]
        assert [(first, count) for count, first in noted] == [tuple(g) for g in gaps.tolist()]
        assert len(gaps) > 3


def test_reading_reports_its_progress_in_bytes_of_the_file(tmp_path):
    path = tmp_path / "run.asc"
    _write_log(path, 200_000)
    calls: list[tuple[int, int]] = []
    read_can_log(path, skip_damaged=True, progress=lambda done, total: calls.append((done, total)))
    size = path.stat().st_size
    assert len(calls) >= 3  # every 65536 frames, and at the end
    assert all(total == size for _, total in calls)
    done = [d for d, _ in calls]
    assert done == sorted(done) and 0 < done[0] < size and done[-1] == size


def test_solve_shows_the_reading_of_a_long_log(tmp_path, monkeypatch):
    path = tmp_path / "run.asc"
    _write_log(path, 100_000)  # 7 MB
    monkeypatch.setattr(logprogress, "PROGRESS_BYTES", 0)  # the log counts as long
    code, out, err = run_cli("solve", str(path), "--latitude", "34")
    assert code == 0 and "azimuth" in out
    lines = [line for line in err.splitlines() if line.startswith("solve: ")]
    assert lines[0] == "solve: reading the log"
    assert lines[-1].endswith("(100%)") and len(lines) >= 3
    # --json prints nothing else.
    code, out, err = run_cli("solve", str(path), "--latitude", "34", "--json")
    assert "solve: " not in err


def test_dump_shows_its_progress_only_when_its_lines_go_to_a_file(tmp_path):
    with (tmp_path / "out.txt").open("w") as fh:
        assert lines_go_to_a_file(fh)  # `dump LOG > out.txt`
    assert lines_go_to_a_file(io.StringIO())  # a program's buffer
    r, w = os.pipe()
    try:  # `dump LOG | less`: less shares the terminal with stderr
        assert not lines_go_to_a_file(os.fdopen(w, "w", closefd=False))
    finally:
        os.close(r)
        os.close(w)
    master, slave = os.openpty()
    try:  # on a terminal the lines show how far it is
        assert not lines_go_to_a_file(os.fdopen(slave, "w", closefd=False))
    finally:
        os.close(master)
        os.close(slave)


def test_dump_shows_the_reading_of_a_long_log_when_its_lines_go_to_a_file(tmp_path, monkeypatch):
    path = tmp_path / "run.asc"
    _write_log(path, 200_000)
    monkeypatch.setattr(logprogress, "PROGRESS_BYTES", 0)  # the log counts as long
    code, out, err = run_cli("dump", str(path), "--raw")  # stdout a buffer, as `dump > file`
    assert code == 0, err
    frames = sum(1 for _ in can.LogReader(str(path)))
    assert len(out.splitlines()) == frames  # every frame printed, none mixed with the progress
    lines = [line for line in err.splitlines() if line.startswith("dump: ")]
    assert lines[0] == "dump: reading the log"
    assert lines[-1].endswith("(100%)") and len(lines) >= 3
    code, out, err = run_cli("dump", str(path), "--count", "5")  # stopped early: no 100 %
    assert code == 0 and len(out.splitlines()) == 5
    assert not any(line.endswith("(100%)") for line in err.splitlines())
    monkeypatch.setattr(logprogress, "PROGRESS_BYTES", path.stat().st_size + 1)
    code, _, err = run_cli("dump", str(path), "--count", "5")  # a short log: nothing shown
    assert code == 0 and "dump: " not in err


@pytest.fixture(scope="module")
def seeded_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The CAN log of a seeded four-position find, in ASC, BLF and candump formats."""
    d = tmp_path_factory.mktemp("seeded")
    logs = {}
    for suffix in (".asc", ".blf", ".log"):
        logs[suffix] = d / f"find{suffix}"
        run_json("find", "--sim", "--warmup", "0", "--window", "3", "--seed", "8",
                 "--positions", "0,90,180,270", "--can-log", str(logs[suffix]))  # fmt: skip
    return logs


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])
def test_a_seeded_log_reads_and_solves_the_same_decoded_together_as_one_by_one(
    seeded_logs, suffix, monkeypatch
):
    path = seeded_logs[suffix]
    together = read_can_log(path, skip_damaged=True)
    solved = run_json("solve", str(path), "--latitude", "34")
    monkeypatch.setattr(canlog, "RUN_FRAMES", 0)  # every frame one by one, as read before
    alone = read_can_log(path, skip_damaged=True)
    solved_alone = run_json("solve", str(path), "--latitude", "34")
    assert len(together.windows) == len(alone.windows) == 4
    assert together.notes == alone.notes and together.frames == alone.frames
    for a, b in zip(together.windows, alone.windows, strict=True):
        assert a.commanded_deg == b.commanded_deg
        for name in ("counter", "time_s", "gyro_dph", "accel_mps2", "table_deg", "temperature_c",
                     "validity"):  # fmt: skip
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    solved.pop("created_utc")
    solved_alone.pop("created_utc")
    assert solved == solved_alone  # the heading and every figure to the last digit
    assert solved["azimuth_deg"] == solved_alone["azimuth_deg"]


def test_calibrate_shows_the_reading_of_a_long_log(seeded_logs, monkeypatch):
    path = seeded_logs[".blf"]
    monkeypatch.setattr(logprogress, "PROGRESS_BYTES", 0)  # the log counts as long
    code, _, err = run_cli("calibrate", str(path))
    assert code == 0, err
    lines = [line for line in err.splitlines() if line.startswith("calibrate: ")]
    reading = lines.index("calibrate: reading the log")
    assert lines[reading - 1] == "calibrate: reading 1 recording(s)"
    assert any(line.endswith("(100%)") for line in lines[reading:])
    assert lines[-1] == "calibrate: done"
    monkeypatch.setattr(logprogress, "PROGRESS_BYTES", path.stat().st_size + 1)
    code, _, err = run_cli("calibrate", str(path))  # a short log: no progress of its reading
    assert code == 0 and "calibrate: reading the log" not in err
