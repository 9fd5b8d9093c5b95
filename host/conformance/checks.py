"""The checks of the conformance suite, in the order they run (protocol.md section numbers in
brackets). Each records figures and problems on its :class:`~northfinder.host.conformance.core.Ctx`."""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass, field

from northfinder.driver.protocol.budget import max_sample_rate, rate_fits
from northfinder.driver.protocol.constants import (
    ANGLE_FULL_TURN,
    CAN_BITRATES,
    CONFIG_DEFAULTS,
    CONFIG_LIMITS,
    INT32_MIN,
    PROTOCOL_VERSION_MAJOR,
    REPLY_DEADLINE_MS,
    ROTATE_BY_LIMIT,
    SAMPLE_RATES_HZ,
    SERIAL_BAUDS,
    CanFunction,
    ConfigKey,
    DeviceState,
    Direction,
    Opcode,
    Result,
    SerialType,
    Validity,
)
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    GetStatus,
    Home,
    RequestIdentify,
    Reset,
    RotateBy,
    RotateTo,
    SelfTest,
    SetConfig,
    Status,
    Stop,
    StreamStart,
    StreamStop,
)
from northfinder.driver.protocol.serial import SerialFrame
from northfinder.host.conformance.core import Ctx, check
from northfinder.host.conformance.session import Answer, SampleRecord

