"""SPIN (protocol 1.1, sections 4.1, 4.5, 5.1): the rate reached and held, the angle monotonic in
the commanded sense, the steady-rate validity pair, BUSY while spinning, STOP back to READY, and
the refusals of rates out of range. A unit of protocol 1.0 skips these checks."""

from __future__ import annotations

import numpy as np

from northfinder.driver.conformance.checks.common import angle_scale, deg, table
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.protocol.constants import (
    VALIDITY_STEADY_RATE,
    ConfigKey,
    DeviceState,
    Result,
)
from northfinder.driver.protocol.counters import counter_diff
from northfinder.driver.protocol.messages import RotateBy, Spin, Stop

#: The mean rate over the steady samples must be within this fraction of the command.
MEAN_RATE_TOLERANCE = 0.01
#: No single tick's rate may be further than this fraction from the command.
TICK_RATE_TOLERANCE = 0.05
#: How long each spin is observed at its steady rate, unit seconds.
OBSERVE_S = 3.0


def _needs_spin(c: Ctx) -> None:
    version = c.shared.get("protocol_version")
    if version is not None and tuple(version) < (1, 1):
        c.skip(f"the unit speaks protocol {version[0]}.{version[1]}; SPIN is 1.1")


def _spin_rate_dps(c: Ctx) -> float:
    """A rate the check spins at: half the unit's rate limit, at most 6 deg/s."""
    return min(6.0, table(c).max_rate_dps / 2.0)


@check("spin.steady")
def spin_steady(c: Ctx) -> None:
    """SPIN +-rate: ROTATING then SPINNING; steady samples carry TABLE_MOVING|TABLE_SETTLING; mean
    rate within 1 %, every tick within 5 %, angle monotonic; BUSY while spinning; STOP brakes to
    SETTLING and READY (4.1, 4.5, 5.1)"""
    _needs_spin(c)
    s = c.s
    limits = table(c)
    rate = _spin_rate_dps(c)
    ramp = rate / limits.max_accel_dps2
    fs = c.config()[ConfigKey.SAMPLE_RATE_HZ]
    for sign in (1.0, -1.0):
        what = f"SPIN {sign * rate:+g} deg/s"
        c.ready()
        c.stream_on()
        n = len(s.statuses)
        a = s.request(Spin(0, round(sign * rate * 1000)))
        if not c.expect(a, Result.OK, what):
            continue
        i = s.wait_state({DeviceState.SPINNING, DeviceState.FAULT}, ramp * 1.5 + 1.0, start=n)
        if i is None:  # about time: a host that stood still reads the status late
            since, now = a.received or a.sent, s.now()
            c.late(f"{what}: no SPINNING status within {ramp * 1.5 + 1.0:.1f} s", since, now,
                   now - since - s.wall(ramp) - c.reply_limit_wall)  # fmt: skip
            s.request(Stop(0))
            continue
        if s.statuses[i][1].state != DeviceState.SPINNING:
            c.fail(f"{what}: {s.statuses[i][1].state.name} instead of SPINNING")
            s.request(Stop(0))
            continue
        t_steady = s.statuses[i][0]
        c.fig(f"{what} to SPINNING", f"{s.unit(t_steady - (a.received or a.sent)):.2f} s")
        busy = s.request(RotateBy(0, round(10.0 / angle_scale(c))))
        c.expect(busy, Result.BUSY, f"ROTATE_BY while spinning ({what})")
        again = s.request(Spin(0, round(sign * rate * 1000)))
        c.expect(again, Result.BUSY, f"SPIN while spinning ({what})")
        s.idle(OBSERVE_S)
        t_end = s.now()
        # Judged by the unit's own counter, not by arrival: a loaded host may read the tick that
        # ends the ramp well after the first SPINNING status.
        c0 = s.statuses[i][1].sample_counter
        recs = [
            r
            for r in s.samples_between(t_steady, t_end)
            if r.complete and r.angle is not None and counter_diff(r.counter, c0) >= 2
        ]
        stop = s.request(Stop(0))
        c.expect(stop, Result.OK, f"STOP while spinning ({what})")
        _judge_steady(c, what, recs, sign * rate, fs)
        j = s.wait_state({DeviceState.READY, DeviceState.FAULT}, ramp * 2 + limits.settle_s + 2.0)
        if j is None:  # about time, as above
            since, now = stop.received or stop.sent, s.now()
            c.late(f"{what}: not READY within {ramp * 2 + limits.settle_s + 2:.1f} s of STOP",
                   since, now,
                   now - since - s.wall(ramp + limits.settle_s) - c.reply_limit_wall)  # fmt: skip
            continue
        if s.statuses[j][1].state != DeviceState.READY:
            c.fail(f"{what}: {s.statuses[j][1].state.name} after STOP, not READY")
            continue
        # The unit's own order: from its first status of the spin on (the statuses before it,
        # READY, it sent before it took the SPIN, however late a loaded host read them).
        first = next(k for k in range(n, i + 1) if s.statuses[k][1].state != DeviceState.READY)
        seq: list[DeviceState] = []
        for _, st in s.statuses[first : j + 1]:
            if not seq or seq[-1] != st.state:
                seq.append(st.state)
        want = [DeviceState.ROTATING, DeviceState.SPINNING, DeviceState.ROTATING]
        want += [DeviceState.SETTLING] if limits.settle_s > 0 else []
        want += [DeviceState.READY]
        if seq != want:
            c.fail(f"{what}: states {' -> '.join(x.name for x in seq)}, expected "
                   f"{' -> '.join(x.name for x in want)}")  # fmt: skip


