"""Rotated CAN logs: ``sim --log`` and ``find``/``record --can-log`` split by size (python-can's
``SizedRotatingLogger``) or by log time, each part a complete log of its own, named
predictably; ``solve`` and ``dump`` read the parts in order and say when frames are missing
between two of them.

The logs are written by real python-can writers and read back by python-can's readers; runs
are the embedded simulator in virtual time.
"""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import can
import pytest
from clirun import run_cli, run_json

from northfinder.driver.errors import ArgumentError
from northfinder.driver.framelog import (
    FrameLog,
    RotatingLog,
    log_parts,
    order_log_parts,
    part_name,
)
from northfinder.host.canlog import read_can_log, read_frames

FIND = ["find", "--sim", "--warmup", "0", "--window", "2", "--azimuth", "42.5"]


def _frames(n: int, rate_hz: float = 100.0, t0: float = 1_700_000_000.0) -> list[can.Message]:
    return [
        can.Message(
            timestamp=t0 + i / rate_hz,
            arbitration_id=0x101,
            data=i.to_bytes(4, "little") + b"\x00\x01\x02\x03",
            is_extended_id=False,
        )
        for i in range(n)
    ]


def _set(path: Path) -> list[Path]:
    return [*log_parts(path), path]


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".csv"])
def test_a_log_rotated_by_size_is_complete_parts_named_in_order(tmp_path, suffix):
    path = tmp_path / f"bus{suffix}"
    sent = _frames(3000)
    with FrameLog(path, max_bytes=16 * 1024) as log:
        for msg in sent:
            log(msg)
    parts = _set(path)
    assert len(parts) >= 3
    assert parts[:-1] == [part_name(path, i) for i in range(len(parts) - 1)]
    assert part_name(path, 7).name == f"bus_#007{suffix}"
    got: list[int] = []
    for part in parts:
        # Each part a complete log of its own: python-can's reader takes it alone.
        with can.LogReader(str(part)) as reader:
            ids = [int.from_bytes(bytes(m.data[:4]), "little") for m in reader]
        assert ids, part
        got += ids
    assert got == list(range(3000))  # nothing lost, nothing twice, in order
    for part in parts[:-1]:
        # python-can rotates before the frame that finds the part at its size: at most one
        # frame (and, for BLF, one compressed container) beyond it.
        assert part.stat().st_size < 16 * 1024 + 64 * 1024


def test_a_log_rotated_by_time_starts_a_part_every_interval_of_log_time(tmp_path):
    path = tmp_path / "bus.log"
    with FrameLog(path, max_seconds=2.0) as log:
        for msg in _frames(1000):  # 10 s at 100 Hz
            log(msg)
    parts = _set(path)
    assert len(parts) == 5
    starts = []
    for part in parts:
        times = [m.timestamp for m in can.LogReader(str(part))]
        starts.append(times[0] - 1_700_000_000.0)
        assert times[-1] - times[0] < 2.0
    assert starts == pytest.approx([0.0, 2.0, 4.0, 6.0, 8.0], abs=1e-6)


def test_rotation_by_size_and_time_together_takes_whichever_comes_first(tmp_path):
    path = tmp_path / "bus.csv"
    logger = RotatingLog(path, max_bytes=1 << 20, max_seconds=3.0)
    with logger:
        for msg in _frames(1000):
            logger.on_message_received(msg)
    assert logger.rollover_count == 3  # by time: 10 s in 3 s parts; far below the size
    assert len(_set(path)) == 4


def test_a_shell_glob_order_is_put_back_in_the_order_written(tmp_path):
    path = tmp_path / "run.log"
    names = [path, *(part_name(path, i) for i in (0, 1, 2, 10))]
    shuffled = sorted(names, key=str)  # run.log, run_#000, run_#001, run_#002, run_#010
    random.Random(1).shuffle(shuffled)
    ordered, notes = order_log_parts(shuffled)
    assert ordered == [part_name(path, i) for i in (0, 1, 2, 10)] + [path]
    assert len(notes) == 7 and notes[0].startswith("part #003 of")
    others = [tmp_path / "a.log", tmp_path / "b.log"]
    assert order_log_parts(others[::-1]) == (others[::-1], [])  # not a set: as given


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"max_bytes": 100}, "4096 to"),
        ({"max_seconds": 0.5}, "1 to"),
    ],
)
def test_the_library_refuses_a_rotation_it_cannot_do(tmp_path, kwargs, says):
    with pytest.raises(ArgumentError, match=says):
        FrameLog(tmp_path / "bus.log", **kwargs)
    with pytest.raises(ArgumentError, match="the formats python-can rotates"):
        FrameLog(tmp_path / "bus.db", max_bytes=1 << 20)


# -- find --can-log rotated, solved and dumped from its parts ---------------------------------
@pytest.fixture(scope="module")
def rotated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, Any]]:
    """A four-window find logged whole and, with the same seed, rotated by size."""
    folder = tmp_path_factory.mktemp("rotated")
    whole, parted = folder / "whole.log", folder / "run.log"
    found = run_json(*FIND, "--seed", "5", "--can-log", str(whole))
    again = run_json(
        *FIND, "--seed", "5", "--can-log", str(parted), "--can-log-rotate", "64K"
    )  # fmt: skip
    assert again["azimuth_deg"] == found["azimuth_deg"]
    return whole, parted, found


