"""``northfinder dump`` on logs of any size and on what is not a log: memory bounded whatever the
log's length, ``--count`` reading no further than it needs, junk reported once with its count
(a log of nothing but junk: exit 2), a bad ``--dbc``, a folder or a FIFO named in one line, and
candump lines with their direction and the bus's channel."""

from __future__ import annotations

import io
import os
import tracemalloc
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import can
import pytest
from clirun import run_cli

from northfinder.cli import main
from northfinder.driver.protocol import Sample, Validity
from northfinder.driver.protocol.can import encode_can
from northfinder.driver.protocol.messages import GetStatus


def _frames(n: int, t0: float = 1_796_400_000.0) -> list[can.Message]:
    """``n`` frames of the 200 Hz stream (node 1); every 50th a host's GET_STATUS (sent)."""
    out: list[can.Message] = []
    k = 0
    while len(out) < n:
        s = Sample(k, (k, -k, 3 * k), (1, 2, 1_000_000), k * 1000, 2500, Validity(3))
        frames = [(f, True) for f in encode_can(s, 1)]
        if k % 50 == 0:
            frames.append((encode_can(GetStatus(k % 255 + 1), 1)[0], False))
        for f, rx in frames:
            out.append(
                can.Message(
                    arbitration_id=f.arbitration_id,
                    data=f.data,
                    is_extended_id=False,
                    timestamp=t0 + k / 200,
                    channel=0,
                    is_rx=rx,
                )
            )
        k += 1
    return out[:n]


def _write(path: Path, frames: list[can.Message]) -> Path:
    with can.Logger(str(path)) as writer:
        for msg in frames:
            writer.on_message_received(msg)
    return path


def _peak_bytes(argv: list[str]) -> int:
    """Peak memory Python allocated while ``northfinder ARGV`` ran in this process (its output
    thrown away as it is written)."""
    with open(os.devnull, "w") as sink, redirect_stdout(sink), redirect_stderr(io.StringIO()):
        tracemalloc.start()
        try:
            code = main(argv)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert code == 0
    return peak


# -- a log of any length in bounded memory ------------------------------------------------------
@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_dump_memory_does_not_grow_with_the_log(tmp_path, suffix):
    """Ten times the frames, the same peak: dump streams the log (it held all of it before)."""
    frames = _frames(60_000)
    small = _write(tmp_path / f"small{suffix}", frames[:6_000])
    large = _write(tmp_path / f"large{suffix}", frames)
    assert large.stat().st_size > 9 * small.stat().st_size
    # Every frame read, a few decoded and printed (COMMAND): the reading is what is measured.
    peak_small = _peak_bytes(["dump", str(small), "--id", "COMMAND"])
    peak_large = _peak_bytes(["dump", str(large), "--id", "COMMAND"])
    assert peak_large < 1.5 * peak_small + 256 * 1024, (peak_small, peak_large)
    assert peak_large < large.stat().st_size / 4
    # --count 5 reads five frames, not the log (which it held whole before).
    assert _peak_bytes(["dump", str(large), "--count", "5"]) < large.stat().st_size / 2


def test_dump_count_stops_reading_after_n_frames(tmp_path):
    """``--count 5`` stops where the fifth frame is: junk after it is never read."""
    log = _write(tmp_path / "run.log", _frames(2_000))
    with log.open("ab") as fh:
        fh.write(bytes(range(256)) * 400)  # binary junk after the frames
    code, out, err = run_cli("dump", str(log), "--count", "5")
    assert code == 0 and len(out.splitlines()) == 5 and err == ""
    code, out, err = run_cli("dump", str(log))
    assert code == 0 and len(out.splitlines()) == 2_000
    assert len(err.splitlines()) == 1 and "warning" in err and "damaged line(s)" in err


# -- junk: once, with a count --------------------------------------------------------------------
JUNK = bytes((i * 7919 + 13) % 256 for i in range(200_000))  # binary, a few line ends


