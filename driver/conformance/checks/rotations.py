"""Rotations (protocol.md 4.1, 4.5, 5): every move command, STOP during a move, commands accepted
while the table turns, and the accuracy, settle time and validity bits of moves to given angles."""

from __future__ import annotations

import itertools

from northfinder.driver.conformance.checks.common import (
    allowed_move_s,
    angle_scale,
    counts,
    deg,
    judge_validity,
    table,
)
from northfinder.driver.conformance.checks.moves import (
    Move,
    begin_long_move,
    finish_move,
    judge_end,
    move,
    still_rotating,
)
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.conformance.session import Answer
from northfinder.driver.protocol.constants import ConfigKey, Direction, Result, Validity
from northfinder.driver.protocol.messages import (
    GetConfig,
    GetStatus,
    Home,
    RequestIdentify,
    RotateBy,
    RotateTo,
    SetConfig,
    Stop,
    StreamStart,
)
from northfinder.driver.protocol.motion import shortest_delta_deg


@check("command.rotate_to")
def command_rotate_to(c: Ctx) -> None:
    """ROTATE_TO answered OK; ROTATING -> SETTLING -> READY; ends on target (4.1, 5)"""
    c.ready()
    start = deg(c, c.s.get_status().angle)
    target = (start + 30.0) % 360.0
    m = move(c, RotateTo(0, counts(c, target)), f"ROTATE_TO {target:.4f}", target, 30.0)
    err = judge_end(c, m, target)
    if err is not None:
        c.fig("error", f"{err:+.4f} deg")
    if m.t_ready is not None and m.answer.received is not None:
        c.fig("reply to READY", f"{c.s.unit(m.t_ready - m.answer.received):.2f} s")


@check("command.rotate_to_direction")
def command_rotate_to_direction(c: Ctx) -> None:
    """ROTATE_TO with direction NEGATIVE / POSITIVE takes the long way round when told (4.1)"""
    c.ready()
    start = deg(c, c.s.get_status().angle)
    for direction, target, travel in (
        (Direction.NEGATIVE, (start + 170.0) % 360.0, -190.0),
        (Direction.POSITIVE, start, 190.0),
    ):
        what = f"ROTATE_TO {target:.4f} {direction.name}"
        m = move(c, RotateTo(0, counts(c, target), direction), what, target, 190.0)
        judge_end(c, m, target)
        if m.travel_deg is None:
            if m.t_ready is not None:
                c.fail(f"{what}: no angle samples during the move to tell the direction")
            continue
        c.fig(f"{direction.name.lower()} travel", f"{m.travel_deg:+.2f} deg")
        if abs(m.travel_deg - travel) > 2.0:
            c.fail(f"{what}: the table travelled {m.travel_deg:+.2f} deg, expected {travel:+.0f}")


@check("command.rotate_by")
def command_rotate_by(c: Ctx) -> None:
    """ROTATE_BY +-25 deg answered OK and ends 25 deg away in the right sense (4.1)"""
    for delta in (25.0, -25.0):
        c.ready()
        start = deg(c, c.s.get_status().angle)
        steps = round(delta / angle_scale(c))
        m = move(c, RotateBy(0, steps), f"ROTATE_BY {delta:+g}", start + delta, abs(delta))
        judge_end(c, m, start + delta)
        if m.travel_deg is not None:
            c.fig(f"travel {delta:+g}", f"{m.travel_deg:+.3f} deg")
            if abs(m.travel_deg - delta) > 1.0:
                c.fail(f"ROTATE_BY {delta:+g}: the table travelled {m.travel_deg:+.3f} deg")


