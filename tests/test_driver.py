"""The host driver against the simulated instrument on every link: each call, the 2000-sample
window, and the faults the simulator's control channel injects (nothing may hang).

On the ``virtual`` link the simulator and the driver share a virtual clock: every duration below is
exact there. The links to a simulator in another process run on the wall clock (marked
``realtime``) with margins that hold on a loaded machine."""

from __future__ import annotations

import math
import threading
from typing import Any

import can
import numpy as np
import pytest
from conftest import link_params

import northfinder.driver.protocol.errors
from northfinder.driver.clock import VirtualClock
from northfinder.driver.conformance.errors import ConformanceError
from northfinder.driver.device import Device, Window
from northfinder.driver.errors import (
    ArgumentError,
    DeviceFault,
    DeviceRefused,
    DeviceReset,
    DriverError,
    EmptyWindow,
    EncodeError,
    LinkError,
    LinkLost,
    ProtocolError,
    ReplyTimeout,
    StreamGap,
)
from northfinder.driver.protocol.can import TickAssembler, TickLoss
from northfinder.driver.protocol.constants import (
    ConfigKey,
    DeviceState,
    Fault,
    Opcode,
    Result,
    Validity,
)
from northfinder.driver.protocol.messages import Sample, SampleAux, SampleX, SampleY, SampleZ

G_34N = 9.7966  # normal gravity at 34 deg N, m/s^2
#: The driver's logic, which is the same on every link: in virtual time only.
#: Slack for a duration on a virtual clock: its deadlines are whole nanoseconds (rounded up, so
#: each deadline in a chain of events may add one), and a difference of two clock readings in
#: seconds carries a float's rounding. Ten nanoseconds against the milliseconds judged.
NS = 1e-8
VIRTUAL_ONLY = pytest.mark.parametrize("sim", link_params(("virtual",)), indirect=True)


def within(sim, elapsed: float, exact: float, wall_margin: float) -> bool:
    """``elapsed`` is ``exact`` in virtual time (to 1 us), and at most ``exact + wall_margin`` on
    the wall clock, where a loaded machine delays every step."""
    if sim.virtual:
        return abs(elapsed - exact) <= 1e-6
    return elapsed <= exact + wall_margin


def fast_table(dev: Device) -> None:
    """A quick table so that moves take a fraction of a second at the simulator's speed."""
    dev.set_config("table_max_rate_mdps", 50_000)
    dev.set_config(ConfigKey.TABLE_MAX_ACCEL_MDPS2, 200_000)
    dev.set_config("settle_time_ms", 200)