@pytest.mark.parametrize("suffix", [".trc", ".asc", ".log", ".csv"])
def test_a_log_of_junk_is_one_line_and_exit_2(tmp_path, suffix, capfd):
    log = tmp_path / f"junk{suffix}"
    log.write_bytes((b"timestamp,arbitration_id,extended,remote,error,dlc,data\n" if suffix == ".csv"
                     else b"") + JUNK)  # fmt: skip
    code, out, err = run_cli("dump", str(log))
    logged = capfd.readouterr()  # python-can's loggers write to the real stderr
    assert code == 2 and out == ""
    assert len(err.splitlines()) == 1 and len(err) < 400, err
    assert f"{log}: not a CAN log python-can reads: no frame" in err
    assert "damaged line(s) skipped (first: line" in err
    assert logged.err == "" and logged.out == ""


@pytest.mark.parametrize("suffix", [".trc", ".asc"])
def test_junk_among_frames_is_counted_once(tmp_path, suffix, capfd):
    """python-can's TRC reader logs a warning a junk line and its ASC reader passes junk over in
    silence: both are counted, in one warning, and every frame is read."""
    frames = _frames(300)
    log = _write(tmp_path / f"run{suffix}", frames)
    lines = log.read_bytes().splitlines(keepends=True)
    junk_lines = [b"\x00\x9d\xffjunk\xfe\x01 line\n", b"\x80\x81\x82\n", b"!!\n"]
    mixed = tmp_path / f"mixed{suffix}"
    mixed.write_bytes(b"".join(lines[:-100] + junk_lines + lines[-100:]))
    code, out, err = run_cli("dump", str(mixed))
    assert capfd.readouterr().err == ""
    assert code == 0 and len(out.splitlines()) == 300
    assert err.count("\n") == 1 and "skipped 3 damaged line(s)" in err
    code, out, err = run_cli("dump", str(mixed), "--strict")
    assert code == 2 and "breaks off" in err and len(out.splitlines()) < 300


# -- what is not a DBC, not a log file -----------------------------------------------------------
@pytest.mark.parametrize(
    "content", [bytes(range(256)) * 8, b"VERSION \"\"\nBO_ nonsense\n", b"{}"],
    ids=["binary", "broken-dbc", "json"],
)  # fmt: skip
def test_a_dbc_that_is_not_one_is_named_in_one_line(tmp_path, content):
    log = _write(tmp_path / "run.log", _frames(10))
    dbc = tmp_path / "other.dbc"
    dbc.write_bytes(content)
    code, out, err = run_cli("dump", str(log), "--dbc", str(dbc))
    assert code == 2 and out == "" and len(err.splitlines()) == 1
    assert f"--dbc {dbc}: not a DBC cantools reads" in err and "internal error" not in err
    code, _, err = run_cli("dump", str(log), "--dbc", str(tmp_path))
    assert code == 2 and "a folder" in err
    code, _, err = run_cli("dump", str(log), "--dbc", str(tmp_path / "none.dbc"))
    assert code == 2 and "no such file" in err


def test_a_folder_or_fifo_given_as_the_log_is_named(tmp_path):
    folder = tmp_path / "logs.log"
    folder.mkdir()
    code, _, err = run_cli("dump", str(folder))
    assert code == 2 and f"{folder}: a folder, not a CAN log" in err
    fifo = tmp_path / "pipe.log"
    os.mkfifo(fifo)
    code, _, err = run_cli("dump", str(fifo))
    assert code == 2 and f"{fifo}: a FIFO, not a regular file" in err
    code, _, err = run_cli("dump", str(tmp_path / "missing.log"))
    assert code == 2 and "no such file" in err
    # solve reads the same logs: a FIFO is refused, not opened (that would wait for a writer).
    code, _, err = run_cli("solve", str(fifo), "--latitude", "34")
    assert code == 2 and f"{fifo}: a FIFO, not a regular file" in err
    code, _, err = run_cli("solve", str(folder), "--latitude", "34")
    assert code == 2 and f"{folder}: a folder, not a CAN log" in err
    csv_fifo = tmp_path / "pipe.csv"  # a recording or a python-can CSV: its header is not read
    os.mkfifo(csv_fifo)
    code, _, err = run_cli("solve", str(csv_fifo), "--latitude", "34")
    assert code == 2 and "not a regular file" in err


