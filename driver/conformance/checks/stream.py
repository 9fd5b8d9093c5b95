"""The sample stream and the heartbeat (protocol.md 4.1, 4.5, 6, 8): switching the stream, then one
observation window (stream on, no commands) judged for period, jitter, rate, counters and validity."""

from __future__ import annotations

import itertools
import statistics

from northfinder.driver.conformance.checks.common import judge_validity
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.protocol.constants import ConfigKey, Result
from northfinder.driver.protocol.counters import counter_diff
from northfinder.driver.protocol.messages import StreamStart, StreamStop

STATUS_OFFSET_LIMIT = 16
"""Largest allowed difference, in ticks, between the counter of STATUS_COUNTERS and the latest
sample received: the anchor of the 8-bit tick extension (protocol.md 8) must be well within 128."""


@check("command.stream_stop")
def command_stream_stop(c: Ctx) -> None:
    """STREAM_STOP answered OK; no sample after the current tick; STREAMING reads 0 (4.1)"""
    s = c.s
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    a = s.request(StreamStop(0))
    if not c.expect(a, Result.OK, "STREAM_STOP") or a.received is None:
        return
    s.streaming = False
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


@check("command.stream_start")
def command_stream_start(c: Ctx) -> None:
    """STREAM_START answered OK; samples start at the next tick; STREAMING reads 1 (4.1)"""
    s = c.s
    c.ready()  # a unit still booting refuses it rightly (refusal.not_ready's business)
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    if s.streaming:
        s.stop_stream()
        s.idle(0.2)
    s.begin_segment()
    a = s.request(StreamStart(0))
    if not c.expect(a, Result.OK, "STREAM_START") or a.received is None:
        return
    s.streaming = True
    n = len(s.samples)
    if not s.wait_until(lambda: len(s.samples) > n, s.wall(1.0 / rate) + 0.5):
        c.fail("no sample arrived after STREAM_START")
        return
    first = c.ms(s.samples[n].t - a.received)
    c.fig("first sample after reply", f"{first:.1f} ms")
    allowed = 1000.0 / rate + c.opt.reply_limit_ms
    if first > allowed:
        c.late(
            f"the first sample came {first:.0f} ms after the reply (one tick is {1000 / rate:g} ms)",
            a.received,
            s.samples[n].t,
            s.wall((first - allowed) / 1000.0),
        )
    v = s.get_config(ConfigKey.STREAMING)
    if v != 1:
        c.fail(f"STREAMING reads {v} after STREAM_START")


def observation(c: Ctx) -> tuple[float, float]:
    """The observation window (stream on, no commands), taken once and shared."""
    if "window" not in c.shared:
        c.ready()
        c.stream_on()
        seconds = max(c.opt.stream_seconds, 3.0)
        t0 = c.s.now()
        c.s.idle(seconds)
        c.shared["window"] = (t0, c.s.now())
    t0, t1 = c.shared["window"]
    return t0, t1


def unit_ticks(c: Ctx) -> tuple[list[int], float]:
    """The unit's own clock over the window: how far its sample counter moved between heartbeats
    (the counter each status carries), and how far it should move (rate x period).

    The host's lateness moves arrival times, never these counters: when they agree with the
    configuration, a rate or a period that failed on arrival times may be the host's doing; when
    they do not, the unit's own timing is off whatever the host did."""
    t0, t1 = observation(c)
    sts = [(t, st) for t, st in c.s.statuses if t0 < t <= t1]
    ticks = [
        counter_diff(b.sample_counter, a.sample_counter)
        for (_, a), (_, b) in itertools.pairwise(sts)
        if a.state == b.state
    ]
    cfg = c.config()
    return ticks, cfg[ConfigKey.SAMPLE_RATE_HZ] * cfg[ConfigKey.HEARTBEAT_PERIOD_MS] / 1000.0


def window_failure(c: Ctx, problem: str, *, each: bool = False) -> None:
    """Record a failure of a check over the window: a timing problem (judged against the host's
    pace) when the unit's counters agree with the configuration, else a failure with the
    counters' figures. ``each``: every interval must agree within 10 % (jitter), not the mean."""
    ticks, want = unit_ticks(c)
    if ticks:
        mean = sum(ticks) / len(ticks)
        if each:
            worst = max(ticks, key=lambda d: abs(d - want))
            off = abs(worst - want) > 0.1 * want + 1
            shown = f"{worst} ticks between two heartbeats"
        else:
            off = abs(mean - want) > max(1.0, c.opt.rate_tolerance * want)
            shown = f"{mean:.2f} ticks per heartbeat"
        c.fig("unit counters", f"{mean:.2f} ticks per heartbeat (expected {want:g})")
        if off:
            c.fail(
                f"{problem}; the unit's own counters show it: {shown}, {want:g} expected at "
                "the configured rate and period"
            )
            return
    t0, t1 = observation(c)
    c.late(problem, t0, t1)