def angle_error(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_every_call_on_the_happy_path(link, sim):
    dev, _ = link
    # A unit in another process may answer late on a loaded machine: each call is under test
    # here, not the reply deadline (the fault tests below judge that).
    dev.reply_timeout = 2.0
    ident = dev.identify()
    assert ident.model == "NF-SIM" and ident.protocol_version[0] == 1
    assert ident.gyro_scale.value == pytest.approx(1e-4)
    st = dev.status()
    assert st.state == DeviceState.READY and st.faults == Fault(0)
    assert 0.0 <= st.angle_deg < 360.0 and math.isfinite(st.temperature_c)
    assert dev.get_config("sample_rate_hz") == 200 == dev.sample_rate_hz
    assert dev.get_config(ConfigKey.NODE_ID) == 1
    config = dev.config()
    assert config[ConfigKey.HEARTBEAT_PERIOD_MS] == 100 and config[ConfigKey.STREAMING] == 0
    fast_table(dev)
    assert dev.get_config("settle_time_ms") == 200

    done = dev.rotate_to(90.0)
    assert done.state == DeviceState.READY and angle_error(done.angle_deg, 90.0) < 0.1
    done = dev.rotate_by(-30.0)
    assert angle_error(done.angle_deg, 60.0) < 0.1
    done = dev.rotate_to(300.0, direction="negative", timeout=10.0)
    assert angle_error(done.angle_deg, 300.0) < 0.1
    assert dev.rotate_by(90.0, wait=False) is None
    sim.clock.sleep(0.05 * sim.speed)
    assert dev.status().state == DeviceState.ROTATING
    stopped = dev.stop(wait=True)
    # STOP leaves the table short of the target of the move it interrupted (300 + 90 = 30 deg)
    assert stopped.state == DeviceState.READY and angle_error(stopped.angle_deg, 30.0) > 1.0
    done = dev.home()
    assert angle_error(done.angle_deg, 0.0) < 0.1
    assert dev.self_test() == 0

    dev.start_streaming()
    assert dev.streaming and dev.get_config("streaming") == 1
    window = dev.acquire(0.5)
    assert len(window) == 100 and window.complete and window.requested == 100
    dev.stop_streaming()
    assert not dev.streaming

    back = dev.reset()
    assert back.state in (DeviceState.WARMUP, DeviceState.READY)
    assert dev.get_config("settle_time_ms") != 200  # configuration back to defaults
    dev.wait_ready()
    stats = dev.stats()
    assert stats.frames_received > 0 and stats.reply_timeouts == 0 and stats.resets_detected >= 1


def test_ten_second_window_at_200_hz_has_2000_contiguous_samples(link, sim):
    dev, _ = link
    requested_at = sim.clock.wall()
    t0 = sim.clock.now()
    window = dev.acquire(10.0)
    elapsed = sim.clock.now() - t0
    assert isinstance(window, Window)
    assert len(window) == 2000 and window.requested == 2000
    assert window.missing == 0 and window.gaps == ()
    assert np.all(np.diff(window.counter) == 1)
    assert np.allclose(np.diff(window.time_s), 0.005)
    assert window.counter.dtype == np.int64 and window.validity.dtype == np.uint8
    assert window.gyro_dph.shape == window.accel_mps2.shape == (2000, 3)
    assert np.all(window.arrival_s >= requested_at)  # nothing from before the request
    assert np.all(window.valid_mask)
    gyro, accel = window.mean()
    assert np.linalg.norm(gyro) == pytest.approx(15.04, abs=0.5)  # Earth rate + bias, deg/h
    assert accel[2] == pytest.approx(G_34N, abs=0.01)
    assert np.allclose(window.gyro_rps, window.gyro_dph * math.pi / 180 / 3600)
    # 10 s of device time at the simulator's speed, never faster than the pace: in virtual time
    # 1999 tick periods after the first sample, which follows the request within the round trips
    # of GET_STATUS and STREAM_START and one tick
    if sim.virtual:
        assert 1999 * 0.005 <= elapsed <= 1999 * 0.005 + 2 * 0.002 + 0.005 + NS
    else:
        assert 0.95 * 10.0 / sim.speed <= elapsed <= 10.0 / sim.speed + 5.0
    with pytest.raises(ValueError):
        window.counter[0] = 0  # the window is read-only


def inject(control, op: str, **args) -> None:
    control.call(op, **args)


def consumed(sim, control, fault: str) -> None:
    """Wait until the simulator has applied a frame fault to as many frames as it was told."""
    deadline = sim.clock.now() + 5.0 * sim.speed
    while control.call("status")["faults"][fault] and sim.clock.now() < deadline:
        sim.clock.sleep(0.02)
    sim.clock.sleep(0.1)  # and the frames after it have reached the driver


def test_dropped_frames_are_detected_and_reported(link, sim):
    dev, ctl = link
    dev.start_streaming()
    before = dev.stats()
    with sim.later(0.2, inject, ctl, "drop", count=5):
        window = dev.acquire(1.0 * sim.speed, on_gap="report")  # 1 s of wall time
    consumed(sim, ctl, "drop_frames")
    assert window.missing >= 1 and window.gaps
    assert sum(count for _, count in window.gaps) == window.missing
    assert len(window) + window.missing == window.requested
    present = set(window.counter.tolist())
    for first, count in window.gaps:
        assert not present & set(range(first, first + count))
    after = dev.stats()
    if dev.link_kind == "serial":
        assert after.frames_lost - before.frames_lost == 5  # the frame sequence counter says 5
    else:
        lost = after.ticks_lost + after.ticks_incomplete
        assert lost - before.ticks_lost - before.ticks_incomplete >= 1

    with sim.later(0.2, inject, ctl, "drop", count=5), pytest.raises(StreamGap) as err:
        dev.acquire(1.0 * sim.speed)
    assert err.value.missing >= 1 and err.value.gaps and "on_gap='report'" in str(err.value)


def test_corrupted_frames_are_ignored_and_counted(link, sim):
    dev, ctl = link
    dev.start_streaming()
    before = dev.stats()
    with sim.later(0.2, inject, ctl, "corrupt", count=3):
        window = dev.acquire(1.0 * sim.speed, on_gap="report")
    consumed(sim, ctl, "corrupt_frames")
    after = dev.stats()
    assert after.frames_rejected - before.frames_rejected >= 3, (before, after)
    assert window.missing <= 3  # a corrupt frame costs at most its own tick
    assert len(window) + window.missing == window.requested
    assert dev.status().state == DeviceState.READY  # and the link goes on


def test_a_simulator_that_stops_by_itself_is_judged_lost_on_time(monkeypatch):
    """In virtual time a simulator that fails falls silent without anybody telling the clock:
    the host has read every frame it sent, so the time without a status counts at once and the
    link is lost three heartbeat periods after the last status."""
    from northfinder.embed import SimulatedInstrument
    from northfinder.firmware_sim.firmware import Firmware
    from northfinder.firmware_sim.imu import Truth

    sim = SimulatedInstrument(
        "paper-rlg", Truth(azimuth_deg=30.0, latitude_deg=34.0), seed=3, clock="virtual",
        warmup_s=0.0,
    ).start()  # fmt: skip
    process, failed_at = Firmware.process, []

    def failing(self, dt):
        if self.now >= 1.0:
            failed_at.append(sim.clock.now())
            raise ZeroDivisionError("a defect in the simulator")
        return process(self, dt)

    try:
        with sim.open_device() as dev:
            dev.wait_ready(timeout=5.0)
            dev.start_streaming()
            monkeypatch.setattr(Firmware, "process", failing)
            with pytest.raises(LinkLost, match="no status"):
                dev.acquire(5.0)
            lost = sim.clock.now()
    finally:
        monkeypatch.undo()
        sim.close()
    # the last status came within one heartbeat period (0.1 s) before the failure
    assert failed_at[0] + 0.2 - NS <= lost <= failed_at[0] + 0.3 + NS


@VIRTUAL_ONLY
def test_a_silent_link_is_judged_lost_on_time_whatever_the_clock_reads(sim):
    """The time without a status is judged by one sum (last status + supervision), so a wait
    until that instant ends with the verdict, at any reading of the clock (an age computed as a
    difference of two readings can round below the limit and add a poll period)."""
    late = []
    for k in range(40):
        with sim.open_device() as dev:
            dev.wait_ready(timeout=5.0)
            dev.start_streaming()
            sim.clock.sleep(0.0137 * (k % 7) + 0.001 * k)  # another instant of the clock each time
            dev.acquire(0.05)  # the last status came at most one heartbeat period before now
            t0 = sim.clock.now()
            sim.control.call("silent", on=True)
            try:
                with pytest.raises(LinkLost, match="no status"):
                    dev.acquire(5.0)
            finally:
                sim.control.call("reset")
            elapsed = sim.clock.now() - t0
        if not 0.2 - NS <= elapsed <= 0.3 + NS:
            late.append((t0, elapsed))
    assert not late


def test_silent_device_times_out_within_the_stated_deadline(link, sim):
    dev, ctl = link
    dev.start_streaming()
    t0 = sim.clock.now()
    with sim.later(0.2, inject, ctl, "silent", on=True), pytest.raises(LinkLost, match="no status"):
        dev.acquire(5.0 * sim.speed)
    elapsed = sim.clock.now() - t0
    # three heartbeat periods (0.3 s) after the last status, which came 0.1 s before it fell
    # silent at the latest
    if sim.virtual:
        assert 0.1 + 0.3 <= elapsed <= 0.2 + 0.3 + NS
    else:
        assert elapsed < 0.2 + 0.3 + 2.0  # not the window's own deadline of several seconds
    t0 = sim.clock.now()
    with pytest.raises(ReplyTimeout) as err:
        dev.get_config("sample_rate_hz")
    elapsed = sim.clock.now() - t0
    assert err.value.deadline_s == pytest.approx(0.75)
    assert err.value.attempts == 3 and err.value.opcode == Opcode.GET_CONFIG
    assert within(sim, elapsed, err.value.deadline_s, 1.0)
    assert not err.value.link_alive and "silent" in str(err.value)
    assert isinstance(err.value, TimeoutError)
    with pytest.raises(LinkLost):
        dev.acquire(1.0)  # refused at once while the heartbeat is missing
    ctl.call("silent", on=False)
    assert dev.status().state == DeviceState.READY  # the link comes back


@VIRTUAL_ONLY
def test_reset_in_the_middle_of_a_window_raises_a_clear_error(link, sim):
    dev, ctl = link
    t0 = sim.clock.now()
    with sim.later(0.3, inject, ctl, "reset"), pytest.raises(DeviceReset, match="restarted"):
        dev.acquire(3.0 * sim.speed)  # 3 s of the test's clock
    elapsed = sim.clock.now() - t0
    # the unit announces itself (IDENTIFY, then a BOOT status) within two reply latencies
    assert 0.3 < elapsed <= 0.3 + 0.002 + NS if sim.virtual else elapsed < 3.0
    assert not dev.streaming
    dev.wait_ready()
    window = dev.acquire(0.2)  # starts the stream again
    assert window.complete and len(window) == 40


@VIRTUAL_ONLY
def test_busy_refusal_surfaces_with_its_code(link, sim):
    dev, ctl = link
    dev.rotate_by(90.0, wait=False)  # 15 s of table motion at the default 6 deg/s
    with pytest.raises(DeviceRefused) as err:
        dev.rotate_by(10.0)
    assert err.value.result == Result.BUSY and err.value.opcode == Opcode.ROTATE_BY
    assert "rotating" in err.value.meaning and "BUSY" in str(err.value)
    # STOP waits for the table's settle time, whatever an earlier test of the module left there.
    settle_s = dev.get_config("settle_time_ms") / 1000.0
    dev.stop(wait=True, timeout=settle_s + 5.0)
    ctl.call("wrong_result", code=int(Result.BUSY))
    with pytest.raises(DeviceRefused) as err:
        dev.get_config("node_id")
    assert err.value.result == Result.BUSY and err.value.opcode == Opcode.GET_CONFIG
    with pytest.raises(DeviceRefused) as err:
        dev.set_config("node_id", 3)
    assert err.value.result == Result.READ_ONLY


@VIRTUAL_ONLY
def test_a_fault_during_a_move_raises(link, sim):
    dev, ctl = link
    ctl.call("stall", on=True)
    with pytest.raises(DeviceFault) as err:
        dev.rotate_by(30.0, timeout=10.0)
    assert err.value.faults & Fault.DRIVE
    ctl.call("stall", on=False)
    assert dev.reset().state != DeviceState.FAULT


@VIRTUAL_ONLY
def test_only_commands_safe_to_repeat_are_sent_again(link, sim):
    dev, ctl = link
    ctl.call("delay_replies", seconds=0.4 * sim.speed)  # each reply 0.4 s late: after the deadline
    t0 = sim.clock.now()
    with pytest.raises(ReplyTimeout) as err:
        dev.get_config("sample_rate_hz")
    assert err.value.attempts == 3 and err.value.link_alive
    assert within(sim, sim.clock.now() - t0, err.value.deadline_s, 1.0)
    with pytest.raises(ReplyTimeout) as err:
        dev.rotate_by(1.0, wait=False)
    assert err.value.attempts == 1 and "may have been carried out" in str(err.value)
    ctl.call("delay_replies", seconds=0.0)
    sim.clock.sleep(0.5 * sim.speed)
    stats = dev.stats()
    assert stats.retries >= 2 and stats.stray_replies >= 3  # late replies are counted, not used
    assert dev.get_config("sample_rate_hz") == 200


@VIRTUAL_ONLY
def test_calls_from_several_threads_while_a_window_is_acquired(link, sim):
    dev, _ = link
    errors: list[BaseException] = []
    results: list[int] = []

    def query() -> None:
        try:
            for _ in range(10):
                results.append(dev.get_config("heartbeat_period_ms"))
                dev.status()
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=query) for _ in range(4)]
    for t in threads:
        t.start()
    window = dev.acquire(0.5 * sim.speed)
    for t in threads:
        t.join(10.0)
    assert not errors and results == [100] * 40
    assert window.complete and np.all(np.diff(window.counter) == 1)
    assert dev.stats().stray_replies == 0


