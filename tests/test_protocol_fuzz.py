"""Bad input: random bytes and CAN frames give typed protocol errors or are counted, never more."""

from __future__ import annotations

import random
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_protocol_golden import GOLDEN, SERIAL_SEQ
from test_protocol_roundtrip import messages, samples

from northfinder.driver.errors import ProtocolError
from northfinder.driver.protocol import (
    Command,
    Identify,
    IdentifyPage,
    Reply,
    Sample,
    SampleAux,
    SampleX,
    Status,
    StatusCounters,
    StatusMain,
)
from northfinder.driver.protocol.can import CanDecoded, CanReceiver, decode_can, encode_can
from northfinder.driver.protocol.constants import Validity
from northfinder.driver.protocol.serial import (
    MAX_FRAME_SIZE,
    Deframer,
    SerialEncoder,
    SerialFrame,
    decode_payload,
    parse_frame,
)

FUZZ = settings(max_examples=200, deadline=None)
PAYLOAD_TYPES: list[Any] = [
    Command,
    Reply,
    Sample,
    SampleX,
    SampleAux,
    Status,
    StatusMain,
    StatusCounters,
    Identify,
    IdentifyPage,
]


@FUZZ
@given(st.binary(max_size=80))
def test_payload_decoders_raise_only_protocol_errors(data):
    for cls in PAYLOAD_TYPES:
        try:
            cls.decode(data)
        except ProtocolError:
            pass
    for msg_type in range(8):
        try:
            decode_payload(msg_type, data)
        except ProtocolError:
            pass
    try:
        parse_frame(data)
    except ProtocolError:
        pass


@FUZZ
@given(st.integers(-5, 0x900), st.binary(max_size=12), st.booleans())
def test_can_decoder_on_random_frames(arbitration_id, data, extended):
    try:
        decoded = decode_can(arbitration_id, data, is_extended_id=extended)
    except ProtocolError:
        pass
    else:
        assert isinstance(decoded, CanDecoded)
        assert len(data) <= 8 and arbitration_id <= 0x7FF and not extended
    receiver = CanReceiver()
    receiver.feed(arbitration_id, data, is_extended_id=extended)
    assert receiver.frames == 1


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=60))
def test_can_receiver_survives_random_traffic(frames):
    receiver = CanReceiver()
    for arbitration_id, data in frames:
        for item in receiver.feed(arbitration_id, data):
            assert not isinstance(item, Exception)
    receiver.ticks.flush()


@FUZZ
@given(st.lists(st.binary(max_size=100), max_size=20))
def test_deframer_on_random_chunks(chunks):
    deframer = Deframer()
    for chunk in chunks:
        for frame in deframer.feed_messages(chunk):
            assert frame is not None
        assert deframer.buffered < MAX_FRAME_SIZE


@FUZZ
@given(st.lists(st.tuples(st.binary(max_size=40), messages), max_size=6), st.data())
def test_deframer_resynchronises_after_garbage(pairs, data):
    encoder = SerialEncoder()
    stream = b""
    sent = []
    for garbage, message in pairs:
        stream += garbage + encoder.encode(message)
        sent.append(message)
    stream += b"\xa5"  # a dangling half sync at the end must not hide anything
    deframer = Deframer()
    got = []
    step = data.draw(st.integers(1, 50))
    for i in range(0, len(stream), step):
        got += deframer.feed_messages(stream[i : i + step])
    # Garbage can forge a frame only with a matching CRC; it cannot hide a real one.
    it = iter(got)
    assert all(any(m == g for g in it) for m in sent)


def test_corrupted_frames_are_counted_and_the_rest_recovered():
    rng = random.Random(1)
    encoder = SerialEncoder()
    good = [GOLDEN[name] for name in sorted(GOLDEN)] * 4
    frames = [encoder.encode(m) for m in good]
    corrupted = set(rng.sample(range(len(frames)), 10))
    stream = bytearray()
    for k, frame in enumerate(frames):
        mutable = bytearray(frame)
        if k in corrupted:
            mutable[rng.randrange(5, len(mutable))] ^= 1 << rng.randrange(8)
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 8))) + mutable
    deframer = Deframer()
    got = []
    for i in range(0, len(stream), 13):
        got += deframer.feed_messages(stream[i : i + 13])
    expected = [m for k, m in enumerate(good) if k not in corrupted]
    assert got == expected
    assert deframer.crc_errors >= len(corrupted)
    assert deframer.lost_frames == len(corrupted)