ANGLE_DEG = 1e-6  # deg per angle count (the default; IDENTIFY may report another)
_NOT_GOOD = 0xFC  # validity bits 2..7
_GOOD = Validity.GYRO_VALID | Validity.ACCEL_VALID
SELF_TEST_MAX_S = 0.5
BOOT_MAX_S = 1.0
RESET_TO_BOOT_S = 0.1
STATUS_OFFSET_LIMIT = 16  # ticks between STATUS_COUNTERS and the latest sample received


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
def _wrap(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def _deg(c: Ctx, counts: int) -> float:
    return counts * c.shared.get("angle_scale", ANGLE_DEG)


def _counts(c: Ctx, deg: float) -> int:
    return round((deg % 360.0) / c.shared.get("angle_scale", ANGLE_DEG)) % ANGLE_FULL_TURN


def _profile_s(distance_deg: float, rate_dps: float, accel_dps2: float) -> float:
    """Duration of a rest-to-rest trapezoidal move (triangular when too short to reach the rate)."""
    d, v, a = abs(distance_deg), rate_dps, accel_dps2
    if d <= v * v / a:
        return 2.0 * math.sqrt(d / a)
    return v / a + d / v


def _table(c: Ctx) -> tuple[float, float, float]:
    """(rate deg/s, acceleration deg/s^2, settle s) from the configuration."""
    cfg = c.config()
    return (
        cfg[ConfigKey.TABLE_MAX_RATE_MDPS] / 1000.0,
        cfg[ConfigKey.TABLE_MAX_ACCEL_MDPS2] / 1000.0,
        cfg[ConfigKey.SETTLE_TIME_MS] / 1000.0,
    )


def _allowed_move_s(c: Ctx, distance_deg: float) -> tuple[float, float]:
    """(expected, allowed) unit seconds from a move's OK reply to READY."""
    v, a, settle = _table(c)
    expected = _profile_s(distance_deg, v, a) + settle
    return expected, expected * 1.1 + c.opt.settle_margin_s


def _validity_problem(v: int, state: DeviceState | None) -> str | None:
    """What is wrong with validity bits ``v`` for a sample taken in ``state`` (protocol.md 4.5)."""
    if state == DeviceState.READY:
        if (v & _GOOD) != _GOOD or v & _NOT_GOOD:
            return "READY needs GYRO_VALID and ACCEL_VALID set and bits 2..7 clear"
    elif state in (DeviceState.BOOT, DeviceState.WARMUP):
        if not v & Validity.WARMING_UP:
            return f"{state.name} needs WARMING_UP"
    elif state == DeviceState.ROTATING:
        if not v & Validity.TABLE_MOVING:
            return "ROTATING needs TABLE_MOVING"
    elif state == DeviceState.SETTLING:
        if not v & Validity.TABLE_SETTLING:
            return "SETTLING needs TABLE_SETTLING"
    elif state == DeviceState.FAULT and not v & Validity.FAULT:
        return "FAULT needs the FAULT bit"
    return None


def _judge_validity(c: Ctx, samples: list[SampleRecord]) -> tuple[int, int, list[str]]:
    """(judged, bad, first problems) for samples away from state changes."""
    s = c.s
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    guard = s.wall(2.0 / rate) + 0.02
    changes = [t for t, _, _ in s.transitions]
    judged = bad = 0
    problems: list[str] = []
    for rec in samples:
        if not rec.complete or any(abs(rec.t - t) < guard for t in changes):
            continue
        judged += 1
        state = s.state_at(rec.t)
        why = _validity_problem(rec.validity, state)
        if why is not None:
            bad += 1
            if len(problems) < 3:
                problems.append(f"sample {rec.counter} validity 0x{rec.validity:02X}: {why}")
    return judged, bad, problems


def _refusals(c: Ctx, cases: list[tuple[str, Command | bytes, Result]]) -> None:
    """Send each case, expect its code, and expect commands rejected to rise by the refusals."""
    s = c.s
    before = s.get_status()
    refused = 0
    for what, cmd, expected in cases:
        a = s.request(cmd)
        c.expect(a, expected, what)
        if a.reply is not None and a.reply.result != Result.OK:
            refused += 1
    after = s.get_status()
    delta = (after.cmd_rejected - before.cmd_rejected) & 0xFF
    c.fig("cases", len(cases))
    c.fig("cmd_rejected delta", delta)
    if delta != refused:
        c.fail(f"commands rejected rose by {delta}, {refused} refusal(s) were sent")


def _config_unchanged(c: Ctx) -> None:
    cfg = c.config()
    for key in (k for k in ConfigKey if not k.read_only and k != ConfigKey.STREAMING):
        now = c.s.get_config(key)
        if now != cfg[key]:
            c.fail(f"{key.name} changed from {cfg[key]} to {now} although the command was refused")


def _undisturbed(c: Ctx, t0: float) -> None:
    """The stream ran on without a gap since ``t0`` and the unit still answers."""
    s = c.s
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    s.idle(max(0.2, 10.0 / rate))
    gaps = s.gaps_since(t0)
    if gaps:
        c.fail(
            f"the stream was disturbed: {gaps[0]}"
            + (f" (+{len(gaps) - 1} more)" if len(gaps) > 1 else "")
        )
    after = [r for r in s.samples if r.t >= t0]
    c.fig("samples meanwhile", len(after))
    if s.streaming and not after:
        c.fail("no samples arrived after the bad input")
    a = s.request(GetStatus(0))
    c.expect(a, Result.OK, "GET_STATUS after the bad input")


def _no_reply_since(c: Ctx, t0: float, what: str) -> None:
    c.s.idle(max(0.1, c.opt.reply_limit_ms / 1000.0))
    got = [r for t, r in c.s.unsolicited if t >= t0]
    if got:
        r = got[0]
        c.fail(
            f"{what} was answered (seq {r.seq}, opcode 0x{int(r.opcode):02X}, result {int(r.result)})"
        )


def _dropped_silently(
    c: Ctx, send: Callable[[], None], count: int, reply_what: str, count_what: str
) -> None:
    """Send bad input with the stream on; expect no reply, ``count`` more in rx malformed and a
    stream that runs on undisturbed (protocol.md 9)."""
    s = c.s
    c.ready()
    c.stream_on()
    before = s.get_status()
    t0 = s.now()
    send()
    _no_reply_since(c, t0, reply_what)
    _malformed_delta(c, before, count, count_what)
    _undisturbed(c, t0)


def _malformed_delta(c: Ctx, before: Status, expected: int | None, what: str) -> None:
    after = c.s.get_status()
    delta = (after.rx_malformed - before.rx_malformed) & 0xFFFF
    c.fig("rx_malformed delta", delta)
    if expected is not None and delta != expected:
        c.fail(f"rx malformed rose by {delta} for {what}, expected {expected}")


# -- moves ---------------------------------------------------------------------------------------
@dataclass
class Move:
    """One commanded move and what the suite saw of it (times are host times)."""

    what: str
    answer: Answer
    start_deg: float
    target_deg: float | None = None
    first_change: float | None = None
    first_index: int = 0
    t_settling: float | None = None
    t_ready: float | None = None
    end_deg: float | None = None
    travel_deg: float | None = None
    states: list[DeviceState] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.answer.reply is not None and self.answer.reply.result == Result.OK


def _begin_move(c: Ctx, cmd: Command, what: str, target_deg: float | None = None) -> Move:
    """Send a move from READY and wait for its first state change; record problems."""
    s = c.s
    c.ready()
    c.stream_on()
    start = _deg(c, s.get_status().angle)
    n = len(s.statuses)
    a = s.request(cmd)
    m = Move(what, a, start, target_deg)
    if not c.expect(a, Result.OK, what):
        return m
    limit = max(s.reply_wait_s, s.wall(0.5))
    i = s.wait_state(
        {DeviceState.ROTATING, DeviceState.SETTLING, DeviceState.FAULT}, s.unit(limit), start=n
    )
    if i is None:
        c.fail(f"{what}: no status of the state change followed the OK reply")
        return m
    m.first_index = i
    t = m.first_change = s.statuses[i][0]
    assert a.received is not None
    lat = c.ms(t - a.received)
    c.shared.setdefault("state_change_ms", []).append(lat)
    if lat > c.opt.reply_limit_ms:
        c.fail(f"{what}: the state-change status came {lat:.0f} ms after the reply")
    return m


def _finish_move(c: Ctx, m: Move, distance_deg: float | None = None) -> Move:
    """Wait for READY after a move, read where the table ended and how it got there."""
    s = c.s
    if m.first_change is None:
        return m
    dist = abs(distance_deg if distance_deg is not None else 360.0)
    _, allowed = _allowed_move_s(c, dist)
    end = s.wait_state(
        {DeviceState.READY, DeviceState.FAULT}, allowed * 2 + 2.0, start=m.first_index + 1
    )
    seq: list[DeviceState] = []
    last = len(s.statuses) - 1 if end is None else end
    for _, st in s.statuses[m.first_index : last + 1]:
        if not seq or seq[-1] != st.state:
            seq.append(st.state)
    m.states = seq
    settling = [
        tt for tt, st in s.statuses[m.first_index : last + 1] if st.state == DeviceState.SETTLING
    ]
    m.t_settling = settling[0] if settling else None
    t = None if end is None else s.statuses[end][0]
    if t is None:
        c.fail(f"{m.what}: the unit did not report READY within {allowed * 2 + 2:.1f} s")
        return m
    if s.statuses and s.state == DeviceState.FAULT:
        c.fail(f"{m.what}: the unit went to FAULT")
        return m
    m.t_ready = t
    m.end_deg = _deg(c, s.get_status().angle)
    angles = [r.angle for r in s.samples_between(m.answer.sent, t) if r.angle is not None]
    if len(angles) > 1:
        m.travel_deg = sum(_wrap(_deg(c, b - a)) for a, b in itertools.pairwise(angles))
    _, _, settle = _table(c)
    want = [DeviceState.ROTATING, DeviceState.SETTLING, DeviceState.READY]
    if settle == 0 and DeviceState.SETTLING not in seq:
        want.remove(DeviceState.SETTLING)
    if seq != want:
        c.fail(
            f"{m.what}: states {' -> '.join(x.name for x in seq)}, expected {' -> '.join(x.name for x in want)}"
        )
    return m


def _move(
    c: Ctx, cmd: Command, what: str, target_deg: float | None = None, distance: float | None = None
) -> Move:
    return _finish_move(c, _begin_move(c, cmd, what, target_deg), distance)


def _judge_end(c: Ctx, m: Move, target_deg: float) -> float | None:
    if m.end_deg is None:
        return None
    err = _wrap(m.end_deg - target_deg)
    if abs(err) > c.opt.accuracy_deg:
        c.fail(
            f"{m.what}: the table ended at {m.end_deg:.4f} deg, {err:+.4f} deg from {target_deg % 360:.4f} "
            f"(allowed {c.opt.accuracy_deg:g})"
        )
    return err


def _long_move(c: Ctx) -> tuple[RotateBy, float]:
    """A ROTATE_BY lasting about two seconds of the unit's time, alternating in sign."""
    v, a, _ = _table(c)
    d = max(5.0, min(170.0, v * (2.0 - v / a)))
    sign = c.shared.get("sign", 1.0)
    c.shared["sign"] = -sign
    return RotateBy(0, round(sign * d / c.shared.get("angle_scale", ANGLE_DEG))), d


def _still_rotating(c: Ctx, a: Answer) -> bool:
    return c.s.state_when_answered(a) == DeviceState.ROTATING


# ------------------------------------------------------------------------------------------------
# identity, state and configuration
# ------------------------------------------------------------------------------------------------
@check("identify", "IDENTIFY answered OK, then a whole identify message of protocol major 1 (4.7)")
def identify(c: Ctx) -> None:
    s = c.s
    n = len(s.identifies)
    errors = len(s.link_errors)
    a = s.request(RequestIdentify(0))
    if not c.expect(a, Result.OK, "IDENTIFY"):
        return
    if not s.wait_until(lambda: len(s.identifies) > n, max(s.reply_wait_s, s.wall(0.5))):
        c.fail("no identify message followed the OK reply")
        return
    ident = s.identifies[n][1]
    c.fig("model", ident.model)
    c.fig("serial", ident.serial_number)
    c.fig("firmware", ".".join(map(str, ident.firmware_version)))
    c.fig("protocol", "{}.{}".format(*ident.protocol_version))
    c.fig("max rate", f"{ident.max_sample_rate_hz} Hz")
    if ident.protocol_version[0] != PROTOCOL_VERSION_MAJOR:
        c.fail(
            f"protocol major version {ident.protocol_version[0]}, this suite checks {PROTOCOL_VERSION_MAJOR}"
        )
    if ident.max_sample_rate_hz not in SAMPLE_RATES_HZ:
        c.fail(f"highest sample rate {ident.max_sample_rate_hz} Hz is not one of {SAMPLE_RATES_HZ}")
    for name in ("gyro_scale", "accel_scale", "angle_scale", "temperature_scale"):
        value = getattr(ident, name).value
        if not (math.isfinite(value) and value > 0):
            c.fail(f"{name} {value!r} is not a positive number")
    if ident.angle_scale.value > 0:
        c.shared["angle_scale"] = ident.angle_scale.value
    if len(s.link_errors) > errors:
        c.fail(f"while identifying: {s.link_errors[errors][1]}")


@check("state.ready", "the unit reaches READY (after boot and warm-up) without a fault (5)")
def state_ready(c: Ctx) -> None:
    st = c.s.get_status()
    c.fig("state", st.state.name)
    t0 = c.s.now()
    c.ready()
    c.fig("waited", f"{c.s.unit(c.s.now() - t0):.1f} s")
    st = c.s.get_status()
    if st.faults:
        c.fail(f"READY with fault flags 0x{int(st.faults):02X}")


@check("command.get_status", "GET_STATUS answered OK and a status follows at once (4.1, 4.6)")
def command_get_status(c: Ctx) -> None:
    s = c.s
    a = s.request(GetStatus(0))
    if not c.expect(a, Result.OK, "GET_STATUS"):
        return
    assert a.received is not None
    ok = s.wait_until(lambda: any(t >= a.received for t, _ in s.statuses), s.reply_wait_s)
    if not ok:
        c.fail("no status followed the OK reply")
        return
    t, st = next((t, st) for t, st in s.statuses if t >= a.received)
    lat = c.ms(t - a.sent)
    c.fig("status after", f"{lat:.1f} ms")
    c.fig("state", st.state.name)
    c.fig("angle", f"{_deg(c, st.angle):.4f} deg")
    c.fig("temperature", "none" if st.temperature == -32768 else f"{st.temperature / 100:.2f} degC")
    if lat > c.opt.reply_limit_ms:
        c.fail(f"the status came {lat:.0f} ms after the command")
    if not 0 <= st.angle < ANGLE_FULL_TURN:
        c.fail(f"status angle {st.angle} outside [0, 360e6)")


@check("command.get_config", "GET_CONFIG of every key answered OK with a value in range (4.4, 7)")
def command_get_config(c: Ctx) -> None:
    s = c.s
    values: dict[ConfigKey, int] = {}
    for key in ConfigKey:
        a = s.request(GetConfig(0, key))
        if not c.expect(a, Result.OK, f"GET_CONFIG {key.name}"):
            continue
        assert a.reply is not None
        k, v = a.reply.config_value()
        if int(k) != key:
            c.fail(f"GET_CONFIG {key.name}: the reply names key {int(k)}")
        values[key] = v
    if len(values) != len(ConfigKey):
        return
    c.shared["config"] = dict(values)
    for key, (lo, hi) in CONFIG_LIMITS.items():
        if not lo <= values[key] <= hi:
            c.fail(f"{key.name} = {values[key]} outside {lo}..{hi}")
    rate, hb = values[ConfigKey.SAMPLE_RATE_HZ], values[ConfigKey.HEARTBEAT_PERIOD_MS]
    bitrate = values[ConfigKey.LINK_BITRATE]
    if rate not in SAMPLE_RATES_HZ:
        c.fail(f"SAMPLE_RATE_HZ = {rate} is not one of {SAMPLE_RATES_HZ}")
    allowed = CAN_BITRATES if c.link_kind == "can" else SERIAL_BAUDS
    if bitrate not in allowed:
        c.fail(f"LINK_BITRATE = {bitrate} is not one of {allowed}")
    node = values[ConfigKey.NODE_ID]
    if c.link_kind == "can" and node != c.opt.node_id:
        c.fail(f"NODE_ID = {node}, but the unit answers as node {c.opt.node_id}")
    expected_max = max_sample_rate(c.link_kind, bitrate, hb)
    if values[ConfigKey.LINK_MAX_SAMPLE_RATE_HZ] != expected_max:
        c.fail(
            f"LINK_MAX_SAMPLE_RATE_HZ = {values[ConfigKey.LINK_MAX_SAMPLE_RATE_HZ]}, protocol.md 7 "
            f"gives {expected_max} Hz for {bitrate} bit/s with a {hb} ms heartbeat"
        )
    if rate in SAMPLE_RATES_HZ and not rate_fits(c.link_kind, bitrate, rate, hb):
        c.fail(f"the configured {rate} Hz does not fit the link (protocol.md 7)")
    c.fig("sample rate", f"{rate} Hz")
    c.fig("heartbeat", f"{hb} ms")
    c.fig("link", f"{bitrate} bit/s")
    c.fig(
        "table",
        f"{values[ConfigKey.TABLE_MAX_RATE_MDPS] / 1000:g} deg/s, "
        f"{values[ConfigKey.TABLE_MAX_ACCEL_MDPS2] / 1000:g} deg/s2, settle {values[ConfigKey.SETTLE_TIME_MS]} ms",
    )


# ------------------------------------------------------------------------------------------------
# stream and heartbeat
# ------------------------------------------------------------------------------------------------
@check(
    "command.stream_stop",
    "STREAM_STOP answered OK; no sample after the current tick; STREAMING reads 0 (4.1)",
)
def command_stream_stop(c: Ctx) -> None:
    s = c.s
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    a = s.request(StreamStop(0))
    if not c.expect(a, Result.OK, "STREAM_STOP"):
        return
    s.streaming = False
    assert a.received is not None
    s.idle(max(0.3, 5.0 / rate))
    late = [
        r for r in s.samples if r.t > a.received + s.wall(1.0 / rate) + c.opt.reply_limit_ms / 1000
    ]
    if late:
        c.fail(
            f"{len(late)} sample(s) arrived after STREAM_STOP and its tick (last counter {late[-1].counter})"
        )
    v = s.get_config(ConfigKey.STREAMING)
    if v != 0:
        c.fail(f"STREAMING reads {v} after STREAM_STOP")


@check(
    "command.stream_start",
    "STREAM_START answered OK; samples start at the next tick; STREAMING reads 1 (4.1)",
)
def command_stream_start(c: Ctx) -> None:
    s = c.s
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    if s.streaming:
        s.stop_stream()
        s.idle(0.2)
    s.begin_segment()
    a = s.request(StreamStart(0))
    if not c.expect(a, Result.OK, "STREAM_START"):
        return
    s.streaming = True
    assert a.received is not None
    n = len(s.samples)
    if not s.wait_until(lambda: len(s.samples) > n, s.wall(1.0 / rate) + 0.5):
        c.fail("no sample arrived after STREAM_START")
        return
    first = c.ms(s.samples[n].t - a.received)
    c.fig("first sample after reply", f"{first:.1f} ms")
    if first > 1000.0 / rate + c.opt.reply_limit_ms:
        c.fail(
            f"the first sample came {first:.0f} ms after the reply (one tick is {1000 / rate:g} ms)"
        )
    v = s.get_config(ConfigKey.STREAMING)
    if v != 1:
        c.fail(f"STREAMING reads {v} after STREAM_START")


def _window(c: Ctx) -> tuple[float, float]:
    """The observation window (stream on, no commands), taken once and shared."""
    if "window" not in c.shared:
        c.ready()
        c.stream_on()
        seconds = max(c.opt.stream_seconds, 3.0)
        t0 = c.s.now()
        c.s.idle(seconds)
        c.shared["window"] = (t0, c.s.now())
    return c.shared["window"]


def _heartbeat_intervals(c: Ctx) -> list[float]:
    t0, t1 = _window(c)
    sts = [(t, st) for t, st in c.s.statuses if t0 <= t <= t1]
    out = []
    for (ta, sa), (tb, sb) in itertools.pairwise(sts):
        if sa.state == sb.state:  # a state change sends an extra status
            out.append(c.ms(tb - ta))
    return out


@check(
    "heartbeat.period",
    "heartbeat period (fit over the window) equals HEARTBEAT_PERIOD_MS within the rate tolerance (6)",
)
def heartbeat_period(c: Ctx) -> None:
    period = c.config()[ConfigKey.HEARTBEAT_PERIOD_MS]
    t0, t1 = _window(c)
    times = [t for t, _ in c.s.statuses if t0 <= t <= t1]
    if len(times) < 6:
        c.fail(f"only {len(times)} status message(s) in the window")
        return
    # The slope of arrival time against index: a late arrival at an end barely moves it.
    mean = c.ms(statistics.linear_regression(range(len(times)), times).slope)
    c.fig("period", f"{mean:.2f} ms (configured {period})")
    c.fig("median interval", f"{statistics.median(_heartbeat_intervals(c)):.2f} ms")
    c.fig("statuses", len(times))
    if abs(mean - period) > c.opt.rate_tolerance * period:
        c.fail(
            f"heartbeat period {mean:.2f} ms, configured {period} ms "
            f"(tolerance {c.opt.rate_tolerance:.0%})"
        )


@check(
    "heartbeat.jitter",
    "every heartbeat interval within 10 % of the period, plus the host margin (6)",
)
def heartbeat_jitter(c: Ctx) -> None:
    period = c.config()[ConfigKey.HEARTBEAT_PERIOD_MS]
    iv = _heartbeat_intervals(c)
    if len(iv) < 5:
        c.fail(f"only {len(iv) + 1} status message(s) in the window")
        return
    dev = [abs(x - period) for x in iv]
    limit = 0.1 * period + c.s.unit(c.opt.jitter_margin_ms)
    c.fig("max deviation", f"{max(dev):.2f} ms")
    c.fig("std", f"{statistics.pstdev(iv):.2f} ms")
    c.fig("limit", f"{limit:.1f} ms")
    if max(dev) > limit:
        worst = iv[dev.index(max(dev))]
        c.fail(
            f"a heartbeat interval of {worst:.1f} ms against a period of {period} ms (limit +-{limit:.1f} ms)"
        )


@check(
    "stream.rate", "sample rate over the window equals SAMPLE_RATE_HZ within the rate tolerance (6)"
)
def stream_rate(c: Ctx) -> None:
    t0, t1 = _window(c)
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    recs = c.s.samples_between(t0, t1)
    c.fig("window", f"{c.s.unit(t1 - t0):.1f} s")
    c.fig("samples", len(recs))
    if len(recs) < 10:
        c.fail(f"only {len(recs)} samples in {c.s.unit(t1 - t0):.1f} s")
        return
    ts = [r.t for r in recs]
    # Samples received against time: a counter jump is stream.counters' business, not the rate's.
    slope = statistics.linear_regression(ts, range(len(ts))).slope  # samples per wall second
    measured = slope / c.s.time_scale
    received = len(recs) / (c.s.unit(ts[-1] - ts[0]) or 1.0)
    c.fig("rate", f"{measured:.3f} Hz (configured {rate})")
    c.fig("received", f"{received:.2f} samples/s")
    if abs(measured - rate) > c.opt.rate_tolerance * rate:
        c.fail(
            f"sample rate {measured:.3f} Hz, configured {rate} Hz (tolerance {c.opt.rate_tolerance:.0%})"
        )
    if abs(received - rate) > c.opt.rate_tolerance * rate + 2.0 / c.s.unit(ts[-1] - ts[0]):
        c.fail(f"{received:.2f} samples/s received against {rate} Hz")


@check(
    "stream.counters",
    "sample counter +1 per tick with no gap, no incomplete tick, no lost frame (4.5, 8)",
)
def stream_counters(c: Ctx) -> None:
    s = c.s
    t0, t1 = _window(c)
    recs = s.samples_between(t0, t1)
    gaps = [text for t, text in s.gaps if t0 <= t <= t1]
    c.fig("samples", len(recs))
    if recs:
        c.fig("counters", f"{recs[0].counter}..{recs[-1].counter}")
    c.fig("gaps", len(gaps))
    if not recs:
        c.fail("no samples in the window")
    if gaps:
        c.fail("; ".join(gaps[:3]) + (f" (+{len(gaps) - 3} more)" if len(gaps) > 3 else ""))
    offs = [d for t, d in s.status_offsets if t0 <= t <= t1]
    if offs:
        c.fig("status counter offset", f"{min(offs)}..{max(offs)} ticks")
        # The anchor of the 8-bit tick extension (protocol.md 8) must be well within 128 ticks.
        bad = [o for o in offs if abs(o) > STATUS_OFFSET_LIMIT]
        if bad:
            c.fail(
                f"STATUS_COUNTERS sample counter differs from the latest sample by {bad[0]} ticks "
                f"(limit {STATUS_OFFSET_LIMIT})"
            )


@check(
    "stream.validity",
    "validity bits of every sample match the state: READY gives GYRO_VALID|ACCEL_VALID, bits 2..7 clear (4.5)",
)
def stream_validity(c: Ctx) -> None:
    t0, t1 = _window(c)
    judged, bad, problems = _judge_validity(c, c.s.samples_between(t0, t1))
    c.fig("judged", judged)
    c.fig("bad", bad)
    if not judged:
        c.fail("no samples to judge")
    if bad:
        c.fail(f"{bad} of {judged} samples: " + "; ".join(problems))


# ------------------------------------------------------------------------------------------------
# commands at rest
# ------------------------------------------------------------------------------------------------
@check("command.stop_at_rest", "STOP at rest answered OK and changes nothing (4.1, 5)")
def command_stop_at_rest(c: Ctx) -> None:
    s = c.s
    c.ready()
    n = len(s.transitions)
    a = s.request(Stop(0))
    c.expect(a, Result.OK, "STOP")
    s.idle(0.3)
    changed = s.transitions[n:]
    if changed:
        c.fail(f"STOP at rest changed the state to {changed[0][2].name}")


@check(
    "command.self_test",
    "SELF_TEST in READY answered OK with a zero failure mask within 500 ms (4.1)",
)
def command_self_test(c: Ctx) -> None:
    s = c.s
    c.ready()
    a = s.request(SelfTest(0), wait=s.wall(SELF_TEST_MAX_S) + s.reply_wait_s)
    if not c.expect(a, Result.OK, "SELF_TEST"):
        return
    assert a.reply is not None and a.latency is not None
    c.fig("reply after", f"{c.ms(a.latency):.1f} ms")
    mask = a.reply.self_test_failures()
    c.fig("failure mask", f"0x{int(mask):04X}")
    if mask:
        c.fail(f"the self test reports failures {mask!r}")
    if c.ms(a.latency) > SELF_TEST_MAX_S * 1000 + c.opt.reply_limit_ms:
        c.fail(f"SELF_TEST took {c.ms(a.latency):.0f} ms")
    st = s.get_status()
    if st.state != DeviceState.READY:
        c.fail(f"state {st.state.name} after a passed self test")


@check(
    "command.set_config",
    "SET_CONFIG echoes the value now in effect; heartbeat and sample rate follow it (4.4)",
)
def command_set_config(c: Ctx) -> None:
    s = c.s
    c.ready()
    c.stream_on()
    cfg = c.config()
    kind, bitrate = c.link_kind, cfg[ConfigKey.LINK_BITRATE]
    rate, hb = cfg[ConfigKey.SAMPLE_RATE_HZ], cfg[ConfigKey.HEARTBEAT_PERIOD_MS]

    def set_value(key: ConfigKey, value: int) -> bool:
        a = s.request(SetConfig(0, key, value))
        if not c.expect(a, Result.OK, f"SET_CONFIG {key.name} {value}"):
            return False
        assert a.reply is not None
        k, v = a.reply.config_value()
        if int(k) != key or v != value:
            c.fail(f"SET_CONFIG {key.name} {value} echoed key {int(k)} value {v}")
        got = s.get_config(key)
        if got != value:
            c.fail(f"GET_CONFIG {key.name} reads {got} after setting {value}")
        return True

    # Heartbeat period: twice the configured one, if it fits (a longer period always does).
    new_hb = min(hb * 2, 5000)
    if set_value(ConfigKey.HEARTBEAT_PERIOD_MS, new_hb):
        t0 = s.now()
        s.idle(max(6 * new_hb / 1000.0, 0.5))
        sts = [(t, st) for t, st in s.statuses if t >= t0]
        iv = [c.ms(b - a) for (a, _), (b, _) in itertools.pairwise(sts[1:])]
        # The same intervals on the unit's own clock, its sample counter: a host that is itself
        # late (a loaded machine, an emulator) must not make a punctual unit fail.
        dev = [
            1000.0 * ((y.sample_counter - x.sample_counter) & 0xFFFFFFFF) / rate
            for (_, x), (_, y) in itertools.pairwise(sts[1:])
        ]
        if len(iv) >= 3:
            mean = statistics.median(iv)  # one late arrival must not decide
            on_unit = statistics.median(dev)
            c.fig(
                "heartbeat",
                f"{mean:.1f} ms wall, {on_unit:.1f} ms by the sample counter (set {new_hb})",
            )
            if min(abs(mean - new_hb), abs(on_unit - new_hb)) > 0.1 * new_hb:
                c.fail(f"after setting {new_hb} ms the heartbeat period is {mean:.1f} ms")
        else:
            c.fail(f"only {len(iv)} heartbeat interval(s) after setting {new_hb} ms")
        set_value(ConfigKey.HEARTBEAT_PERIOD_MS, hb)
    # Sample rate: another rate that fits; the counter keeps counting through the change.
    others = [r for r in SAMPLE_RATES_HZ if r != rate and rate_fits(kind, bitrate, r, hb)]
    if others:
        new_rate = min(others, key=lambda r: abs(r - rate))
        t0 = s.now()
        if set_value(ConfigKey.SAMPLE_RATE_HZ, new_rate):
            t1 = s.now()
            s.idle(max(1.0, 40.0 / new_rate))
            recs = s.samples_between(t1 + s.wall(2.0 / min(rate, new_rate)), s.now())
            if len(recs) >= 10:
                slope = statistics.linear_regression(
                    [r.t for r in recs], [r.counter for r in recs]
                ).slope
                measured = slope / s.time_scale
                c.fig("sample rate", f"{measured:.2f} Hz (set {new_rate})")
                if abs(measured - new_rate) > max(0.02, c.opt.rate_tolerance) * new_rate:
                    c.fail(f"after setting {new_rate} Hz the stream runs at {measured:.2f} Hz")
            else:
                c.fail(f"only {len(recs)} samples after setting {new_rate} Hz")
            set_value(ConfigKey.SAMPLE_RATE_HZ, rate)
            s.idle(0.2)
            gaps = s.gaps_since(t0)
            if gaps:
                c.fail(f"the counter did not keep counting through the rate change: {gaps[0]}")
    # A motion key set to its own value.
    set_value(ConfigKey.SETTLE_TIME_MS, cfg[ConfigKey.SETTLE_TIME_MS])


# ------------------------------------------------------------------------------------------------
# refusals at rest
# ------------------------------------------------------------------------------------------------
_UNDEFINED_OPCODES = (0x00, 0x03, 0x14, 0x22, 0x42, 0x7F, 0xFF)
_ARG_BYTES = {
    Opcode.ROTATE_TO: 5,
    Opcode.ROTATE_BY: 4,
    Opcode.GET_CONFIG: 1,
    Opcode.SET_CONFIG: 5,
}


@check(
    "refusal.unknown_command",
    "undefined opcodes answered UNKNOWN_COMMAND, echoing seq and opcode, before the length check (4.3)",
)
def refusal_unknown_command(c: Ctx) -> None:
    s = c.s
    c.ready()
    cases: list[tuple[str, Command | bytes, Result]] = [
        (f"opcode 0x{op:02X}", s.raw(op), Result.UNKNOWN_COMMAND) for op in _UNDEFINED_OPCODES
    ]
    cases.append(
        ("opcode 0x7F with 6 argument bytes", s.raw(0x7F, bytes(6)), Result.UNKNOWN_COMMAND)
    )
    _refusals(c, cases)


@check(
    "bad_input.wrong_length",
    "every opcode with one argument byte too few or too many: BAD_ARGUMENT, counted in rx malformed, stream undisturbed (4.3, 9)",
)
def bad_input_wrong_length(c: Ctx) -> None:
    s = c.s
    c.ready()
    c.stream_on()
    t0 = s.now()
    before = s.get_status()
    cases: list[tuple[str, Command | bytes, Result]] = []
    for op in Opcode:
        n = _ARG_BYTES.get(op, 0)
        if n:
            cases.append(
                (
                    f"{op.name} with {n - 1} argument bytes",
                    s.raw(op, bytes(n - 1)),
                    Result.BAD_ARGUMENT,
                )
            )
        if n + 1 <= 6:
            cases.append(
                (
                    f"{op.name} with {n + 1} argument bytes",
                    s.raw(op, bytes(n + 1)),
                    Result.BAD_ARGUMENT,
                )
            )
    _refusals(c, cases)
    _malformed_delta(c, before, len(cases), f"{len(cases)} commands of the wrong length")
    _undisturbed(c, t0)


@check(
    "refusal.bad_argument",
    "ROTATE_TO with an undefined direction: BAD_ARGUMENT, also before the range check (4.3)",
)
def refusal_bad_argument(c: Ctx) -> None:
    s = c.s
    c.ready()
    start = s.get_status().angle
    cases: list[tuple[str, Command | bytes, Result]] = []
    for d in (3, 0x80, 0xFF):
        cases.append(
            (
                f"ROTATE_TO direction {d}",
                s.raw(Opcode.ROTATE_TO, (1000).to_bytes(4, "little") + bytes((d,))),
                Result.BAD_ARGUMENT,
            )
        )
    cases.append(
        (
            "ROTATE_TO angle 360e6 and direction 3",
            s.raw(Opcode.ROTATE_TO, ANGLE_FULL_TURN.to_bytes(4, "little") + b"\x03"),
            Result.BAD_ARGUMENT,
        )
    )
    _refusals(c, cases)
    st = s.get_status()
    if st.state != DeviceState.READY or st.angle != start:
        c.fail(
            f"after the refusals the state is {st.state.name} and the angle moved from {start} to {st.angle}"
        )


@check(
    "refusal.out_of_range",
    "arguments outside their range answered OUT_OF_RANGE and nothing changes (4.3, 4.4)",
)
def refusal_out_of_range(c: Ctx) -> None:
    s = c.s
    c.ready()
    start = s.get_status().angle
    cases: list[tuple[str, Command | bytes, Result]] = [
        ("ROTATE_TO 360e6", RotateTo(0, ANGLE_FULL_TURN), Result.OUT_OF_RANGE),
        ("ROTATE_TO 0xFFFFFFFF", RotateTo(0, 0xFFFFFFFF, Direction.POSITIVE), Result.OUT_OF_RANGE),
        ("ROTATE_BY +720e6+1", RotateBy(0, ROTATE_BY_LIMIT + 1), Result.OUT_OF_RANGE),
        ("ROTATE_BY -720e6-1", RotateBy(0, -ROTATE_BY_LIMIT - 1), Result.OUT_OF_RANGE),
        ("ROTATE_BY INT32_MIN", RotateBy(0, INT32_MIN), Result.OUT_OF_RANGE),
        ("SAMPLE_RATE_HZ 150", SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, 150), Result.OUT_OF_RANGE),
        ("SAMPLE_RATE_HZ 0", SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, 0), Result.OUT_OF_RANGE),
        ("SAMPLE_RATE_HZ 800", SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, 800), Result.OUT_OF_RANGE),
    ]
    for key, (lo, hi) in CONFIG_LIMITS.items():
        if key == ConfigKey.SAMPLE_RATE_HZ:
            continue
        if lo > 0:
            cases.append((f"{key.name} {lo - 1}", SetConfig(0, key, lo - 1), Result.OUT_OF_RANGE))
        cases.append((f"{key.name} {hi + 1}", SetConfig(0, key, hi + 1), Result.OUT_OF_RANGE))
    _refusals(c, cases)
    _config_unchanged(c)
    st = s.get_status()
    if st.state != DeviceState.READY or st.angle != start:
        c.fail(
            f"after the refusals the state is {st.state.name} and the angle moved from {start} to {st.angle}"
        )


