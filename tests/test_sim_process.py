"""``northfinder sim`` as a real subprocess, reached over a pseudo-terminal with pyserial and with
python-can's own ``slcan`` interface; and its behaviour under random input."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import can
import numpy as np
import pytest
import serial
from simprocess import sim_process

from northfinder.driver.protocol.can import CanReceiver, TickLoss, encode_can
from northfinder.driver.protocol.constants import Opcode, Result, SerialType
from northfinder.driver.protocol.messages import (
    GetStatus,
    Identify,
    Reply,
    RequestIdentify,
    Sample,
    Status,
    StreamStart,
)
from northfinder.driver.protocol.serial import Deframer, SerialEncoder, SerialFrame
from northfinder.firmware_sim.control import ControlClient

pytestmark = pytest.mark.subprocess


@contextmanager
def simulator(*link: str, seed: int = 1) -> Iterator[tuple[str, str]]:
    """Start ``northfinder sim`` on a new pty; yield (pty path, control address) once the device
    is READY; always stop it."""
    args = ("--warmup", "0", "--seed", str(seed), "--control", "127.0.0.1:0")
    with sim_process(*link, *args, ready=True) as f:
        yield f["pty"], f["control"]


def enough(replies: set[int], samples: int = 0) -> Callable[[list], bool]:
    """Whether the messages read so far hold OK replies to ``replies`` and more than ``samples``
    samples: what a read waits for (at most its seconds) before it returns."""

    def seen(got: list) -> bool:
        ok = {m.seq for m in got if isinstance(m, Reply) and m.ok}
        return replies <= ok and sum(isinstance(m, Sample) for m in got) > samples

    return seen


def read_serial(
    port: serial.Serial,
    deframer: Deframer,
    seconds: float,
    until: Callable[[list], bool] | None = None,
) -> list:
    """Messages read for ``seconds``, or until ``until`` holds of them."""
    out: list = []
    end = time.monotonic() + seconds
    while time.monotonic() < end and not (until is not None and until(out)):
        out += deframer.feed_messages(port.read(4096))
    return out


@pytest.mark.realtime
def test_serial_pty_subprocess_identifies_streams_and_answers():
    with simulator("--pty") as (path, control):
        with serial.Serial(path, 115200, timeout=0.05) as port:
            enc, de = SerialEncoder(), Deframer()
            port.reset_input_buffer()
            port.write(enc.encode(RequestIdentify(1)) + enc.encode(StreamStart(2)))
            got = read_serial(port, de, 5.0, until=enough({1, 2}, 300))
            port.write(enc.encode(GetStatus(3)))
            got += read_serial(port, de, 2.0, until=enough({3}))
        replies = {m.seq: m for m in got if isinstance(m, Reply)}
        assert {1, 2, 3} <= set(replies) and all(replies[k].ok for k in (1, 2, 3))
        assert any(isinstance(m, Identify) and m.model == "NF-SIM" for m in got)
        counters = np.array([m.counter for m in got if isinstance(m, Sample)])
        assert len(counters) > 300 and np.all(np.diff(counters) == 1)
        assert de.crc_errors == 0 and de.lost_frames == 0
        with ControlClient(control) as ctl:
            assert ctl.call("status")["state"] == "READY"


def can_send(bus: can.BusABC, message) -> None:
    for frame in encode_can(message, 1):
        bus.send(
            can.Message(arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False)
        )


def read_can(
    bus: can.BusABC, rx: CanReceiver, seconds: float, until: Callable[[list], bool] | None = None
) -> list:
    """Messages read for ``seconds``, or until ``until`` holds of them."""
    out: list = []
    end = time.monotonic() + seconds
    while time.monotonic() < end and not (until is not None and until(out)):
        msg = bus.recv(0.05)
        if msg is not None:
            out += rx.feed(msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id)
    return out


@pytest.mark.realtime
def test_slcan_pty_subprocess_reached_with_python_can():
    with simulator("--slcan-pty") as (path, _control):
        with can.Bus(interface="slcan", channel=path, sleep_after_open=0, bitrate=500_000) as bus:
            rx = CanReceiver(node_id=1)
            can_send(bus, RequestIdentify(1))
            can_send(bus, StreamStart(2))
            got = read_can(bus, rx, 5.0, until=enough({1, 2}, 300))
        assert any(isinstance(m, Identify) for m in got)
        assert {m.seq for m in got if isinstance(m, Reply) and m.ok} >= {1, 2}
        samples = [m for m in got if isinstance(m, Sample)]
        assert len(samples) > 300
        assert not [m for m in got if isinstance(m, TickLoss)]
        assert np.all(np.diff([s.counter for s in samples]) == 1)


@pytest.mark.realtime
def test_random_bytes_on_serial_do_not_disturb_the_stream():
    rng = np.random.default_rng(7)
    with simulator("--pty", seed=4) as (path, control):
        with serial.Serial(path, 115200, timeout=0.02) as port:
            enc, de = SerialEncoder(), Deframer()
            port.reset_input_buffer()
            port.write(enc.encode(StreamStart(1)))
            got = read_serial(port, de, 0.3)
            for i in range(40):
                junk = rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes()
                if i % 4 == 0:  # a well-framed command with an undefined opcode: must be refused
                    junk += SerialFrame(
                        SerialType.COMMAND, 200 + i, bytes((100 + i, 0x7E))
                    ).encode()
                port.write(junk)
                got += read_serial(port, de, 0.05)
            port.write(enc.encode(GetStatus(99)))
            have = sum(isinstance(m, Sample) for m in got)
            got += read_serial(port, de, 2.0, until=enough({99}, 400 - have))
        counters = np.array([m.counter for m in got if isinstance(m, Sample)])
        assert len(counters) > 400 and np.all(np.diff(counters) == 1), "the stream has a gap"
        refused = [m for m in got if isinstance(m, Reply) and m.result == Result.UNKNOWN_COMMAND]
        assert len(refused) == 10
        status = [m for m in got if isinstance(m, Status)][-1]
        assert status.rx_malformed > 0
        assert any(isinstance(m, Reply) and m.seq == 99 and m.ok for m in got), (
            "no answer after the junk"
        )
        with ControlClient(control) as ctl:
            assert ctl.call("status")["rx_malformed"] >= 10


@pytest.mark.realtime
def test_random_can_frames_do_not_disturb_the_stream():
    rng = np.random.default_rng(11)
    with simulator("--slcan-pty", seed=5) as (path, control):
        with can.Bus(interface="slcan", channel=path, sleep_after_open=0) as bus:
            rx = CanReceiver(node_id=1)
            can_send(bus, StreamStart(1))
            got = read_can(bus, rx, 0.3)
            sent_bad = 0
            for _ in range(150):
                arb = int(rng.integers(0, 0x800))
                data = rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes()
                if arb == 0x041:
                    continue  # a random frame could be a real command; those are sent below
                bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
            for seq in range(20):  # undefined opcodes and wrong lengths on our command id
                bad = (
                    bytes((seq, 0x70 + seq % 8))
                    if seq % 2
                    else bytes((seq, Opcode.ROTATE_TO, 1, 2))
                )
                bus.send(can.Message(arbitration_id=0x041, data=bad, is_extended_id=False))
                sent_bad += 1
            got += read_can(bus, rx, 1.0)
            can_send(bus, GetStatus(77))
            have = sum(isinstance(m, Sample) for m in got)
            got += read_can(bus, rx, 2.0, until=enough({77}, 250 - have))
        samples = [m for m in got if isinstance(m, Sample)]
        assert len(samples) > 250
        assert not [m for m in got if isinstance(m, TickLoss)], "the stream has a gap"
        assert np.all(np.diff([s.counter for s in samples]) == 1)
        answers = [m for m in got if isinstance(m, Reply) and m.seq < 20 and m.result != Result.OK]
        assert len(answers) == sent_bad
        assert any(isinstance(m, Reply) and m.seq == 77 and m.ok for m in got)
        with ControlClient(control) as ctl:
            assert ctl.call("status")["rx_malformed"] >= sent_bad


def test_sim_refuses_bad_arguments_with_one_clear_line():
    env = dict(os.environ)
    for args, text in (
        (["--pty", "--serial", "/dev/null"], "choose exactly one link"),
        (["--pty", "--sensor", "nope"], "unknown sensor preset 'nope'"),
        (["--pty", "--latitude", "90"], "too close to a pole"),
        (["--pty", "--control", "10.1.2.3:5"], "only loopback addresses"),
        (["--pty", "--node-id", "0"], "--node-id"),
    ):
        res = subprocess.run(
            [
                sys.executable,
                "-c",
                "from northfinder.cli import main; raise SystemExit(main())",
                "sim",
                *args,
            ],
            capture_output=True,
            text=True,
            timeout=30,
            env=env,
        )
        assert res.returncode != 0
        assert text in res.stderr and "Traceback" not in res.stderr, res.stderr


@pytest.mark.parametrize("control", ["0", "127.0.0.1:0"])
def test_sim_control_port_0_picks_a_free_port_and_prints_it(control):
    """``--control 0`` (docs/cli.md): any free port on loopback, printed as ``control ADDRESS``."""
    import re

    with sim_process("--pty", "--warmup", "0", "--control", control) as facts:
        m = re.fullmatch(r"(127\.0\.0\.1|\[::1\]):(\d+)", facts["control"])
        assert m is not None, facts["control"]
        assert int(m.group(2)) > 0
        with ControlClient(facts["control"]) as ctl:
            assert "state" in ctl.call("status")
