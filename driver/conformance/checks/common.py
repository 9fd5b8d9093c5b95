"""Helpers shared by the checks: angles in the unit's counts, the table's limits, validity bits,
and what bad input must not disturb."""

from __future__ import annotations

import math
from collections.abc import Callable

from northfinder.driver.conformance.core import Ctx
from northfinder.driver.conformance.session import Answer, SampleRecord
from northfinder.driver.protocol.constants import (
    ANGLE_DEG_PER_COUNT,
    ANGLE_FULL_TURN,
    VALIDITY_GOOD,
    VALIDITY_STEADY_RATE,
    VALIDITY_UNFIT,
    ConfigKey,
    DeviceState,
    Result,
    Validity,
)
from northfinder.driver.protocol.messages import GetStatus, Reset, Status
from northfinder.driver.protocol.motion import TableLimits

SELF_TEST_MAX_S = 0.5
"""The unit answers SELF_TEST within this time (protocol.md 4.1)."""
BOOT_MAX_S = 1.0
"""BOOT lasts at most this long (protocol.md 5)."""
STATE_CHANGE_STATUS_S = 0.005
"""A status follows a state change within this time (protocol.md 6)."""
RESET_TO_BOOT_S = 0.1
"""The BOOT status follows the reply to RESET within this time (protocol.md 4.1)."""
ONE_DEG_COUNTS = round(1.0 / ANGLE_DEG_PER_COUNT)
"""One degree in angle counts at the protocol's default scale."""


# -- angles ------------------------------------------------------------------------------------------
def angle_scale(c: Ctx) -> float:
    """Degrees per angle count: the unit's own (from ``identify``), else the protocol's default."""
    return float(c.shared.get("angle_scale", ANGLE_DEG_PER_COUNT))


def deg(c: Ctx, counts: int) -> float:
    """Angle counts in degrees."""
    return counts * angle_scale(c)


def counts(c: Ctx, degrees: float) -> int:
    """An absolute angle in counts, in [0, one turn)."""
    return round((degrees % 360.0) / angle_scale(c)) % ANGLE_FULL_TURN


# -- the table ---------------------------------------------------------------------------------------
def table(c: Ctx) -> TableLimits:
    """Rate and acceleration limits and settle time, from the configuration."""
    return TableLimits.from_config(c.config())


def allowed_move_s(c: Ctx, distance_deg: float) -> tuple[float, float]:
    """(expected, allowed) unit seconds from a move's OK reply to READY."""
    expected = table(c).ready_after_s(distance_deg)
    return expected, expected * 1.1 + c.opt.settle_margin_s


# -- validity bits -----------------------------------------------------------------------------------
def validity_problem(v: int, state: DeviceState | None) -> str | None:
    """What is wrong with validity bits ``v`` for a sample taken in ``state`` (protocol.md 4.5)."""
    if state == DeviceState.READY:
        if (v & VALIDITY_GOOD) != VALIDITY_GOOD or v & VALIDITY_UNFIT:
            return "READY needs GYRO_VALID and ACCEL_VALID set and bits 2..7 clear"
    elif state in (DeviceState.BOOT, DeviceState.WARMUP):
        if not v & Validity.WARMING_UP:
            return f"{state.name} needs WARMING_UP"
    elif state == DeviceState.ROTATING:
        if not v & Validity.TABLE_MOVING:
            return "ROTATING needs TABLE_MOVING"
        if v & Validity.TABLE_SETTLING:
            return "ROTATING needs TABLE_SETTLING clear (both bits mean a steady spin)"
    elif state == DeviceState.SPINNING:
        if v & VALIDITY_STEADY_RATE != VALIDITY_STEADY_RATE:
            return "SPINNING needs TABLE_MOVING and TABLE_SETTLING (steady rate)"
    elif state == DeviceState.SETTLING:
        if not v & Validity.TABLE_SETTLING:
            return "SETTLING needs TABLE_SETTLING"
    elif state == DeviceState.FAULT and not v & Validity.FAULT:
        return "FAULT needs the FAULT bit"
    return None


def judge_validity(c: Ctx, samples: list[SampleRecord]) -> tuple[int, int, list[str]]:
    """(judged, bad, first problems) for samples away from state changes. Each sample is judged
    in the state the unit was in when it took it, by the unit's own sample counters
    (:meth:`~.session.Session.state_of`), not by when the host read it."""
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    # A status follows a change within 5 ms (protocol.md 6): the ticks of those 5 ms and two more
    # either side may show either state.
    guard = 2 + math.ceil(STATE_CHANGE_STATUS_S * rate)
    judged = bad = 0
    problems: list[str] = []
    for rec in samples:
        if not rec.complete:
            continue
        state = c.s.state_of(rec, guard)
        if state is None:
            continue
        judged += 1
        why = validity_problem(rec.validity, state)
        if why is not None:
            bad += 1
            if len(problems) < 3:
                problems.append(f"sample {rec.counter} validity 0x{rec.validity:02X}: {why}")
    return judged, bad, problems


# -- what a refusal or bad input must leave alone ----------------------------------------------------
def config_unchanged(c: Ctx) -> None:
    """Every writable key (but STREAMING) still holds the value the suite found."""
    cfg = c.config()
    for key in (k for k in ConfigKey if not k.read_only and k != ConfigKey.STREAMING):
        now = c.s.get_config(key)
        if now != cfg[key]:
            c.fail(f"{key.name} changed from {cfg[key]} to {now} although the command was refused")


def undisturbed(c: Ctx, t0: float) -> None:
    """The stream ran on without a gap since ``t0`` and the unit still answers."""
    s = c.s
    rate = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    s.idle(max(0.2, 10.0 / rate))
    c.gaps(s.gaps_found_since(t0), "the stream was disturbed: ")
    after = [r for r in s.samples if r.t >= t0]
    c.fig("samples meanwhile", len(after))
    if s.streaming and not after:
        c.fail("no samples arrived after the bad input")
    a = s.request(GetStatus(0))
    c.expect(a, Result.OK, "GET_STATUS after the bad input")


def no_reply_since(c: Ctx, t0: float, what: str) -> None:
    """No reply arrived since ``t0`` (for input the unit must drop silently)."""
    c.s.idle(max(0.1, c.opt.reply_limit_ms / 1000.0))
    got = [r for t, r in c.s.unsolicited if t >= t0]
    if got:
        r = got[0]
        c.fail(
            f"{what} was answered (seq {r.seq}, opcode 0x{int(r.opcode):02X}, result {int(r.result)})"
        )


def malformed_delta(c: Ctx, before: Status, expected: int | None, what: str) -> None:
    """The unit's rx malformed counter rose by ``expected`` since the status ``before``."""
    after = c.s.get_status()
    delta = (after.rx_malformed - before.rx_malformed) & 0xFFFF
    c.fig("rx_malformed delta", delta)
    if expected is not None and delta != expected:
        c.fail(f"rx malformed rose by {delta} for {what}, expected {expected}")


def dropped_silently(
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
    no_reply_since(c, t0, reply_what)
    malformed_delta(c, before, count, count_what)
    undisturbed(c, t0)


# -- reset -------------------------------------------------------------------------------------------
def reset_to_boot(c: Ctx) -> tuple[Answer, int | None]:
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