def _judge_steady(c: Ctx, what: str, recs: list, rate_dps: float, fs: float) -> None:
    if len(recs) < 2:
        c.fail(f"{what}: no steady samples to judge")
        return
    unsteady = [r for r in recs if r.validity & VALIDITY_STEADY_RATE != VALIDITY_STEADY_RATE]
    if unsteady:
        c.fail(
            f"{what}: {len(unsteady)} of {len(recs)} samples in SPINNING lack the steady-rate "
            f"pair (first: validity 0x{unsteady[0].validity:02X})"
        )
    counter = np.array([r.counter for r in recs], dtype=float)
    angle = np.array([deg(c, r.angle) for r in recs])
    step = (np.diff(angle) + 180.0) % 360.0 - 180.0  # each step is far below half a turn
    ticks = np.diff(counter)
    tick_rate = step / ticks * fs
    mean = float(step.sum() / ticks.sum() * fs)
    c.fig(f"{what} mean rate", f"{mean:+.4f} deg/s")
    c.fig(f"{what} tick rate", f"{tick_rate.min():+.3f} .. {tick_rate.max():+.3f} deg/s")
    if abs(mean - rate_dps) > MEAN_RATE_TOLERANCE * abs(rate_dps):
        c.fail(f"{what}: mean rate {mean:+.4f} deg/s, more than 1 % from the command")
    if np.any(np.abs(tick_rate - rate_dps) > TICK_RATE_TOLERANCE * abs(rate_dps)):
        c.fail(f"{what}: a tick's rate was {tick_rate[np.argmax(np.abs(tick_rate - rate_dps))]:+.3f} "
               "deg/s, more than 5 % from the command")  # fmt: skip
    if np.any(np.sign(step) != np.sign(rate_dps)):
        c.fail(f"{what}: the angle did not advance monotonically in the commanded sense")


@check("spin.refusals")
def spin_refusals(c: Ctx) -> None:
    """SPIN with rate 0 or beyond TABLE_MAX_RATE_MDPS either way is refused with OUT_OF_RANGE, and
    the table stays READY (4.3)"""
    _needs_spin(c)
    s = c.s
    c.ready()
    limit = c.config()[ConfigKey.TABLE_MAX_RATE_MDPS]
    for rate in (0, limit + 1, -limit - 1, 2**31 - 1, -(2**31)):
        c.expect(s.request(Spin(0, rate)), Result.OUT_OF_RANGE, f"SPIN {rate}")
    st = s.get_status()
    if st.state != DeviceState.READY:
        c.fail(f"after refused SPINs the unit is {st.state.name}, not READY")
