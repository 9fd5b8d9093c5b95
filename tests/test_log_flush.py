"""A CAN log is readable while it is written: a reader of the file sees every frame up to the
last flush, and the simulator flushes its log as each reply goes out, so a log read after a
host's last reply holds that host's session whole (docs/walkthrough.md reads the simulator's log
while it runs)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import can
import pytest
from lockstep import make

from northfinder.driver.errors import ArgumentError
from northfinder.driver.framelog import FrameLog
from northfinder.driver.protocol import GetStatus, Reply, StreamStart
from northfinder.driver.protocol.can import CanReceiver, encode_can, split_can_id
from northfinder.driver.protocol.constants import CanFunction
from northfinder.driver.protocol.serial import Deframer, SerialEncoder
from northfinder.firmware_sim.adapters import CanLink, PseudoTerminal, SerialLink
from northfinder.firmware_sim.runner import LockstepClock, Runner

#: The formats read back while open (``.log.gz`` and ``.mf4`` are whole only when closed; a
#: gzip stream is flushed, but a reader wants its end marker).
READABLE_OPEN = (".log", ".asc", ".csv", ".blf", ".trc")


def _frames(n: int) -> list[can.Message]:
    return [
        can.Message(
            timestamp=1_700_000_000.0 + k / 100,
            arbitration_id=0x100 + k % 7,
            data=bytes([k % 256, 1, 2, 3]),
            is_extended_id=False,
        )
        for k in range(n)
    ]


def _on_disk(path: Path) -> list[tuple[int, bytes]]:
    """The frames a separate reader of ``path`` finds now (ids and data; none where the file
    does not yet hold a whole header, as a BLF file before its first write)."""
    got: list[tuple[int, bytes]] = []
    try:
        for m in can.LogReader(str(path)):
            got.append((m.arbitration_id, bytes(m.data)))
    except struct.error:
        pass
    return got


def _replies_on_disk(path: Path) -> set[int]:
    """The sequence numbers of the replies in the file now."""
    rx = CanReceiver(node_id=1)
    got = [m for frame in _on_disk(path) for m in rx.feed(*frame)]
    return {m.seq for m in got if isinstance(m, Reply)}


@pytest.mark.parametrize("suffix", READABLE_OPEN)
def test_flush_puts_every_frame_logged_so_far_in_the_file(tmp_path, suffix):
    path = tmp_path / f"open{suffix}"
    sent = _frames(50)
    log = FrameLog(path, flush_s=3600.0)
    try:
        for msg in sent:
            log(msg)
        assert len(_on_disk(path)) < len(sent)  # buffered: what the flush is for
        log.flush()
        assert _on_disk(path) == [(m.arbitration_id, bytes(m.data)) for m in sent]
    finally:
        log.close()
    assert _on_disk(path) == [(m.arbitration_id, bytes(m.data)) for m in sent]


def test_a_log_flushed_with_every_frame_needs_no_flush_call(tmp_path):
    path = tmp_path / "each.log"
    with FrameLog(path, flush_s=0.0) as log:
        for k, msg in enumerate(_frames(20), 1):
            log(msg)
            assert len(_on_disk(path)) == k


def test_a_negative_flush_interval_is_refused(tmp_path):
    with pytest.raises(ArgumentError, match="flush interval"):
        FrameLog(tmp_path / "x.log", flush_s=-1.0)


class _Counted(FrameLog):
    """A log that counts its flushes."""

    flushes = 0

    def flush(self) -> None:
        self.flushes += 1
        super().flush()


class _Watched:
    """A device end of a bus that reads the log from disk as each reply frame goes out."""

    def __init__(self, bus: can.BusABC, path: Path, log: FrameLog) -> None:
        self.bus, self.path, self.log = bus, path, log
        self.seen: list[tuple[int, int]] = []  # (frames on disk, frames logged) at each reply

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if split_can_id(msg.arbitration_id)[0] == CanFunction.REPLY:
            self.seen.append((len(_on_disk(self.path)), self.log.frames))
        self.bus.send(msg, timeout)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.bus.recv(timeout)


def test_the_simulator_on_can_flushes_its_log_as_it_answers_and_not_at_heartbeats(tmp_path):
    path = tmp_path / "sim.log"
    with (
        can.Bus(interface="virtual", channel="flush-can", receive_own_messages=False) as dev_bus,
        can.Bus(interface="virtual", channel="flush-can") as host,
        _Counted(path, flush_s=3600.0) as log,
    ):
        fw = make()
        clock = LockstepClock()
        device_end = _Watched(dev_bus, path, log)
        runner = Runner(fw, CanLink(device_end, fw, 1, tap=log), clock)
        rx = CanReceiver(node_id=1)
        received: list = []

        def advance(seconds: float) -> None:
            for _ in range(round(seconds / 0.01)):
                clock.advance(0.01)
                runner.step(0.0)
                while (msg := host.recv(0.0)) is not None:
                    received.extend(rx.feed(msg.arbitration_id, msg.data))

        advance(0.5)
        at_start = log.flushes  # the device's announcement of itself at power-on
        commands = (StreamStart(1), GetStatus(2))
        for seq, command in enumerate(commands, 1):
            for frame in encode_can(command, 1):
                host.send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                                      is_extended_id=False))  # fmt: skip
            advance(0.2)
            assert any(isinstance(m, Reply) and m.seq == seq for m in received)
            # The host has its reply: the file holds it (and the command and all before).
            assert seq in _replies_on_disk(path)
        # As each reply went out, the file already held every frame logged before it (the
        # command it answers among them).
        assert len(device_end.seen) == len(commands)
        assert all(on_disk == logged for on_disk, logged in device_end.seen)
        assert log.frames > 100  # the stream's samples were logged between the replies
        assert log.flushes == at_start + 2 * len(commands)
        advance(5.0)  # heartbeats and samples only: no flush of their own
        assert log.flushes == at_start + 2 * len(commands)


def test_the_simulator_on_serial_flushes_its_log_with_each_reply(tmp_path):
    path = tmp_path / "sim.log"
    pty = PseudoTerminal()
    host = os.open(pty.path, os.O_RDWR | os.O_NOCTTY)
    try:
        with FrameLog(path, flush_s=3600.0) as log:
            fw = make()
            clock = LockstepClock()
            runner = Runner(fw, SerialLink(pty.stream, fw, tap=log), clock)
            encoder, deframer = SerialEncoder(), Deframer()
            os.set_blocking(host, False)
            received: list = []

            def advance(seconds: float) -> None:
                for _ in range(round(seconds / 0.01)):
                    clock.advance(0.01)
                    runner.step(0.0)
                    try:
                        received.extend(deframer.feed_messages(os.read(host, 65536)))
                    except BlockingIOError:
                        pass

            advance(0.5)
            for seq, command in enumerate((StreamStart(1), GetStatus(2)), 1):
                os.write(host, encoder.encode(command))
                advance(0.2)
                assert any(isinstance(m, Reply) and m.seq == seq for m in received)
                assert seq in _replies_on_disk(path)
            assert log.frames > 100
    finally:
        os.close(host)
        pty.close()