@check(
    "refusal.unknown_key",
    "GET_CONFIG and SET_CONFIG of undefined keys below 0x10 answered UNKNOWN_KEY (4.3)",
)
def refusal_unknown_key(c: Ctx) -> None:
    c.ready()
    cases: list[tuple[str, Command | bytes, Result]] = []
    for key in (0x00, 0x07, 0x0F, 0x13, 0x7F, 0xFF):
        cases.append((f"GET_CONFIG key 0x{key:02X}", GetConfig(0, key), Result.UNKNOWN_KEY))
    for key in (0x00, 0x07, 0x0F):
        cases.append((f"SET_CONFIG key 0x{key:02X}", SetConfig(0, key, 1), Result.UNKNOWN_KEY))
    _refusals(c, cases)
    _config_unchanged(c)


@check(
    "refusal.read_only",
    "SET_CONFIG of keys 0x10..0x12 answered READ_ONLY; values unchanged (4.3, 4.4)",
)
def refusal_read_only(c: Ctx) -> None:
    s = c.s
    c.ready()
    cfg = c.config()
    cases: list[tuple[str, Command | bytes, Result]] = []
    for key in (k for k in ConfigKey if k.read_only):
        cases.append(
            (f"SET_CONFIG {key.name} (same value)", SetConfig(0, key, cfg[key]), Result.READ_ONLY)
        )
        cases.append((f"SET_CONFIG {key.name} 1", SetConfig(0, key, 1), Result.READ_ONLY))
    _refusals(c, cases)
    for key in (k for k in ConfigKey if k.read_only):
        now = s.get_config(key)
        if now != cfg[key]:
            c.fail(f"{key.name} changed from {cfg[key]} to {now}")


