"""The suite's conversation with a unit: requests and replies, and a record of everything it sent.

:class:`Session` sends commands on a raw link, matches replies by seq and opcode, and keeps what the
unit sends in time order: statuses (and the state changes they show), identify messages, samples
with their full counters, and every irregularity seen on the way (a counter gap, an incomplete CAN
tick, a serial frame lost, an undecodable frame, a reply nobody asked for). Checks read these
records; the session itself judges nothing.

Times: ``t`` values are seconds of the session's clock: host monotonic seconds (the wall clock) by
default. The unit may run faster than wall time (an accelerated simulator); ``time_scale`` is the
unit's seconds per wall second, and :meth:`Session.unit` / :meth:`Session.wall` convert durations.
On a :class:`~northfinder.driver.clock.VirtualClock` shared with an in-process simulator the clock
polls the link at every instant and stamps each arrival with the instant it was sent; the unit's
time is the clock's (``time_scale`` 1).
"""

from __future__ import annotations

import bisect
import dataclasses
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from northfinder.driver.clock import Clock, WallClock
from northfinder.driver.conformance.errors import LinkFault, NoReply
from northfinder.driver.conformance.pace import HostPace
from northfinder.driver.conformance.wire import Arrival, RawLink, TickParts
from northfinder.driver.protocol.constants import (
    SAMPLE_RATE_DEFAULT_HZ,
    ConfigKey,
    DeviceState,
    Opcode,
    Result,
)
from northfinder.driver.protocol.counters import TickCounter, counter_diff
from northfinder.driver.protocol.errors import ProtocolError
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    GetStatus,
    Identify,
    Reply,
    Sample,
    Status,
    StreamStart,
    StreamStop,
)

__all__ = ["LAG_LOOKBACK_S", "Answer", "LinkFault", "SampleRecord", "Session"]

LAG_LOOKBACK_S = 2.0
"""How far before an interval :meth:`Session.lag` looks for the unit's messages on time, wall s:
longer than any stall a loaded host showed (1.7 s at load 13 on two cores)."""


@dataclass(frozen=True, slots=True)
class SampleRecord:
    """One sample tick as the suite saw it.

    Attributes
    ----------
    t : float
        Host receipt time, s.
    counter : int
        Full 32-bit sample counter (on CAN extended from the 8-bit tick and the status anchor).
    validity : int
        Validity bits (0 for an incomplete CAN tick without its AUX frame).
    angle : int or None
        Encoder angle, 1e-6 deg (None when the AUX frame is missing).
    complete : bool
        False for a CAN tick of which some frames did not arrive.
    """

    t: float
    counter: int
    validity: int
    angle: int | None
    complete: bool = True


@dataclass(slots=True)
class Answer:
    """A command sent and its reply (if one came)."""

    payload: bytes
    sent: float
    reply: Reply | None = None
    received: float | None = None
    statuses_before: int | None = None
    """How many statuses had arrived before the reply (orders the reply among the statuses)."""
    samples_before: int | None = None
    """How many samples had arrived before the reply: the unit queued those before replying."""

    @property
    def seq(self) -> int:
        return self.payload[0]

    @property
    def opcode(self) -> int:
        return self.payload[1]

    @property
    def latency(self) -> float | None:
        """Wall seconds from sending to the reply, or None."""
        return None if self.received is None else self.received - self.sent

    @property
    def name(self) -> str:
        try:
            return Opcode(self.opcode).name
        except ValueError:
            return f"opcode 0x{self.opcode:02X}"