@check("command.home")
def command_home(c: Ctx) -> None:
    """HOME answered OK and ends at encoder zero by the shortest way (4.1)"""
    c.ready()
    start = deg(c, c.s.get_status().angle)
    way = shortest_delta_deg(start, 0.0)
    m = move(c, Home(0), "HOME", 0.0, abs(way))
    err = judge_end(c, m, 0.0)
    if err is not None:
        c.fig("error", f"{err:+.4f} deg")
    if m.travel_deg is not None:
        c.fig("travel", f"{m.travel_deg:+.2f} deg")
        if abs(m.travel_deg - way) > 1.0:
            c.fail(
                f"HOME from {start:.3f} deg travelled {m.travel_deg:+.2f} deg, the shortest way is {way:+.2f}"
            )


@check("command.rotate_to_present")
def command_rotate_to_present(c: Ctx) -> None:
    """ROTATE_TO the present angle is OK and still passes through ROTATING and SETTLING (4.1)"""
    c.ready()
    here = c.s.get_status().angle
    m = move(c, RotateTo(0, here), "ROTATE_TO the present angle", deg(c, here), 0.0)
    c.fig("states", " -> ".join(x.name for x in m.states))


@check("command.stop_while_rotating")
def command_stop_while_rotating(c: Ctx) -> None:
    """STOP during a move answered OK; the table decelerates to SETTLING, then READY, short of its
    target (4.1, 5)"""
    s = c.s
    limits = table(c)
    v, acc = limits.max_rate_dps, limits.max_accel_dps2
    m = begin_long_move(c)
    if m is None or m.turn_deg is None:
        return
    d = abs(m.turn_deg)
    s.idle(0.4 * limits.move_time_s(d))
    a = s.request(Stop(0))
    if not c.expect(a, Result.OK, "STOP while rotating"):
        return
    if not still_rotating(c, a):
        c.note("the move ended before STOP arrived")
    finish_move(c, m)
    if m.t_settling is not None and a.received is not None:
        decel = s.unit(m.t_settling - a.received)
        c.fig("STOP to SETTLING", f"{decel:.2f} s")
        allowed = v / acc * 1.1 + c.opt.reply_limit_ms / 1000 + 0.05
        if decel > allowed:
            c.late(
                f"SETTLING came {decel:.2f} s after STOP; braking from {v:g} deg/s at {acc:g} "
                f"deg/s2 takes {v / acc:.2f} s",
                a.received,
                m.t_settling,
                s.wall(decel - allowed),
            )
    if m.travel_deg is not None:
        c.fig("travel", f"{m.travel_deg:+.2f} of {m.turn_deg:+.1f} deg")
        # Judged by where the unit says the table was when it took STOP (its last sample before
        # its reply), not by when the host sent it: a host that stood still sends STOP late.
        at_stop = travel_before(c, m, a)
        brake = v * v / (2 * acc) * 1.1
        if at_stop is not None and abs(at_stop) + brake > d - 1.0:
            c.note(f"the unit took STOP {abs(at_stop):.1f} deg into the {d:.1f} deg move: too "
                   "late to stop short")  # fmt: skip
        elif abs(m.travel_deg) > d - 1.0:
            c.fail(f"the table travelled {m.travel_deg:+.2f} deg of {d:.1f}: STOP did not stop it")


def travel_before(c: Ctx, m: Move, a: Answer) -> float | None:
    """How far the table had turned, deg, by the last sample the unit sent before its reply to
    ``a`` (None without samples of the move before it)."""
    if a.samples_before is None:
        return None
    angles = [
        r.angle
        for r in c.s.samples[: a.samples_before]
        if r.t >= m.answer.sent and r.angle is not None
    ]
    if len(angles) < 2:
        return None
    return sum(shortest_delta_deg(0.0, deg(c, y - x)) for x, y in itertools.pairwise(angles))


@check("command.while_rotating")
def command_while_rotating(c: Ctx) -> None:
    """queries, streaming and non-motion settings are accepted while ROTATING; the stream shows
    TABLE_MOVING (5)"""
    s = c.s
    cfg = c.config()
    m = begin_long_move(c)
    if m is None:
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
        if a.reply is not None and not still_rotating(c, a):
            c.note(f"{what}: the move had ended")
    s.wait_until(lambda: len(s.identifies) > n_id, s.reply_wait_s)
    if len(s.identifies) == n_id:
        c.fail("no identify message followed IDENTIFY while rotating")
    finish_move(c, m)


