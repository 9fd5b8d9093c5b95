"""frame_batch on python-can's virtual bus: in order, at most n, a closed bus refused, through
python-can's public API."""

from __future__ import annotations

import ast
import inspect

import can
import pytest

from northfinder.driver import transport
from northfinder.driver.transport import frame_batch


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