@check(
    "refusal.rate_exceeds_link",
    "a sample rate or heartbeat that does not fit the link: RATE_EXCEEDS_LINK, nothing changed (4.3, 7)",
)
def refusal_rate_exceeds_link(c: Ctx) -> None:
    c.ready()
    cfg = c.config()
    kind, bitrate = c.link_kind, cfg[ConfigKey.LINK_BITRATE]
    rate, hb = cfg[ConfigKey.SAMPLE_RATE_HZ], cfg[ConfigKey.HEARTBEAT_PERIOD_MS]
    cases: list[tuple[str, Command | bytes, Result]] = []
    for r in SAMPLE_RATES_HZ:
        if not rate_fits(kind, bitrate, r, hb):
            cases.append(
                (
                    f"SAMPLE_RATE_HZ {r}",
                    SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, r),
                    Result.RATE_EXCEEDS_LINK,
                )
            )
    lo = CONFIG_LIMITS[ConfigKey.HEARTBEAT_PERIOD_MS][0]
    if not rate_fits(kind, bitrate, rate, lo):
        cases.append(
            (
                f"HEARTBEAT_PERIOD_MS {lo}",
                SetConfig(0, ConfigKey.HEARTBEAT_PERIOD_MS, lo),
                Result.RATE_EXCEEDS_LINK,
            )
        )
    if not cases:
        c.skip(
            f"every sample rate and heartbeat period fits a {kind} link of {bitrate} bit/s: nothing to refuse"
        )
    _refusals(c, cases)
    _config_unchanged(c)


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------
@check(
    "bad_input.short_command",
    "a command of 0 or 1 bytes (no opcode) is not answered, is counted in rx malformed, and the stream goes on (4.2, 9)",
)
def bad_input_short_command(c: Ctx) -> None:
    s = c.s

    def send() -> None:
        s.link.send_command(b"")
        s.link.send_command(bytes((s.next_seq(),)))

    _dropped_silently(c, send, 2, "a command without an opcode", "two commands without an opcode")


