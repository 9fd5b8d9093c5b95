"""Moves as the suite sees them: send a move from READY, follow its states to READY, measure where
the table ended and how far it travelled."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

from northfinder.driver.conformance.checks.common import allowed_move_s, angle_scale, deg, table
from northfinder.driver.conformance.core import Ctx
from northfinder.driver.conformance.session import Answer
from northfinder.driver.protocol.constants import DeviceState, Result
from northfinder.driver.protocol.messages import Command, RotateBy
from northfinder.driver.protocol.motion import shortest_delta_deg


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
    turn_deg: float | None = None
    """The turn commanded, signed (relative moves)."""

    @property
    def ok(self) -> bool:
        return self.answer.reply is not None and self.answer.reply.result == Result.OK


def begin_move(c: Ctx, cmd: Command, what: str, target_deg: float | None = None) -> Move:
    """Send a move from READY and wait for its first state change; record problems."""
    s = c.s
    c.ready()
    c.stream_on()
    start = deg(c, s.get_status().angle)
    n = len(s.statuses)
    a = s.request(cmd)
    m = Move(what, a, start, target_deg)
    if not c.expect(a, Result.OK, what) or a.received is None:
        return m
    limit = max(s.reply_wait_s, s.wall(0.5))
    i = s.wait_state(
        {DeviceState.ROTATING, DeviceState.SETTLING, DeviceState.FAULT}, s.unit(limit), start=n
    )
    if i is None:
        # About time: a host that stood still reads the status late (the rule of pace.py).
        now = s.now()
        c.late(
            f"{what}: no status of the state change followed the OK reply within {limit:.1f} s",
            a.received,
            now,
            now - a.received - c.reply_limit_wall,
        )
        return m
    m.first_index = i
    t = m.first_change = s.statuses[i][0]
    lat = c.ms(t - a.received)
    c.shared.setdefault("state_change_ms", []).append(lat)
    if lat > c.opt.reply_limit_ms:
        c.late(
            f"{what}: the state-change status came {lat:.0f} ms after the reply",
            a.received,
            t,
            t - a.received - c.reply_limit_wall,
        )
    return m


def finish_move(c: Ctx, m: Move, distance_deg: float | None = None) -> Move:
    """Wait for READY after a move, read where the table ended and how it got there.

    ``distance_deg`` (default: the commanded turn, else a whole turn) sets how long to wait.
    """
    s = c.s
    if m.first_change is None:
        return m
    if distance_deg is None:
        distance_deg = 360.0 if m.turn_deg is None else m.turn_deg
    dist = abs(distance_deg)
    _, allowed = allowed_move_s(c, dist)
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
        since = m.answer.received or m.answer.sent
        now = s.now()
        c.late(
            f"{m.what}: the unit did not report READY within {allowed * 2 + 2:.1f} s",
            since,
            now,
            now - since - s.wall(allowed),
        )
        return m
    if s.statuses and s.state == DeviceState.FAULT:
        c.fail(f"{m.what}: the unit went to FAULT")
        return m
    m.t_ready = t
    m.end_deg = deg(c, s.get_status().angle)
    angles = [r.angle for r in s.samples_between(m.answer.sent, t) if r.angle is not None]
    if len(angles) > 1:
        m.travel_deg = sum(
            shortest_delta_deg(0.0, deg(c, b - a)) for a, b in itertools.pairwise(angles)
        )
    want = [DeviceState.ROTATING, DeviceState.SETTLING, DeviceState.READY]
    if table(c).settle_s == 0 and DeviceState.SETTLING not in seq:
        want.remove(DeviceState.SETTLING)
    if seq != want:
        c.fail(
            f"{m.what}: states {' -> '.join(x.name for x in seq)}, expected {' -> '.join(x.name for x in want)}"
        )
    return m


def move(
    c: Ctx, cmd: Command, what: str, target_deg: float | None = None, distance: float | None = None
) -> Move:
    """A whole move: :func:`begin_move` then :func:`finish_move`."""
    return finish_move(c, begin_move(c, cmd, what, target_deg), distance)


def judge_end(c: Ctx, m: Move, target_deg: float) -> float | None:
    """The table's end error from ``target_deg``, deg, recorded as a problem beyond the accuracy."""
    if m.end_deg is None:
        return None
    err = shortest_delta_deg(target_deg, m.end_deg)
    if abs(err) > c.opt.accuracy_deg:
        c.fail(
            f"{m.what}: the table ended at {m.end_deg:.4f} deg, {err:+.4f} deg from {target_deg % 360:.4f} "
            f"(allowed {c.opt.accuracy_deg:g})"
        )
    return err


def begin_long_move(c: Ctx) -> Move | None:
    """Start a ROTATE_BY lasting about two seconds of the unit's time (alternating in sign, so the
    table stays near where it was) and wait until it turns; None if it did not (recorded)."""
    limits = table(c)
    v, a = limits.max_rate_dps, limits.max_accel_dps2
    d = max(5.0, min(170.0, v * (2.0 - v / a)))
    sign = c.shared.get("sign", 1.0)
    c.shared["sign"] = -sign
    cmd = RotateBy(0, round(sign * d / angle_scale(c)))
    m = begin_move(c, cmd, f"ROTATE_BY {deg(c, cmd.delta):+.1f}")
    m.turn_deg = sign * d
    return m if m.first_change is not None else None


def still_rotating(c: Ctx, a: Answer) -> bool:
    """Whether the last status before the reply to ``a`` showed ROTATING."""
    return c.s.state_when_answered(a) == DeviceState.ROTATING