def heartbeat_intervals(c: Ctx) -> list[float]:
    """Intervals between statuses of the window, unit ms (a state change sends an extra status)."""
    t0, t1 = observation(c)
    # After t0: a status that answered the last command before the window arrived at t0 (at the
    # same instant in virtual time) and is no heartbeat.
    sts = [(t, st) for t, st in c.s.statuses if t0 < t <= t1]
    out = []
    for (ta, sa), (tb, sb) in itertools.pairwise(sts):
        if sa.state == sb.state:
            out.append(c.ms(tb - ta))
    return out


@check("heartbeat.period")
def heartbeat_period(c: Ctx) -> None:
    """heartbeat period (fit over the window) equals HEARTBEAT_PERIOD_MS within the rate tolerance
    (6)"""
    period = c.config()[ConfigKey.HEARTBEAT_PERIOD_MS]
    t0, t1 = observation(c)
    times = [t for t, _ in c.s.statuses if t0 < t <= t1]
    if len(times) < 6:
        c.fail(f"only {len(times)} status message(s) in the window")
        return
    # The slope of arrival time against index: a late arrival at an end barely moves it.
    mean = c.ms(statistics.linear_regression(range(len(times)), times).slope)
    c.fig("period", f"{mean:.2f} ms (configured {period})")
    c.fig("median interval", f"{statistics.median(heartbeat_intervals(c)):.2f} ms")
    c.fig("statuses", len(times))
    if abs(mean - period) > c.opt.rate_tolerance * period:
        window_failure(
            c,
            f"heartbeat period {mean:.2f} ms, configured {period} ms "
            f"(tolerance {c.opt.rate_tolerance:.0%})",
        )


@check("heartbeat.jitter")
def heartbeat_jitter(c: Ctx) -> None:
    """every heartbeat interval within 10 % of the period, plus the host margin (6)"""
    period = c.config()[ConfigKey.HEARTBEAT_PERIOD_MS]
    iv = heartbeat_intervals(c)
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
        window_failure(
            c,
            f"a heartbeat interval of {worst:.1f} ms against a period of {period} ms "
            f"(limit +-{limit:.1f} ms)",
            each=True,
        )


@check("stream.rate")
def stream_rate(c: Ctx) -> None:
    """sample rate over the window equals SAMPLE_RATE_HZ within the rate tolerance (6)"""
    t0, t1 = observation(c)
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
    problems = []
    if abs(measured - rate) > c.opt.rate_tolerance * rate:
        problems.append(
            f"sample rate {measured:.3f} Hz, configured {rate} Hz (tolerance {c.opt.rate_tolerance:.0%})"
        )
    if abs(received - rate) > c.opt.rate_tolerance * rate + 2.0 / c.s.unit(ts[-1] - ts[0]):
        problems.append(f"{received:.2f} samples/s received against {rate} Hz")
    if problems:
        window_failure(c, "; ".join(problems))


@check("stream.counters")
def stream_counters(c: Ctx) -> None:
    """sample counter +1 per tick with no gap, no incomplete tick, no lost frame (4.5, 8)"""
    s = c.s
    t0, t1 = observation(c)
    recs = s.samples_between(t0, t1)
    found = [(t, text) for t, text in s.gaps if t0 <= t <= t1]
    gaps = [text for _, text in found]
    c.fig("samples", len(recs))
    if recs:
        c.fig("counters", f"{recs[0].counter}..{recs[-1].counter}")
    c.fig("gaps", len(gaps))
    if not recs:
        c.fail("no samples in the window")
    c.gaps(found, "")
    offs = [d for t, d in s.status_offsets if t0 <= t <= t1]
    if offs:
        c.fig("status counter offset", f"{min(offs)}..{max(offs)} ticks")
        bad = [o for o in offs if abs(o) > STATUS_OFFSET_LIMIT]
        if bad:
            c.fail(
                f"STATUS_COUNTERS sample counter differs from the latest sample by {bad[0]} ticks "
                f"(limit {STATUS_OFFSET_LIMIT})"
            )


@check("stream.validity")
def stream_validity(c: Ctx) -> None:
    """validity bits of every sample match the state: READY gives GYRO_VALID|ACCEL_VALID, bits 2..7
    clear (4.5)"""
    t0, t1 = observation(c)
    judged, bad, problems = judge_validity(c, c.s.samples_between(t0, t1))
    c.fig("judged", judged)
    c.fig("bad", bad)
    if not judged:
        c.fail("no samples to judge")
    if bad:
        c.fail(f"{bad} of {judged} samples: " + "; ".join(problems))