class Session:
    """Requests, replies and the record of one unit on one raw link.

    Parameters
    ----------
    link : RawLink
        The suite's end of the link.
    time_scale : float
        The unit's seconds per wall second (1 for a real instrument).
    reply_wait_s : float
        Wall seconds to wait for a reply before declaring it missing (long enough to measure a
        late reply; the check judges lateness separately).
    clock : Clock, optional
        The host's clock (default the wall clock); see the module docstring for a virtual one.
    """

    def __init__(
        self,
        link: RawLink,
        time_scale: float = 1.0,
        reply_wait_s: float = 1.0,
        clock: Clock | None = None,
    ) -> None:
        self.clock: Clock = WallClock() if clock is None else clock
        self.link = link
        self.pace = HostPace(self.clock)
        """The host's own pace beside the link (the runner starts and stops it)."""
        if self.clock.virtual:
            # The checks also send on the link directly: every send tells the clock, so that the
            # unit takes it at this instant.
            link.after_send = self.clock.notify
        self._arrived = 0  # arrivals recorded so far (a virtual clock's waits watch it)
        self.time_scale = float(time_scale)
        self.reply_wait_s = reply_wait_s
        self._seq = 0
        self.statuses: list[tuple[float, Status]] = []
        self.identifies: list[tuple[float, Identify]] = []
        self.samples: list[SampleRecord] = []
        self.gaps: list[tuple[float, str]] = []
        self.link_errors: list[tuple[float, str]] = []
        self.unsolicited: list[tuple[float, Reply]] = []
        self.answers: list[Answer] = []
        self.transitions: list[tuple[float, DeviceState | None, DeviceState]] = []
        self.changes: list[tuple[float, int, DeviceState]] = []
        """Each state change as the unit stamped it: (arrival time, the sample counter its status
        carries, the new state). The counter places the change among the unit's own ticks."""
        self.state: DeviceState | None = None
        self.streaming = False
        """Whether the suite believes the stream is on (it switched it on, or saw samples)."""
        self._pending: dict[tuple[int, int], Answer] = {}
        self._overdue: dict[tuple[int, int], Answer] = {}
        self.late_answers: list[tuple[Answer, str]] = []
        """Replies :meth:`ok` got only after the wait, and what they answered (to be judged)."""
        """Answers whose wait ended without a reply: a reply that comes later is theirs (late)."""
        self._last_counter: int | None = None
        self._ticks = TickCounter()  # CAN: the 8-bit tick extended to the full counter
        self._rate_hz = float(SAMPLE_RATE_DEFAULT_HZ)  # the unit's tick rate, as last heard
        self._rate_known = False
        self._run = 0  # counts the runs of the unit's clock: a reset, a new rate, a counter back
        self._mark_counter: int | None = None
        self.marks: list[tuple[float, float, int]] = []
        """The unit's clock against arrival, for every status and sample: (arrival time, arrival
        time less the sample counter's time at the unit's rate, the run of the unit's clock).
        The second grows when the unit's messages come later than its own clock would have them
        (:meth:`lag`)."""
        self.status_offsets: list[tuple[float, int]] = []
        """(time, latest sample counter - status sample counter) while streaming."""
        self._last_seq: int | None = None
        self.seq_restart_pending = False
        self.serial_frames_lost = 0
        self.losses: list[tuple[float, str]] = []
        """Serial frames lost (sequence counter gaps), when found; never cleared."""
        if self.clock.virtual:
            self.clock.add_poller(self._poll)

    def close(self) -> None:
        """Stop being polled by a virtual clock (the link is the caller's)."""
        self.clock.remove_poller(self._poll)

    # -- time -------------------------------------------------------------------------------------
    @property
    def arrived(self) -> int:
        """Everything heard from the link so far (messages and link errors)."""
        return self._arrived

    def unit(self, wall_s: float) -> float:
        """A wall duration in the unit's seconds."""
        return wall_s * self.time_scale

    def wall(self, unit_s: float) -> float:
        """A duration in the unit's seconds as wall seconds."""
        return unit_s / self.time_scale

    def now(self) -> float:
        return self.clock.now()

    # -- receiving --------------------------------------------------------------------------------
    def _poll(self) -> bool:
        """On a virtual clock: record what has arrived, stamped with the present instant."""
        arrivals = self.link.receive(0.0)
        t = self.clock.now()
        for arrival in arrivals:
            self._record(dataclasses.replace(arrival, t=t))
        return bool(arrivals)

    def pump(self, timeout: float = 0.0) -> None:
        """Receive and record what arrives within ``timeout`` wall seconds (returns early once
        something came)."""
        if self.clock.virtual:
            seen = self._arrived
            self.clock.wait_until(lambda: self._arrived != seen, self.now() + timeout)
            return
        t0 = self.now()
        arrivals = self.link.receive(timeout)
        self.pace.read(t0, timeout, self.now() - t0)
        for arrival in arrivals:
            self._record(arrival)

    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Receive until ``predicate()`` holds or ``timeout`` wall seconds pass; return whether it held."""
        end = self.now() + timeout
        while True:
            if predicate():
                return True
            left = end - self.now()
            if left <= 0:
                return predicate()
            self.pump(min(left, 0.01))

    def idle(self, unit_s: float) -> None:
        """Receive for ``unit_s`` of the unit's seconds."""
        end = self.now() + self.wall(unit_s)
        while (left := end - self.now()) > 0:
            self.pump(min(left, 0.01))

    def drain(self, wall_s: float = 0.1) -> None:
        """Receive for a moment and forget link errors so far (a port opened mid-frame)."""
        end = self.now() + wall_s
        while (left := end - self.now()) > 0:
            self.pump(min(left, 0.01))
        self.link_errors.clear()
        self.gaps.clear()

    def _record(self, a: Arrival) -> None:
        self._arrived += 1
        if a.seq is not None:
            self._check_serial_seq(a)
        m = a.message
        if isinstance(m, str):
            self.link_errors.append((a.t, m))
        elif isinstance(m, Reply):
            key = (m.seq, int(m.opcode))
            answer = self._pending.pop(key, None) or self._overdue.pop(key, None)
            if answer is None:
                self.unsolicited.append((a.t, m))
            else:
                answer.reply, answer.received = m, a.t
                answer.statuses_before = len(self.statuses)
                answer.samples_before = len(self.samples)
                self._note_rate(m)
        elif isinstance(m, Status):
            self._on_status(a.t, m)
        elif isinstance(m, Identify):
            self.identifies.append((a.t, m))
        elif isinstance(m, Sample):
            self._on_sample(a.t, m.counter, int(m.validity), m.angle, True)
        elif isinstance(m, TickParts):
            self._on_tick(a.t, m)

    def _check_serial_seq(self, a: Arrival) -> None:
        seq = a.seq
        assert seq is not None
        if self._last_seq is not None and seq != (self._last_seq + 1) & 0xFF:
            if self.seq_restart_pending and seq == 0:
                self.seq_restart_pending = False
            else:
                lost = (seq - self._last_seq - 1) & 0xFF
                self.serial_frames_lost += lost
                text = f"serial sequence counter {self._last_seq} -> {seq}: {lost} frame(s) lost"
                self.gaps.append((a.t, text))
                self.losses.append((a.t, text))
        elif self.seq_restart_pending and seq == 0:
            self.seq_restart_pending = False
        self._last_seq = seq

    def _note_rate(self, m: Reply) -> None:
        """An OK reply to GET_CONFIG or SET_CONFIG of the sample rate: the unit's tick rate."""
        if m.result != Result.OK or int(m.opcode) not in (Opcode.GET_CONFIG, Opcode.SET_CONFIG):
            return
        try:
            key, value = m.config_value()
        except ProtocolError:
            return
        if key == ConfigKey.SAMPLE_RATE_HZ and value > 0:
            if value != self._rate_hz or not self._rate_known:
                self._run += 1
            self._rate_hz, self._rate_known = float(value), True

    def _mark(self, t: float, counter: int) -> None:
        """The unit's clock (its sample counter) against the arrival time ``t``; only once the
        unit's rate is known (a reply that carries it, or the defaults after a reset): at a
        wrong rate the counter drifts against time and would read as lag."""
        if not self._rate_known:
            return
        last = self._mark_counter
        if last is not None and counter_diff(counter, last) < 0:
            self._run += 1  # the counter went back: a reset
        self._mark_counter = counter
        self.marks.append((t, t - self.wall(counter / self._rate_hz), self._run))

    def lag(
        self, t0: float, t1: float, lookback_s: float = LAG_LOOKBACK_S, after_s: float = 0.2
    ) -> float:
        """How late the unit's messages came in ``[t0, t1 + after_s]`` by the unit's own clock,
        wall s: the latest arrival against the unit's sample counter, less the earliest of the
        same run of its clock since ``t0 - lookback_s``. A reader that keeps up and a unit that
        keeps time give a few ms; a reader behind the link, or a unit on this host that the host
        starved (its clock slips), give how far behind they were. 0 without such arrivals."""
        i = bisect.bisect_left(self.marks, (t0 - lookback_s,))
        base: dict[int, float] = {}
        worst: dict[int, float] = {}
        for t, offset, run in self.marks[i:]:
            if t > t1 + after_s:
                break
            base[run] = min(base.get(run, offset), offset)
            if t >= t0:
                worst[run] = max(worst.get(run, offset), offset)
        return max((w - base[run] for run, w in worst.items()), default=0.0)

    def _on_status(self, t: float, s: Status) -> None:
        self.statuses.append((t, s))
        if s.state == DeviceState.BOOT and self.state != DeviceState.BOOT:
            self._rate_hz = float(SAMPLE_RATE_DEFAULT_HZ)  # a reset restores the defaults
            self._rate_known = True
            self._run += 1
        self._mark(t, s.sample_counter)
        if s.state != self.state:
            self.transitions.append((t, self.state, s.state))
            self.changes.append((t, s.sample_counter, s.state))
            if s.state == DeviceState.BOOT:
                self.begin_segment()
                self.streaming = False
            self.state = s.state
        if self._ticks.sync(s.sample_counter):
            # CAN counters before the first status were known modulo 256 only: now placed.
            self._last_counter = self._ticks.last
        elif self._last_counter is not None and self.samples and t - self.samples[-1].t < 0.05:
            diff = counter_diff(self._last_counter, s.sample_counter)
            self.status_offsets.append((t, diff))

    def _on_tick(self, t: float, p: TickParts) -> None:
        counter, _ = self._ticks.place(p.tick)
        if not p.complete:
            missing = [n for n, f in zip("XYZ", (p.x, p.y, p.z), strict=True) if f is None]
            missing += ["AUX"] if p.aux is None else []
            self.gaps.append(
                (t, f"tick {p.tick} (counter {counter}) incomplete: no {', '.join(missing)}")
            )
        aux = p.aux
        self._on_sample(
            t,
            counter,
            int(aux.validity) if aux else 0,
            aux.angle if aux else None,
            p.complete,
            self._ticks.anchored,
        )

    def _on_sample(
        self,
        t: float,
        counter: int,
        validity: int,
        angle: int | None,
        ok: bool,
        placed: bool = True,
    ) -> None:
        """``placed``: the full counter is known (on CAN once a status anchored the tick)."""
        last = self._last_counter
        d = 1 if last is None else counter_diff(counter, last)
        if d == 0:
            self.gaps.append((t, f"sample counter {counter} repeated"))
        elif d > 1:
            self.gaps.append(
                (t, f"sample counter jumped from {last} to {counter}: {d - 1} tick(s) missing")
            )
        elif d < 0:
            self.gaps.append((t, f"sample counter went back from {last} to {counter}"))
        self._last_counter = counter
        self.streaming = True
        self.samples.append(SampleRecord(t, counter, validity, angle, ok))
        if placed:
            self._mark(t, counter)

    def begin_segment(self) -> None:
        """The stream (re)starts: counters need not continue from the previous sample."""
        self._last_counter = None
        self._ticks.restart()

    def expect_restart(self) -> None:
        """The unit is about to reset: its serial sequence counter will restart at 0."""
        self.seq_restart_pending = True

    # -- sending ----------------------------------------------------------------------------------
    def next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFF
        return self._seq

    def send(self, command: Command | bytes) -> Answer:
        """Send a command (its seq replaced by the next one) or a raw payload; do not wait."""
        if isinstance(command, Command):
            payload = dataclasses.replace(command, seq=self.next_seq()).encode()
        else:
            payload = bytes(command)
        answer = Answer(payload, self.now())
        if len(payload) >= 2:
            self._overdue.pop((payload[0], payload[1]), None)
            self._pending[(payload[0], payload[1])] = answer
            self.answers.append(answer)
        self.link.send_command(payload)
        return answer

    def track(self, payload: bytes) -> Answer:
        """Expect a reply to a command payload sent by other means (inside raw bytes)."""
        answer = Answer(bytes(payload), self.now())
        self._overdue.pop((payload[0], payload[1]), None)
        self._pending[(payload[0], payload[1])] = answer
        self.answers.append(answer)
        return answer

    def request(self, command: Command | bytes, wait: float | None = None) -> Answer:
        """Send a command and receive until its reply arrives or ``wait`` wall seconds pass."""
        answer = self.send(command)
        self.wait_until(
            lambda: answer.reply is not None, self.reply_wait_s if wait is None else wait
        )
        if answer.reply is None:
            # Still listened for: a reply that comes after the wait is this answer's, late.
            key = (answer.seq, answer.opcode)
            self._pending.pop(key, None)
            self._overdue[key] = answer
        return answer

    def await_late(self, answer: Answer, wall_s: float) -> None:
        """Listen up to ``wall_s`` more for the reply of an answer whose wait ended without one."""
        self.wait_until(lambda: answer.reply is not None, wall_s)

    def raw(self, opcode: int, args: bytes = b"") -> bytes:
        """A command payload with the next seq, any opcode and any argument bytes."""
        return bytes((self.next_seq(), opcode & 0xFF)) + bytes(args)

    # -- common conversations ---------------------------------------------------------------------
    def ok(self, command: Command | bytes, what: str | None = None) -> Answer:
        """Send and demand an OK reply.

        Raises
        ------
        LinkFault
            No reply, or a reply other than OK.
        """
        a = self.request(command)
        if a.reply is None:
            # Late is not wrong: listen as long again; a reply that comes goes on record (the
            # check judges its delay), and the conversation goes on.
            self.await_late(a, self.reply_wait_s)
            if a.reply is None:
                raise NoReply(a, what or a.name)
            self.late_answers.append((a, what or a.name))
        if a.reply.result != Result.OK:
            raise LinkFault(f"{what or a.name} answered {describe_result(a.reply.result)}")
        return a

    def get_config(self, key: ConfigKey | int) -> int:
        """Read a configuration value (GET_CONFIG must succeed)."""
        a = self.ok(GetConfig(0, key), f"GET_CONFIG {_key_name(key)}")
        assert a.reply is not None
        k, v = a.reply.config_value()
        if int(k) != int(key):
            raise LinkFault(f"GET_CONFIG {_key_name(key)} answered for key {int(k)}")
        return v

    def get_status(self) -> Status:
        """GET_STATUS and the status that follows it."""
        n = len(self.statuses)
        a = self.ok(GetStatus(0))
        t0 = a.received if a.received is not None else a.sent

        def after() -> Status | None:
            return next((st for t, st in self.statuses[n:] if t >= t0), None)

        if not self.wait_until(lambda: after() is not None, self.reply_wait_s):
            raise LinkFault("no status followed the OK reply to GET_STATUS")
        status = after()
        assert status is not None
        return status

    def start_stream(self) -> None:
        if not self.streaming:
            self.begin_segment()
        self.ok(StreamStart(0))
        self.streaming = True

    def stop_stream(self) -> None:
        self.ok(StreamStop(0))
        self.streaming = False

    def wait_state(
        self, states: Iterable[DeviceState], timeout_unit: float, start: int | None = None
    ) -> int | None:
        """Wait for a status in one of ``states`` among ``statuses[start:]`` (default: statuses
        still to come); return its index in :attr:`statuses`, or None. Indices, not receipt
        times, order the statuses: frames read in one chunk share a time."""
        wanted = set(states)
        first = len(self.statuses) if start is None else start

        def seen() -> int | None:
            for i in range(first, len(self.statuses)):
                if self.statuses[i][1].state in wanted:
                    return i
            return None

        self.wait_until(lambda: seen() is not None, self.wall(timeout_unit))
        return seen()

    def state_at(self, t: float) -> DeviceState | None:
        """The state the unit's statuses showed at host time ``t``."""
        state = None
        for tt, _, new in self.transitions:
            if tt > t:
                break
            state = new
        return state

    def state_of(self, rec: SampleRecord, guard_ticks: int = 2) -> DeviceState | None:
        """The state the unit was in when it took sample ``rec``, by its own counters: the state
        of its latest change whose status carries a counter below the sample's (a status carries
        the counter of the latest tick queued before it), among the changes since the unit last
        booted before the sample arrived. None when unknown (no change seen before it) or when
        the sample is within ``guard_ticks`` of a change (its validity may show either state).
        Arrival times do not order them: a host that reads late reads a status and the samples
        around it at once."""
        epoch = 0
        for i, (t, _, new) in enumerate(self.changes):
            if t > rec.t:
                break
            if new == DeviceState.BOOT:
                epoch = i
        state: DeviceState | None = None
        for _, counter, new in self.changes[epoch:]:
            if new == DeviceState.BOOT and state is not None:
                break  # the next boot: a later epoch
            d = counter_diff(rec.counter, counter)
            if abs(d) <= guard_ticks:
                return None
            if d > 0:
                state = new
        return state

    def state_when_answered(self, answer: Answer) -> DeviceState | None:
        """The state the last status before the reply showed (None if no reply or no status)."""
        n = answer.statuses_before
        return self.statuses[n - 1][1].state if n else None

    def samples_between(self, t0: float, t1: float) -> list[SampleRecord]:
        return [s for s in self.samples if t0 <= s.t <= t1]

    def behind(self, t: float, rate_hz: float, lookback_s: float = 1.0) -> float:
        """How far the reader was behind the unit's stream around ``t``, wall s: the largest delay
        of a sample that arrived in ``[t - lookback_s, t]`` against the earliest any sample of the
        same run of the stream arrived, by the unit's own sample counter (``rate_hz`` ticks a
        unit second). A reader that keeps up reads each sample a few ms after it is sent; one that
        fell behind reads it as late as the data waiting in the link."""
        per_tick = self.wall(1.0 / rate_hz)
        earliest: float | None = None
        last: SampleRecord | None = None
        worst = 0.0
        for r in self.samples:
            if r.t > t:
                break
            # The counter counts every tick since boot, streamed or not: only a reset (the
            # counter going back) starts afresh.
            if last is None or counter_diff(r.counter, last.counter) <= 0:
                earliest = None
            offset = r.t - r.counter * per_tick
            earliest = offset if earliest is None else min(earliest, offset)
            if r.t >= t - lookback_s:
                worst = max(worst, offset - earliest)
            last = r
        return worst

    def gaps_since(self, t0: float) -> list[str]:
        return [text for t, text in self.gaps if t >= t0]

    def gaps_found_since(self, t0: float) -> list[tuple[float, str]]:
        """The gaps found since ``t0``: (time, text)."""
        return [(t, text) for t, text in self.gaps if t >= t0]


def describe_result(code: int) -> str:
    """``BUSY (1)`` or ``undefined code 42``."""
    try:
        return f"{Result(code).name} ({int(code)})"
    except ValueError:
        return f"undefined result code {int(code)}"


def _key_name(key: ConfigKey | int) -> str:
    try:
        return ConfigKey(key).name
    except ValueError:
        return f"key 0x{int(key):02X}"