@check(
    "bad_input.unknown_id",
    "CAN frames of other identifiers, other nodes and extended ids are ignored without counting (2.1, 9)",
)
def bad_input_unknown_id(c: Ctx) -> None:
    s = c.s
    if c.link_kind != "can":
        c.skip("CAN only (serial: see bad_input.unknown_type)")
    node = c.opt.node_id
    other = node + 1 if node < 15 else node - 1
    probe = bytes((s.next_seq(), Opcode.GET_STATUS))
    frames = [
        (0x7FF, bytes(8), False),
        (0x123, probe, False),
        (0x060 + node, probe, False),  # unused base
        (CanFunction.COMMAND, probe, False),  # node 0 is reserved
        (CanFunction.COMMAND + other, probe, False),
        (CanFunction.COMMAND + node, probe, True),  # 29-bit id equal to ours
    ]
    c.fig("frames", len(frames))

    def send() -> None:
        for arb, data, ext in frames:
            s.link.send_frame(arb, data, extended=ext)  # type: ignore[attr-defined]

    _dropped_silently(
        c, send, 0, "a frame not addressed to the unit", "frames that are not the unit's"
    )


@check(
    "bad_input.unknown_type",
    "serial frames with a good CRC and an undefined type are dropped and counted, not answered (9)",
)
def bad_input_unknown_type(c: Ctx) -> None:
    s = c.s
    if c.link_kind != "serial":
        c.skip("serial only (CAN: see bad_input.unknown_id)")
    types = (0x00, 0x06, 0x7F, 0xFF)

    def send() -> None:
        for ty in types:
            s.link.send_frame(ty, bytes((s.next_seq(), Opcode.GET_STATUS)))  # type: ignore[attr-defined]

    _dropped_silently(
        c,
        send,
        len(types),
        "a frame of an undefined type",
        f"{len(types)} frames of undefined types",
    )


def _frame(c: Ctx, cmd: Command) -> bytes:
    payload = cmd.encode()
    return SerialFrame(SerialType.COMMAND, c.s.link.seq, payload).encode()  # type: ignore[attr-defined]


@check(
    "bad_input.bad_crc",
    "serial frames with a bad CRC or a length above 64 are dropped and counted, not answered (2.2, 9)",
)
def bad_input_bad_crc(c: Ctx) -> None:
    s = c.s
    if c.link_kind != "serial":
        c.skip("serial only (the CAN controller checks the CRC)")

    def send() -> None:
        bad = bytearray(_frame(c, GetStatus(s.next_seq())))
        bad[-1] ^= 0x5A
        s.link.send_bytes(bytes(bad))  # type: ignore[attr-defined]
        s.link.send_bytes(bytes((0xA5, 0x5A, 65, SerialType.COMMAND, 0)) + bytes(8))  # type: ignore[attr-defined]

    _dropped_silently(c, send, 2, "a frame with a bad CRC", "one bad CRC and one length above 64")


@check(
    "bad_input.resync",
    "after a false sync only the first sync byte is discarded: frames behind it and after garbage are answered (2.2)",
)
def bad_input_resync(c: Ctx) -> None:
    s = c.s
    if c.link_kind != "serial":
        c.skip("serial only")
    c.ready()
    c.stream_on()
    t0 = s.now()
    # A header claiming 12 payload bytes (19 in all) swallows the start of the two commands behind it.
    a1 = GetStatus(s.next_seq())
    a2 = GetConfig(s.next_seq(), ConfigKey.SAMPLE_RATE_HZ)
    false_sync = bytes((0xA5, 0x5A, 12, SerialType.COMMAND, 0))
    s.link.send_bytes(false_sync + _frame(c, a1) + _frame(c, a2))  # type: ignore[attr-defined]
    # Garbage without any sync byte, then a command.
    a3 = GetStatus(s.next_seq())
    garbage = bytes(b for b in range(256) if b != 0xA5)
    s.link.send_bytes(garbage + _frame(c, a3))  # type: ignore[attr-defined]
    tracked = {
        "the GET_STATUS behind the false sync": s.track(a1.encode()),
        "the GET_CONFIG behind the false sync": s.track(a2.encode()),
        "the GET_STATUS after the garbage": s.track(a3.encode()),
    }
    s.wait_until(lambda: all(x.reply is not None for x in tracked.values()), s.reply_wait_s)
    for what, x in tracked.items():
        c.expect(x, Result.OK, what)
    c.fig("answered", f"{sum(x.reply is not None for x in tracked.values())} of {len(tracked)}")
    _undisturbed(c, t0)


