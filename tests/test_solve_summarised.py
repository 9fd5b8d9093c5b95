"""`solve` of a CAN log or an NPZ recording reduces each window as it ends and drops its samples: memory is one
window's samples and small summaries whatever the number of windows, and the result is the one
solved from every window held, to the last digit (measured with tracemalloc, numpy's buffers
traced too)."""

from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path
from typing import Any

import can
import pytest
from clirun import run_json
from seeded import saved, seeded_windows, solved_both_ways

import northfinder.cli.solve as solve
import northfinder.host.canlog as canlog
from northfinder.driver.protocol import Sample, Validity
from northfinder.driver.protocol.can import encode_can
from northfinder.driver.protocol.messages import RotateTo, StreamStart, StreamStop
from northfinder.host.canlog import read_can_log
from northfinder.host.recording import summarise_npz

NODE = 1
RATE_HZ = 200.0


def _write_log(path: Path, windows: int, ticks: int) -> None:
    """A session of ``windows`` windows of ``ticks`` samples each, at 0, 90, 180, 270 deg."""
    counter, t = 1000, 1_700_000_000.0
    with can.Logger(str(path)) as log:

        def send(message: object, at: float) -> None:
            for f in encode_can(message, NODE):  # type: ignore[arg-type]
                log.on_message_received(
                    can.Message(timestamp=at, arbitration_id=f.arbitration_id, data=f.data,
                                is_extended_id=False)
                )  # fmt: skip

        for seq in range(windows):
            angle = 90_000_000 * (seq % 4)
            send(RotateTo(3 * seq, angle), t)
            send(StreamStart(3 * seq + 1), t)
            for k in range(ticks):
                s = Sample(
                    counter, (k % 7, -(k % 5), 3), (1, 2, 1_000_000 - k % 3), angle, 2500,
                    Validity.GYRO_VALID | Validity.ACCEL_VALID,
                )  # fmt: skip
                send(s, t + k / RATE_HZ)
                counter += 1
            t += ticks / RATE_HZ
            send(StreamStop(3 * seq + 2), t)
            counter += 50


def _peak(path: Path) -> int:
    gc.collect()
    tracemalloc.start()
    try:
        session = read_can_log(path, summarise=solve.summariser("none", False))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert session.windows == () and len(session.summaries) == len(session.window_numbers)
    return peak


def test_a_log_of_four_times_the_windows_holds_one_window_at_a_time(tmp_path):
    ticks = 4000
    few, many = tmp_path / "few.blf", tmp_path / "many.blf"
    _write_log(few, 2, ticks)
    _write_log(many, 8, ticks)
    _peak(few)  # the first reading imports and caches what every later one uses
    growth = _peak(many) - _peak(few)
    one_window = 81 * ticks  # a window's arrays in physical units, bytes
    # Six windows more: held whole they would add 6 x 81 bytes a sample; summarised as each
    # ends, at most a fraction of one window (the summaries and the notes grow).
    assert growth < one_window / 2, (growth, one_window)


