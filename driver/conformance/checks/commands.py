"""Commands at rest (protocol.md 4.1, 4.4, 5, 6): STOP, SELF_TEST, SET_CONFIG and RESET."""

from __future__ import annotations

import itertools
import statistics

from northfinder.driver.conformance.checks.common import (
    BOOT_MAX_S,
    RESET_TO_BOOT_S,
    SELF_TEST_MAX_S,
    reset_to_boot,
)
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.protocol.budget import max_sample_rate, rate_fits
from northfinder.driver.protocol.constants import (
    CONFIG_DEFAULTS,
    CONFIG_LIMITS,
    SAMPLE_RATES_HZ,
    UINT32_MAX,
    ConfigKey,
    DeviceState,
    Result,
)
from northfinder.driver.protocol.messages import SelfTest, SetConfig, Stop

_HEARTBEAT_MAX_MS = CONFIG_LIMITS[ConfigKey.HEARTBEAT_PERIOD_MS][1]


@check("command.stop_at_rest")
def command_stop_at_rest(c: Ctx) -> None:
    """STOP at rest answered OK and changes nothing (4.1, 5)"""
    s = c.s
    c.ready()
    n = len(s.transitions)
    a = s.request(Stop(0))
    c.expect(a, Result.OK, "STOP")
    s.idle(0.3)
    changed = s.transitions[n:]
    if changed:
        c.fail(f"STOP at rest changed the state to {changed[0][2].name}")


@check("command.self_test")
def command_self_test(c: Ctx) -> None:
    """SELF_TEST in READY answered OK with a zero failure mask within 500 ms (4.1)"""
    s = c.s
    c.ready()
    a = s.request(SelfTest(0), wait=s.wall(SELF_TEST_MAX_S) + s.reply_wait_s)
    if not c.expect(a, Result.OK, "SELF_TEST") or a.reply is None or a.latency is None:
        return
    c.fig("reply after", f"{c.ms(a.latency):.1f} ms")
    mask = a.reply.self_test_failures()
    c.fig("failure mask", f"0x{int(mask):04X}")
    if mask:
        c.fail(f"the self test reports failures {mask!r}")
    allowed = SELF_TEST_MAX_S * 1000 + c.opt.reply_limit_ms
    if c.ms(a.latency) > allowed and a.received is not None:
        c.late(
            f"SELF_TEST took {c.ms(a.latency):.0f} ms",
            a.sent,
            a.received,
            s.wall((c.ms(a.latency) - allowed) / 1000.0),
        )
    st = s.get_status()
    if st.state != DeviceState.READY:
        c.fail(f"state {st.state.name} after a passed self test")


@check("command.set_config")
def command_set_config(c: Ctx) -> None:
    """SET_CONFIG echoes the value now in effect; heartbeat and sample rate follow it (4.4)"""
    s = c.s
    c.ready()
    c.stream_on()
    cfg = c.config()
    kind, bitrate = c.link_kind, cfg[ConfigKey.LINK_BITRATE]
    rate, hb = cfg[ConfigKey.SAMPLE_RATE_HZ], cfg[ConfigKey.HEARTBEAT_PERIOD_MS]

    def set_value(key: ConfigKey, value: int) -> bool:
        a = s.request(SetConfig(0, key, value))
        if not c.expect(a, Result.OK, f"SET_CONFIG {key.name} {value}") or a.reply is None:
            return False
        k, v = a.reply.config_value()
        if int(k) != key or v != value:
            c.fail(f"SET_CONFIG {key.name} {value} echoed key {int(k)} value {v}")
        got = s.get_config(key)
        if got != value:
            c.fail(f"GET_CONFIG {key.name} reads {got} after setting {value}")
        return True

    # Heartbeat period: twice the configured one, if it fits (a longer period always does).
    new_hb = min(hb * 2, _HEARTBEAT_MAX_MS)
    if set_value(ConfigKey.HEARTBEAT_PERIOD_MS, new_hb):
        t0 = s.now()
        s.idle(max(6 * new_hb / 1000.0, 0.5))
        sts = [(t, st) for t, st in s.statuses if t >= t0]
        iv = [c.ms(b - a) for (a, _), (b, _) in itertools.pairwise(sts[1:])]
        # The same intervals on the unit's own clock, its sample counter: a host that is itself
        # late (a loaded machine, an emulator) must not make a punctual unit fail.
        dev = [
            1000.0 * ((y.sample_counter - x.sample_counter) & UINT32_MAX) / rate
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
            # Too few arrived in the time waited: about time (a host that did not read them).
            c.late(f"only {len(iv)} heartbeat interval(s) after setting {new_hb} ms", t0, s.now())
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
                    c.late(
                        f"after setting {new_rate} Hz the stream runs at {measured:.2f} Hz",
                        recs[0].t,
                        recs[-1].t,
                    )
            else:
                c.late(f"only {len(recs)} samples after setting {new_rate} Hz", t1, s.now())
            set_value(ConfigKey.SAMPLE_RATE_HZ, rate)
            s.idle(0.2)
            c.gaps(
                s.gaps_found_since(t0),
                "the counter did not keep counting through the rate change: ",
            )
    # A motion key set to its own value.
    set_value(ConfigKey.SETTLE_TIME_MS, cfg[ConfigKey.SETTLE_TIME_MS])


@check("command.reset")
def command_reset(c: Ctx) -> None:
    """RESET: reply first, BOOT within 100 ms, IDENTIFY during BOOT, BOOT at most 1 s, defaults,
    counters and sequence restart (4.1, 6)"""
    s = c.s
    c.ready()
    cfg = c.config()
    hb = cfg[ConfigKey.HEARTBEAT_PERIOD_MS]
    changed = hb * 2 if hb * 2 <= _HEARTBEAT_MAX_MS else hb // 2
    c.s.ok(SetConfig(0, ConfigKey.HEARTBEAT_PERIOD_MS, changed))
    n_id = len(s.identifies)
    a, i_boot = reset_to_boot(c)
    if i_boot is None or a.received is None:
        return
    t_boot, boot_status = s.statuses[i_boot]
    c.fig("reply to BOOT", f"{c.ms(t_boot - a.received):.1f} ms")
    if a.received > t_boot:
        c.fail("the BOOT status came before the reply to RESET")
    allowed = RESET_TO_BOOT_S * 1000 + c.opt.reply_limit_ms
    if c.ms(t_boot - a.received) > allowed:
        c.late(
            f"BOOT came {c.ms(t_boot - a.received):.0f} ms after the reply (at most 100 ms)",
            a.received,
            t_boot,
            s.wall((c.ms(t_boot - a.received) - allowed) / 1000.0),
        )
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
    # The tick before the first after boot may be numbered 2**32 - 1.
    counter = -1 if after.sample_counter == UINT32_MAX else after.sample_counter
    # Since the command was sent, not since its reply was read: the unit restarted after the
    # one and before the other, and a host that read the reply late must not move the bound.
    since = s.unit(s.now() - a.sent)
    limit = (since + 0.5) * max(SAMPLE_RATES_HZ)
    c.fig("sample counter after boot", counter)
    if counter > limit:
        c.fail(f"the sample counter did not restart: {counter} after {since:.2f} s")
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
