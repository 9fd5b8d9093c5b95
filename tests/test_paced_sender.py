"""The paced sender (firmware_sim.runner.PacedSender): the runner's loop computes ahead, the
sender sends each message at its due time on the device's tick grid, in order, from a bounded
queue, and after a stall slips instead of bursting. Injected wall clock and sleep (exact).

The sender process (firmware_sim.sender.ProcessSender, firmware_sim/sender_child.py): its records,
one write per chunk in order, and what its reports do to the simulator; tests/test_pacing.py
stalls it on the wall clock."""

from __future__ import annotations

import errno
import socket
import threading
from collections import deque

import numpy as np
import pytest

from northfinder.driver.protocol.messages import Sample, StreamStart
from northfinder.firmware_sim import sender_child
from northfinder.firmware_sim.errors import SimError
from northfinder.firmware_sim.firmware import Firmware
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.runner import MAX_LAG_WALL_S, PacedSender, RealTimeClock, Runner
from northfinder.firmware_sim.sender import ProcessSender
from northfinder.firmware_sim.sensors import load_spec


class FakeWall:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += max(s, 1e-6)


class Recorder:
    def __init__(self, wall: FakeWall) -> None:
        self.wall = wall
        self.sent: list[tuple[float, float, object]] = []  # (wall, due time, message)

    def poll(self, timeout: float) -> int:
        return 0

    def send(self, outgoing) -> None:
        self.sent += [(self.wall.t, o.time_s, o.message) for o in outgoing]


def setup():
    wall = FakeWall()
    firmware = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(1), warmup_s=0.0)
    link = Recorder(wall)
    runner = Runner(firmware, link, RealTimeClock(1.0, monotonic=wall))
    sender = PacedSender(runner, sleep=wall.sleep, monotonic=wall, spin=lambda: wall.sleep(1e-5))
    return runner, sender, wall, link


def run_for(runner, sender, wall, seconds):
    end = wall.t + seconds
    while wall.t < end:
        runner.produce(sender)
        if not sender.send_next(idle=0.0):
            wall.t += 0.001


def samples(link):
    return [(w, due, m) for w, due, m in link.sent if isinstance(m, Sample)]


def test_messages_leave_in_order_at_their_due_times_on_the_tick_grid():
    runner, sender, wall, link = setup()
    run_for(runner, sender, wall, 0.6)
    runner.firmware.handle(StreamStart(1))
    run_for(runner, sender, wall, 1.0)
    s = samples(link)
    assert len(s) == pytest.approx(200, abs=3)
    sent_at = np.array([w for w, _, _ in s])
    due = np.array([d for _, d, _ in s])
    # never before its due time, and within one spin of it
    assert np.all(sent_at >= due - 1e-9)
    assert np.all(sent_at - due < PacedSender.SPIN_S + 2e-6)
    # deadlines are the tick grid (5 ms), not the previous send plus a period
    assert np.allclose(np.diff(due), 0.005, atol=1e-9)
    counters = [m.counter for _, _, m in s]
    assert counters == list(range(counters[0], counters[0] + len(counters)))
    times = [d for _, d, _ in link.sent]
    assert times == sorted(times)  # replies, statuses and samples in one time order


def test_the_queue_is_bounded_and_leads_the_clock_by_little():
    runner, sender, wall, _link = setup()
    run_for(runner, sender, wall, 0.6)
    runner.firmware.handle(StreamStart(1))
    runner.produce(sender)
    assert 0 < sender.queued <= Runner.MAX_QUEUED
    lead = runner.firmware.now - runner.clock.now()
    assert 0 <= lead <= Runner.LEAD_WALL_S + 1e-9
    runner.clock.set_speed(1000.0)  # a fast pace: the queue, not the lead, bounds it
    runner.produce(sender)
    assert sender.queued <= Runner.MAX_QUEUED + 60  # one step's output past the bound at most


def test_after_a_stall_the_sender_slips_and_does_not_burst():
    runner, sender, wall, link = setup()
    run_for(runner, sender, wall, 0.6)
    runner.firmware.handle(StreamStart(1))
    run_for(runner, sender, wall, 0.5)
    before = len(samples(link))
    runner.produce(sender)
    wall.t += 1.0  # the process stalls with output queued
    run_for(runner, sender, wall, 0.5)
    assert runner.lag.slips >= 1 and runner.lag.slipped_s == pytest.approx(1.0, abs=0.05)
    after = np.array([w for w, _, _ in samples(link)[before:]])
    assert np.count_nonzero(after < after[0] + 0.05) <= 0.05 * 200 + 2  # its pace, no burst
    assert len(after) == pytest.approx(100, abs=3)
    counters = [m.counter for _, _, m in samples(link)]
    assert np.all(np.diff(counters) == 1)  # nothing dropped


def test_a_short_delay_is_caught_up_without_a_slip():
    runner, sender, wall, _link = setup()
    run_for(runner, sender, wall, 0.6)
    runner.firmware.handle(StreamStart(1))
    run_for(runner, sender, wall, 0.3)
    wall.t += MAX_LAG_WALL_S * 0.5
    run_for(runner, sender, wall, 0.3)
    assert runner.lag.slips == 0


