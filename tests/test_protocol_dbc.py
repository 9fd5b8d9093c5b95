"""protocol.dbc, read by cantools, decodes every CAN message exactly as the codec does."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import cantools
import pytest
from hypothesis import given, settings
from test_protocol_golden import GOLDEN
from test_protocol_roundtrip import messages

from northfinder.driver.protocol import (
    CanFunction,
    Command,
    Fault,
    GetConfig,
    Identify,
    IdentifyPage,
    Opcode,
    Reply,
    RotateBy,
    RotateTo,
    SampleAux,
    SampleAxis,
    SetConfig,
    Spin,
    StatusCounters,
    StatusMain,
    Validity,
)
from northfinder.driver.protocol.can import decode_can, encode_can

DBC = Path(__file__).resolve().parents[1] / "protocol.dbc"

_VALIDITY_SIGNALS = {
    "GyroValid": Validity.GYRO_VALID,
    "AccelValid": Validity.ACCEL_VALID,
    "TableMoving": Validity.TABLE_MOVING,
    "TableSettling": Validity.TABLE_SETTLING,
    "GyroSaturated": Validity.GYRO_SATURATED,
    "AccelSaturated": Validity.ACCEL_SATURATED,
    "WarmingUp": Validity.WARMING_UP,
    "Fault": Validity.FAULT,
}
_FAULT_SIGNALS = {
    "FaultGyro": Fault.GYRO,
    "FaultAccel": Fault.ACCEL,
    "FaultEncoder": Fault.ENCODER,
    "FaultDrive": Fault.DRIVE,
    "FaultOverTemperature": Fault.OVER_TEMPERATURE,
    "FaultSelfTest": Fault.SELF_TEST,
    "FaultSupply": Fault.SUPPLY,
    "FaultInternal": Fault.INTERNAL,
}


#: The signals of frames whose fields map one to one onto signals: signal -> field.
_FIELD_SIGNALS: dict[type, dict[str, str]] = {
    SampleAux: {"Tick": "tick", "TableAngle": "angle", "Temperature": "temperature"},
    StatusMain: {"State": "state", "TableAngle": "angle", "Temperature": "temperature"},
    StatusCounters: {
        "SampleCounter": "sample_counter",
        "RxMalformed": "rx_malformed",
        "TxDropped": "tx_dropped",
        "CmdRejected": "cmd_rejected",
    },
}
#: Flag fields, one signal a bit: field and its bits' signals.
_FLAG_SIGNALS: dict[type, tuple[str, Mapping[str, int]]] = {
    SampleAux: ("validity", _VALIDITY_SIGNALS),
    StatusMain: ("faults", _FAULT_SIGNALS),
}


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    loaded = cantools.database.load_file(str(DBC))
    assert isinstance(loaded, cantools.database.can.Database)
    return loaded


def _bits(value: int, table: Mapping[str, int]) -> dict[str, int]:
    return {name: int(bool(value & mask)) for name, mask in table.items()}


def expected_signals(part) -> dict[str, int]:
    """Raw signal values the DBC must give for one decoded CAN frame."""
    if isinstance(part, Command):
        sig = {"Seq": part.seq, "Opcode": part.OPCODE}
        if isinstance(part, RotateTo):
            sig |= {"RotateToAngle": part.angle, "RotateToDirection": part.direction}
        elif isinstance(part, RotateBy):
            sig["RotateByAngle"] = part.delta
        elif isinstance(part, Spin):
            sig["SpinRate"] = part.rate
        elif isinstance(part, GetConfig):
            sig["GetConfigKey"] = part.key
        elif isinstance(part, SetConfig):
            sig |= {"SetConfigKey": part.key, "SetConfigValue": part.value}
        return sig
    if isinstance(part, Reply):
        sig = {"Seq": part.seq, "Opcode": part.opcode, "Result": part.result}
        if part.ok and part.opcode in (Opcode.GET_CONFIG, Opcode.SET_CONFIG):
            key, value = part.config_value()
            prefix = "GetConfig" if part.opcode == Opcode.GET_CONFIG else "SetConfig"
            sig |= {f"{prefix}ReplyKey": key, f"{prefix}ReplyValue": value}
        elif part.ok and part.opcode == Opcode.SELF_TEST:
            sig["SelfTestFailures"] = part.self_test_failures()
        return sig
    if isinstance(part, SampleAxis):
        axis = part.axis.name
        return {"Tick": part.tick, f"Gyro{axis}": part.gyro, f"Accel{axis}": part.accel}
    if isinstance(part, SampleAux | StatusMain | StatusCounters):
        sig = {name: getattr(part, field) for name, field in _FIELD_SIGNALS[type(part)].items()}
        if type(part) in _FLAG_SIGNALS:
            field, table = _FLAG_SIGNALS[type(part)]
            sig |= _bits(getattr(part, field), table)
        return sig
    if isinstance(part, IdentifyPage):
        return {"IdentPage": part.index, "IdentLastPage": part.last}
    raise AssertionError(part)


def identify_signals(ident: Identify) -> dict[str, int]:
    """Raw signals of all identify pages together."""
    sig = dict(
        zip(
            ["ProtocolMajor", "ProtocolMinor", "FirmwareMajor", "FirmwareMinor", "FirmwarePatch"],
            [*ident.protocol_version, *ident.firmware_version],
            strict=True,
        )
    )
    sig |= {
        "MaxSampleRate": ident.max_sample_rate_hz,
        "SerialNumber": ident.serial_number,
        "HardwareRevision": ident.hardware_revision,
    }
    model = ident.model.encode("ascii").ljust(7, b"\0")
    sig |= {f"ModelChar{i}": b for i, b in enumerate(model)}
    for name in ("Gyro", "Accel", "Angle", "Temperature"):
        scale = getattr(ident, f"{name.lower()}_scale")
        sig |= {f"{name}ScaleMantissa": scale.mantissa, f"{name}ScaleExponent": scale.exponent}
    return sig


def check_against_dbc(db, message) -> None:
    if isinstance(message, Reply) and message.opcode not in set(Opcode):
        # The DBC multiplexes on the defined opcodes; a reply echoing an undefined one
        # (UNKNOWN_COMMAND) is outside its table, and cantools says so.
        (frame,) = encode_can(message)
        with pytest.raises(cantools.database.DecodeError):
            db.decode_message(frame.arbitration_id, frame.data, allow_truncated=True)
        return
    identify_seen: dict[str, int] = {}
    for frame in encode_can(message, node_id=1):
        part = decode_can(*frame).message
        raw = db.decode_message(
            frame.arbitration_id,
            frame.data,
            decode_choices=False,
            scaling=False,
            allow_truncated=True,
        )
        expected = expected_signals(part)
        if isinstance(part, IdentifyPage):
            identify_seen |= {k: v for k, v in raw.items() if k not in expected}
            raw = {k: v for k, v in raw.items() if k in expected}
        assert raw == expected, type(part).__name__
    if isinstance(message, Identify):
        assert identify_seen == identify_signals(message)


def test_dbc_loads_with_every_function(db):
    ids = {m.frame_id: m for m in db.messages}
    assert sorted(ids) == sorted(f + 1 for f in CanFunction)
    for function in CanFunction:
        assert ids[function + 1].name == function.name
    for name in ("SAMPLE_X", "SAMPLE_Y", "SAMPLE_Z", "SAMPLE_AUX"):
        assert db.get_message_by_name(name).cycle_time == 5
    for name in ("STATUS", "STATUS_COUNTERS"):
        assert db.get_message_by_name(name).cycle_time == 100


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_vectors_decode_with_cantools(db, name):
    check_against_dbc(db, GOLDEN[name])


@settings(max_examples=150, deadline=None)
@given(messages)
def test_random_messages_decode_with_cantools(db, message):
    check_against_dbc(db, message)


def test_scaled_units(db):
    sample = GOLDEN["sample"]
    x, _, _, aux = encode_can(sample)
    phys = db.decode_message(x.arbitration_id, x.data)
    assert phys["GyroX"] == pytest.approx(12.3456)
    assert phys["AccelX"] == pytest.approx(0.001234)
    phys = db.decode_message(aux.arbitration_id, aux.data)
    assert phys["TableAngle"] == pytest.approx(123.456789)
    assert phys["Temperature"] == pytest.approx(25.12)
    assert db.get_message_by_name("SAMPLE_X").get_signal_by_name("GyroX").unit == "deg/h"
    assert db.get_message_by_name("SAMPLE_X").get_signal_by_name("AccelX").unit == "g"
    status = db.decode_message(*encode_can(GOLDEN["status"])[0])
    assert str(status["State"]) == "READY"
