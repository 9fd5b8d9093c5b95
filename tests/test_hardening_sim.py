"""The simulator under abuse: control requests that must be refused before they act, the control
socket's limits, and the firmware's RESET, tick and drive-fault edges. In lockstep wherever the
behaviour does not depend on a socket."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import socket
import threading
import tracemalloc
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from northfinder.cli import main
from northfinder.driver.protocol.constants import DeviceState, Fault, Validity
from northfinder.driver.protocol.messages import (
    GetStatus,
    Identify,
    Reply,
    Reset,
    RotateTo,
    Sample,
    Status,
    StreamStart,
)
from northfinder.driver.protocol.serial import SerialEncoder
from northfinder.firmware_sim.control import (
    MAX_LINE_BYTES,
    OPS,
    ControlClient,
    ControlError,
    Controller,
    ControlServer,
)
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.firmware import Firmware, Outgoing
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.runner import LockstepClock, Runner
from northfinder.firmware_sim.sensors import load_spec

NAN, INF = float("nan"), float("inf")


class WireLink:
    """Encodes every message as the serial link does (a value the wire cannot carry raises here,
    as it would kill the runner) and keeps what was sent."""

    def __init__(self) -> None:
        self.sent: list[Outgoing] = []
        self._encoder = SerialEncoder()

    def poll(self, timeout: float) -> int:
        return 0

    def send(self, outgoing: list[Outgoing]) -> None:
        for item in outgoing:
            self._encoder.encode(item.message)
        self.sent += outgoing

    def messages(self, kind: type) -> list:
        return [o.message for o in self.sent if isinstance(o.message, kind)]


@dataclass
class Unit:
    """A simulated unit in lockstep with its control channel, without a socket."""

    firmware: Firmware
    link: WireLink
    clock: LockstepClock
    runner: Runner
    control: Controller

    def run(self, seconds: float, step: float = 0.01) -> None:
        for _ in range(round(seconds / step)):
            self.clock.advance(step)
            self.runner.step()

    def counters(self) -> np.ndarray:
        return np.array([s.counter for s in self.link.messages(Sample)])


def make_unit(spec: str = "ideal", streaming: bool = True) -> Unit:
    fw = Firmware(load_spec(spec), Truth(30.0, 34.0), np.random.default_rng(0), warmup_s=0.0)
    link, clock = WireLink(), LockstepClock()
    runner = Runner(fw, link, clock)
    unit = Unit(fw, link, clock, runner, Controller(runner))
    unit.run(1.0)  # through BOOT
    if streaming:
        fw.handle(StreamStart(1))
        unit.run(0.1)
    return unit


def observable(unit: Unit) -> tuple:
    fw = unit.firmware
    return (
        fw.instrument.spec,
        fw.instrument.truth,
        dataclasses.asdict(fw.faults),
        fw.instrument.table.stalled,
        unit.clock.speed,
        unit.clock.paused,
        pickle.dumps(fw.instrument),
    )


# -- control requests ----------------------------------------------------------------------------

ABUSE = [
    ({"op": "bias_step", "gyro_dph": [NAN, 0, 0]}, "gyro_dph[0]"),
    ({"op": "bias_step", "accel_ug": [0, INF, 0]}, "accel_ug[1]"),
    ({"op": "bias_step", "gyro_dph": [1e300, 0, 0]}, "1000000"),
    ({"op": "bias_step", "gyro_dph": [1, 2]}, "three numbers"),
    ({"op": "vibration", "hz": NAN}, "hz"),
    ({"op": "vibration", "hz": 1e6}, "200 Hz"),
    ({"op": "vibration", "gyro_dph": INF}, "gyro_dph"),
    ({"op": "impulses", "gyro_dph": NAN}, "gyro_dph"),
    ({"op": "impulses", "count": 100_000}, "from 1 to 10000"),
    ({"op": "impulses", "count": 1_000_000}, "from 1 to 10000"),
    ({"op": "impulses", "count": 10_000, "interval_s": 3600}, "86400 s"),
    ({"op": "impulses", "interval_s": 0}, "0.01 to 3600"),
    ({"op": "set_truth", "azimuth_deg": NAN}, "azimuth_deg"),
    ({"op": "set_truth", "latitude_deg": INF}, "latitude_deg"),
    ({"op": "set_truth", "pitch_deg": 60}, "45"),
    ({"op": "set_truth", "heading": 3}, "keys are azimuth_deg, latitude_deg"),
    ({"op": "speed", "value": NAN}, "0.001 to 10000"),
    ({"op": "speed", "value": 0}, "0.001 to 10000"),
    ({"op": "speed", "speed": 2}, "unknown key 'speed'; keys are value"),
    ({"op": "delay_replies", "seconds": -1}, "0 to 3600"),
    ({"op": "delay_replies"}, "seconds is required"),
    ({"op": "drop", "count": 10**30}, "0 to 100000"),
    ({"op": "drop", "count": 2.5}, "whole number"),
    ({"op": "skip_counter", "count": -1}, "0 to 1000000"),
    ({"op": "silent", "on": "yes"}, "true or false"),
    ({"op": "stall", "on": 1}, "true or false"),
    ({"op": "wrong_result", "code": 256}, "0 to 255"),
    ({"op": "status", "verbose": True}, "takes no keys"),
    ({"op": "set_sensor", "values": [1]}, "object of sensor fields"),
    ({"op": "set_sensor", "values": {"gyro.arw_dpsh": NAN}}, "gyro.arw_dpsh"),
    ({"op": "set_sensor", "values": {"table.max_rate_dps": 1e300}}, "outside its range 0 to 1000"),
    ({"op": "set_sensor", "values": {"table.max_rate_dps": 100}}, "TABLE_MAX_RATE_MDPS"),
    ({"op": "set_sensor", "values": {"table.max_rate_dps": 1e-300}}, "0.001 to 50"),
    ({"op": "set_sensor", "values": {"table.settle_s": 500}}, "SETTLE_TIME_MS"),
    ({"op": "set_sensor", "values": {"table.settle_s": 1e9}}, "outside its range 0 to 600"),
    ({"op": "set_sensor", "values": {"disturbance.impulse_rate_hz": 1000}}, "400 impulses"),
    ({"op": "set_sensor", "values": {"disturbance.impulse_duration_s": 5}}, "1 s"),
    ({"op": "nope"}, "ops are bias_step"),
    ({"op": 5}, 'string "op"'),
    ([1, 2], 'string "op"'),
]


@pytest.mark.parametrize(("request_", "named"), ABUSE, ids=[json.dumps(r)[:60] for r, _ in ABUSE])
def test_bad_requests_are_refused_before_they_act_and_the_stream_goes_on(request_, named):
    unit = make_unit()
    before = observable(unit)
    reply = unit.control.handle(request_)
    assert reply["ok"] is False and named in reply["error"], reply
    assert "\n" not in reply["error"] and len(reply["error"]) < 300
    assert observable(unit) == before  # nothing changed
    unit.run(2.0)  # a value the wire cannot carry would raise here
    counters = unit.counters()
    assert len(counters) > 400 and np.all(np.diff(counters) == 1)


#: Values for required keys, and a skip of 0 ticks (a skip is a gap on purpose).
GIVEN: dict[str, dict[str, Any]] = {
    "set_sensor": {"values": {"gyro.arw_dpsh": 0.001}},
    "delay_replies": {"seconds": 0},
    "drop_replies": {"count": 0},
    "slow_heartbeat": {"factor": 1.0},
    "slow_stream": {"factor": 1.0},
    "skip_counter": {"count": 0},
    "speed": {"value": 1.0},
}


def test_every_operation_accepts_its_keys_at_their_defaults_and_bounds():
    unit = make_unit()
    for name, op in OPS.items():
        if name in ("silent", "pause", "reset"):
            continue  # they stop the stream on purpose
        args: dict[str, Any] = {
            k: key.default for k, key in op.keys.items() if key.default is not None
        }
        args.update(GIVEN.get(name, {}))
        reply = unit.control.handle({"op": name, **args})
        assert reply["ok"] is True, (name, reply)
        for key_name, key in op.keys.items():
            if key.lo is None or key.hi is None:
                continue

            def value(x: float, key=key) -> float | list[float]:
                return [x] * 3 if key.kind == "vec3" else x

            # Both bounds are inclusive; just beyond them is refused, naming the key.
            key.check(key_name, value(key.lo))  # raises if refused
            key.check(key_name, value(key.hi))
            for beyond in (key.lo - abs(key.lo) * 1e-9 - 1e-9, key.hi * (1 + 1e-9) + 1e-9):
                with pytest.raises(ControlError, match=key_name):
                    key.check(key_name, value(beyond))
    unit.run(2.0)
    assert np.all(np.diff(unit.counters()) == 1)


def test_timing_defects_ordered_through_the_control_channel():
    """A slow heartbeat, a slow stream and a dropped reply, in lockstep: exactly what was ordered,
    the counters counting the unit's own ticks, and everything back at factor 1."""
    unit = make_unit()
    fw = unit.firmware
    assert unit.control.handle({"op": "slow_heartbeat", "factor": 2.0})["ok"]
    assert unit.control.handle({"op": "slow_stream", "factor": 2.0})["ok"]
    unit.link.sent.clear()
    unit.run(2.0)
    statuses = [o.time_s for o in unit.link.sent if isinstance(o.message, Status)]
    np.testing.assert_allclose(np.diff(statuses), 0.2, atol=1e-9)  # 100 ms configured
    samples = [o.time_s for o in unit.link.sent if isinstance(o.message, Sample)]
    np.testing.assert_allclose(np.diff(samples), 0.01, atol=1e-9)  # 200 Hz configured: 100 Hz
    assert np.all(np.diff(unit.counters()) == 1)  # no gap: every tick the unit made is counted
    counters = [o.message.sample_counter for o in unit.link.sent if isinstance(o.message, Status)]
    assert set(np.diff(counters)) == {20}  # 20 of its ticks per heartbeat: 200 ms at 100 Hz
    assert unit.control.handle({"op": "drop_replies", "count": 1})["ok"]
    unit.link.sent.clear()
    fw.handle(GetStatus(7))
    fw.handle(GetStatus(8))
    unit.run(0.1)
    assert [r.seq for r in unit.link.messages(Reply)] == [8]  # the first one dropped
    assert fw.faults.drop_replies == 0
    assert unit.control.handle({"op": "slow_heartbeat", "factor": 1.0})["ok"]
    assert unit.control.handle({"op": "slow_stream", "factor": 1.0})["ok"]
    unit.link.sent.clear()
    unit.run(1.0)
    statuses = [o.time_s for o in unit.link.sent if isinstance(o.message, Status)]
    np.testing.assert_allclose(np.diff(statuses), 0.1, atol=1e-9)
    assert len(unit.link.messages(Sample)) in (199, 200, 201)


