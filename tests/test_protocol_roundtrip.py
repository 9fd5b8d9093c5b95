"""Hypothesis round trips of every message: payload, serial frame and CAN frames."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from northfinder.driver.protocol import (
    Command,
    ConfigKey,
    DeviceState,
    Direction,
    Fault,
    Identify,
    Opcode,
    Reply,
    Result,
    Sample,
    SampleAux,
    SampleAxis,
    Scale,
    Status,
    Validity,
)
from northfinder.driver.protocol.can import (
    CanReceiver,
    TickAssembler,
    decode_can,
    encode_can,
    split_can_id,
)
from northfinder.driver.protocol.constants import CanFunction
from northfinder.driver.protocol.errors import EncodeError
from northfinder.driver.protocol.serial import Deframer, SerialEncoder, decode_frame, parse_frame

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFF_FFFF)
i16 = st.integers(-(1 << 15), (1 << 15) - 1)
i24 = st.integers(-(1 << 23), (1 << 23) - 1)
i32 = st.integers(-(1 << 31), (1 << 31) - 1)
keys = st.one_of(st.sampled_from(ConfigKey), u8)

#: Every command class, one per opcode (as decoding names it).
COMMAND_TYPES = sorted(
    {type(Command.decode(c(0).encode())) for c in Command.__subclasses__()},
    key=lambda c: c.OPCODE,
)
#: Each argument's values: by its name where it has a type of its own, else by its struct code.
_BY_NAME = {"direction": st.sampled_from(Direction), "key": keys}
_BY_CODE = {"B": u8, "I": u32, "i": i32}
commands = st.one_of(
    *(
        st.builds(c, u8, *(_BY_NAME.get(name, _BY_CODE[code]) for name, code in c._FIELDS))
        for c in COMMAND_TYPES
    )
)

_unknown_opcode = u8.filter(lambda v: v not in set(Opcode))
_no_data_opcodes = [op for op in Opcode if op not in (Opcode.GET_CONFIG, Opcode.SET_CONFIG)]
_no_data_opcodes.remove(Opcode.SELF_TEST)
replies = st.one_of(
    st.builds(Reply.config, u8, st.sampled_from([Opcode.GET_CONFIG, Opcode.SET_CONFIG]), keys, u32),
    st.builds(Reply.self_test, u8, u16),
    st.builds(Reply, u8, st.sampled_from(_no_data_opcodes), st.just(Result.OK)),
    st.builds(Reply, u8, st.sampled_from(Opcode), st.sampled_from(list(Result)[1:])),
    st.builds(Reply, u8, _unknown_opcode, u8, st.binary(max_size=5)),
)


def samples(accel: st.SearchStrategy[int] = i24) -> st.SearchStrategy[Sample]:
    """Samples; the default accelerometer range is the CAN one (i24)."""
    return st.builds(
        Sample,
        counter=u32,
        gyro=st.tuples(i32, i32, i32),
        accel=st.tuples(accel, accel, accel),
        angle=u32,
        temperature=i16,
        validity=st.builds(Validity, u8),
    )


statuses = st.builds(
    Status,
    state=st.sampled_from(DeviceState),
    angle=u32,
    temperature=i16,
    faults=st.builds(Fault, u8),
    sample_counter=u32,
    rx_malformed=u16,
    tx_dropped=u8,
    cmd_rejected=u8,
)
scales = st.builds(Scale, u32, st.integers(-128, 127))
identifies = st.builds(
    Identify,
    model=st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=7),
    serial_number=u32,
    hardware_revision=u8,
    firmware_version=st.tuples(u8, u8, u8),
    protocol_version=st.tuples(u8, u8),
    max_sample_rate_hz=u16,
    gyro_scale=scales,
    accel_scale=scales,
    angle_scale=scales,
    temperature_scale=scales,
)
messages = st.one_of(commands, replies, samples(), statuses, identifies)
"""Every message kind, with fields that fit both links."""

EXAMPLES = settings(max_examples=150, deadline=None)


def test_every_opcode_has_its_command():
    assert [c.OPCODE for c in COMMAND_TYPES] == sorted(Opcode)


@EXAMPLES
@given(messages)
def test_payload_round_trip(message):
    decoder = Command.decode if isinstance(message, Command) else type(message).decode
    assert decoder(message.encode()) == message


@EXAMPLES
@given(st.one_of(messages, samples(i32)), u8)
def test_serial_frame_round_trip(message, seq):
    frame = parse_frame(SerialEncoder(seq).encode(message))
    assert frame.seq == seq
    assert decode_frame(frame) == message


@EXAMPLES
@given(st.lists(st.one_of(messages, samples(i32)), max_size=8), st.data())
def test_serial_stream_in_any_chunking(batch, data):
    encoder = SerialEncoder(data.draw(u8))
    stream = b"".join(encoder.encode(m) for m in batch)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    deframer = Deframer()
    out = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += deframer.feed_messages(stream[a:b])
    assert out == batch
    assert deframer.lost_frames == deframer.crc_errors == deframer.discarded_bytes == 0
    assert deframer.buffered == 0


@EXAMPLES
@given(messages, st.integers(1, 15))
def test_can_round_trip(message, node_id):
    receiver = CanReceiver(node_id=node_id)
    if isinstance(message, Sample):
        receiver.ticks.sync(message.counter)
    out = []
    for frame in encode_can(message, node_id):
        assert frame.arbitration_id <= 0x7FF and len(frame.data) <= 8
        out += receiver.feed(*frame)
    assert out == [message]
    assert receiver.malformed == receiver.unknown_id == receiver.other_node == 0


@EXAMPLES
@given(st.lists(samples(), min_size=1, max_size=6), u32)
def test_can_consecutive_ticks_keep_full_counter(batch, start):
    receiver = CanReceiver()
    receiver.ticks.sync(start)
    expected = []
    out = []
    for k, s in enumerate(batch):
        s = Sample(
            (start + 1 + k) & 0xFFFF_FFFF, s.gyro, s.accel, s.angle, s.temperature, s.validity
        )
        expected.append(s)
        for frame in encode_can(s):
            out += receiver.feed(*frame)
    assert out == expected
    assert receiver.ticks.lost == receiver.ticks.incomplete == 0


@EXAMPLES
@given(samples(), st.integers(1, 15))
def test_a_samples_can_payloads_are_its_frames_encoded(sample, node_id):
    """The stream's fast encoder packs exactly what the four frame messages encode to."""
    frames = encode_can(sample, node_id)
    assert [f.data for f in frames] == [part.encode() for part in sample.split()]
    assert sample.can_payloads() == tuple(part.encode() for part in sample.split())
    fast = Sample.fast(*(getattr(sample, f.name) for f in dataclasses.fields(Sample)))
    assert fast == sample and hash(fast) == hash(sample) and repr(fast) == repr(sample)
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.counter = 1  # type: ignore[misc]
    functions = [CanFunction.SAMPLE_X, CanFunction.SAMPLE_Y, CanFunction.SAMPLE_Z,
                 CanFunction.SAMPLE_AUX]  # fmt: skip
    assert [split_can_id(f.arbitration_id) for f in frames] == [(f, node_id) for f in functions]


