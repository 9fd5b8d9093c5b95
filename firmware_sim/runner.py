"""Clocks and the loop that drives the firmware on a link.

Paced clocks: :class:`RealTimeClock` (paced from its start instant, so no drift accumulates),
the same with a speed factor (accelerated rehearsal), and :class:`LockstepClock` (the caller
advances time; for tests). The :class:`Runner` polls the link, advances the firmware to the
clock's time and sends what the firmware emits. A lock serialises the loop with the control
channel.

Pacing (protocol.md 12, "The simulator's pace"): a paced runner that falls behind its clock (the
process was stalled or starved of CPU) catches up at once only while it is at most
:data:`MAX_LAG_WALL_S` wall seconds behind (ordinary scheduling jitter). Further behind, it does
not send the backlog in a burst: the clock slips (:meth:`RealTimeClock.slip`), so the simulated
time the device had reached continues from now at the configured pace, and the time lost is
counted (:attr:`Runner.lag`), logged and reported by the control channel's ``status``.

Virtual time: given a clock with ``virtual = True`` (``northfinder.driver.clock.VirtualClock``,
shared with the driver in the same process), the runner has no loop of its own. It is one of the
clock's sources (:meth:`Runner.next_event_s`, :meth:`Runner.run_until`): the clock lets it act
whenever a host waits, and moves time straight to the next message it will send.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from operator import attrgetter
from typing import TYPE_CHECKING, Any, Protocol

from northfinder.firmware_sim import sender_child
from northfinder.firmware_sim.errors import SimConfigError, SimError
from northfinder.firmware_sim.firmware import (
    NS_PER_S,
    VIRTUAL_LOOKAHEAD_S,
    Firmware,
    Outgoing,
)

if TYPE_CHECKING:
    from northfinder.firmware_sim.sender import Capture, ProcessSender

log = logging.getLogger("northfinder.sim.runner")
_time_of = attrgetter("time_s")  # an output's due time, simulated s

#: How far a paced runner may fall behind its clock, wall seconds, before it slips the clock
#: instead of catching up (a catch-up sends its backlog faster than the configured pace).
MAX_LAG_WALL_S = 0.05
#: While a paced runner keeps falling behind, it logs a summary this often, wall seconds.
LAG_LOG_EVERY_S = 10.0


#: Whether a spin on the clock is worth it here (``sender_child.cheap_clock``, measured once: the
#: sender process decides the same way).
cheap_clock = functools.cache(sender_child.cheap_clock)


class Link(Protocol):
    """A wire adapter of the simulated device (:mod:`northfinder.firmware_sim.adapters`)."""

    def poll(self, timeout: float) -> int: ...
    def send(self, outgoing: list[Outgoing]) -> None: ...


class SimClock(Protocol):
    """What a :class:`Runner` needs from a clock: simulated time, and how long to wait for it.

    :class:`RealTimeClock` and :class:`LockstepClock` are clocks; so is any object with these
    members (a virtual clock shared with a test, for instance).
    """

    @property
    def speed(self) -> float:
        """Simulated seconds per wall second."""
        ...

    @property
    def paused(self) -> bool: ...

    def now(self) -> float:
        """Simulated time, s."""
        ...

    def set_speed(self, speed: float) -> None: ...
    def pause(self) -> None: ...
    def resume(self) -> None: ...

    def wall_until(self, sim_t: float) -> float:
        """Wall seconds until simulated time ``sim_t`` (0 if past)."""
        ...

    def slip(self, seconds: float) -> None:
        """Let simulated time fall back by ``seconds`` (the runner lost them; see the module
        docstring)."""
        ...


class VirtualTime(Protocol):
    """A virtual clock that drives sources (``northfinder.driver.clock.VirtualClock``)."""

    @property
    def virtual(self) -> bool: ...

    def now(self) -> float: ...
    def notify(self) -> None: ...
    def add_source(self, source: Any) -> None: ...
    def remove_source(self, source: Any) -> None: ...


class RealTimeClock:
    """Simulated time = speed x wall time since start, re-anchored on every speed change or pause.

    Parameters
    ----------
    speed : float
        Simulated seconds per wall second (1 = real time).
    monotonic : callable
        Wall clock (``time.monotonic``); injectable for tests.
    """

    def __init__(self, speed: float = 1.0, monotonic: Callable[[], float] = time.monotonic) -> None:
        self._monotonic = monotonic
        self._check(speed)
        self._speed = float(speed)
        self._anchor_wall = monotonic()
        self._anchor_sim = 0.0
        self._paused = False

    @staticmethod
    def _check(speed: float) -> None:
        if not (isinstance(speed, int | float) and 0 < speed <= 10_000):
            raise SimConfigError(f"speed: must be a number in (0, 10000], got {speed!r}")

    @property
    def speed(self) -> float:
        return self._speed

    @property
    def paused(self) -> bool:
        return self._paused

    def now(self) -> float:
        if self._paused:
            return self._anchor_sim
        return self._anchor_sim + (self._monotonic() - self._anchor_wall) * self._speed

    def _reanchor(self) -> None:
        self._anchor_sim = self.now()
        self._anchor_wall = self._monotonic()

    def set_speed(self, speed: float) -> None:
        self._check(speed)
        self._reanchor()
        self._speed = float(speed)

    def pause(self) -> None:
        self._reanchor()
        self._paused = True

    def resume(self) -> None:
        if self._paused:
            self._anchor_wall = self._monotonic()
            self._paused = False

    def wall_until(self, sim_t: float) -> float:
        """Wall seconds until simulated time ``sim_t`` (0 if past; long if paused)."""
        if self._paused:
            return 0.05
        return max(0.0, (sim_t - self.now()) / self._speed)

    def slip(self, seconds: float) -> None:
        self._anchor_sim -= seconds

    def align(self, sim_t: float) -> None:
        """Simulated time is ``sim_t`` now (a loop that starts: what happened before, such as
        starting a sender process, is not time the device lost)."""
        self._anchor_sim = float(sim_t)
        self._anchor_wall = self._monotonic()

    def wall_at(self, sim_t: float) -> float:
        """The wall clock's reading (``monotonic``) at which simulated time reaches ``sim_t``
        at the present pace (infinite while paused)."""
        if self._paused:
            return math.inf
        return self._anchor_wall + (sim_t - self._anchor_sim) / self._speed


class LockstepClock:
    """A clock that moves only when told: ``advance(dt)``. Any step is carried out in full by the
    runner's next :meth:`Runner.step` (in steps of at most ``Runner.MAX_STEP_S``, the link polled
    between them): nothing is behind a clock that waits for the simulator."""

    lockstep = True

    def __init__(self) -> None:
        self._t = 0.0
        self.speed = 1.0
        self.paused = False

    def now(self) -> float:
        return self._t

    def advance(self, dt: float) -> None:
        self._t += dt

    def set_speed(self, speed: float) -> None:
        self.speed = speed

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        self.paused = False

    def wall_until(self, sim_t: float) -> float:
        return 0.0

    def slip(self, seconds: float) -> None:
        self._t -= seconds


@dataclass
class Lag:
    """How a paced runner kept its pace (see the module docstring).

    Attributes
    ----------
    behind_s : float
        Simulated seconds by which the oldest message not yet sent is late now.
    slipped_s : float
        Simulated seconds dropped in total by slipping the clock (time the device lost).
    slips : int
        How many times the clock slipped.
    last_slip_s : float
        Simulated seconds dropped by the latest slip.
    """

    behind_s: float = 0.0
    slipped_s: float = 0.0
    slips: int = 0
    last_slip_s: float = 0.0


class Runner:
    """Drives one firmware on one link with one clock.

    ``step()`` does one round (poll, advance, send); ``run(stop)`` loops until ``stop`` is set.
    With a virtual clock (``clock.virtual``) the runner is a source of that clock instead
    (:meth:`attach`), and :meth:`step` and :meth:`run` are not used.
    """

    def __init__(self, firmware: Firmware, link: Link, clock: SimClock | VirtualTime) -> None:
        self.firmware = firmware
        self.link = link
        self.clock = clock
        self.lock = threading.RLock()
        self.sent = 0
        self.lag = Lag()
        self._lag_logged_at = -math.inf
        self._lag_since_log = 0.0
        # Virtual time: the clock's time minus the firmware's, ns (grows while paused).
        self._offset_ns = 0
        self._paused_at: float | None = None
        #: Paced mode only: send from a dedicated thread (:class:`PacedSender`) what this loop
        #: computes ahead, so that no computation holds a message that is due.
        self.paced_sender = False
        #: Paced mode only, and preferred to the thread: a sender process and the capture around
        #: the link's stream or bus whose writes it sends (:mod:`~northfinder.firmware_sim.sender`).
        self.sender_process: tuple[ProcessSender, Capture] | None = None

    def sender_info(self) -> dict[str, Any]:
        """How the output is sent: ``{"kind": "loop"}`` (by the loop that computes it),
        ``"thread"`` (:class:`PacedSender`) or ``"process"`` (with its ``pid`` and the
        ``SCHED_FIFO`` ``priority`` it runs at, 0 for the ordinary class)."""
        if self.sender_process is not None:
            sender = self.sender_process[0]
            return {"kind": "process", "pid": sender.pid, "priority": sender.priority}
        return {"kind": "thread" if self.paced_sender and not self.virtual else "loop"}

    @property
    def virtual(self) -> bool:
        """Whether the runner is driven by a virtual clock."""
        return bool(getattr(self.clock, "virtual", False))

    def _paced(self) -> SimClock:
        if self.virtual:
            raise SimConfigError("the runner is driven by a virtual clock: it has no loop")
        return self.clock  # type: ignore[return-value]

    # -- speed and pause, for the control channel -------------------------------------------------
    @property
    def speed(self) -> float | None:
        """Simulated seconds per wall second; None on a virtual clock (as fast as it can)."""
        return None if self.virtual else float(self._paced().speed)

    @property
    def paused(self) -> bool:
        return self._paused_at is not None if self.virtual else bool(self._paced().paused)

    def set_speed(self, speed: float) -> None:
        if self.virtual:
            raise SimConfigError(
                "speed: this simulator runs in virtual time, as fast as its host lets it; "
                "a speed applies to a paced simulator (northfinder sim --speed)"
            )
        self._paced().set_speed(speed)

    def pause(self) -> None:
        """Stop simulated time (the device falls silent; a host's time goes on)."""
        if not self.virtual:
            self._paced().pause()
        elif self._paused_at is None:
            self._paused_at = self.clock.now()

    def resume(self) -> None:
        if not self.virtual:
            self._paced().resume()
        elif self._paused_at is not None:
            self._offset_ns += round((self.clock.now() - self._paused_at) * NS_PER_S)
            self._paused_at = None

    # -- virtual time: a source of the clock -----------------------------------------------------
    def attach(self) -> None:
        """Become a source of the virtual clock (``northfinder.driver.clock.VirtualClock``)."""
        clock = self.clock
        if not self.virtual:
            raise SimConfigError("attach: the runner's clock is not a virtual clock")
        with self.lock:  # the firmware's time goes on from the clock's present
            self._offset_ns = round(clock.now() * NS_PER_S) - self.firmware.now_ns
            self.firmware.lookahead_s = VIRTUAL_LOOKAHEAD_S
        clock.add_source(self)  # type: ignore[union-attr]

    def detach(self) -> None:
        if self.virtual:
            self.clock.remove_source(self)  # type: ignore[union-attr]

    def changed(self) -> None:
        """The firmware was changed from outside the loop (the control channel): a virtual
        clock lets it act at the present."""
        notify = getattr(self.clock, "notify", None)
        if self.virtual and notify is not None:
            notify()

    def next_event_s(self) -> float:
        """Clock time of the next message the device sends by itself (inf while paused)."""
        with self.lock:
            if self._paused_at is not None:
                return math.inf
            self.firmware.prefetch()
            return self.firmware.next_output_s() + self._offset_ns / NS_PER_S

    def run_until(self, t: float) -> bool:
        """Take the commands that arrived, advance the firmware to clock time ``t`` and send
        what is due; True if anything was received or sent."""
        with self.lock:
            n = self.link.poll(0.0)
            if self._paused_at is not None:
                return n > 0
            target_ns = round(t * NS_PER_S) - self._offset_ns
            dt_ns = target_ns - self.firmware.now_ns
            out = self.firmware.process(dt_ns / NS_PER_S) if dt_ns >= 0 else []
            if out:
                self.sent += len(out)
                self.link.send(out)
        return bool(n or out)

    #: Most simulated time one step covers. When the simulator runs behind (a fast speed factor or
    #: a busy machine) it catches up in steps this long, polling the link between them, so
    #: commands are still answered within the protocol's reply deadline.
    MAX_STEP_S = 0.02
    #: Longest wait for incoming frames between steps, wall seconds.
    MAX_WAIT_S = 0.05
    #: The last part of the wait for a message that is due, spent re-reading the clock rather
    #: than asleep, wall seconds; none where a clock read is a costly system call
    #: (:func:`cheap_clock`).
    SPIN_S = sender_child.SPIN_S
    #: The look-ahead's next chunk is computed only when the next message is due at least this
    #: far ahead, wall seconds (a chunk of 0.2 s takes about a millisecond here), ...
    PREFETCH_QUIET_S = 0.003
    #: ... and after waiting this long for commands, so that a host in this interpreter reads
    #: what was just sent first, wall seconds.
    PREFETCH_AFTER_S = 0.001

    def step(self, poll_timeout: float = 0.0) -> None:
        clock = self._paced()
        self.link.poll(poll_timeout)
        with self.lock:
            now = clock.now()
            # How late the oldest message not yet sent is: a backlog beyond the limit would go
            # out as a burst, so the clock slips instead.
            late = now - self.firmware.next_output_s()
            self.lag.behind_s = max(0.0, late)
            lockstep = getattr(clock, "lockstep", False)
            if late > MAX_LAG_WALL_S * clock.speed and not clock.paused and not lockstep:
                self._slip(clock, late)
                now -= late
            dt = min(now - self.firmware.now, self.MAX_STEP_S)
            if dt > 0:
                out = self.firmware.process(dt)
                self.sent += len(out)
                self.link.send(out)
            # A lockstep clock stepped further than one step: catch up to it now, answering
            # commands between the steps as a paced runner would.
            # (The firmware keeps time in whole nanoseconds: a remainder below that is no step.)
            while lockstep and now - self.firmware.now > 1e-6:
                self.link.poll(0.0)
                before = self.firmware.now
                out = self.firmware.process(min(now - self.firmware.now, self.MAX_STEP_S))
                self.sent += len(out)
                self.link.send(out)
                if self.firmware.now <= before:
                    break

    def _slip(self, clock: SimClock, behind: float) -> None:
        """Fallen too far behind: the clock slips back to the oldest message due (no burst)."""
        clock.slip(behind)
        lag = self.lag
        lag.behind_s = 0.0
        lag.slipped_s += behind
        lag.slips += 1
        lag.last_slip_s = behind
        self._lag_since_log += behind
        wall = time.monotonic()
        if wall - self._lag_logged_at >= LAG_LOG_EVERY_S:
            log.warning(
                "t=%.3f s: the simulator fell behind its clock by %.3f s (%.3f s wall at speed "
                "%g) and continues at its pace from here; %.3f s of simulated time lost in %d "
                "slip(s) so far",
                self.firmware.now,
                self._lag_since_log,
                self._lag_since_log / clock.speed,
                clock.speed,
                lag.slipped_s,
                lag.slips,
            )
            self._lag_logged_at = wall
            self._lag_since_log = 0.0

    def run(self, stop: threading.Event) -> None:
        align = getattr(self.clock, "align", None)
        if align is not None and not self.virtual:
            with self.lock:  # the device's time runs from the loop's start
                align(self.firmware.now)
        if self.sender_process is not None:
            self._run_with_process(stop, *self.sender_process)
            return
        if self.paced_sender:
            self._run_with_sender(stop)
            return
        clock = self._paced()
        spin = self.SPIN_S if cheap_clock() else 0.0
        while not stop.is_set():
            with self.lock:
                due = self.firmware.next_output_s()
                prefetch = self.firmware.prefetch_due
            wait = clock.wall_until(due)
            if prefetch and wait > self.PREFETCH_QUIET_S:
                # The next chunk is computed in the quiet part of a period: after a host that
                # shares this interpreter had the time to read what was just sent, and well
                # before the next message is due.
                self.link.poll(self.PREFETCH_AFTER_S)
                with self.lock:
                    if clock.wall_until(self.firmware.next_output_s()) > self.PREFETCH_QUIET_S / 2:
                        self.firmware.prefetch()
                continue
            if 0 < wait <= spin:
                # The last moments on the clock itself: a timed wait wakes up late.
                while clock.wall_until(due) > 0 and not clock.paused:
                    pass
                wait = 0.0
            # Sleep until shortly before the next message is due; a frame arriving ends the
            # wait at once.
            self.step(min(self.MAX_WAIT_S, max(0.0, wait - spin)) if wait > spin else 0.0)

    #: Paced sender: how far ahead of its clock the loop computes output, wall seconds (replies to
    #: commands wait at most this long behind the queued output; protocol.md: 20 ms).
    LEAD_WALL_S = 0.01
    #: Paced sender: most messages queued for the sender.
    MAX_QUEUED = 256

    def produce(self, sender: PacedSender) -> None:
        """One round of the paced loop with a sender: advance the firmware to LEAD_WALL_S ahead
        of the clock (bounded by the sender's queue) and hand the output to the sender."""
        clock = self._paced()
        with self.lock:
            now = clock.now()
            late = now - self.firmware.next_output_s()
            if late > MAX_LAG_WALL_S * clock.speed and not clock.paused and not sender.queued:
                self._slip(clock, late)  # the loop itself was held up: no backlog burst
                now -= late
            self.lag.behind_s = max(0.0, late)
            target = now + self.LEAD_WALL_S * clock.speed
            while sender.queued < self.MAX_QUEUED:
                dt = min(target - self.firmware.now, self.MAX_STEP_S)
                if round(dt * NS_PER_S) <= 0:
                    break  # within a nanosecond of the target: the firmware's clock resolution
                out = self.firmware.process(dt)
                if out:
                    sender.put(out)
            self.firmware.prefetch()

    def _run_with_sender(self, stop: threading.Event) -> None:
        self._paced()
        sender = PacedSender(self).start()
        try:
            while not stop.is_set() and sender.error is None:
                self.produce(sender)
                self.link.poll(min(self.MAX_WAIT_S, max(0.001, self.LEAD_WALL_S / 2)))
        finally:
            sender.stop()
        if sender.error is not None:
            raise sender.error

    def produce_for(self, sender: ProcessSender, capture: Capture) -> None:
        """One round of the paced loop with a sender process: take its reports, advance the
        firmware to LEAD_WALL_S ahead of the clock and hand each due time's output, encoded by
        the link into ``capture``, to the sender with its due time on the monotonic clock."""
        clock = self._paced()
        wall_at = getattr(clock, "wall_at", None)
        if wall_at is None:
            raise SimConfigError("a sender process needs a real-time clock (RealTimeClock)")
        with self.lock:
            self._take_reports(sender, clock)
            now = clock.now()
            late = now - self.firmware.next_output_s()
            if late > MAX_LAG_WALL_S * clock.speed and not clock.paused:
                self._slip(clock, late)  # the loop itself was held up: no backlog burst
                now -= late
            self.lag.behind_s = max(0.0, late)
            if clock.paused:
                return
            target = now + self.LEAD_WALL_S * clock.speed
            while True:
                dt = min(target - self.firmware.now, self.MAX_STEP_S)
                if round(dt * NS_PER_S) <= 0:
                    break  # within a nanosecond of the target: the firmware's clock resolution
                for due, group in itertools.groupby(self.firmware.process(dt), _time_of):
                    items = list(group)
                    capture.begin()
                    self.link.send(items)
                    chunks = capture.take()
                    if chunks:
                        sender.put(wall_at(due), chunks)
                    self.sent += len(items)
            self.firmware.prefetch()

    def _take_reports(self, sender: ProcessSender, clock: SimClock) -> None:
        """Apply what the sender process reported: its slips (the clock slips with it), the
        chunks the link did not take (counted as dropped), a link that failed (raised)."""
        for kind, value in sender.reports():
            if kind == sender_child.SLIP:
                self._slip(clock, value / NS_PER_S * clock.speed)
                sender.epoch += 1
            elif kind == sender_child.DROPPED:
                self.firmware.tx_dropped += value
            elif kind == sender_child.FAILED:
                raise SimError(
                    f"the sender process could not write to the link: {os.strerror(value)}"
                )
        if not sender.alive:
            code = sender.returncode
            how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit {code}"
            raise SimError(f"the sender process has ended ({how})")

    def _run_with_process(
        self, stop: threading.Event, sender: ProcessSender, capture: Capture
    ) -> None:
        try:
            while not stop.is_set():
                self.produce_for(sender, capture)
                self.link.poll(min(self.MAX_WAIT_S, max(0.001, self.LEAD_WALL_S / 2)))
        finally:
            sender.close()


class PacedSender:
    """Sends a paced runner's output at its due times, on its own thread.

    Items are (simulated due time, message) in time order, put by the runner's loop; the sender
    sleeps to each item's due time on the runner's clock (deadlines from the device's tick grid,
    not from the previous send), most of the gap in ``time.sleep`` and the last
    :attr:`SPIN_S` in a spin, and only sends. An item more than :data:`MAX_LAG_WALL_S` late
    (the process was stalled) slips the clock back to it (:meth:`Runner._slip`), so the stream
    goes on at its pace instead of bursting. ``sleep``, ``monotonic`` and ``spin`` are injectable for tests.
    """

    SPIN_S = 0.0005

    def __init__(
        self,
        runner: Runner,
        *,
        sleep: Callable[[float], None] = time.sleep,
        monotonic: Callable[[], float] = time.monotonic,
        spin: Callable[[], None] = lambda: None,
    ) -> None:
        self.runner = runner
        self._spin = spin
        self._sleep = sleep
        self._monotonic = monotonic
        self._items: deque[Outgoing] = deque()
        # Taken as itself in ``with`` statements, never through Condition.__enter__ (a raising
        # signal handler can leave a lock held there: driver/clock.py says how).
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="simulator-sender", daemon=True)
        self.error: BaseException | None = None

    @property
    def queued(self) -> int:
        return len(self._items)

    def put(self, outgoing: list[Outgoing]) -> None:
        with self._lock:
            self._items.extend(outgoing)
            self._cond.notify()

    def start(self) -> PacedSender:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        with self._lock:
            self._cond.notify()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._items.clear()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self.send_next()
        except BaseException as exc:  # reported to the runner's loop, which raises it
            self.error = exc

    def send_next(self, idle: float = 0.05) -> bool:
        """Wait for the next item's due time and send it and all others due with it."""
        with self._lock:
            if not self._items:
                self._cond.wait(idle)
                if not self._items:
                    return False
            first = self._items[0].time_s
        clock = self.runner._paced()
        while not self._stop.is_set():
            if clock.paused:
                self._sleep(0.005)
                continue
            wait = clock.wall_until(first)
            if wait <= 0:
                break
            if wait > self.SPIN_S:
                self._sleep(wait - self.SPIN_S)
            else:
                self._spin()  # the last moments: re-read the clock until due
        if self._stop.is_set():
            return False
        late = clock.now() - first
        if late > MAX_LAG_WALL_S * clock.speed:
            with self.runner.lock:
                self.runner._slip(clock, late)
        now = clock.now()
        with self._lock:
            due = []
            while self._items and self._items[0].time_s <= now:
                due.append(self._items.popleft())
        if due:
            self.runner.sent += len(due)
            self.runner.link.send(due)
        return bool(due)


class BackgroundRunner:
    """A runner on its own thread: ``with BackgroundRunner(runner): ...`` starts and stops it.

    Used to embed a simulated instrument in a host process (``northfinder find --sim``, tests).
    """

    def __init__(self, runner: Runner) -> None:
        self.runner = runner
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="simulator", daemon=True)
        self.error: BaseException | None = None

    def _run(self) -> None:
        try:
            self.runner.run(self._stop)
        except BaseException as exc:  # reported to the owner; a dead simulator must not be silent
            self.error = exc
            raise

    def start(self) -> BackgroundRunner:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    @property
    def alive(self) -> bool:
        """Whether the runner's thread runs (False before :meth:`start`, after :meth:`stop` or a
        failure, whose exception is :attr:`error`)."""
        return self._thread.is_alive()

    def __enter__(self) -> BackgroundRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