def test_the_largest_impulse_burst_costs_constant_memory_and_arrives_on_time():
    unit = make_unit()
    size = len(pickle.dumps(unit.firmware.instrument))
    t_inject = unit.firmware.now
    reply = unit.control.handle({"op": "impulses", "count": 10_000, "interval_s": 0.5})
    assert reply["ok"], reply
    assert len(pickle.dumps(unit.firmware.instrument)) - size < 2000
    unit.run(3.0)
    samples = [(o.time_s, o.message) for o in unit.link.sent if isinstance(o.message, Sample)]
    t = np.array([ts for ts, _ in samples])
    gyro = np.array([s.gyro for _, s in samples], dtype=float) * 1e-4  # deg/h
    hit = np.linalg.norm(gyro - np.median(gyro, axis=0), axis=1) > 1.0
    # Each impulse lasts 50 ms (the preset's duration; a 5 ms tick may end just after it) and
    # one starts every 0.5 s from the request: every one that has begun shows, nothing else.
    k = np.floor((t - t_inject) / 0.5)
    phase = (t - t_inject) - 0.5 * k
    inside = (t > t_inject) & (phase > 0) & (phase <= 0.0551)
    assert not (hit & ~inside).any()
    begun = {i for i in range(100) if t_inject + 0.5 * i + 0.0051 <= t[-1]}
    assert set(k[hit].astype(int)) == begun and len(begun) == 6