@pytest.mark.parametrize(
    "field, value",
    [("gyro", (1 << 31, 0, 0)), ("accel", (0, 1 << 23, 0)), ("accel", (0, 0, 0.5)),
     ("angle", -1), ("temperature", 40_000), ("validity", 256), ("gyro", (1, 2))],
)  # fmt: skip
def test_a_sample_that_does_not_fit_a_frame_is_refused_by_name(field, value):
    sample = dataclasses.replace(
        Sample(5, (1, 2, 3), (4, 5, 6), 7, 8, Validity(3)), **{field: value}
    )
    with pytest.raises(EncodeError):
        encode_can(sample)


@EXAMPLES
@given(st.lists(samples(), min_size=1, max_size=8), st.data())
def test_the_receivers_sample_frames_give_what_their_messages_give(batch, data):
    """CanReceiver takes sample frames straight into the tick; the same frames decoded into
    messages and given to a tick assembler one by one give the same samples and losses,
    whatever is dropped, repeated or sent out of turn."""
    frames = []
    for k, s in enumerate(batch):
        frames += encode_can(dataclasses.replace(s, counter=k + 1))
    n = len(frames)
    picks = data.draw(st.lists(st.integers(0, n - 1), max_size=2 * n))
    order = data.draw(st.permutations(range(n))) if data.draw(st.booleans()) else range(n)
    sent = [frames[i] for i in order if i not in picks[: len(picks) // 2]] + [
        frames[i] for i in picks[len(picks) // 2 :]
    ]
    receiver = CanReceiver(node_id=1)
    receiver.ticks.sync(0)
    reference = TickAssembler()
    reference.sync(0)
    got, want = [], []
    for frame in sent:
        got += receiver.feed(*frame)
        part = decode_can(*frame).message
        assert isinstance(part, SampleAxis | SampleAux)
        want += reference.add(part)
    assert got == want
    assert receiver.ticks.flush() == reference.flush()
    for name in ("complete", "incomplete", "lost", "duplicates"):
        assert getattr(receiver.ticks, name) == getattr(reference, name)