def test_a_long_gap_is_measured_in_full(link, sim):
    dev, ctl = link
    dev.start_streaming()
    with sim.later(0.2, inject, ctl, "skip_counter", count=300):
        # more than 300 ticks after the jump, however fast the simulator runs
        window = dev.acquire(0.6 * sim.speed + 2.0, on_gap="report")
    assert window.missing == 300 and len(window) == window.requested - 300


def test_closing_releases_the_link_and_stops_the_reader(link, sim):
    dev, _ = link
    dev.start_streaming()
    dev.close()
    assert dev.closed
    if sim.virtual:  # no reader thread: the clock polled the link, and polls it no more
        assert dev._reader is None and dev._pump not in sim.clock._pollers
    else:
        assert not dev._reader.is_alive()
    with pytest.raises(LinkError):
        dev.status()
    dev.close()  # idempotent
    with sim.open_device() as again:  # the bus or port is free for the next host
        assert again.status().state == DeviceState.READY
        assert not again.streaming  # the stream was stopped on close
        transport = again._transport
    if again.link_kind == "serial":
        assert not transport.port.is_open
    else:
        assert transport.bus._is_shutdown


def test_a_failed_open_releases_the_bus():
    bus = can.Bus(interface="virtual", channel="northfinder-nobody", receive_own_messages=False)
    clock = VirtualClock()
    with pytest.raises(ReplyTimeout, match="IDENTIFY"):
        Device.from_bus(bus, own_bus=True, clock=clock)
    assert clock.now() == pytest.approx(3 * 0.25)  # IDENTIFY sent three times, then given up
    assert bus._is_shutdown


