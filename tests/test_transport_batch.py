"""frame_batch on python-can's virtual bus: in order, at most n, a closed bus refused, through
python-can's public API."""

from __future__ import annotations

import ast
import dataclasses
import inspect

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from northfinder.driver import transport
from northfinder.driver.protocol import Sample, Validity
from northfinder.driver.protocol.can import CanReceiver, encode_can
from northfinder.driver.transport import CanTransport, frame_batch


def test_a_virtual_batch_takes_the_waiting_frames_in_order_and_at_most_n():
    with (
        can.Bus(interface="virtual", channel="batch-order") as tx,
        can.Bus(interface="virtual", channel="batch-order") as rx,
    ):
        take = frame_batch(rx)
        assert take(5) == []
        for i in range(7):
            tx.send(can.Message(arbitration_id=i, is_extended_id=False))
        assert [m.arbitration_id for m in take(5)] == [0, 1, 2, 3, 4]
        assert [m.arbitration_id for m in take(5)] == [5, 6]
        assert take(5) == []


def test_a_closed_virtual_bus_is_refused_as_python_can_refuses_it():
    tx = can.Bus(interface="virtual", channel="batch-closed")
    rx = can.Bus(interface="virtual", channel="batch-closed")
    take = frame_batch(rx)
    tx.send(can.Message(arbitration_id=1))
    rx.shutdown()
    with pytest.raises(can.CanOperationError):
        take(4)
    tx.shutdown()


def test_the_transport_reads_no_private_attribute_of_python_can_but_the_noted_one():
    """Only ``_buffer`` of the slcan bus, under a dated note naming the python-can issue."""
    tree = ast.parse(inspect.getsource(transport))
    private = {
        node.attr
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr.startswith("_")
        and not node.attr.endswith("__")  # a dunder (``__name__``, ``super().__init__``)
        and not (isinstance(node.value, ast.Name) and node.value.id in {"self", "cls"})
    }
    strings = {
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str)
    }
    assert not private, private
    assert "_buffer" in strings and "python-can#2028" in inspect.getsource(transport)
    assert "mutex" not in inspect.getsource(transport)


_SAMPLES = st.builds(
    Sample,
    counter=st.integers(0, 0xFFFF_FFFF),
    gyro=st.tuples(*[st.integers(-(1 << 31), (1 << 31) - 1)] * 3),
    accel=st.tuples(*[st.integers(-(1 << 23), (1 << 23) - 1)] * 3),
    angle=st.integers(0, 0xFFFF_FFFF),
    temperature=st.integers(-(1 << 15), (1 << 15) - 1),
    validity=st.builds(Validity, st.integers(0, 0xFF)),
)


def _other(frame: can.Message, kind: int) -> can.Message:
    """A frame like ``frame`` that is not one of the unit's sample frames as sent."""
    data = bytes(frame.data)
    if kind == 0:  # another node's
        return can.Message(arbitration_id=frame.arbitration_id + 1, data=data, is_extended_id=False)
    if kind == 1:  # an extended id of the same value
        return can.Message(arbitration_id=frame.arbitration_id, data=data, is_extended_id=True)
    if kind == 2:  # a wrong length
        return can.Message(arbitration_id=frame.arbitration_id, data=data[:7], is_extended_id=False)
    return can.Message(arbitration_id=frame.arbitration_id, is_remote_frame=True, dlc=8,
                       is_extended_id=False)  # fmt: skip


@settings(max_examples=150, deadline=None)
@given(st.lists(_SAMPLES, min_size=1, max_size=8), st.data())
def test_the_transport_decodes_a_stream_as_the_receiver_does_frame_by_frame(batch, data):
    """Whole ticks in sending order are taken four frames at once; whatever is dropped,
    repeated, sent out of turn, mixed with the next tick's or not the unit's sample frame, the samples, losses and counters
    are those of a receiver fed one frame at a time."""
    frames = [
        can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False)
        for k, s in enumerate(batch)
        for f in encode_can(
            dataclasses.replace(s, counter=(k * data.draw(st.integers(1, 3)) + 1)), 2
        )
    ]
    n = len(frames)
    edits = data.draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, 6)), max_size=n))
    sent = list(frames)
    for i, kind in sorted(edits, reverse=True):
        if kind < 4:
            sent.insert(i, _other(frames[i], kind))
        elif kind == 4:
            sent.insert(i, frames[i])  # a repeat
        elif kind == 5 and i + 4 < len(sent):  # the same frame of the next tick in its place
            sent[i], sent[i + 4] = sent[i + 4], sent[i]
        elif i < len(sent):
            del sent[i]
    if data.draw(st.booleans()):
        order = data.draw(st.permutations(range(len(sent))))
        sent = [sent[i] for i in order]
    reference = CanReceiver(node_id=2)
    reference.ticks.sync(0)
    want = []
    for msg in sent:
        if not msg.is_remote_frame:
            want += reference.feed(msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id)
    with (
        can.Bus(interface="virtual", channel="batch-decode") as tx,
        can.Bus(interface="virtual", channel="batch-decode") as rx,
    ):
        link = CanTransport(rx, node_id=2)
        link.receiver.ticks.sync(0)
        for msg in sent:
            tx.send(msg)
        got = []
        while items := link.recv(0.0):
            got += items
    assert got == want
    assert link.receiver.ticks.flush() == reference.ticks.flush()
    for name in ("frames", "unknown_id", "malformed", "other_node"):
        assert getattr(link.receiver, name) == getattr(reference, name), name
    for name in ("complete", "incomplete", "lost", "duplicates"):
        assert getattr(link.receiver.ticks, name) == getattr(reference.ticks, name), name