def test_a_value_that_is_not_a_number_in_the_physics_is_sent_as_saturated():
    unit = make_unit()
    fw = unit.firmware
    fw.apply(lambda: fw.instrument.inject_bias_step((NAN, 0.0, 0.0)))  # behind the channel's back
    unit.run(1.0)
    tail = unit.link.messages(Sample)[-100:]
    assert all(s.validity & Validity.GYRO_SATURATED for s in tail)
    assert np.all(np.diff(unit.counters()) == 1)


def test_a_specification_the_device_cannot_run_is_refused_at_construction():
    spec = load_spec("ideal").with_values({"table.max_rate_dps": 100.0})
    with pytest.raises(SimConfigError, match=r"table.max_rate_dps: 100 .*TABLE_MAX_RATE_MDPS"):
        Firmware(spec, Truth(), np.random.default_rng(0))


# -- the control socket -----------------------------------------------------------------------


@pytest.fixture
def served():
    unit = make_unit(streaming=False)
    server = ControlServer(unit.control, "127.0.0.1:0").start()
    yield server
    server.close()


def _raw(address: str) -> socket.socket:
    host, _, port = address.rpartition(":")
    return socket.create_connection((host.strip("[]"), int(port)), timeout=10)


def _replies(sock: socket.socket, lines: list[bytes]) -> list[dict]:
    reader = sock.makefile("rb")
    out = []
    for line in lines:
        sock.sendall(line)
        reply = reader.readline()
        assert reply.endswith(b"\n") and reply.count(b"\n") == 1, reply
        out.append(json.loads(reply))
    return out


