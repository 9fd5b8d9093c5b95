"""A paced simulator never falls behind silently: after a stall it reports its lag, logs it, slips
its clock and goes on at its pace (protocol.md 12), never sending its backlog in a burst.

The logic runs on an injected wall clock (exact); one test stops a ``northfinder sim`` process for
a second (SIGSTOP, as a starved process is) and reads its stream on the wall clock (``realtime``).
"""

from __future__ import annotations

import logging
import os
import re
import signal
import time

import numpy as np
import pytest
import serial
from simprocess import sim_process

from northfinder.driver.protocol.messages import Sample, StreamStart
from northfinder.driver.protocol.serial import Deframer, SerialEncoder
from northfinder.firmware_sim.control import ControlClient, Controller
from northfinder.firmware_sim.firmware import Firmware
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.runner import MAX_LAG_WALL_S, RealTimeClock, Runner
from northfinder.firmware_sim.sensors import load_spec


class FakeWall:
    """A wall clock the test moves."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Recorder:
    """A link that notes the fake wall time at which each sample leaves."""

    def __init__(self, wall: FakeWall) -> None:
        self.wall = wall
        self.sent: list[float] = []

    def poll(self, timeout: float) -> int:
        return 0

    def send(self, outgoing) -> None:
        self.sent += [self.wall.t for o in outgoing if isinstance(o.message, Sample)]


def paced(speed: float) -> tuple[Runner, FakeWall, Recorder]:
    wall = FakeWall()
    firmware = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(1), warmup_s=0.0)
    recorder = Recorder(wall)
    runner = Runner(firmware, recorder, RealTimeClock(speed, monotonic=wall))
    run_for(runner, wall, 0.6 / speed)  # past BOOT
    firmware.handle(StreamStart(1))
    return runner, wall, recorder


def run_for(runner: Runner, wall: FakeWall, seconds: float, step: float = 0.001) -> None:
    end = wall.t + seconds
    while wall.t < end - 1e-12:
        wall.t += step
        runner.step()


@pytest.mark.parametrize("speed", [1.0, 10.0])
def test_after_a_stall_the_runner_slips_reports_and_keeps_its_pace(speed, caplog):
    runner, wall, link = paced(speed)
    rate = 200.0 * speed  # samples per wall second at this pace
    run_for(runner, wall, 1.0)
    assert runner.lag.slips == 0 and runner.lag.slipped_s == 0.0
    before = len(link.sent)
    assert before == pytest.approx(rate * 1.0, abs=3)  # on pace
    wall.t += 2.0  # the process stalls for 2 s of wall time
    with caplog.at_level(logging.WARNING, logger="northfinder.sim.runner"):
        run_for(runner, wall, 1.0)
    lag = runner.lag
    assert lag.slips == 1 and lag.last_slip_s == pytest.approx(2.0 * speed, abs=0.01 * speed)
    assert lag.slipped_s == lag.last_slip_s and lag.behind_s < MAX_LAG_WALL_S * speed
    assert any("fell behind its clock" in r.getMessage() for r in caplog.records)
    after = np.array(link.sent[before:])
    # no burst: in the first 0.1 s after the stall at most its pace and one step's worth
    first = np.count_nonzero(after < after[0] + 0.1)
    assert first <= rate * 0.1 + rate * 0.001 + 2
    # and the second after the stall is at the pace again
    assert len(after) == pytest.approx(rate * 1.0, rel=0.02)
    # the device's own time lost the stall: counters continuous, simulated time behind the clock
    assert runner.firmware.now == pytest.approx(runner.clock.now(), abs=0.01 * speed)


def test_a_short_delay_is_caught_up_and_not_counted_as_a_slip():
    runner, wall, link = paced(1.0)
    run_for(runner, wall, 0.5)
    wall.t += MAX_LAG_WALL_S * 0.5  # a scheduling delay within the limit
    run_for(runner, wall, 0.5)
    assert runner.lag.slips == 0
    assert len(link.sent) == pytest.approx(200.0 * (1.0 + MAX_LAG_WALL_S * 0.5), abs=3)


def test_the_control_channel_reports_the_lag():
    runner, wall, _ = paced(5.0)
    run_for(runner, wall, 0.2)
    wall.t += 1.0
    run_for(runner, wall, 0.2)
    status = Controller(runner).handle({"op": "status"})
    assert status["ok"] and status["clock"] == "paced" and status["speed"] == 5.0
    assert status["lag"]["slips"] == 1 and status["lag"]["slipped_s"] == pytest.approx(5.0, 0.01)


@pytest.mark.realtime
@pytest.mark.subprocess
@pytest.mark.parametrize(
    "sender, stopped",
    [("loop", "simulator"), ("process", "simulator"), ("process", "sender")],
    ids=["loop", "process-simulator-stalled", "process-sender-stalled"],
)
def test_a_starved_sim_process_reports_its_lag_and_streams_at_its_pace_after(sender, stopped):
    """The simulator (or, with ``--paced-sender``, its sender process) gets no CPU for half a
    second (ten times the 50 ms it may fall behind before it slips): the lag is reported, and the
    stream goes on at its pace."""
    speed, stall_s, after_s = 2.0, 0.5, 1.0
    args = ["--pty", "--warmup", "0", "--seed", "4", "--speed", str(speed)]
    if sender == "process":
        args.append("--paced-sender")
    with sim_process(*args, "--control", "127.0.0.1:0", ready=True) as facts:
        with (
            serial.Serial(facts["pty"], 115200, timeout=0.05) as port,
            ControlClient(facts["control"]) as ctl,
        ):
            deframer = Deframer()
            port.write(SerialEncoder().encode(StreamStart(1)))
            time.sleep(0.2)
            status = ctl.call("status")
            before = status["lag"]
            assert status["sender"]["kind"] == sender
            pid = int(facts["pid"]) if stopped == "simulator" else status["sender"]["pid"]
            os.kill(pid, signal.SIGSTOP)
            time.sleep(stall_s)  # starved: no CPU at all
            port.reset_input_buffer()
            os.kill(pid, signal.SIGCONT)
            arrivals: list[float] = []
            end = time.monotonic() + after_s
            while time.monotonic() < end:
                got = deframer.feed_messages(port.read(4096))
                now = time.monotonic()
                arrivals += [now for m in got if isinstance(m, Sample)]
            lag = ctl.call("status")["lag"]
    assert lag["slips"] >= before["slips"] + 1
    assert lag["slipped_s"] - before["slipped_s"] >= 0.8 * stall_s * speed  # about what it lost
    # Its last words on stopping give the totals (scripts/hil.d/rehearsal.py reads them).
    last = re.search(
        r"stopped at t=[0-9.]+ s; fell behind its clock (\d+) time\(s\), ([0-9.]+) s of "
        r"simulated time lost", facts["stderr"],
    )  # fmt: skip
    assert last, facts["stderr"][-500:]
    assert int(last[1]) >= lag["slips"] and float(last[2]) >= lag["slipped_s"] - 1e-3
    t = np.array(arrivals)
    assert len(t) > 0
    # No burst after the stall: in any 0.25 s at most the pace plus scheduling slack (a backlog of
    # the lost half second would put 200 samples in the first moment), and on average the pace.
    rate = 200.0 * speed
    worst = max(np.count_nonzero((t >= a) & (t < a + 0.25)) for a in t)
    assert worst <= rate * 0.25 * 1.6 + 20
    assert len(t) / after_s == pytest.approx(rate, rel=0.25)