# ------------------------------------------------------------------------------------------------
# moves
# ------------------------------------------------------------------------------------------------
@check(
    "command.rotate_to",
    "ROTATE_TO answered OK; ROTATING -> SETTLING -> READY; ends on target (4.1, 5)",
)
def command_rotate_to(c: Ctx) -> None:
    c.ready()
    start = _deg(c, c.s.get_status().angle)
    target = (start + 30.0) % 360.0
    m = _move(c, RotateTo(0, _counts(c, target)), f"ROTATE_TO {target:.4f}", target, 30.0)
    err = _judge_end(c, m, target)
    if err is not None:
        c.fig("error", f"{err:+.4f} deg")
    if m.t_ready is not None and m.answer.received is not None:
        c.fig("reply to READY", f"{c.s.unit(m.t_ready - m.answer.received):.2f} s")


@check(
    "command.rotate_to_direction",
    "ROTATE_TO with direction NEGATIVE / POSITIVE takes the long way round when told (4.1)",
)
def command_rotate_to_direction(c: Ctx) -> None:
    c.ready()
    start = _deg(c, c.s.get_status().angle)
    for direction, target, travel in (
        (Direction.NEGATIVE, (start + 170.0) % 360.0, -190.0),
        (Direction.POSITIVE, start, 190.0),
    ):
        what = f"ROTATE_TO {target:.4f} {direction.name}"
        m = _move(c, RotateTo(0, _counts(c, target), direction), what, target, 190.0)
        _judge_end(c, m, target)
        if m.travel_deg is None:
            if m.t_ready is not None:
                c.fail(f"{what}: no angle samples during the move to tell the direction")
            continue
        c.fig(f"{direction.name.lower()} travel", f"{m.travel_deg:+.2f} deg")
        if abs(m.travel_deg - travel) > 2.0:
            c.fail(f"{what}: the table travelled {m.travel_deg:+.2f} deg, expected {travel:+.0f}")


@check(
    "command.rotate_by",
    "ROTATE_BY +-25 deg answered OK and ends 25 deg away in the right sense (4.1)",
)
def command_rotate_by(c: Ctx) -> None:
    for delta in (25.0, -25.0):
        c.ready()
        start = _deg(c, c.s.get_status().angle)
        counts = round(delta / c.shared.get("angle_scale", ANGLE_DEG))
        m = _move(c, RotateBy(0, counts), f"ROTATE_BY {delta:+g}", start + delta, abs(delta))
        _judge_end(c, m, start + delta)
        if m.travel_deg is not None:
            c.fig(f"travel {delta:+g}", f"{m.travel_deg:+.3f} deg")
            if abs(m.travel_deg - delta) > 1.0:
                c.fail(f"ROTATE_BY {delta:+g}: the table travelled {m.travel_deg:+.3f} deg")


@check("command.home", "HOME answered OK and ends at encoder zero by the shortest way (4.1)")
def command_home(c: Ctx) -> None:
    c.ready()
    start = _deg(c, c.s.get_status().angle)
    m = _move(c, Home(0), "HOME", 0.0, abs(_wrap(start)))
    err = _judge_end(c, m, 0.0)
    if err is not None:
        c.fig("error", f"{err:+.4f} deg")
    if m.travel_deg is not None:
        c.fig("travel", f"{m.travel_deg:+.2f} deg")
        if abs(m.travel_deg - _wrap(-start)) > 1.0:
            c.fail(
                f"HOME from {start:.3f} deg travelled {m.travel_deg:+.2f} deg, the shortest way is {_wrap(-start):+.2f}"
            )


@check(
    "command.rotate_to_present",
    "ROTATE_TO the present angle is OK and still passes through ROTATING and SETTLING (4.1)",
)
def command_rotate_to_present(c: Ctx) -> None:
    c.ready()
    here = c.s.get_status().angle
    m = _move(c, RotateTo(0, here), "ROTATE_TO the present angle", _deg(c, here), 0.0)
    c.fig("states", " -> ".join(x.name for x in m.states))


@check(
    "command.stop_while_rotating",
    "STOP during a move answered OK; the table decelerates to SETTLING, then READY, short of its target (4.1, 5)",
)
def command_stop_while_rotating(c: Ctx) -> None:
    s = c.s
    cmd, d = _long_move(c)
    v, acc, _ = _table(c)
    m = _begin_move(c, cmd, f"ROTATE_BY {cmd.delta * 1e-6:+.1f}")
    if m.first_change is None:
        return
    s.idle(0.4 * _profile_s(d, v, acc))
    a = s.request(Stop(0))
    if not c.expect(a, Result.OK, "STOP while rotating"):
        return
    if not _still_rotating(c, a):
        c.note("the move ended before STOP arrived")
    _finish_move(c, m, d)
    if m.t_settling is not None and a.received is not None:
        decel = s.unit(m.t_settling - a.received)
        c.fig("STOP to SETTLING", f"{decel:.2f} s")
        if decel > v / acc * 1.1 + c.opt.reply_limit_ms / 1000 + 0.05:
            c.fail(
                f"SETTLING came {decel:.2f} s after STOP; braking from {v:g} deg/s at {acc:g} deg/s2 takes {v / acc:.2f} s"
            )
    if m.travel_deg is not None:
        c.fig("travel", f"{m.travel_deg:+.2f} of {math.copysign(d, cmd.delta):+.1f} deg")
        if abs(m.travel_deg) > d - 1.0:
            c.fail(f"the table travelled {m.travel_deg:+.2f} deg of {d:.1f}: STOP did not stop it")


@check(
    "refusal.busy",
    "moves, SELF_TEST and motion keys refused with BUSY while ROTATING and while SETTLING (4.3, 5)",
)
def refusal_busy(c: Ctx) -> None:
    s = c.s
    cmd, d = _long_move(c)
    cfg = c.config()
    m = _begin_move(c, cmd, f"ROTATE_BY {cmd.delta * 1e-6:+.1f}")
    if m.first_change is None:
        return
    here = s.get_status().angle
    rotating = [
        ("ROTATE_TO while rotating", RotateTo(0, here)),
        ("ROTATE_BY while rotating", RotateBy(0, 1_000_000)),
        ("HOME while rotating", Home(0)),
        ("SELF_TEST while rotating", SelfTest(0)),
        (
            "SET_CONFIG TABLE_MAX_RATE_MDPS while rotating",
            SetConfig(0, ConfigKey.TABLE_MAX_RATE_MDPS, cfg[ConfigKey.TABLE_MAX_RATE_MDPS]),
        ),
        (
            "SET_CONFIG TABLE_MAX_ACCEL_MDPS2 while rotating",
            SetConfig(0, ConfigKey.TABLE_MAX_ACCEL_MDPS2, cfg[ConfigKey.TABLE_MAX_ACCEL_MDPS2]),
        ),
        (
            "SET_CONFIG SETTLE_TIME_MS while rotating",
            SetConfig(0, ConfigKey.SETTLE_TIME_MS, cfg[ConfigKey.SETTLE_TIME_MS]),
        ),
    ]
    judged = 0
    for what, command in rotating:
        a = s.request(command, wait=s.wall(SELF_TEST_MAX_S) + s.reply_wait_s)
        if a.reply is not None and a.reply.result == Result.OK and not _still_rotating(c, a):
            c.note(f"{what}: the move had ended")
            continue
        judged += 1
        c.expect(a, Result.BUSY, what)
    # SETTLING: wait for it, then try again.
    if s.wait_state({DeviceState.SETTLING}, _allowed_move_s(c, d)[1], start=m.first_index):
        for what, command in (
            ("ROTATE_BY while settling", RotateBy(0, 1_000_000)),
            ("HOME while settling", Home(0)),
            ("SELF_TEST while settling", SelfTest(0)),
            (
                "SET_CONFIG SETTLE_TIME_MS while settling",
                SetConfig(0, ConfigKey.SETTLE_TIME_MS, cfg[ConfigKey.SETTLE_TIME_MS]),
            ),
        ):
            a = s.request(command, wait=s.wall(SELF_TEST_MAX_S) + s.reply_wait_s)
            if (
                a.received is not None
                and s.state_when_answered(a) != DeviceState.SETTLING
                and a.reply
                and a.reply.ok
            ):
                c.note(f"{what}: settling had ended")
                continue
            judged += 1
        c.expect(a, Result.BUSY, what)
    _finish_move(c, m, d)
    c.fig("refusals judged", judged)


