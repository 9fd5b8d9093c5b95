"""The simulated firmware in lockstep: states, every command and refusal, the stream, determinism."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from lockstep import IDEAL, ask, make, run

from northfinder.driver.protocol import (
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    GetConfig,
    GetStatus,
    Home,
    Identify,
    Opcode,
    Reply,
    RequestIdentify,
    Reset,
    Result,
    RotateBy,
    RotateTo,
    Sample,
    SelfTest,
    SetConfig,
    Status,
    Stop,
    StreamStart,
    StreamStop,
    Validity,
)
from northfinder.driver.protocol.can import CanReceiver, encode_can
from northfinder.firmware_sim.adapters import CanLink
from northfinder.firmware_sim.firmware import LinkInfo
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.runner import LockstepClock, Runner
from northfinder.firmware_sim.sensors import load_spec

DPH = math.pi / 180 / 3600


def test_boot_warmup_ready_and_the_state_log():
    fw = make(warmup_s=5.0)
    changes = []
    fw.on_state_change = lambda old, new, t: changes.append((old, new, round(t, 2)))
    assert fw.state == DeviceState.BOOT
    run(fw, 0.6)
    assert fw.state == DeviceState.WARMUP
    statuses = [m for m in run(fw, 5.0) if isinstance(m, Status)]
    assert statuses[0].state == DeviceState.WARMUP and statuses[-1].state == DeviceState.READY
    assert [(a, b) for a, b, _ in changes] == [
        (DeviceState.BOOT, DeviceState.WARMUP),
        (DeviceState.WARMUP, DeviceState.READY),
    ]
    assert changes[1][2] == pytest.approx(5.0, abs=0.011)


def test_rotating_settling_ready_and_encoder_angle():
    spec = IDEAL.with_values(
        {"table.indexing_error_deg": 0.02, "table.settle_s": 1.5, "table.max_rate_dps": 10.0}
    )
    fw = make(spec=spec)
    run(fw, 1.0)
    reply, _ = ask(fw, RotateTo(1, 45_000_000))
    assert reply.result == Result.OK
    assert fw.state == DeviceState.ROTATING
    run(fw, 5.0)
    assert fw.state == DeviceState.SETTLING
    run(fw, 1.5)
    assert fw.state == DeviceState.READY
    _, out = ask(fw, GetStatus(2))
    status = next(m for m in out if isinstance(m, Status))
    # the encoder says where the table is, not what was commanded
    assert status.angle != 45_000_000
    assert abs(status.angle - 45_000_000) < 200_000


def test_every_command_has_its_reply():
    fw = make(link=LinkInfo("can", 500_000), serial_number=1234)
    run(fw, 1.0)
    reply, out = ask(fw, RequestIdentify(1))
    ident = next(m for m in out if isinstance(m, Identify))
    assert (
        reply.ok and ident.serial_number == 1234 and ident.gyro_scale.value == pytest.approx(1e-4)
    )
    reply, out = ask(fw, GetStatus(2))
    assert reply.ok and next(m for m in out if isinstance(m, Status)).state == DeviceState.READY
    assert ask(fw, StreamStart(3))[0].ok and fw.streaming
    assert ask(fw, StreamStop(4))[0].ok and not fw.streaming
    for key, value in (
        (ConfigKey.SAMPLE_RATE_HZ, 200),
        (ConfigKey.LINK_BITRATE, 500_000),
        (ConfigKey.NODE_ID, 1),
    ):
        reply, _ = ask(fw, GetConfig(5, key))
        assert reply.ok and reply.config_value() == (key, value)
    reply, _ = ask(fw, SetConfig(6, ConfigKey.SAMPLE_RATE_HZ, 100))
    assert reply.ok and reply.config_value() == (ConfigKey.SAMPLE_RATE_HZ, 100)
    reply, _ = ask(fw, SelfTest(7))
    assert reply.ok and reply.self_test_failures() == 0
    assert ask(fw, RotateBy(8, -30_000_000))[0].ok
    run(fw, 0.5)
    assert ask(fw, Stop(9))[0].ok
    run(fw, 5.0)
    assert fw.state == DeviceState.READY
    assert ask(fw, Home(10))[0].ok
    run(fw, 10.0)
    assert fw.status().angle == 0
    assert ask(fw, RotateTo(11, 10_000_000, Direction.NEGATIVE))[0].ok
    run(fw, 1.0)
    assert fw.instrument.table.state(fw.now)[1] < 0  # the long way round, clockwise
    run(fw, 60.0)
    assert ask(fw, Reset(12))[0].ok
    assert fw.state == DeviceState.BOOT and fw.sample_rate_hz == 200


@pytest.mark.parametrize(
    ("command", "result"),
    [
        (RotateTo(1, 360_000_000), Result.OUT_OF_RANGE),
        (RotateBy(1, 720_000_001), Result.OUT_OF_RANGE),
        (SetConfig(1, ConfigKey.SAMPLE_RATE_HZ, 300), Result.OUT_OF_RANGE),
        (SetConfig(1, ConfigKey.HEARTBEAT_PERIOD_MS, 1), Result.OUT_OF_RANGE),
        (SetConfig(1, ConfigKey.NODE_ID, 2), Result.READ_ONLY),
        (SetConfig(1, 0x7F, 2), Result.UNKNOWN_KEY),
        (GetConfig(1, 0x7F), Result.UNKNOWN_KEY),
    ],
)
def test_refusals_of_bad_arguments(command, result):
    fw = make()
    run(fw, 1.0)
    assert ask(fw, command)[0].result == result
    assert fw.status().cmd_rejected == 1


def test_not_ready_during_warmup_and_busy_while_moving():
    fw = make(warmup_s=3.0)
    run(fw, 1.0)
    assert ask(fw, RotateTo(1, 1_000_000))[0].result == Result.NOT_READY
    assert ask(fw, StreamStart(2))[0].ok  # streaming is allowed while warming up
    run(fw, 3.0)
    assert ask(fw, RotateBy(3, 90_000_000))[0].ok
    for cmd in (
        RotateTo(4, 0),
        RotateBy(5, 1),
        Home(6),
        SelfTest(7),
    ):
        assert ask(fw, cmd)[0].result == Result.BUSY, cmd
    assert ask(fw, SetConfig(8, ConfigKey.SETTLE_TIME_MS, 2000))[0].result == Result.BUSY
    assert ask(fw, SetConfig(8, ConfigKey.HEARTBEAT_PERIOD_MS, 200))[0].ok
    run(fw, 9.5)
    assert fw.state == DeviceState.SETTLING
    assert ask(fw, RotateBy(9, 1))[0].result == Result.BUSY


def test_boot_accepts_only_queries_and_reset_and_checks_run_in_protocol_order():
    fw = make(warmup_s=10.0)
    first = run(fw, 0.02)
    assert any(isinstance(m, Identify) for m in first)  # the device announces itself in BOOT
    for cmd in (StreamStart(1), SetConfig(2, ConfigKey.SAMPLE_RATE_HZ, 100), SelfTest(3), Stop(4)):
        assert ask(fw, cmd, 0.01)[0].result == Result.NOT_READY, cmd
    for query in (RequestIdentify(5), GetStatus(6), GetConfig(7, ConfigKey.NODE_ID)):
        assert ask(fw, query, 0.01)[0].ok, query
    run(fw, 1.0)
    # state is checked before the argument range (protocol.md table 4.3)
    assert ask(fw, RotateTo(8, 400_000_000))[0].result == Result.NOT_READY
    run(fw, 10.0)
    assert ask(fw, RotateTo(9, 400_000_000))[0].result == Result.OUT_OF_RANGE


def test_every_state_change_sends_a_status_at_once():
    fw = make(warmup_s=2.03, boot_s=0.55)  # off the 100 ms heartbeat grid
    statuses = [
        (round(o.time_s, 3), o.message.state)
        for o in fw.process(5.0)
        if isinstance(o.message, Status)
    ]
    assert (0.55, DeviceState.WARMUP) in statuses
    assert (2.03, DeviceState.READY) in statuses
    assert len(statuses) == 51 + 2  # heartbeats at 0, 0.1, ... 5.0 and the two changes


def test_rate_that_does_not_fit_the_link_is_refused():
    fw = make(link=LinkInfo("serial", 38_400))
    run(fw, 1.0)
    # at 38400 baud the default falls back to a rate that fits
    assert fw.sample_rate_hz < 200
    assert (
        ask(fw, SetConfig(1, ConfigKey.SAMPLE_RATE_HZ, 400))[0].result == Result.RATE_EXCEEDS_LINK
    )
    max_rate = ask(fw, GetConfig(2, ConfigKey.LINK_MAX_SAMPLE_RATE_HZ))[0].config_value()[1]
    assert ask(fw, SetConfig(3, ConfigKey.SAMPLE_RATE_HZ, max_rate))[0].ok
    can_fw = make(link=LinkInfo("can", 125_000))
    run(can_fw, 1.0)
    assert (
        ask(can_fw, SetConfig(1, ConfigKey.SAMPLE_RATE_HZ, 400))[0].result
        == Result.RATE_EXCEEDS_LINK
    )


def test_stalled_table_is_a_drive_fault_until_reset():
    fw = make()
    run(fw, 1.0)
    fw.stall_table(True)
    assert ask(fw, RotateBy(1, 90_000_000))[0].ok
    run(fw, 0.1)
    assert fw.state == DeviceState.FAULT
    status = fw.status()
    assert status.faults & Fault.DRIVE
    assert ask(fw, RotateBy(2, 1_000_000))[0].result == Result.FAULT
    assert ask(fw, SelfTest(3))[0].self_test_failures() != 0
    fw.stall_table(False)
    assert ask(fw, Reset(4))[0].ok
    run(fw, 1.0)
    assert fw.state == DeviceState.READY


def test_stream_rate_and_counters_over_ten_simulated_minutes():
    fw = make(spec=load_spec("paper-rlg"))
    fw.process(1.0)
    fw.handle(StreamStart(1))
    samples = []
    heartbeats = 0
    for _ in range(600):
        for o in fw.process(1.0):
            if isinstance(o.message, Sample):
                samples.append((o.time_s, o.message))
            elif isinstance(o.message, Status):
                heartbeats += 1
    counters = np.array([s.counter for _, s in samples])
    times = np.array([t for t, _ in samples])
    assert len(samples) == 200 * 600
    assert np.all(np.diff(counters) == 1)
    assert np.allclose(np.diff(times), 0.005, atol=1e-9)
    assert heartbeats == pytest.approx(6000, abs=2)
    valid = Validity.GYRO_VALID | Validity.ACCEL_VALID
    assert all(s.validity & valid == valid for _, s in samples[200:])


def test_sample_counts_carry_the_physics_exactly():
    fw = make(boot_s=0.0)
    fw.handle(StreamStart(1))
    out = [m for m in run(fw, 10.0, step=0.5) if isinstance(m, Sample)]
    assert len(out) == 2000
    gyro_dph = np.array([s.gyro for s in out]) * 1e-4
    from northfinder.firmware_sim.imu import Instrument

    ins = Instrument(IDEAL, Truth(azimuth_deg=30.0, latitude_deg=34.0), np.random.default_rng(0))
    exact = ins.generate(len(out)).gyro_rps / DPH
    # window sums of the counts are exact to one count
    assert np.all(np.abs(gyro_dph.sum(0) - exact.sum(0)) <= 1e-4 + 1e-9)


def test_identical_seeds_give_identical_streams():
    def stream(seed):
        fw = make(spec=load_spec("nav-fog"), seed=seed)
        fw.process(1.0)
        fw.handle(StreamStart(1))
        return [m for m in run(fw, 5.0, step=0.05) if isinstance(m, Sample)]

    a, b, c = stream(5), stream(5), stream(6)
    assert a == b and a != c


def test_bad_frames_are_counted_and_answered_on_virtual_can():
    with (
        can.Bus(interface="virtual", channel="fwtest-bad", receive_own_messages=False) as dev_bus,
        can.Bus(interface="virtual", channel="fwtest-bad") as host,
    ):
        fw = make()
        clock = LockstepClock()
        runner = Runner(fw, CanLink(dev_bus, fw, 1), clock)
        rx = CanReceiver(node_id=1)

        def advance(seconds: float) -> list:
            got = []
            for _ in range(round(seconds / 0.01)):
                clock.advance(0.01)
                runner.step(0.0)
                while (msg := host.recv(0.0)) is not None:
                    got += rx.feed(msg.arbitration_id, msg.data)
            return got

        advance(1.0)
        host.send(
            can.Message(arbitration_id=0x041, data=bytes([7, 0x77]), is_extended_id=False)
        )  # unknown opcode
        host.send(
            can.Message(
                arbitration_id=0x041, data=bytes([8, Opcode.ROTATE_BY, 1]), is_extended_id=False
            )
        )  # short
        host.send(can.Message(arbitration_id=0x041, data=b"", is_extended_id=False))  # empty
        host.send(
            can.Message(arbitration_id=0x042, data=bytes([9, 1]), is_extended_id=False)
        )  # other node
        got = advance(0.2)
        replies = {m.seq: m.result for m in got if isinstance(m, Reply)}
        assert replies == {7: Result.UNKNOWN_COMMAND, 8: Result.BAD_ARGUMENT}
        for frame in encode_can(GetStatus(10), 1):
            host.send(
                can.Message(
                    arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=False
                )
            )
        got = advance(0.2)
        status = [m for m in got if isinstance(m, Status)][-1]
        assert status.rx_malformed == 3 and status.cmd_rejected == 2
        assert fw.state == DeviceState.READY


def test_queries_at_any_instant_leave_the_stream_as_it_would_have_been():
    """A query rewinds the look-ahead computation to its instant; every random process (white
    and flicker noise, impulses, the table's indexing error, the moves' transients) must then draw
    again exactly what it drew before, so the samples are those of a run without queries."""
    spec = load_spec("paper-prototype").with_values(
        {"disturbance.impulse_rate_hz": 3.0, "table.indexing_error_deg": 0.01}
    )

    def samples(query_at: list[int], lookahead_s: float) -> list[Sample]:
        fw = make(spec=spec, seed=11)
        fw.lookahead_s = lookahead_s
        fw.process(1.0)
        fw.handle(StreamStart(1))
        fw.process(0.5)
        fw.handle(RotateTo(2, 90_000_000))
        out, t_ms, seq = [], 1500, 3
        for q_ms in [*sorted(query_at), 40_000]:  # whole milliseconds: the steps add up exactly
            step = (q_ms - t_ms) / 1000
            out += [o.message for o in fw.process(step) if isinstance(o.message, Sample)]
            t_ms = q_ms
            fw.handle(GetStatus(seq & 0xFF))
            seq += 1
        return out

    quiet = samples([], 0.2)
    rng = np.random.default_rng(3)
    asked = samples(list(rng.integers(1600, 39_900, 60)), 0.2)
    assert len(quiet) == len(asked) == round(38.5 * 200)
    assert asked == quiet
    assert samples(list(rng.integers(1600, 39_900, 60)), 1.0) == quiet  # any chunk length


@pytest.mark.parametrize("lookahead_s", [0.2, 1.0])
def test_a_command_at_the_instant_of_power_on_is_answered(lookahead_s):
    """The output computed ahead from power-on is rewound to t = 0, where the first status is
    due and no sample tick has ended yet."""
    fw = make()
    fw.lookahead_s = lookahead_s
    fw.prefetch()
    reply, out = ask(fw, GetStatus(1))
    assert reply.result == Result.OK
    assert any(isinstance(m, Status) for m in out)


def test_the_samples_frames_packed_with_their_chunk_are_what_each_sample_encodes_to():
    """The stream's CAN data packed for a chunk at once (``Outgoing.frames``) equals each
    sample's own frames, through warm-up, a move, settling, saturation and a counter skip."""
    spec = IDEAL.with_values({"table.settle_s": 0.5, "table.max_rate_dps": 30.0})
    fw = make(warmup_s=0.6, spec=spec, boot_s=0.0)
    fw.handle(StreamStart(1))
    out = [o for _ in range(300) for o in fw.process(0.01)]
    fw.handle(RotateTo(2, 90_000_000))
    fw.faults.skip_counter = 3
    out += [o for _ in range(500) for o in fw.process(0.013)]
    samples = [o for o in out if isinstance(o.message, Sample)]
    assert len(samples) > 1000
    assert all(o.frames == b"".join(o.message.can_payloads()) for o in samples)
    assert {o.frames is None for o in out if not isinstance(o.message, Sample)} == {True}
    kinds = {int(o.message.validity) for o in samples}
    assert len(kinds) >= 3, kinds  # warming up, moving, settling, good