# -- candump lines: direction, channel, pipeable -------------------------------------------------
def test_dump_keeps_the_direction_and_raw_lines_read_back(tmp_path):
    frames = _frames(300)
    log = _write(tmp_path / "run.log", frames)
    code, out, _ = run_cli("dump", str(log))
    assert code == 0
    for line, msg in zip(out.splitlines(), frames, strict=True):
        head = line.split(" :: ")[0]
        assert head.endswith(" T" if not msg.is_rx else " R"), line
        assert head.split()[1] == "can0"
    assert sum(" T :: COMMAND(" in line for line in out.splitlines()) == 2
    # --raw: candump -L lines that python-can's reader and cantools' log parser read back.
    code, raw, _ = run_cli("dump", str(log), "--raw")
    assert code == 0
    assert raw == log.read_text()  # as python-can's candump writer wrote them
    again = tmp_path / "again.log"
    again.write_text(raw)
    with can.LogReader(str(again)) as reader:
        back = list(reader)
    assert [(m.arbitration_id, bytes(m.data), m.is_rx) for m in back] == [
        (m.arbitration_id, bytes(m.data), m.is_rx) for m in frames
    ]
    import cantools.logreader

    parsed = list(cantools.logreader.Parser(io.StringIO(raw)))
    assert [(f.frame_id, f.data) for f in parsed] == [
        (m.arbitration_id, bytes(m.data)) for m in frames
    ]


def test_a_live_slcan_bus_is_printed_with_its_channel(monkeypatch):
    """An SLCAN bus gives frames without a channel: the line names the channel given (-c)."""
    import northfinder.cli.dump as dump

    def slcan_loop(args):
        bus = can.Bus(interface="slcan", channel=args.channel)
        frame = encode_can(GetStatus(9), 1)[0]  # looped back by pyserial's loop://
        bus.send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                             is_extended_id=False))  # fmt: skip
        return bus

    monkeypatch.setattr(dump, "open_can_bus", slcan_loop)
    code, out, err = run_cli("dump", "-i", "slcan", "-c", "loop://", "--count", "1",
                             "--duration", "30")  # fmt: skip
    assert code == 0, err
    assert " loop:// 041#0902 R :: COMMAND(Seq: 9, Opcode: GET_STATUS)" in out


# -- a kernel without SocketCAN -------------------------------------------------------------------
def test_a_kernel_without_socketcan_gets_a_hint(monkeypatch):
    """``[Errno 97] Address family not supported by protocol`` alone does not say what to do."""
    import argparse
    import errno

    import can.cli

    from northfinder.driver.transport import bus_open_hint

    no_family = OSError(errno.EAFNOSUPPORT, os.strerror(errno.EAFNOSUPPORT))
    wrapped = argparse.ArgumentError(None, "cannot create bus")
    wrapped.__cause__ = no_family
    assert "this kernel has no SocketCAN" in bus_open_hint(no_family)
    assert "scripts/hil" in bus_open_hint(wrapped) and "--slcan-pty" in bus_open_hint(wrapped)
    assert bus_open_hint(OSError(errno.ENODEV, "No such device")) == ""  # vcan0 not set up

    def refuse(*_a, **_k):
        raise no_family

    monkeypatch.setattr(can.cli, "create_bus_from_namespace", refuse)
    code, _, err = run_cli("dump", "-i", "socketcan", "-c", "vcan0")
    assert code == 1 and len(err.splitlines()) == 1
    assert "Address family not supported" in err and "this kernel has no SocketCAN" in err