def test_every_reply_is_one_json_line_and_the_connection_survives(served):
    deep = b"[" * 30_000 + b"]" * 30_000 + b"\n"
    long_int = b'{"op": "drop", "count": ' + b"9" * 5000 + b"}\n"
    lines = [
        deep,
        long_int,
        b'{"op": "drop", "count": ' + b"9" * 4000 + b"}\n",
        b"\xff\xfe\n",
        b"\n",
        b"null\n",
        b'{"op": "speed", "value": NaN}\n',
        b'{"op": "speed", "value": 1e400}\n',
        b'{"op": "status", "x": 1}\n',
        b'{"op": "nope"}\n',
        b'{"op": "status"}\n',
    ]
    with _raw(served.address) as sock:
        replies = _replies(sock, lines)
    assert [r["ok"] for r in replies] == [False] * (len(lines) - 1) + [True]
    assert "nested too deeply" in replies[0]["error"]
    assert "not a JSON line" in replies[1]["error"]
    assert "0 to 100000" in replies[2]["error"]
    assert replies[-1]["state"] == "READY"


def test_an_overlong_line_is_refused_without_holding_it(served):
    size = 10 * 1024 * 1024
    line = b"x" * size + b"\n"
    with _raw(served.address) as sock:
        reader = sock.makefile("rb")
        tracemalloc.start()
        try:
            sender = threading.Thread(target=sock.sendall, args=(line,))
            sender.start()
            first = json.loads(reader.readline())
            sender.join()
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < 2_000_000  # a few chunks of the limit, never the line
        assert first == {"ok": False, "error": f"request line longer than {MAX_LINE_BYTES} bytes"}
        assert _replies(sock, [b'{"op": "status"}\n'])[0]["ok"]  # the next line is answered


def test_a_line_of_exactly_the_limit_is_read(served):
    line = b'{"op": "status"}' + b" " * (MAX_LINE_BYTES - 16) + b"\n"
    assert len(line) == MAX_LINE_BYTES + 1
    with _raw(served.address) as sock:
        assert _replies(sock, [line])[0]["ok"]


def test_ipv6_loopback_works_or_is_one_clear_error():
    unit = make_unit(streaming=False)
    try:
        server = ControlServer(unit.control, "[::1]:0")
    except SimConfigError as exc:
        assert "cannot listen there" in str(exc) and "\n" not in str(exc)
        return
    with server.start():
        assert server.address.startswith("[::1]:")
        with ControlClient(server.address) as client:
            assert client.call("status")["ok"]
    assert not server._thread.is_alive()