@check(
    "command.while_rotating",
    "queries, streaming and non-motion settings are accepted while ROTATING; the stream shows TABLE_MOVING (5)",
)
def command_while_rotating(c: Ctx) -> None:
    s = c.s
    cmd, d = _long_move(c)
    cfg = c.config()
    m = _begin_move(c, cmd, f"ROTATE_BY {cmd.delta * 1e-6:+.1f}")
    if m.first_change is None:
        return
    n_id = len(s.identifies)
    for what, command in (
        ("GET_STATUS while rotating", GetStatus(0)),
        ("GET_CONFIG while rotating", GetConfig(0, ConfigKey.TABLE_MAX_RATE_MDPS)),
        ("IDENTIFY while rotating", RequestIdentify(0)),
        ("STREAM_START while streaming and rotating", StreamStart(0)),
        (
            "SET_CONFIG HEARTBEAT_PERIOD_MS while rotating",
            SetConfig(0, ConfigKey.HEARTBEAT_PERIOD_MS, cfg[ConfigKey.HEARTBEAT_PERIOD_MS]),
        ),
    ):
        a = s.request(command)
        c.expect(a, Result.OK, what)
        if a.reply is not None and not _still_rotating(c, a):
            c.note(f"{what}: the move had ended")
    s.wait_until(lambda: len(s.identifies) > n_id, s.reply_wait_s)
    if len(s.identifies) == n_id:
        c.fail("no identify message followed IDENTIFY while rotating")
    _finish_move(c, m, d)


@check(
    "refusal.check_order",
    "while ROTATING the checks run in the order of table 4.3: opcode, length, state, range (4.3)",
)
def refusal_check_order(c: Ctx) -> None:
    s = c.s
    cmd, d = _long_move(c)
    m = _begin_move(c, cmd, f"ROTATE_BY {cmd.delta * 1e-6:+.1f}")
    if m.first_change is None:
        return
    cases: list[tuple[str, bytes | Command, Result]] = [
        (
            "undefined opcode 0x7F with 6 argument bytes",
            s.raw(0x7F, bytes(6)),
            Result.UNKNOWN_COMMAND,
        ),
        ("ROTATE_TO with 3 argument bytes", s.raw(Opcode.ROTATE_TO, bytes(3)), Result.BAD_ARGUMENT),
        (
            "ROTATE_TO with direction 3",
            s.raw(Opcode.ROTATE_TO, bytes(4) + b"\x03"),
            Result.BAD_ARGUMENT,
        ),
        ("ROTATE_TO 360e6", RotateTo(0, ANGLE_FULL_TURN), Result.BUSY),
        ("ROTATE_BY 721 deg", RotateBy(0, ROTATE_BY_LIMIT + 1_000_000), Result.BUSY),
        (
            "SET_CONFIG TABLE_MAX_RATE_MDPS 0",
            SetConfig(0, ConfigKey.TABLE_MAX_RATE_MDPS, 0),
            Result.BUSY,
        ),
        (
            "SET_CONFIG SAMPLE_RATE_HZ 150 (not a motion key)",
            SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, 150),
            Result.OUT_OF_RANGE,
        ),
    ]
    for what, command, expected in cases:
        a = s.request(command)
        if (
            expected == Result.BUSY
            and a.reply is not None
            and not _still_rotating(c, a)
            and a.reply.result != Result.BUSY
        ):
            c.note(f"{what}: the move had ended")
            continue
        c.expect(a, expected, what)
    _finish_move(c, m, d)


def _rotations(c: Ctx) -> list[tuple[float, Move, float]]:
    """ROTATE_TO each angle of the options once; shared by the rotation checks."""
    if "rotations" not in c.shared:
        out = []
        for angle in c.opt.angles_deg:
            c.ready()
            start = _deg(c, c.s.get_status().angle)
            dist = abs(_wrap(angle - start))
            m = _move(c, RotateTo(0, _counts(c, angle)), f"ROTATE_TO {angle % 360:g}", angle, dist)
            out.append((angle % 360.0, m, dist))
            c.s.idle(0.3)
        c.shared["rotations"] = out
    return c.shared["rotations"]


@check("rotation.accuracy", "ROTATE_TO each --angles target ends within the stated accuracy (4.1)")
def rotation_accuracy(c: Ctx) -> None:
    for angle, m, _ in _rotations(c):
        if not m.ok:
            c.fail(f"{m.what}: not accepted")
            continue
        err = _judge_end(c, m, angle)
        if err is not None:
            c.fig(f"{angle:g}", f"{err * 1000:+.1f} mdeg")
    c.fig("limit", f"+-{c.opt.accuracy_deg * 1000:g} mdeg")


@check(
    "rotation.settle_time",
    "READY within profile time (rate, acceleration) + SETTLE_TIME_MS + margin; SETTLING lasts SETTLE_TIME_MS (5)",
)
def rotation_settle_time(c: Ctx) -> None:
    s = c.s
    _, _, settle = _table(c)
    for angle, m, dist in _rotations(c):
        if m.t_ready is None or m.answer.received is None:
            c.fail(f"{m.what}: no READY to time")
            continue
        took = s.unit(m.t_ready - m.answer.received)
        expected, allowed = _allowed_move_s(c, dist)
        c.fig(f"{angle:g}", f"{took:.2f} s (expected {expected:.2f})")
        if took > allowed:
            c.fail(f"{m.what}: READY after {took:.2f} s, allowed {allowed:.2f} s ({dist:.2f} deg)")
        if m.t_settling is not None:
            settling = s.unit(m.t_ready - m.t_settling)
            host = c.opt.reply_limit_ms / 1000.0  # the SETTLING status may arrive late
            if settling < settle * 0.9 - host or settling > settle * 1.1 + c.opt.settle_margin_s:
                c.fail(
                    f"{m.what}: SETTLING lasted {settling:.2f} s, SETTLE_TIME_MS is {settle * 1000:g}"
                )


@check(
    "rotation.validity",
    "during the moves samples carry TABLE_MOVING, then TABLE_SETTLING, then are clean in READY (4.5)",
)
def rotation_validity(c: Ctx) -> None:
    rot = _rotations(c)
    if not rot:
        c.skip("no rotations")
    t0 = min(m.answer.sent for _, m, _ in rot)
    t1 = max((m.t_ready or m.answer.sent) for _, m, _ in rot) + c.s.wall(0.2)
    recs = c.s.samples_between(t0, t1)
    judged, bad, problems = _judge_validity(c, recs)
    moving = sum(bool(r.validity & Validity.TABLE_MOVING) for r in recs)
    settling = sum(bool(r.validity & Validity.TABLE_SETTLING) for r in recs)
    c.fig("judged", judged)
    c.fig("moving", moving)
    c.fig("settling", settling)
    if bad:
        c.fail(f"{bad} of {judged} samples: " + "; ".join(problems))
    if not moving:
        c.fail("no sample carried TABLE_MOVING during the moves")


# ------------------------------------------------------------------------------------------------
# reset and boot
# ------------------------------------------------------------------------------------------------
def _reset(c: Ctx) -> tuple[Answer, int | None]:
    """RESET; return its answer and the index of the BOOT status in the session's statuses."""
    s = c.s
    s.expect_restart()
    n = len(s.statuses)
    a = s.request(Reset(0))
    if not c.expect(a, Result.OK, "RESET"):
        return a, None
    i = s.wait_state({DeviceState.BOOT}, RESET_TO_BOOT_S + 1.0, start=n)
    if i is None:
        c.fail("no BOOT status after RESET")
        return a, None
    return a, i