def rotations(c: Ctx) -> list[tuple[float, Move, float]]:
    """ROTATE_TO each angle of the options once; shared by the rotation checks."""
    if "rotations" not in c.shared:
        out = []
        for angle in c.opt.angles_deg:
            c.ready()
            start = deg(c, c.s.get_status().angle)
            dist = abs(shortest_delta_deg(start, angle))
            m = move(c, RotateTo(0, counts(c, angle)), f"ROTATE_TO {angle % 360:g}", angle, dist)
            out.append((angle % 360.0, m, dist))
            c.s.idle(0.3)
        c.shared["rotations"] = out
    done: list[tuple[float, Move, float]] = c.shared["rotations"]
    return done


@check("rotation.accuracy")
def rotation_accuracy(c: Ctx) -> None:
    """ROTATE_TO each --angles target ends within the stated accuracy (4.1)"""
    for angle, m, _ in rotations(c):
        if not m.ok:
            c.fail(f"{m.what}: not accepted")
            continue
        err = judge_end(c, m, angle)
        if err is not None:
            c.fig(f"{angle:g}", f"{err * 1000:+.1f} mdeg")
    c.fig("limit", f"+-{c.opt.accuracy_deg * 1000:g} mdeg")


@check("rotation.settle_time")
def rotation_settle_time(c: Ctx) -> None:
    """READY within profile time (rate, acceleration) + SETTLE_TIME_MS + margin; SETTLING lasts
    SETTLE_TIME_MS (5)"""
    s = c.s
    settle = table(c).settle_s
    for angle, m, dist in rotations(c):
        if m.t_ready is None or m.answer.received is None:
            c.fail(f"{m.what}: no READY to time")
            continue
        took = s.unit(m.t_ready - m.answer.received)
        expected, allowed = allowed_move_s(c, dist)
        c.fig(f"{angle:g}", f"{took:.2f} s (expected {expected:.2f})")
        if took > allowed:
            c.late(
                f"{m.what}: READY after {took:.2f} s, allowed {allowed:.2f} s ({dist:.2f} deg)",
                m.answer.received,
                m.t_ready,
                s.wall(took - allowed),
            )
        if m.t_settling is not None:
            settling = s.unit(m.t_ready - m.t_settling)
            host = c.opt.reply_limit_ms / 1000.0  # the SETTLING status may arrive late
            lo, hi = settle * 0.9 - host, settle * 1.1 + c.opt.settle_margin_s
            if settling < lo or settling > hi:
                c.late(
                    f"{m.what}: SETTLING lasted {settling:.2f} s, SETTLE_TIME_MS is {settle * 1000:g}",
                    m.answer.received,
                    m.t_ready,
                    s.wall(lo - settling if settling < lo else settling - hi),
                )


@check("rotation.validity")
def rotation_validity(c: Ctx) -> None:
    """during the moves samples carry TABLE_MOVING, then TABLE_SETTLING, then are clean in READY
    (4.5)"""
    rot = rotations(c)
    if not rot:
        c.skip("no rotations")
    t0 = min(m.answer.sent for _, m, _ in rot)
    t1 = max((m.t_ready or m.answer.sent) for _, m, _ in rot) + c.s.wall(0.2)
    recs = c.s.samples_between(t0, t1)
    judged, bad, problems = judge_validity(c, recs)
    moving = sum(bool(r.validity & Validity.TABLE_MOVING) for r in recs)
    settling = sum(bool(r.validity & Validity.TABLE_SETTLING) for r in recs)
    c.fig("judged", judged)
    c.fig("moving", moving)
    c.fig("settling", settling)
    if bad:
        c.fail(f"{bad} of {judged} samples: " + "; ".join(problems))
    if not moving:
        c.fail("no sample carried TABLE_MOVING during the moves")