def test_a_unix_socket_path_is_taken_only_when_free_or_stale(tmp_path):
    unit = make_unit(streaming=False)
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    with pytest.raises(SimConfigError, match="exists and is not a socket"):
        ControlServer(unit.control, f"unix:{precious}")
    assert precious.read_text() == "keep me"

    live = tmp_path / "live.sock"
    first = ControlServer(unit.control, f"unix:{live}").start()
    try:
        with pytest.raises(SimConfigError, match="another process is listening"):
            ControlServer(unit.control, f"unix:{live}")
        with ControlClient(f"unix:{live}") as client:
            assert client.call("status")["ok"]  # the first server still serves
    finally:
        first.close()
    assert not live.exists()

    stale = tmp_path / "stale.sock"
    left = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    left.bind(str(stale))
    left.close()  # a socket file nobody listens on, as a killed process leaves it
    server = ControlServer(unit.control, f"unix:{stale}").start()
    try:
        with ControlClient(f"unix:{stale}") as client:
            assert client.call("status")["ok"]
    finally:
        server.close()
    assert not stale.exists()


def test_simctl_names_the_right_key(served, capsys):
    assert main(["simctl", served.address, "speed", "speed=2"]) == 2  # refused: a wrong request
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown key 'speed'; keys are value" in err
    assert main(["simctl", served.address, "speed", "value=2"]) == 0


def test_simctl_help_lists_every_operation_and_key(capsys):
    assert main(["simctl", "--help"]) == 0
    text = capsys.readouterr().out
    for name, op in OPS.items():
        assert f"  {name}: {op.help.split()[0]}" in text
        for key_name, key in op.keys.items():
            assert key.describe(key_name).split(":")[0] in text, key_name


@pytest.mark.parametrize("baud", ["0", "-9600", "12.5", "fast"])
def test_sim_refuses_a_bad_baud_rate_at_parse_time(baud, capsys):
    assert main(["sim", "--pty", f"--baud={baud}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("northfinder sim: error: argument --baud:"), err


def test_sim_refuses_a_bad_control_address_at_parse_time(capsys):
    assert main(["sim", "--pty", "--control", "10.1.2.3:5"]) == 2
    assert "only loopback addresses" in capsys.readouterr().err


# -- firmware edges -----------------------------------------------------------------------------


def _kinds(outgoing: list[Outgoing]) -> list[tuple[str, int | None]]:
    return [
        (type(o.message).__name__, getattr(o.message, "seq", None))
        for o in outgoing
        if not isinstance(o.message, Sample)
    ]


@pytest.mark.parametrize("gap_s", [0.0, 0.0005])
@pytest.mark.parametrize("delay_s", [0.0, 0.05])
def test_reset_answers_the_commands_before_it_first(gap_s, delay_s):
    fw = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(0), warmup_s=0.0)
    fw.process(1.0)
    fw.faults.reply_delay_s = delay_s
    fw.handle(GetStatus(7))
    fw.process(gap_s)
    fw.handle(Reset(8))
    out = []
    for _ in range(60):
        out += fw.process(0.005)
    kinds = _kinds(out)
    # protocol.md 4.2: every command gets its reply; 6: the reply to RESET precedes BOOT's messages.
    assert kinds[:4] == [("Reply", 7), ("Status", None), ("Reply", 8), ("Identify", None)], kinds
    replies = [o.message for o in out if isinstance(o.message, Reply)]
    assert [r.seq for r in replies] == [7, 8] and all(r.ok for r in replies)
    statuses = [o.message for o in out if isinstance(o.message, Status)]
    assert statuses[0].state == DeviceState.READY  # answers GET_STATUS before the reset
    assert all(s.state == DeviceState.BOOT for s in statuses[1:3])
    times = [o.time_s for o in out]
    assert times == sorted(times)


@pytest.mark.parametrize("at_s", [1.014999999, 1.015, 1.0150000001, 1.0124999999, 1.0175])
def test_a_command_next_to_a_tick_boundary_loses_no_tick(at_s):
    fw = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(0), warmup_s=0.0)
    out = fw.process(0.9)
    fw.handle(StreamStart(1))
    out += fw.process(at_s - 0.9)
    fw.handle(GetStatus(2))
    for _ in range(500):
        out += fw.process(0.001)
    counters = [m.counter for m in (o.message for o in out) if isinstance(m, Sample)]
    assert np.all(np.diff(counters) == 1), counters[:10]


