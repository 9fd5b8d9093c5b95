"""Identity, state and configuration (protocol.md 4.1, 4.4, 4.6, 4.7, 5, 7)."""

from __future__ import annotations

import math

from northfinder.driver.conformance.checks.common import deg
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.protocol.budget import max_sample_rate, rate_fits
from northfinder.driver.protocol.constants import (
    ANGLE_FULL_TURN,
    CAN_BITRATES,
    CONFIG_LIMITS,
    PROTOCOL_VERSION_MAJOR,
    SAMPLE_RATES_HZ,
    SERIAL_BAUDS,
    TEMPERATURE_DEGC_PER_COUNT,
    TEMPERATURE_NOT_AVAILABLE,
    ConfigKey,
    Result,
)
from northfinder.driver.protocol.messages import GetConfig, GetStatus, RequestIdentify


@check("identify")
def identify(c: Ctx) -> None:
    """IDENTIFY answered OK, then a whole identify message of protocol major 1 (4.7)"""
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
    c.shared["protocol_version"] = tuple(ident.protocol_version)
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


@check("state.ready")
def state_ready(c: Ctx) -> None:
    """the unit reaches READY (after boot and warm-up) without a fault (5)"""
    st = c.s.get_status()
    c.fig("state", st.state.name)
    t0 = c.s.now()
    c.ready()
    c.fig("waited", f"{c.s.unit(c.s.now() - t0):.1f} s")
    st = c.s.get_status()
    if st.faults:
        c.fail(f"READY with fault flags 0x{int(st.faults):02X}")


@check("command.get_status")
def command_get_status(c: Ctx) -> None:
    """GET_STATUS answered OK and a status follows at once (4.1, 4.6)"""
    s = c.s
    a = s.request(GetStatus(0))
    if not c.expect(a, Result.OK, "GET_STATUS") or a.received is None:
        return
    t_reply = a.received
    ok = s.wait_until(lambda: any(t >= t_reply for t, _ in s.statuses), s.reply_wait_s)
    if not ok:
        c.fail("no status followed the OK reply")
        return
    t, st = next((t, st) for t, st in s.statuses if t >= t_reply)
    lat = c.ms(t - a.sent)
    c.fig("status after", f"{lat:.1f} ms")
    c.fig("state", st.state.name)
    c.fig("angle", f"{deg(c, st.angle):.4f} deg")
    c.fig(
        "temperature",
        "none"
        if st.temperature == TEMPERATURE_NOT_AVAILABLE
        else f"{st.temperature * TEMPERATURE_DEGC_PER_COUNT:.2f} degC",
    )
    if lat > c.opt.reply_limit_ms:
        c.late(
            f"the status came {lat:.0f} ms after the command",
            a.sent,
            t,
            s.wall((lat - c.opt.reply_limit_ms) / 1000.0),
        )
    if not 0 <= st.angle < ANGLE_FULL_TURN:
        c.fail(f"status angle {st.angle} outside [0, 360e6)")


@check("command.get_config")
def command_get_config(c: Ctx) -> None:
    """GET_CONFIG of every key answered OK with a value in range (4.4, 7)"""
    s = c.s
    values: dict[ConfigKey, int] = {}
    for key in ConfigKey:
        a = s.request(GetConfig(0, key))
        if not c.expect(a, Result.OK, f"GET_CONFIG {key.name}") or a.reply is None:
            continue
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