@pytest.fixture(scope="module")
def seeded_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The CAN log of a seeded four-position find, in ASC and BLF."""
    d = tmp_path_factory.mktemp("seeded")
    logs = {}
    for suffix in (".asc", ".blf"):
        logs[suffix] = d / f"find{suffix}"
        run_json("find", "--sim", "--warmup", "0", "--window", "3", "--seed", "8",
                 "--positions", "0,90,180,270", "--can-log", str(logs[suffix]))  # fmt: skip
    return logs


@pytest.mark.parametrize(
    ("suffix", "options"),
    [(".asc", []), (".blf", []), (".blf", ["--denoise", "hampel"]), (".blf", ["--window", "2"])],
)
def test_solve_summarised_as_read_gives_the_result_of_every_window_held(
    seeded_logs, suffix, options, monkeypatch
):
    path = str(seeded_logs[suffix])
    streamed = run_json("solve", path, "--latitude", "34", *options)
    monkeypatch.setattr(solve, "summariser", lambda *_: None)  # every window held, as before
    held = run_json("solve", path, "--latitude", "34", *options)
    streamed.pop("created_utc")
    held.pop("created_utc")
    assert streamed == held  # the heading and every figure to the last digit


def test_a_rate_known_only_after_a_window_ended_reads_the_log_again(seeded_logs, monkeypatch):
    path = seeded_logs[".blf"]
    summarise = solve.summariser("none", False)
    whole = read_can_log(path, summarise=summarise)
    assert len(whole.summaries) == 4
    real_ended, real_read = canlog._Scan._ended, canlog._Scan.read
    reads = []

    def ended_at_another_rate(self, segments):
        rate, self.rate = self.rate, self.rate * 2  # as though the log changed it afterwards
        try:
            real_ended(self, segments)
        finally:
            self.rate = rate

    def counted(self, *args):
        reads.append(self.summarise is not None)
        real_read(self, *args)

    monkeypatch.setattr(canlog._Scan, "_ended", ended_at_another_rate)
    monkeypatch.setattr(canlog._Scan, "read", counted)
    again = read_can_log(path, summarise=summarise)
    assert reads == [True, False]  # summarised as read, then read again whole
    assert [s.window for s in again.summaries] == [s.window for s in whole.summaries]


# NPZ recordings: read window by window from the column layout.

OLD = Path(__file__).parent / "data" / "recording-v1-seed1.npz"


def _npz(tmp_path: Path, windows: int, n: int = 2000, **changes: Any) -> Path:
    made = seeded_windows(windows, n, windows, dt=changes.get("dt", 1.0))
    return saved(tmp_path / f"rec{windows}.npz", made, changes.get("meta", {}))


@pytest.mark.parametrize(
    "options", [[], ["--denoise", "hampel"], ["--latitude", "40"], ["--solver", "least-squares"]]
)
def test_an_npz_solved_window_by_window_gives_the_result_of_every_window_held(
    tmp_path, monkeypatch, options
):
    streamed, held = solved_both_ways(OLD, monkeypatch, *options)
    assert streamed == held and streamed[0] in (0, 3)  # 3: inconsistent at a wrong latitude
    path = _npz(tmp_path, 8)
    streamed, held = solved_both_ways(path, monkeypatch, *options)
    assert streamed == held and "azimuth_deg" in streamed[1]


def test_an_npz_of_four_times_the_windows_holds_one_window_at_a_time(tmp_path):
    n = 20_000
    few, many = _npz(tmp_path, 2, n), _npz(tmp_path, 8, n)
    summarise = solve.summariser("none", False)

    def peak(path: Path) -> int:
        gc.collect()
        tracemalloc.start()
        try:
            got = summarise_npz(path, summarise)
            _, top = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert got is not None  # read window by window, not left to the whole reader
        return top

    peak(few)
    growth = peak(many) - peak(few)
    one_window = 8 * (1 + 1 + 3 + 3 + 1 + 1) * n  # its arrays in float64/int64, bytes
    assert growth < one_window / 2, (growth, one_window)


@pytest.mark.parametrize("dt", [1.00995, 0.99005, 1.02])
def test_a_rate_near_the_limit_is_left_to_the_whole_reader_and_judged_as_before(
    tmp_path, monkeypatch, dt
):
    path = _npz(tmp_path, 4, dt=dt)
    assert summarise_npz(path, solve.summariser("none", False)) is None
    streamed, held = solved_both_ways(path, monkeypatch)
    assert streamed == held
    assert (streamed[0] == 2) == (dt == 1.02), streamed[2]


def test_a_partial_and_a_damaged_npz_say_what_they_did(tmp_path, monkeypatch):
    path = _npz(tmp_path, 3, meta={"plan": {"positions_deg": [0, 90, 180, 270], "window_s": 10.0},
                                    "status": "interrupted"})  # fmt: skip
    streamed, held = solved_both_ways(path, monkeypatch)
    assert streamed == held and "interrupted: 3 of 4 windows" in streamed[1]["source"]["partial"]
    data = bytearray(path.read_bytes())
    at = data.index(b"gyro_dph.npy") + 2000  # inside the gyro's compressed samples
    data[at : at + 8] = b"\0" * 8
    path.write_bytes(bytes(data))
    assert summarise_npz(path, solve.summariser("none", False)) is None
    streamed, held = solved_both_ways(path, monkeypatch)
    assert streamed == held and streamed[0] == 2 and streamed[2].count("\n") == 1
