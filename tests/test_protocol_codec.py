"""Codec details: CRC, typed errors, result meanings, counter extension, link budget."""

from __future__ import annotations

import pytest
from test_protocol_golden import GOLDEN

from northfinder.driver.errors import (
    BadCommandError,
    CrcError,
    DriverError,
    EncodeError,
    PayloadError,
    ProtocolError,
    UnknownMessageError,
)
from northfinder.driver.protocol import (
    Identify,
    Opcode,
    Result,
    RotateTo,
    Sample,
    SampleAux,
    SampleX,
    SampleY,
    SampleZ,
    Validity,
    result_meaning,
)
from northfinder.driver.protocol.budget import (
    can_bus_load,
    can_frame_bits,
    max_sample_rate,
    rate_fits,
)
from northfinder.driver.protocol.can import (
    TickAssembler,
    TickLoss,
    can_id,
    decode_can,
    split_can_id,
)
from northfinder.driver.protocol.constants import CanFunction
from northfinder.driver.protocol.counters import TickCounter, counter_diff, nearest_counter
from northfinder.driver.protocol.errors import ArgumentError
from northfinder.driver.protocol.serial import crc16_ccitt, encode_serial, parse_frame


def crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE written out bit by bit, independent of the codec's."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def test_crc_check_value_and_independent_implementation():
    assert crc16_ccitt(b"123456789") == 0x29B1 == crc_bitwise(b"123456789")
    frame = encode_serial(GOLDEN["sample"], 7)
    assert frame[-2:] == crc_bitwise(frame[2:-2]).to_bytes(2, "little")


def test_bad_crc_is_typed():
    frame = bytearray(encode_serial(GOLDEN["cmd_stop"], 1))
    frame[6] ^= 0xFF
    with pytest.raises(CrcError) as info:
        parse_frame(bytes(frame))
    assert info.value.expected != info.value.received
    assert isinstance(info.value, ProtocolError) and isinstance(info.value, DriverError)


@pytest.mark.parametrize(
    ("payload", "result"),
    [
        (bytes([9, 0x7F]), Result.UNKNOWN_COMMAND),
        (bytes([9, Opcode.STOP, 0]), Result.BAD_ARGUMENT),
        (bytes([9, Opcode.ROTATE_TO, 0, 0, 0]), Result.BAD_ARGUMENT),
        (bytes([9, Opcode.ROTATE_TO, 0, 0, 0, 0, 3]), Result.BAD_ARGUMENT),
    ],
)
def test_bad_commands_carry_what_the_reply_needs(payload, result):
    with pytest.raises(BadCommandError) as info:
        decode_can(0x041, payload)
    assert (info.value.seq, info.value.opcode, info.value.result) == (9, payload[1], result)


def test_unknown_ids_and_lengths():
    for bad_id in (0x040, 0x000, 0x7FF, 0x141, 0x801):
        with pytest.raises(UnknownMessageError):
            decode_can(bad_id, bytes(8))
    with pytest.raises(UnknownMessageError):
        decode_can(0x101, bytes(8), is_extended_id=True)
    with pytest.raises(PayloadError):
        decode_can(0x101, bytes(7))
    with pytest.raises(PayloadError):
        decode_can(0x101, bytes(9))
    with pytest.raises(PayloadError):
        decode_can(0x201, bytes([7]) + bytes(7))  # undefined state (6 is SPINNING since 1.1)


def test_can_ids():
    assert can_id(CanFunction.SAMPLE_AUX, 15) == 0x13F
    assert split_can_id(0x13F) == (CanFunction.SAMPLE_AUX, 15)
    with pytest.raises(EncodeError):
        can_id(CanFunction.COMMAND, 0)


def test_encode_refuses_what_does_not_fit():
    with pytest.raises(EncodeError, match="accel"):
        SampleX(0, 0, 1 << 23).encode()
    with pytest.raises(EncodeError, match="angle"):
        RotateTo(0, -1).encode()
    with pytest.raises(EncodeError, match="model"):
        Identify("TOO-LONG-NAME", 1).encode()
    with pytest.raises(EncodeError):
        Sample(0, (0, 0, 0), (0, 0, 1 << 31), 0, 0, Validity(0)).encode()


def test_every_result_has_a_meaning():
    for code in Result:
        assert code.meaning and result_meaning(code) == code.meaning
    assert "undefined" in result_meaning(200)