def test_bad_arguments_name_the_choices():
    with pytest.raises(ValueError, match="keys are"):
        Device._key("colour")
    with pytest.raises(ValueError, match="shortest"):
        Device._direction("sideways")
    with pytest.raises(ArgumentError, match="shortest"):  # the driver's own error, a ValueError
        Device._direction("sideways")
    with pytest.raises(LinkError, match="serial port"):
        Device.open_serial("/dev/nonexistent-northfinder")


def test_errors_share_one_root():
    for exc in (DeviceRefused, ReplyTimeout, LinkLost, StreamGap, DeviceReset, DeviceFault):
        assert issubclass(exc, DriverError)
    for other in (ArgumentError, EmptyWindow, ProtocolError, EncodeError, ConformanceError):
        assert issubclass(other, DriverError)
    # The codec's errors are defined beside the self-contained codec and re-exported.
    assert ProtocolError is northfinder.driver.protocol.errors.ProtocolError
    err = DeviceRefused(Opcode.ROTATE_TO, Result.BUSY, Result.BUSY.meaning)
    assert err.result == Result.BUSY and err.meaning == Result.BUSY.meaning


def _tick(asm: TickAssembler, counter: int) -> list:
    t = counter & 0xFF
    out = []
    for part in (
        SampleX(t, 0, 0),
        SampleY(t, 0, 0),
        SampleZ(t, 0, 0),
        SampleAux(t, 0, 0, Validity(3)),
    ):
        out += asm.add(part)
    return out


