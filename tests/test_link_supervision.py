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


class SteppedClock(HandClock):
    """:class:`HandClock` whose waits end when the test moves its time past their deadline."""

    def wait_until(self, predicate, deadline):
        # No timed re-check: a waiter that is not notified of a change hangs (the test's own
        # 30 s limits then fail it), so a lost wake-up cannot pass.
        with self._lock:
            while not predicate():
                if deadline is not None and self.t >= deadline:
                    return False
                self._cv.wait()
            return True

    def set(self, t: float) -> None:
        self.t = t
        self.notify()


@pytest.fixture
def stepped() -> Iterator[tuple[DeviceLink, ScriptedTransport, SteppedClock]]:
    """A link whose reader began a read at 0.0 that the host does not finish yet."""
    clock = SteppedClock()
    transport = ScriptedTransport()
    transport.sent = []  # type: ignore[attr-defined]
    transport.send = transport.sent.append  # type: ignore[attr-defined,method-assign]
    link = DeviceLink(transport, clock=clock)
    transport.next_read(1)
    transport.items.put([STATUS])
    transport.next_read(2)
    yield link, transport, clock
    link._stop.set()
    transport.items.put(None)
    link.close()


def _asked(link: DeviceLink, transport: ScriptedTransport, clock: SteppedClock):
    """GET_STATUS sent at 0.0 in a thread, the host then standing still until 0.8 (the reply
    limit is 0.25 s): returns the thread's result holder once the request waits for the reader."""
    from northfinder.driver.protocol.messages import GetStatus

    out: dict[str, object] = {}

    def ask() -> None:
        try:
            out["reply"] = link._request(GetStatus, attempts=1)
        except Exception as exc:
            out["error"] = exc

    thread = threading.Thread(target=ask, daemon=True)
    thread.start()
    for _ in range(3000):
        if transport.sent:  # type: ignore[attr-defined]
            break
        threading.Event().wait(0.01)
    clock.set(0.8)
    for _ in range(3000):
        if link._catching_up:
            break
        threading.Event().wait(0.01)
    assert link._catching_up == 1, "the request did not wait for the reader after its deadline"
    out["thread"] = thread
    return out


def test_a_reply_that_waited_in_the_link_while_the_host_stood_still_is_taken(stepped):
    from northfinder.driver.protocol.messages import Reply

    link, transport, clock = stepped
    out = _asked(link, transport, clock)
    command = transport.sent[0]
    transport.items.put([Reply.to(command)])  # the read begun at 0.0 finds the reply at last
    out["thread"].join(30.0)
    assert "error" not in out, out.get("error")
    assert out["reply"].seq == command.seq


def test_a_reply_that_never_came_times_out_once_a_later_read_finds_nothing(stepped):
    from northfinder.driver.errors import ReplyTimeout

    link, transport, clock = stepped
    out = _asked(link, transport, clock)
    transport.items.put(None)  # the read begun at 0.0, before the deadline, ends with nothing
    transport.next_read(3)
    assert out["thread"].is_alive()
    transport.items.put(None)  # the read begun at 0.8 ends with nothing too
    out["thread"].join(30.0)
    assert isinstance(out.get("error"), ReplyTimeout), out
    assert "no reply to GET_STATUS within 0.25 s" in str(out["error"])


def _sample(counter: int):
    from northfinder.driver.protocol.constants import Validity
    from northfinder.driver.protocol.messages import Sample

    return Sample(counter, (0, 0, 0), (0, 0, 0), 0, 2500, Validity(0))


def test_a_stream_counts_as_stopped_only_once_a_later_read_brings_no_sample(stalled):
    link, transport, clock = stalled
    clock.t = 0.8  # the stall deadline was 0.5; the host did not run the reader since 0.0
    assert not link._no_sample_since(0.5)
    transport.items.put(None)  # the read begun at 0.0 ends with nothing
    transport.next_read(4)
    assert not link._no_sample_since(0.5)
    transport.items.put([_sample(1), STATUS])  # the read begun at 0.8 finds samples waiting
    transport.next_read(5)
    assert not link._no_sample_since(0.5)
    transport.items.put(5)  # part of a frame: perhaps a sample
    transport.next_read(6)
    assert not link._no_sample_since(0.5)
    transport.items.put([STATUS])  # statuses only, as at a short heartbeat: the stream stopped
    transport.next_read(7)
    assert link._no_sample_since(0.5)


def test_reads_that_each_bring_part_of_a_frame_decide_a_stall_a_second_later(stalled):
    link, transport, clock = stalled
    clock.t = 1.0
    transport.items.put(None)
    transport.next_read(4)  # begun at 1.0
    transport.items.put(3)
    transport.next_read(5)
    assert not link._no_sample_since(0.5)
    clock.t = 1.5  # a busy bus: every read hears frames of other nodes
    transport.items.put(3)
    transport.next_read(6)
    transport.items.put(3)  # the read begun at 1.5 (CATCH_UP_S after the deadline) is done
    transport.next_read(7)
    assert link._no_sample_since(0.5)