def test_tick_assembler_wraps_and_reports():
    asm = TickAssembler()
    asm.sync(0x1_00FE)
    aux = SampleAux(0, 0, 0, Validity(0))
    out = []
    for tick in (0xFF, 0x00, 0x03):
        for part in (SampleX(tick, 1, 2), *_yz(tick), SampleAux(tick, 0, 0, Validity(0))):
            out += asm.add(part)
    assert [o.counter for o in out if isinstance(o, Sample)] == [0x1_00FF, 0x1_0100, 0x1_0103]
    assert TickLoss(0x1_0101, 2, False) in out
    out = asm.add(SampleX(0x04, 1, 2)) + asm.add(SampleX(0x05, 1, 2))
    assert out == [TickLoss(0x1_0104, 1, True)]
    assert asm.add(aux) == [TickLoss(0x1_0105, 1, True), TickLoss(0x1_0106, 250, False)]
    assert (asm.lost, asm.incomplete) == (252, 2)


def test_counter_arithmetic_across_the_wrap():
    u32 = 0xFFFF_FFFF
    assert counter_diff(0, u32) == 1 and counter_diff(u32, 0) == -1
    assert counter_diff(5, 3) == 2 and counter_diff(3, 5) == -2 and counter_diff(9, 9) == 0
    assert (
        counter_diff(1 << 31, 0) == -(1 << 31) and counter_diff((1 << 31) - 1, 0) == (1 << 31) - 1
    )
    assert nearest_counter(0x10, 0x1_0000) == 0x1_0010
    assert nearest_counter(0xF0, 0x1_0000) == 0xFFF0
    assert nearest_counter(0xFF, 0) == u32 and nearest_counter(0x00, u32) == 0
    assert nearest_counter(0x180, 0x1_0000) == 0xFF80  # low8 taken modulo 256; a tie goes back


def test_tick_counter_places_ticks_before_the_first_anchor_where_they_belong():
    tc = TickCounter()
    assert tc.place(7) == (7, None) and not tc.anchored
    assert tc.place(8) == (8, 1)
    real = 999_944  # a counter whose low byte is 8
    assert tc.sync(real) and tc.last == real and tc.anchored
    assert not tc.sync(real)  # already anchored: nothing moves
    assert tc.place(9) == (real + 1, 1)
    assert tc.place(9) == (real + 1, 0)  # the same tick again changes nothing
    assert tc.place(12) == (real + 4, 3)
    tc.restart()
    assert tc.last is None and tc.place(20) == (real + 12, None) and tc.anchored


def test_tick_assembler_joining_a_running_stream_reports_no_false_loss():
    asm = TickAssembler()
    assert [s.counter for s in _ticks(asm, 7, 8)] == [7, 8]  # before any status: counter = tick
    asm.sync(999_944)  # the status gives the real counter of tick 8
    out = _ticks(asm, 999_945)
    assert [s.counter for s in out if isinstance(s, Sample)] == [999_945]
    assert not any(isinstance(s, TickLoss) for s in out) and asm.lost == 0


def _ticks(asm, *counters):
    out = []
    for c in counters:
        t = c & 0xFF
        for part in (SampleX(t, 1, 2), *_yz(t), SampleAux(t, 0, 0, Validity(3))):
            out += asm.add(part)
    return out


def _yz(tick):
    return SampleY(tick, 3, 4), SampleZ(tick, 5, 6)


def test_link_budget():
    assert can_frame_bits(8, worst_case=False) == 111
    assert can_frame_bits(8) == 135
    assert 1_000_000 / can_frame_bits(8, worst_case=False) == pytest.approx(9009, abs=1)
    assert can_bus_load(500_000, 200) == pytest.approx(820 * 135 / 500_000)
    assert [max_sample_rate("can", b) for b in (125_000, 250_000, 500_000, 1_000_000)] == [
        100,
        200,
        400,
        400,
    ]
    assert [max_sample_rate("serial", b) for b in (38_400, 57_600, 115_200, 230_400)] == [
        50,
        100,
        200,
        400,
    ]
    assert not rate_fits("serial", 115_200, 200, heartbeat_period_ms=10)
    with pytest.raises(ValueError, match="'can' or 'serial'"):
        rate_fits("usb", 1, 1)
    with pytest.raises(ArgumentError):
        rate_fits("usb", 1, 1)