def test_can_tick_counter_measures_gaps_of_256_or_more_with_the_status_anchor():
    asm = TickAssembler()
    asm.sync(1000)
    assert [s.counter for s in _tick(asm, 1001) if isinstance(s, Sample)] == [1001]
    asm.sync(1001)
    # 300 ticks lost, then a status (anchor) before the next tick: the gap is 300, not 44
    asm.sync(1301)
    out = _tick(asm, 1302)
    assert out[0] == TickLoss(1002, 300, False) and out[1].counter == 1302
    # the stream was switched off and on: ticks not sent are not lost
    asm.sync(5000)
    asm.restart()
    out = _tick(asm, 5002)
    assert len(out) == 1 and out[0].counter == 5002 and asm.lost == 300


@pytest.mark.parametrize("reader", ["installed", "bulk"])
def test_an_slcan_batch_takes_the_waiting_frames_without_a_read_that_waits(reader):
    """python-can's ``slcan`` ``recv(0.0)`` on an empty port waits for the port's read timeout
    (1 ms): the driver takes the frames that came with the first one while bytes are waiting or
    whole lines are held, and no read of the port waits (each batch would otherwise end 1 ms late,
    on a timer). ``bulk``: python-can's next reader (all waiting bytes at once, the lines after
    the first kept in the bus)."""
    import os
    import time

    import serial

    from northfinder.driver.protocol.can import encode_can
    from northfinder.driver.protocol.messages import Validity
    from northfinder.driver.transport import frame_batch
    from northfinder.firmware_sim.adapters import PseudoTerminal, slcan_line

    pty = PseudoTerminal()
    bus: Any = can.Bus(interface="slcan", channel=pty.path, bitrate=500_000, sleep_after_open=0)
    port = bus.serialPortOrig
    try:
        if reader == "bulk":

            def bulk_read(timeout):
                expiry = serial.Timeout(timeout)
                while True:
                    bus._buffer.extend(port.read(port.in_waiting or 1))
                    for i, byte in enumerate(bus._buffer):
                        if byte in b"\r\a":
                            line = bus._buffer[: i + 1].decode()
                            del bus._buffer[: i + 1]
                            return line
                    if expiry.expired():
                        return None

            bus._read = bulk_read
        waited = []  # reads of the port that came back empty after waiting for its timeout
        read = port.read

        def recorded(size=1):
            data = read(size)
            if not data and port.timeout:
                waited.append(size)
            return data

        port.read = recorded
        take = frame_batch(bus)
        frames = encode_can(Sample(7, (1, 2, 3), (4, 5, 6), 8, 9, Validity(0)), 1)
        text = b"".join(
            slcan_line(
                can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False)
            )
            for f in frames
        )

        def arrive(data: bytes) -> None:
            """Write to the adapter's side; return once the host's side has it all (the kernel
            moves a pty's bytes across in a worker of its own)."""
            want = port.in_waiting + len(data)
            os.write(pty.master, data)
            for _ in range(10_000):  # a bound for a hang, not a measure
                if port.in_waiting >= want:
                    return
                time.sleep(0.001)
            raise AssertionError(f"the pty passed {port.in_waiting} of {want} bytes")

        arrive(text[:-5])  # four frames, the last one not complete yet
        got = take(16)
        assert [bytes(m.data) for m in got] == [bytes(f.data) for f in frames[:3]]
        arrive(text[-5:])
        (last,) = take(16)
        assert bytes(last.data) == bytes(frames[3].data)
        assert take(16) == []
        assert waited == []
        assert port.timeout == 0.001  # as python-can set it
        bus.shutdown()
        with pytest.raises(can.CanOperationError, match="closed"):
            take(16)
    finally:
        if port.is_open:
            bus.shutdown()
        pty.close()