def test_large_random_input_does_not_hang():
    rng = random.Random(2)
    blob = bytes(rng.randrange(256) for _ in range(200_000))
    worst = b"\xa5\x5a\x40" * 20_000  # false syncs announcing the longest payload
    deframer = Deframer()
    deframer.feed(blob)
    deframer.feed(worst)
    assert deframer.buffered < MAX_FRAME_SIZE
    assert deframer.frames == 0 or deframer.crc_errors > 0


def test_sequence_gap_counts_lost_frames():
    encoder = SerialEncoder(250)
    frames = [encoder.encode(GOLDEN["cmd_stop"]) for _ in range(10)]
    deframer = Deframer()
    deframer.feed(b"".join(frames[:3] + frames[6:]))
    assert deframer.lost_frames == 3 and deframer.frames == 7


def test_oversized_length_is_a_false_sync():
    frame = SerialFrame(5, SERIAL_SEQ, bytes(64)).encode()
    deframer = Deframer()
    assert deframer.feed(b"\xa5\x5a\x41\x00" + frame) == [SerialFrame(5, SERIAL_SEQ, bytes(64))]
    assert deframer.length_errors == 1
    with pytest.raises(ProtocolError):
        SerialFrame(5, 0, bytes(65)).encode()


@FUZZ
@given(st.lists(samples(), min_size=3, max_size=12), st.data())
def test_tick_assembler_reports_every_missing_frame(batch, data):
    receiver = CanReceiver()
    receiver.ticks.sync(0)
    frames = []
    for k, s in enumerate(batch, start=1):
        s = Sample(k, s.gyro, s.accel, s.angle, s.temperature, s.validity)
        frames += encode_can(s)
    dropped = set(data.draw(st.sets(st.integers(0, len(frames) - 1), max_size=len(frames) - 1)))
    kept = [f for i, f in enumerate(frames) if i not in dropped]
    out = []
    for f in kept:
        out += receiver.feed(*f)
    out += receiver.ticks.flush()
    ticks = receiver.ticks
    full_ticks = {i // 4 for i in range(len(frames))} - {i // 4 for i in dropped}
    assert ticks.complete == len(full_ticks)
    samples_out = [o for o in out if isinstance(o, Sample)]
    assert [s.counter for s in samples_out] == [t + 1 for t in sorted(full_ticks)]
    # Every tick is accounted for, except wholly missing ticks after the last frame seen.
    last_seen = max(i // 4 for i in range(len(frames)) if i not in dropped)
    assert ticks.complete + ticks.incomplete + ticks.lost == last_seen + 1 - min(
        i // 4 for i in range(len(frames)) if i not in dropped
    )


def _frame_with_crc_high_a5(seq: int) -> bytes:
    for counter in range(100_000):
        frame = SerialEncoder(seq).encode(Sample(counter, (1, 2, 3), (4, 5, 6), 7, 8, Validity(3)))
        if frame[-1] == 0xA5:
            return frame
    raise AssertionError("no frame with a CRC high byte of 0xA5")


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 1000])
def test_a_frame_that_lost_its_last_byte_a5_does_not_take_the_next_frame_with_it(chunk):
    """The lost byte 0xA5 is completed by the next frame's first sync byte (a valid CRC): the
    next frame must still be found, beginning inside the frame just delivered."""
    first = SerialEncoder(0).encode(Sample(9, (1, 1, 1), (1, 1, 1), 1, 1, Validity(3)))
    hit = _frame_with_crc_high_a5(1)
    after = [
        SerialEncoder(2 + k).encode(Sample(100 + k, (0, 0, 0), (0, 0, 0), 0, 0, Validity(3)))
        for k in range(2)
    ]
    stream = first + hit[:-1] + b"".join(after)
    deframer = Deframer()
    got = []
    for i in range(0, len(stream), chunk):
        got += deframer.feed(stream[i : i + chunk])
    assert [f.payload for f in got] == [first[5:-2], hit[5:-2], after[0][5:-2], after[1][5:-2]]
    assert deframer.lost_frames == 0 and deframer.crc_errors == 0 and deframer.length_errors == 0
    assert deframer.buffered == 0


def test_a_clean_stream_of_frames_ending_in_a5_counts_nothing():
    frames = [_frame_with_crc_high_a5(k) for k in range(3)]
    deframer = Deframer()
    got = [f for b in b"".join(frames) for f in deframer.feed(bytes([b]))]
    assert len(got) == 3 and deframer.discarded_bytes == deframer.crc_errors == 0
    assert deframer.length_errors == 0 and deframer.buffered == 0