def test_solve_reads_the_parts_of_a_rotated_log_as_the_whole_log(rotated):
    whole, parted, found = rotated
    parts = _set(parted)
    assert len(parts) >= 4
    frames = sum(1 for _ in read_frames(parts))
    assert frames == sum(1 for _ in read_frames(whole))
    shell_order = sorted(str(p) for p in parts)  # what run*.log expands to
    code, out, err = run_cli("solve", *shell_order, "--latitude", "34", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["source"]["parts"] == [str(p) for p in parts]
    assert doc["azimuth_deg"] == pytest.approx(found["azimuth_deg"], abs=1e-9)
    assert err == ""
    # A quoted glob is expanded and ordered the same way.
    code, out, _ = run_cli("solve", str(parted.with_name("run*.log")), "--latitude", "34", "--json")
    assert code == 0 and json.loads(out)["azimuth_deg"] == doc["azimuth_deg"]


def test_a_part_left_out_is_reported_and_its_window_left_out(rotated):
    _, parted, _ = rotated
    parts = _set(parted)
    session = read_can_log(parts)
    # The first part wholly inside a window: leaving it out costs that window.
    middle = next(
        i for i in range(1, len(parts) - 1)
        if read_can_log(parts[:i] + parts[i + 1 :], min_windows=1).incomplete_windows
    )  # fmt: skip
    kept = parts[:middle] + parts[middle + 1 :]
    gapped = read_can_log(kept, min_windows=1)
    assert len(gapped.part_gaps) == 2  # the missing name, and the counter's jump
    assert f"part #{middle:03d} of" in gapped.part_gaps[0]
    assert "sample counter jumps" in gapped.part_gaps[1]
    # The window the gap cuts into, and the next (its command may be among the missing frames).
    assert 1 <= len(gapped.incomplete_windows) <= 2
    assert any("frames missing between" in note for note in gapped.incomplete)
    assert len(gapped.windows) <= len(session.windows)
    code, out, err = run_cli("solve", *map(str, kept), "--latitude", "34", "--strict")
    assert code == 1 and out == "" and "frames missing between" in err
    assert len(err.splitlines()) == 1
    code, out, err = run_cli("dump", *map(str, kept))
    assert code == 0 and "frames missing between" in err


def test_dump_reads_the_parts_in_order(rotated):
    whole, parted, _ = rotated
    code, out, err = run_cli("dump", *sorted(map(str, _set(parted))))
    assert code == 0 and err == ""
    code, reference, _ = run_cli("dump", str(whole))
    strip = [line.split(" ", 1)[1] for line in reference.splitlines()]
    assert [line.split(" ", 1)[1] for line in out.splitlines()] == strip


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--can-log-rotate", "1M"], "--can-log-rotate: rotates a log; give --can-log FILE"),
        (["--can-log", "{d}/x.db", "--can-log-rotate", "1h"], "the formats python-can rotates"),
        (["--can-log", "{d}/old.log", "--can-log-rotate", "1M"], "an earlier rotated log"),
        (["--can-log", "{d}/x.log", "--can-log-rotate", "12B"], "a size must be 4K to 1T"),
        (["--can-log", "{d}/x.log", "--can-log-rotate", "10m"], "a size (10M, 1G), an age"),
        (["--can-log", "{d}/x.log", "--can-log-rotate", "4096"], "a size (10M, 1G), an age"),
        (["--can-log", "{d}/x.log", "--can-log-rotate", "0.5s"], "an age must be 1s to 366d"),
        (["--can-log", "{d}/x.log", "--can-log-rotate", "1M,2M"], "or one of each"),
    ],
)
def test_a_rotation_that_cannot_be_done_is_refused_before_any_work(tmp_path, argv, says):
    part_name(tmp_path / "old.log", 0).write_text("")
    argv = [a.format(d=tmp_path) for a in argv]
    code, out, err = run_cli(*FIND, "--latitude", "34", *argv)
    assert code == 2 and out == "" and says in err, err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "x.log").exists()


def test_sim_refuses_a_rotation_without_a_log_before_it_starts():
    code, out, err = run_cli("sim", "--pty", "--log-rotate", "60s")
    assert code == 2 and out == "" and "--log-rotate: rotates a log; give --log FILE" in err


@pytest.mark.parametrize(
    ("text", "limits"),
    [("10M", (10 << 20, 0.0)), ("1h", (0, 3600.0)), ("64KiB,90s", (64 << 10, 90.0)),
     ("15min", (0, 900.0)), ("8192B", (8192, 0.0)), ("1G, 2d", (1 << 30, 172_800.0))],
)  # fmt: skip
def test_a_rotation_is_a_size_an_age_or_both(text, limits):
    from northfinder.cli.files import rotation_limits

    assert rotation_limits(text) == limits


@pytest.mark.subprocess
@pytest.mark.realtime
def test_sim_log_rotated_by_age_on_a_serial_pty_solves_as_the_run_found(tmp_path):
    """``northfinder sim --pty --log X.asc --log-rotate 1s``: ASC parts of a second of wall time
    each (each file's times from its own start), read in order by their absolute times."""
    from simprocess import sim_process

    log = tmp_path / "serial.asc"
    args = ["--pty", "--warmup", "0", "--speed", "10", "--seed", "4", "--azimuth", "123"]
    with sim_process(*args, "--log", str(log), "--log-rotate", "1s", wanted={"pty"}) as facts:
        found = run_json(
            "find", "--serial", facts["pty"], "--latitude", "34", "--window", "2",
            "--positions", "0,180",  # one move and two settles: 5 s of wall time at speed 10
            "--reply-timeout", "2", "--link-timeout", "3",
        )  # fmt: skip
    parts = _set(log)
    assert len(parts) >= 2
    for part in parts:
        assert part.read_text().rstrip().endswith("End TriggerBlock")  # each closed whole
    solved = run_json("solve", *map(str, parts), "--latitude", "34", "--window", "2")
    assert solved["azimuth_deg"] == pytest.approx(found["azimuth_deg"], abs=1e-9)