def test_decimal_millisecond_steps_with_commands_keep_every_tick_on_its_grid():
    fw = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(0), warmup_s=0.0)
    out = []
    for i in range(4000):
        out += fw.process(0.001)
        if i == 900:
            fw.handle(StreamStart(1))
        elif i > 900 and i % 7 == 0:
            fw.handle(GetStatus(i & 0xFF))
    assert fw.now == 4.0
    samples = [o for o in out if isinstance(o.message, Sample)]
    counters = np.array([o.message.counter for o in samples])  # type: ignore[union-attr]
    times = np.array([o.time_s for o in samples])
    assert np.all(np.diff(counters) == 1)
    assert np.allclose(times, (counters + 1) / 200.0, rtol=0, atol=1e-12)
    answers = {o.time_s for o in out if isinstance(o.message, Reply)}
    beats = np.array([o.time_s for o in out if isinstance(o.message, Status)])
    beats = beats[[b not in answers for b in beats]]  # not the statuses GET_STATUS asked for
    assert len(beats) > 35 and np.all(np.round(beats * 10) / 10 == beats)  # exactly on 100 ms


def test_a_table_jammed_mid_move_ends_in_a_drive_fault():
    unit = make_unit("paper-rlg")
    fw = unit.firmware
    fw.handle(RotateTo(2, 180_000_000))
    unit.run(10.0)
    assert fw.state == DeviceState.ROTATING
    jammed_at, n = fw.now, len(unit.link.sent)
    assert unit.control.handle({"op": "stall"})["ok"]
    unit.run(30.0)  # past the end of the 180 deg profile and its settling
    status = fw.status()
    assert fw.state == DeviceState.FAULT and status.faults & Fault.DRIVE
    angle = status.angle * 1e-6
    assert 20.0 < angle < 170.0  # where it jammed, far from the command
    after = unit.link.sent[n:]
    first = next(o for o in after if isinstance(o.message, Status))
    assert first.message.state == DeviceState.FAULT and first.time_s - jammed_at <= 0.005
    states = {o.message.state for o in after if isinstance(o.message, Status)}
    assert states == {DeviceState.FAULT}  # never READY
    assert all(s.validity & Validity.FAULT for s in unit.link.messages(Sample)[-100:])
    assert unit.control.handle({"op": "reset"})["ok"]
    unit.run(1.0)
    assert fw.state == DeviceState.READY


def test_a_table_jammed_at_rest_faults_on_the_next_move_not_before():
    unit = make_unit("paper-rlg")
    fw = unit.firmware
    assert unit.control.handle({"op": "stall"})["ok"]
    unit.run(1.0)
    assert fw.state == DeviceState.READY  # it holds its angle: nothing is wrong yet
    fw.handle(RotateTo(3, 90_000_000))
    unit.run(0.01)
    assert fw.state == DeviceState.FAULT and fw.status().faults & Fault.DRIVE
    first = next(m for m in unit.link.messages(Status)[::-1] if m.state != DeviceState.FAULT)
    assert first.state == DeviceState.READY  # no SETTLING status after the FAULT one
    tail = [m.state for m in unit.link.messages(Status)]
    assert tail[tail.index(DeviceState.FAULT) :] == [DeviceState.FAULT] * (
        len(tail) - tail.index(DeviceState.FAULT)
    )


def test_the_channel_refuses_through_the_client_with_the_servers_message(served):
    with ControlClient(served.address) as client:
        with pytest.raises(ControlError, match="impulses: count: expected a whole number"):
            client.call("impulses", count=100_000)
        assert client.call("impulses", count=3)["ok"]


def test_identify_follows_reset_reply_once():
    fw = Firmware(load_spec("ideal"), Truth(), np.random.default_rng(0), warmup_s=0.0)
    fw.process(1.0)
    fw.handle(Reset(1))
    out = fw.process(1.0)
    assert sum(isinstance(o.message, Identify) for o in out) == 1


def test_a_server_closed_before_it_started_neither_hangs_nor_leaves_its_socket(tmp_path):
    path = tmp_path / "x.sock"
    unit = make_unit(streaming=False)
    server = ControlServer(unit.control, f"unix:{path}")
    server.close()  # never started
    assert not os.path.exists(path)