def test_paused_clock_holds_queued_output_and_stop_cleans_up():
    runner, sender, wall, link = setup()
    run_for(runner, sender, wall, 0.6)
    runner.firmware.handle(StreamStart(1))
    runner.produce(sender)
    n = len(link.sent)
    runner.pause()
    sender.start()
    threading.Event().wait(0.05)  # the thread waits on the paused clock (fake wall moves by sleeps)
    assert len(link.sent) == n
    sender.stop()
    assert not sender._thread.is_alive() and sender.queued == 0


@pytest.mark.realtime
def test_a_runner_with_its_sender_streams_at_its_pace_on_the_wall_clock():
    wall_link: list[float] = []
    import time

    class Link:
        def poll(self, timeout: float) -> int:
            time.sleep(timeout)
            return 0

        def send(self, outgoing) -> None:
            wall_link.extend(time.monotonic() for o in outgoing if isinstance(o.message, Sample))

    firmware = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(1), warmup_s=0.0)
    firmware.process(0.6)
    firmware.handle(StreamStart(1))
    clock = RealTimeClock(1.0)
    clock.slip(-0.6)  # the clock at the firmware's time
    runner = Runner(firmware, Link(), clock)
    runner.paced_sender = True
    stop = threading.Event()
    t = threading.Thread(target=runner.run, args=(stop,))
    t.start()
    time.sleep(2.0)
    stop.set()
    t.join(5.0)
    assert not t.is_alive()
    iv = np.diff(wall_link)
    assert len(wall_link) == pytest.approx(400, rel=0.15)
    assert np.median(np.abs(iv - 0.005)) < 0.002


# -- the sender process ------------------------------------------------------------------------


def test_the_sender_process_reads_records_in_any_pieces():
    record = [
        sender_child.HEADER.pack(10, 0, 2),
        sender_child.LENGTH.pack(3),
        b"abc",
        sender_child.LENGTH.pack(0),
    ]
    data = (
        b"".join(record) + sender_child.HEADER.pack(20, 1, 1) + sender_child.LENGTH.pack(1) + b"z"
    )
    for cut in range(len(data) + 1):
        buf, out = bytearray(data[:cut]), deque[tuple[int, int, list[bytes]]]()
        assert sender_child.parse(buf, out)
        buf += data[cut:]
        assert sender_child.parse(buf, out)
        assert list(out) == [(10, 0, [b"abc", b""]), (20, 1, [b"z"])] and not buf
    assert not sender_child.parse(bytearray(sender_child.HEADER.pack(-1, 0, 0)), deque())  # stop


@pytest.mark.subprocess
def test_the_sender_process_writes_each_chunk_in_order_and_reports_its_class():
    """Each chunk is one write (a datagram socket keeps the boundaries, as a CAN socket keeps its
    frames), in order. The records are due at the monotonic clock's origin, long past: the first
    slips (reported before anything is written) and the rest follow it at their spacing."""
    here, there = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    sender = ProcessSender(there.fileno(), priority=0)
    try:
        for k in range(50):
            sender.put(k * 1e-4, [b"%d" % k, b"again %d" % k])
        here.settimeout(60.0)  # a bound for a hang, not a measure
        got = [here.recv(100) for _ in range(100)]
        assert got == [c for k in range(50) for c in (b"%d" % k, b"again %d" % k)]
        # nothing dropped or failed (a machine busy enough to delay it may make it slip again)
        kinds = [kind for kind, _ in sender.reports()]
        assert kinds[0] == sender_child.SCHEDULING and sender_child.SLIP in kinds
        assert set(kinds) == {sender_child.SCHEDULING, sender_child.SLIP}
        assert sender.priority == 0 and sender.alive
    finally:
        sender.close()
        here.close()
        there.close()
    assert not sender.alive
    with pytest.raises(SimError):
        ProcessSender(there.fileno(), priority=100)


def test_a_runner_with_a_sender_process_slips_with_it_and_counts_what_it_dropped():
    """The sender's reports reach the simulator: a slip moves its clock back (and later records
    carry the new epoch), dropped chunks count in tx_dropped, a failed link stops it."""

    class Reporting:
        def __init__(self, reports):
            self._reports, self.epoch, self.alive = list(reports), 0, True
            self.returncode: int | None = None

        def reports(self):
            out, self._reports = self._reports, []
            return out

    wall = FakeWall()
    firmware = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(1), warmup_s=0.0)
    clock = RealTimeClock(1.0, monotonic=wall)
    runner = Runner(firmware, Recorder(wall), clock)
    sender = Reporting([(sender_child.SLIP, 250_000_000), (sender_child.DROPPED, 3)])
    wall.t = 1.0
    runner._take_reports(sender, clock)  # type: ignore[arg-type]
    assert clock.now() == pytest.approx(0.75)
    assert runner.lag.slips == 1 and runner.lag.slipped_s == pytest.approx(0.25)
    assert sender.epoch == 1 and firmware.tx_dropped == 3
    sender = Reporting([(sender_child.FAILED, errno.EIO)])
    with pytest.raises(SimError, match="Input/output error"):
        runner._take_reports(sender, clock)  # type: ignore[arg-type]
    sender = Reporting([])
    sender.alive, sender.returncode = False, -9
    with pytest.raises(SimError, match=r"ended \(killed by signal 9"):
        runner._take_reports(sender, clock)  # type: ignore[arg-type]