@check(
    "command.reset",
    "RESET: reply first, BOOT within 100 ms, IDENTIFY during BOOT, BOOT at most 1 s, defaults, counters and sequence restart (4.1, 6)",
)
def command_reset(c: Ctx) -> None:
    s = c.s
    c.ready()
    cfg = c.config()
    hb = cfg[ConfigKey.HEARTBEAT_PERIOD_MS]
    changed = min(hb * 2, 5000) if hb * 2 <= 5000 else hb // 2
    c.s.ok(SetConfig(0, ConfigKey.HEARTBEAT_PERIOD_MS, changed))
    n_id = len(s.identifies)
    a, i_boot = _reset(c)
    if i_boot is None or a.received is None:
        return
    t_boot = s.statuses[i_boot][0]
    c.fig("reply to BOOT", f"{c.ms(t_boot - a.received):.1f} ms")
    if a.received > t_boot:
        c.fail("the BOOT status came before the reply to RESET")
    if c.ms(t_boot - a.received) > RESET_TO_BOOT_S * 1000 + c.opt.reply_limit_ms:
        c.fail(f"BOOT came {c.ms(t_boot - a.received):.0f} ms after the reply (at most 100 ms)")
    t_boot, boot_status = s.statuses[i_boot]
    for name in ("rx_malformed", "tx_dropped", "cmd_rejected"):
        if getattr(boot_status, name):
            c.fail(
                f"{name} is {getattr(boot_status, name)} in the BOOT status: counters restart at 0"
            )
    i_next = s.wait_state(
        {DeviceState.WARMUP, DeviceState.READY, DeviceState.FAULT}, BOOT_MAX_S + 2.0, start=i_boot
    )
    if i_next is None:
        c.fail("the unit did not leave BOOT")
        return
    t_next = s.statuses[i_next][0]
    boot_s = s.unit(t_next - t_boot)
    c.fig("BOOT", f"{boot_s * 1000:.0f} ms")
    if boot_s > BOOT_MAX_S + c.opt.reply_limit_ms / 1000:
        c.fail(f"BOOT lasted {boot_s:.2f} s (at most 1 s)")
    idents = [t for t, _ in s.identifies[n_id:] if t >= a.sent]
    if not idents:
        c.fail("no IDENTIFY was sent during BOOT")
    elif idents[0] > t_next + c.opt.reply_limit_ms / 1000:
        c.fail("the IDENTIFY after RESET came after BOOT ended")
    after = s.statuses[-1][1]
    counter = -1 if after.sample_counter == 0xFFFFFFFF else after.sample_counter
    limit = (s.unit(s.now() - a.received) + 0.5) * max(SAMPLE_RATES_HZ)
    c.fig("sample counter after boot", counter)
    if counter > limit:
        c.fail(
            f"the sample counter did not restart: {counter} after {s.unit(s.now() - a.received):.2f} s"
        )
    if c.link_kind == "serial" and s.seq_restart_pending:
        c.fail("the serial sequence counter did not restart at 0 after RESET")
    s.seq_restart_pending = False
    c.ready()
    bitrate = cfg[ConfigKey.LINK_BITRATE]
    hb_default = CONFIG_DEFAULTS[ConfigKey.HEARTBEAT_PERIOD_MS]
    rate_default = CONFIG_DEFAULTS[ConfigKey.SAMPLE_RATE_HZ]
    if not rate_fits(c.link_kind, bitrate, rate_default, hb_default):
        rate_default = max_sample_rate(c.link_kind, bitrate, hb_default)
    expected = {
        ConfigKey.HEARTBEAT_PERIOD_MS: hb_default,
        ConfigKey.SAMPLE_RATE_HZ: rate_default,
        ConfigKey.STREAMING: 0,
    }
    for key, want in expected.items():
        v = s.get_config(key)
        if v != want:
            c.fail(f"{key.name} is {v} after RESET, expected the default {want}")
    # The table limits are the instrument's own: compared with table 4.4 only as figures.
    for key in (
        ConfigKey.TABLE_MAX_RATE_MDPS,
        ConfigKey.TABLE_MAX_ACCEL_MDPS2,
        ConfigKey.SETTLE_TIME_MS,
    ):
        v = s.get_config(key)
        if v != CONFIG_DEFAULTS[key]:
            c.fig(f"{key.name} default", f"{v} (table 4.4: {CONFIG_DEFAULTS[key]})")
    s.streaming = False
    s.begin_segment()


@check(
    "refusal.not_ready",
    "in BOOT only IDENTIFY, GET_STATUS, GET_CONFIG are served, the rest NOT_READY (before the range and key checks); in WARMUP moves are NOT_READY (4.3, 5)",
)
def refusal_not_ready(c: Ctx) -> None:
    s = c.s
    c.ready()
    cfg = c.config()
    _, i_boot = _reset(c)
    if i_boot is None:
        return
    s.seq_restart_pending = False
    cases: list[tuple[str, Command | bytes, Result]] = [
        ("ROTATE_BY in BOOT", RotateBy(0, 1_000_000), Result.NOT_READY),
        ("HOME in BOOT", Home(0), Result.NOT_READY),
        ("SELF_TEST in BOOT", SelfTest(0), Result.NOT_READY),
        ("STREAM_START in BOOT", StreamStart(0), Result.NOT_READY),
        (
            "SET_CONFIG in BOOT",
            SetConfig(0, ConfigKey.SETTLE_TIME_MS, cfg[ConfigKey.SETTLE_TIME_MS]),
            Result.NOT_READY,
        ),
        ("SET_CONFIG key 0x07 in BOOT (state before key)", SetConfig(0, 0x07, 1), Result.NOT_READY),
        (
            "ROTATE_TO 360e6 in BOOT (state before range)",
            RotateTo(0, ANGLE_FULL_TURN),
            Result.NOT_READY,
        ),
        ("GET_STATUS in BOOT", GetStatus(0), Result.OK),
        ("GET_CONFIG in BOOT", GetConfig(0, ConfigKey.SAMPLE_RATE_HZ), Result.OK),
        ("IDENTIFY in BOOT", RequestIdentify(0), Result.OK),
    ]
    sent = [(what, s.send(cmd), expected) for what, cmd, expected in cases]
    s.wait_until(lambda: all(x.reply is not None for _, x, _ in sent), s.reply_wait_s + s.wall(0.5))
    i_left = s.wait_state(
        {DeviceState.WARMUP, DeviceState.READY, DeviceState.FAULT}, BOOT_MAX_S + 2.0, start=i_boot
    )
    t_left = None if i_left is None else s.statuses[i_left][0]
    judged = 0
    for what, x, expected in sent:
        if (
            x.reply is not None
            and i_left is not None
            and x.statuses_before is not None
            and x.statuses_before > i_left
        ):
            c.note(f"{what}: answered after BOOT ended")
            continue
        judged += 1
        c.expect(x, expected, what)
    c.fig("judged in BOOT", f"{judged} of {len(sent)}")
    if judged == 0:
        c.skip("BOOT ended before any reply: too short to test from this host")
    if t_left is not None and s.state == DeviceState.WARMUP:
        for what, cmd in (
            ("ROTATE_BY in WARMUP", RotateBy(0, 1_000_000)),
            ("HOME in WARMUP", Home(0)),
        ):
            x = s.request(cmd)
            if s.state == DeviceState.WARMUP:
                c.expect(x, Result.NOT_READY, what)
    else:
        c.note("the unit went from BOOT straight to READY: WARMUP refusals not tried")
    s.streaming = False
    s.begin_segment()
    c.ready()


@check(
    "refusal.fault",
    "in FAULT moves and SET_CONFIG are refused with FAULT (4.3) — only if the unit is in FAULT",
)
def refusal_fault(c: Ctx) -> None:
    st = c.s.get_status()
    if st.state != DeviceState.FAULT:
        c.skip("the unit is not in FAULT, and the protocol gives the host no way to cause one")
    cfg = c.config()
    _refusals(
        c,
        [
            ("ROTATE_BY in FAULT", RotateBy(0, 1_000_000), Result.FAULT),
            ("HOME in FAULT", Home(0), Result.FAULT),
            (
                "SET_CONFIG in FAULT",
                SetConfig(0, ConfigKey.SETTLE_TIME_MS, cfg[ConfigKey.SETTLE_TIME_MS]),
                Result.FAULT,
            ),
        ],
    )


# ------------------------------------------------------------------------------------------------
# whole-run figures
# ------------------------------------------------------------------------------------------------
@check(
    "timing.reply",
    "every reply within the reply limit (host-measured; the unit's deadline is 20 ms) (6)",
)
def timing_reply(c: Ctx) -> None:
    answers = [a for a in c.s.answers if a.opcode != Opcode.SELF_TEST]
    lat = sorted(c.ms(a.latency) for a in answers if a.latency is not None)
    missing = [a for a in answers if a.reply is None and a.opcode != Opcode.RESET]
    if not lat:
        c.skip("no replies to time")
    over = sum(x > REPLY_DEADLINE_MS for x in lat)
    c.fig("replies", len(lat))
    c.fig("median", f"{statistics.median(lat):.1f} ms")
    c.fig("p95", f"{lat[int(0.95 * (len(lat) - 1))]:.1f} ms")
    c.fig("max", f"{lat[-1]:.1f} ms")
    c.fig(f"over {REPLY_DEADLINE_MS} ms", over)
    sc = c.shared.get("state_change_ms")
    if sc:
        c.fig("state-change status max", f"{max(sc):.1f} ms")
    if lat[-1] > c.opt.reply_limit_ms:
        c.fail(
            f"{sum(x > c.opt.reply_limit_ms for x in lat)} repl(ies) later than {c.opt.reply_limit_ms:g} ms (max {lat[-1]:.0f} ms)"
        )
    if missing:
        c.fail(
            f"{len(missing)} command(s) without a reply, first {missing[0].name} seq {missing[0].seq}"
        )


@check(
    "link.integrity",
    "over the whole run: every frame from the unit decodes, no reply without a command, no serial frame lost (2, 8, 9)",
)
def link_integrity(c: Ctx) -> None:
    s = c.s
    c.fig("link errors", len(s.link_errors))
    c.fig("unanswered replies", len(s.unsolicited))
    if c.link_kind == "serial":
        c.fig("serial frames lost", s.serial_frames_lost)
        if s.serial_frames_lost:
            c.fail(
                f"{s.serial_frames_lost} serial frame(s) from the unit lost (sequence counter gaps)"
            )
    if s.link_errors:
        c.fail(f"{len(s.link_errors)} bad frame(s) from the unit, first: {s.link_errors[0][1]}")
    strays = len(s.unsolicited)
    if strays:
        r = next(r for _, r in s.unsolicited)
        c.fail(
            f"{strays} repl(ies) matching no command, first seq {r.seq} opcode 0x{int(r.opcode):02X}"
        )
