"""Bad input (protocol.md 2, 4.2, 9): what the unit must drop, count and survive, without a reply and
without disturbing the stream. Commands of the wrong length are refusals (see ``refusals``)."""

from __future__ import annotations

from northfinder.driver.conformance.checks.common import dropped_silently, undisturbed
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.conformance.wire import CanRawLink, SerialRawLink
from northfinder.driver.protocol.constants import (
    NODE_ID_MAX,
    CanFunction,
    ConfigKey,
    Opcode,
    Result,
    SerialType,
)
from northfinder.driver.protocol.messages import Command, GetConfig, GetStatus
from northfinder.driver.protocol.serial import MAX_PAYLOAD, SYNC, SerialFrame


def can_link(c: Ctx, reason: str) -> CanRawLink:
    """The suite's CAN link, which can send any frame; skip the check on another link."""
    link = c.s.link
    if c.link_kind != "can" or not isinstance(link, CanRawLink):
        c.skip(reason)
    return link


def serial_link(c: Ctx, reason: str) -> SerialRawLink:
    """The suite's serial link, which can send any bytes; skip the check on another link."""
    link = c.s.link
    if c.link_kind != "serial" or not isinstance(link, SerialRawLink):
        c.skip(reason)
    return link


def command_frame(link: SerialRawLink, cmd: Command) -> bytes:
    """A well-formed serial COMMAND frame carrying ``cmd`` with the link's sequence counter."""
    return SerialFrame(SerialType.COMMAND, link.seq, cmd.encode()).encode()


@check("bad_input.short_command")
def bad_input_short_command(c: Ctx) -> None:
    """a command of 0 or 1 bytes (no opcode) is not answered, is counted in rx malformed, and the
    stream goes on (4.2, 9)"""
    s = c.s

    def send() -> None:
        s.link.send_command(b"")
        s.link.send_command(bytes((s.next_seq(),)))

    dropped_silently(c, send, 2, "a command without an opcode", "two commands without an opcode")


@check("bad_input.unknown_id")
def bad_input_unknown_id(c: Ctx) -> None:
    """CAN frames of other identifiers, other nodes and extended ids are ignored without counting
    (2.1, 9)"""
    s = c.s
    link = can_link(c, "CAN only (serial: see bad_input.unknown_type)")
    node = c.opt.node_id
    other = node + 1 if node < NODE_ID_MAX else node - 1
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
            link.send_frame(arb, data, extended=ext)

    dropped_silently(
        c, send, 0, "a frame not addressed to the unit", "frames that are not the unit's"
    )


@check("bad_input.unknown_type")
def bad_input_unknown_type(c: Ctx) -> None:
    """serial frames with a good CRC and an undefined type are dropped and counted, not answered (9)"""
    s = c.s
    link = serial_link(c, "serial only (CAN: see bad_input.unknown_id)")
    types = (0x00, 0x06, 0x7F, 0xFF)

    def send() -> None:
        for ty in types:
            link.send_frame(ty, bytes((s.next_seq(), Opcode.GET_STATUS)))

    dropped_silently(
        c,
        send,
        len(types),
        "a frame of an undefined type",
        f"{len(types)} frames of undefined types",
    )


@check("bad_input.bad_crc")
def bad_input_bad_crc(c: Ctx) -> None:
    """serial frames with a bad CRC or a length above 64 are dropped and counted, not answered
    (2.2, 9)"""
    s = c.s
    link = serial_link(c, "serial only (the CAN controller checks the CRC)")

    def send() -> None:
        bad = bytearray(command_frame(link, GetStatus(s.next_seq())))
        bad[-1] ^= 0x5A
        link.send_bytes(bytes(bad))
        link.send_bytes(SYNC + bytes((MAX_PAYLOAD + 1, SerialType.COMMAND, 0)) + bytes(8))

    dropped_silently(c, send, 2, "a frame with a bad CRC", "one bad CRC and one length above 64")


@check("bad_input.resync")
def bad_input_resync(c: Ctx) -> None:
    """after a false sync only the first sync byte is discarded: frames behind it and after garbage
    are answered (2.2)"""
    s = c.s
    link = serial_link(c, "serial only")
    c.ready()
    c.stream_on()
    t0 = s.now()
    # A header claiming 12 payload bytes (19 in all) swallows the start of the two commands behind it.
    a1 = GetStatus(s.next_seq())
    a2 = GetConfig(s.next_seq(), ConfigKey.SAMPLE_RATE_HZ)
    false_sync = SYNC + bytes((12, SerialType.COMMAND, 0))
    link.send_bytes(false_sync + command_frame(link, a1) + command_frame(link, a2))
    # Garbage without any sync byte, then a command.
    a3 = GetStatus(s.next_seq())
    garbage = bytes(b for b in range(256) if b != SYNC[0])
    link.send_bytes(garbage + command_frame(link, a3))
    tracked = {
        "the GET_STATUS behind the false sync": s.track(a1.encode()),
        "the GET_CONFIG behind the false sync": s.track(a2.encode()),
        "the GET_STATUS after the garbage": s.track(a3.encode()),
    }
    s.wait_until(lambda: all(x.reply is not None for x in tracked.values()), s.reply_wait_s)
    for what, x in tracked.items():
        c.expect(x, Result.OK, what)
    c.fig("answered", f"{sum(x.reply is not None for x in tracked.values())} of {len(tracked)}")
    undisturbed(c, t0)
