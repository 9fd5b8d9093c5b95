"""Link supervision judges the unit's silence, not the host's own stall (protocol.md 6): a host
that did not run its reader for longer than the supervision time (three heartbeat periods, 0.3 s
by default) reads what waited in the link before it concludes anything, and the link is lost only
once a read that began after the deadline found nothing.

In lockstep: the driver's reader thread runs against a scripted transport (each read returns what
the test hands it, when the test hands it) and a clock the test sets; nothing waits on time."""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator

import pytest

from northfinder.driver.clock import WallClock
from northfinder.driver.device_link import DeviceLink
from northfinder.driver.errors import LinkLost
from northfinder.driver.protocol.constants import DeviceState, Fault
from northfinder.driver.protocol.messages import Status

STATUS = Status(DeviceState.READY, 0, 2500, Fault(0), 0, 0, 0, 0)


class HandClock(WallClock):
    """The wall clock's waits, at an instant the test sets."""

    def __init__(self) -> None:
        super().__init__()
        self.t = 0.0

    def now(self) -> float:  # type: ignore[override]
        return self.t

    def wall(self) -> float:  # type: ignore[override]
        return self.t


class ScriptedTransport:
    """Each read takes the next item the test puts (a list of messages, or a number of bytes that
    complete nothing); :meth:`next_read` waits until the reader has begun its next read."""

    kind = "serial"

    def __init__(self) -> None:
        self.items: queue.Queue[list | int | None] = queue.Queue()
        self.reads = 0
        self._began = threading.Condition()
        self.bytes = 0

    def recv(self, timeout: float) -> list:
        with self._began:
            self.reads += 1
            self._began.notify_all()
        item = self.items.get(timeout=30.0)
        if item is None:
            return []
        if isinstance(item, int):
            self.bytes += item
            return []
        return item

    def next_read(self, n: int) -> None:
        """Wait (at most 30 s of real time) until the reader began read number ``n``."""
        with self._began:
            assert self._began.wait_for(lambda: self.reads >= n, 30.0)

    def send(self, command: object) -> None:
        pass

    def restart_stream(self) -> list:
        return []

    def counters(self) -> dict[str, int]:
        return {"frames_received": 0, "bytes_received": self.bytes}

    def close(self) -> None:
        self.items.put(None)


@pytest.fixture
def stalled() -> Iterator[tuple[DeviceLink, ScriptedTransport, HandClock]]:
    clock = HandClock()
    transport = ScriptedTransport()
    link = DeviceLink(transport, clock=clock)
    transport.next_read(1)
    transport.items.put([STATUS])  # a status at 0.0: the link counts as lost after 0.3 s
    transport.next_read(2)
    transport.items.put(None)  # nothing more came: the reader read all that arrived
    transport.next_read(3)  # and began another read at 0.0, which the host does not finish yet
    yield link, transport, clock
    link._stop.set()
    transport.items.put(None)
    link.close()


def test_a_host_that_stood_still_reads_the_waiting_status_before_judging(stalled):
    link, transport, clock = stalled
    clock.t = 0.8  # the host did not run the reader for 0.8 s: the unit's status waits in the link
    assert link._link_alive()
    transport.items.put([STATUS])  # the reader runs again and reads it
    transport.next_read(4)
    assert link._link_alive() and link.last_status is not None
    assert link.last_status.received_at == 0.8


def test_a_unit_silent_past_the_deadline_is_lost_once_a_later_read_finds_nothing(stalled):
    link, transport, clock = stalled
    clock.t = 0.8
    assert link._link_alive()  # not judged on the read that began before the deadline
    transport.items.put(None)  # that read ends with nothing
    transport.next_read(4)  # the next begins at 0.8, after the deadline (0.3)
    assert link._link_alive()
    transport.items.put(None)  # and finds nothing: the unit is silent
    transport.next_read(5)
    assert not link._link_alive()
    with pytest.raises(LinkLost, match=r"no status from the device for 0.80 s \(limit 0.30 s"):
        link._wait_for(lambda: None, clock.t + 1.0, lambda: LinkLost("deadline"))


def test_bytes_that_complete_no_message_yet_keep_the_link_up(stalled):
    link, transport, clock = stalled
    clock.t = 0.8
    transport.items.put(None)
    transport.next_read(4)
    transport.items.put(7)  # part of a frame: the unit is sending
    transport.next_read(5)
    assert link._link_alive()
    transport.items.put(None)  # then nothing at all, on a read begun after the deadline
    transport.next_read(6)
    assert not link._link_alive()
