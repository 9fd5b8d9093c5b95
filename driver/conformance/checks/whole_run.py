"""Figures over the whole run (protocol.md 2, 6, 8, 9): reply latencies and link integrity. These
checks run last and judge everything the session recorded."""

from __future__ import annotations

import statistics

from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.protocol.constants import REPLY_DEADLINE_MS, Opcode


@check("timing.reply")
def timing_reply(c: Ctx) -> None:
    """every reply within the reply limit (host-measured; the unit's deadline is 20 ms) (6)"""
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
    late = [
        a
        for a in answers
        if a.latency is not None
        and a.received is not None
        and c.ms(a.latency) > c.opt.reply_limit_ms
    ]
    # Each late reply is judged against the host's pace while it was awaited.
    for i, a in enumerate(late):
        assert a.latency is not None and a.received is not None
        text = (
            f"{len(late)} repl(ies) later than {c.opt.reply_limit_ms:g} ms (max {lat[-1]:.0f} ms)"
            if i == 0
            else ""
        )
        c.late(text, a.sent, a.received, a.latency - c.reply_limit_wall)
    now = c.s.now()
    for i, a in enumerate(missing):
        text = (
            f"{len(missing)} command(s) without a reply, first {missing[0].name} seq {missing[0].seq}"
            if i == 0
            else ""
        )
        c.late(text, a.sent, now, now - a.sent - c.reply_limit_wall)


@check("link.integrity")
def link_integrity(c: Ctx) -> None:
    """over the whole run: every frame from the unit decodes, no reply without a command, no serial
    frame lost (2, 8, 9)"""
    s = c.s
    c.fig("link errors", len(s.link_errors))
    c.fig("unanswered replies", len(s.unsolicited))
    # Frames lost or broken are judged one by one against how far the reader was behind the
    # stream then: a link whose reader fell behind further than it holds drops what comes next
    # (a full tty buffer), which is the host's doing when the host could not keep pace.
    if c.link_kind == "serial":
        c.fig("serial frames lost", s.serial_frames_lost)
        for i, (t, text) in enumerate(s.losses):
            head = f"{s.serial_frames_lost} serial frame(s) from the unit lost (sequence counter gaps), first: "
            c.lost(head + text if i == 0 else "", t)
    for i, (t, text) in enumerate(s.link_errors):
        head = f"{len(s.link_errors)} bad frame(s) from the unit, first: "
        c.lost(head + text if i == 0 else "", t)
    strays = len(s.unsolicited)
    if strays:
        r = next(r for _, r in s.unsolicited)
        c.fail(
            f"{strays} repl(ies) matching no command, first seq {r.seq} opcode 0x{int(r.opcode):02X}"
        )
