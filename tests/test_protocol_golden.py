"""Golden byte vectors: read out of protocol.md, checked in both directions for every message.

Each vector in protocol.md is a block::

    [golden <name>]
    fields: ...            (for the reader; not parsed)
    can:    <id>#<hex>     (one line per CAN frame, candump notation, node 1)
    serial: <hex bytes>    (one whole frame, sequence counter 0x2A)

The objects below are written independently of the bytes; the bytes were checked by hand
against the layout tables in protocol.md.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from northfinder.driver.protocol import (
    Command,
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    GetConfig,
    GetStatus,
    Home,
    Identify,
    Message,
    Opcode,
    Reply,
    RequestIdentify,
    Reset,
    Result,
    RotateBy,
    RotateTo,
    Sample,
    Scale,
    SelfTest,
    SelfTestFailure,
    SetConfig,
    Spin,
    Status,
    Stop,
    StreamStart,
    StreamStop,
    Validity,
)
from northfinder.driver.protocol.can import CanFrame, CanReceiver, decode_can, encode_can
from northfinder.driver.protocol.serial import Deframer, decode_frame, encode_serial, parse_frame

PROTOCOL_MD = Path(__file__).resolve().parents[1] / "protocol.md"
SERIAL_SEQ = 0x2A

GOLDEN: dict[str, Message] = {
    "cmd_identify": RequestIdentify(1),
    "cmd_get_status": GetStatus(2),
    "cmd_rotate_to": RotateTo(3, 90_000_000, Direction.SHORTEST),
    "cmd_rotate_to_negative": RotateTo(4, 359_999_999, Direction.NEGATIVE),
    "cmd_rotate_by": RotateBy(5, -180_000_000),
    "cmd_stop": Stop(6),
    "cmd_home": Home(7),
    "cmd_stream_start": StreamStart(8),
    "cmd_stream_stop": StreamStop(9),
    "cmd_get_config": GetConfig(10, ConfigKey.SAMPLE_RATE_HZ),
    "cmd_set_config": SetConfig(11, ConfigKey.HEARTBEAT_PERIOD_MS, 250),
    "cmd_reset": Reset(12),
    "cmd_self_test": SelfTest(13),
    "cmd_spin": Spin(16, 6_000),
    "cmd_spin_negative": Spin(17, -2_500),
    "reply_spin_out_of_range": Reply(18, Opcode.SPIN, Result.OUT_OF_RANGE),
    "reply_ok": Reply(3, Opcode.ROTATE_TO, Result.OK),
    "reply_busy": Reply(5, Opcode.ROTATE_BY, Result.BUSY),
    "reply_get_config": Reply.config(10, Opcode.GET_CONFIG, ConfigKey.SAMPLE_RATE_HZ, 200),
    "reply_set_config": Reply.config(11, Opcode.SET_CONFIG, ConfigKey.HEARTBEAT_PERIOD_MS, 250),
    "reply_rate_exceeds_link": Reply(14, Opcode.SET_CONFIG, Result.RATE_EXCEEDS_LINK),
    "reply_self_test": Reply.self_test(13, SelfTestFailure.GYRO_X | SelfTestFailure.DRIVE),
    "reply_unknown_command": Reply(15, 0x7F, Result.UNKNOWN_COMMAND),
    "sample": Sample(
        counter=76_805,
        gyro=(123_456, -98_765, 150_000),
        accel=(1_234, -2_345, 1_000_123),
        angle=123_456_789,
        temperature=2_512,
        validity=Validity.GYRO_VALID | Validity.ACCEL_VALID,
    ),
    "sample_moving": Sample(
        counter=0xFFFF_FFFF,
        gyro=(-45_000, 2_147_483_647, -2_147_483_648),
        accel=(-8_388_608, 8_388_607, 0),
        angle=359_999_999,
        temperature=-1_050,
        validity=Validity.ACCEL_VALID
        | Validity.TABLE_MOVING
        | Validity.GYRO_SATURATED
        | Validity.ACCEL_SATURATED,
    ),
    "sample_spinning": Sample(
        counter=1_000,
        gyro=(9_000, -120_000, 216_000_000),
        accel=(-5_000, 3_000, 1_000_000),
        angle=90_000_123,
        temperature=2_300,
        validity=Validity.GYRO_VALID
        | Validity.ACCEL_VALID
        | Validity.TABLE_MOVING
        | Validity.TABLE_SETTLING,
    ),
    "status_spinning": Status(
        state=DeviceState.SPINNING,
        angle=270_000_000,
        temperature=2_300,
        faults=Fault(0),
        sample_counter=1_000,
        rx_malformed=0,
        tx_dropped=0,
        cmd_rejected=1,
    ),
    "status": Status(
        state=DeviceState.READY,
        angle=123_456_789,
        temperature=2_512,
        faults=Fault(0),
        sample_counter=76_805,
        rx_malformed=1,
        tx_dropped=0,
        cmd_rejected=2,
    ),
    "status_fault": Status(
        state=DeviceState.FAULT,
        angle=0,
        temperature=-32_768,
        faults=Fault.ENCODER | Fault.DRIVE,
        sample_counter=65_536,
        rx_malformed=0x1234,
        tx_dropped=255,
        cmd_rejected=7,
    ),
    "identify": Identify(
        model="NF-200",
        serial_number=20_240_117,
        hardware_revision=3,
        firmware_version=(1, 2, 3),
        protocol_version=(1, 0),
        max_sample_rate_hz=400,
        gyro_scale=Scale(1, -4),
        accel_scale=Scale(1, -6),
        angle_scale=Scale(1, -6),
        temperature_scale=Scale(1, -2),
    ),
}

_BLOCK = re.compile(r"^\[golden (\w+)\]\s*$")
_CAN = re.compile(r"^can:\s+([0-9A-Fa-f]{3})#([0-9A-Fa-f]*)\s*$")
_SERIAL = re.compile(r"^serial:\s+((?:[0-9A-Fa-f]{2}\s*)+)$")


def parse_golden(text: str) -> dict[str, tuple[list[CanFrame], bytes]]:
    """``{name: (can frames, serial frame bytes)}`` from the golden blocks of protocol.md."""
    vectors: dict[str, tuple[list[CanFrame], bytes]] = {}
    name: str | None = None
    for line in text.splitlines():
        line = line.strip()
        if m := _BLOCK.match(line):
            name = m.group(1)
            assert name not in vectors, f"golden vector {name} appears twice"
            vectors[name] = ([], b"")
        elif name is not None and (m := _CAN.match(line)):
            vectors[name][0].append(CanFrame(int(m.group(1), 16), bytes.fromhex(m.group(2))))
        elif name is not None and (m := _SERIAL.match(line)):
            vectors[name] = (vectors[name][0], bytes.fromhex(m.group(1)))
        elif not line or line.startswith("```"):
            name = None
    return vectors


@pytest.fixture(scope="module")
def vectors() -> dict[str, tuple[list[CanFrame], bytes]]:
    return parse_golden(PROTOCOL_MD.read_text(encoding="utf-8"))


def test_every_vector_is_documented_and_complete(vectors):
    assert set(vectors) == set(GOLDEN)
    for name, (frames, serial) in vectors.items():
        assert frames, f"{name}: no can line"
        assert serial, f"{name}: no serial line"


def test_every_message_kind_has_a_vector():
    kinds = {type(m) for m in GOLDEN.values()}
    opcodes = {m.OPCODE for m in GOLDEN.values() if isinstance(m, Command)}
    assert opcodes == set(Opcode)
    assert {Reply, Sample, Status, Identify} <= kinds


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_can_encode_matches_golden(vectors, name):
    assert encode_can(GOLDEN[name], node_id=1) == vectors[name][0]


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_can_decode_matches_golden(vectors, name):
    receiver = CanReceiver(node_id=1)
    message = GOLDEN[name]
    if isinstance(message, Sample):
        receiver.ticks.sync(message.counter)
    out = []
    for frame in vectors[name][0]:
        assert decode_can(*frame).node_id == 1
        out += receiver.feed(*frame)
    assert out == [GOLDEN[name]]
    assert receiver.malformed == receiver.unknown_id == 0


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_serial_encode_matches_golden(vectors, name):
    assert encode_serial(GOLDEN[name], SERIAL_SEQ) == vectors[name][1]


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_serial_decode_matches_golden(vectors, name):
    frame = parse_frame(vectors[name][1])
    assert frame.seq == SERIAL_SEQ
    assert decode_frame(frame) == GOLDEN[name]
    deframer = Deframer()
    assert deframer.feed_messages(vectors[name][1]) == [GOLDEN[name]]
    assert deframer.crc_errors == deframer.discarded_bytes == 0


def test_hand_checked_bytes(vectors):
    """A few fields spelled out byte by byte, independent of the codec."""
    (rotate,), _ = vectors["cmd_rotate_to"]
    assert rotate.arbitration_id == 0x041
    assert rotate.data == bytes([3, 0x10]) + (90_000_000).to_bytes(4, "little") + b"\x00"
    (by,), _ = vectors["cmd_rotate_by"]
    assert by.data[2:] == (-180_000_000).to_bytes(4, "little", signed=True)
    x, y, z, aux = vectors["sample"][0]
    assert [f.arbitration_id for f in (x, y, z, aux)] == [0x101, 0x111, 0x121, 0x131]
    assert x.data == bytes([76_805 & 0xFF]) + (123_456).to_bytes(4, "little") + (1_234).to_bytes(
        3, "little"
    )
    assert z.data[5:] == (1_000_123).to_bytes(3, "little", signed=True)
    assert aux.data[1:5] == (123_456_789).to_bytes(4, "little")
    assert aux.data[5:7] == (2_512).to_bytes(2, "little") and aux.data[7] == 0x03
    serial = vectors["sample"][1]
    assert serial[:5] == bytes([0xA5, 0x5A, 35, 0x05, SERIAL_SEQ])
    assert serial[5:9] == (76_805).to_bytes(4, "little")


def test_spin_bytes_by_hand(vectors):
    """Version 1.1: SPIN's i32 rate in 1e-3 deg/s, state SPINNING and the steady-rate pair."""
    (spin,), _ = vectors["cmd_spin"]
    assert spin.arbitration_id == 0x041
    assert spin.data == bytes([16, 0x14]) + (6_000).to_bytes(4, "little", signed=True)
    (neg,), _ = vectors["cmd_spin_negative"]
    assert neg.data[2:] == (-2_500).to_bytes(4, "little", signed=True)
    aux = vectors["sample_spinning"][0][3]
    assert aux.data[7] == 0x0F  # GYRO_VALID | ACCEL_VALID | TABLE_MOVING | TABLE_SETTLING
    z = vectors["sample_spinning"][0][2]
    assert z.data[1:5] == (216_000_000).to_bytes(4, "little")  # 6 deg/s = 21 600 deg/h
    (main, _counters), _ = vectors["status_spinning"]
    assert main.data[0] == 6
