"""Time for the driver: the wall clock, and a virtual clock shared with an in-process simulator.

Everything in :class:`~northfinder.driver.device.Device` that depends on time (reply timeouts,
link supervision, move and window deadlines, arrival stamps) reads one clock and waits on it. A
clock offers:

- ``now()``: monotonic seconds; ``wall()``: the stamp of an arrival (``Window.arrival_s``);
- ``wait_until(predicate, deadline)``: block until ``predicate()`` holds (True) or the clock
  reaches ``deadline`` (False); ``notify()`` tells waiters that something they may be waiting
  for has changed; ``sleep(seconds)``;
- ``participant()``: a context in which the calling thread counts as a party of the clock
  (used by the virtual clock to decide when every party waits);
- ``add_poller(fn)`` / ``remove_poller(fn)`` and ``virtual``: how a receiver gets its input
  (a reader thread on the wall clock; a poll at every instant on the virtual clock).

:class:`WallClock` is ``time.monotonic`` with a condition variable. :class:`VirtualClock` is a
small discrete-event kernel: time stands still while any party works and jumps, when every
party waits, straight to the next event (a message due from a simulator attached as a *source*,
or the earliest deadline of a waiter), as trio's autojump clock or an event simulator does. The
thread that waits drives it: it lets the sources act at the present instant, runs the pollers
(the hosts' receive paths), evaluates the waiters' predicates, and only when nothing is left to
do at the present moves time on. No thread runs freely, so the same inputs give the same frames
at the same virtual times whatever the machine's load.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol

__all__ = ["Clock", "Source", "VirtualClock", "WallClock", "ns_at_or_after"]

NS_PER_S = 1_000_000_000
#: Longest a thread waiting on a virtual clock sleeps before it looks again, wall seconds. A
#: safety net only: every change that matters notifies the waiters.
_RECHECK_S = 0.5


def ns_at_or_after(t: float) -> int:
    """The first whole nanosecond whose time in seconds (``ns / 1e9``) is at or after ``t``."""
    ns = math.ceil(t * NS_PER_S)
    while ns / NS_PER_S < t:
        ns += 1
    return ns


class Clock(Protocol):
    """What the driver needs from a clock (see the module docstring)."""

    @property
    def virtual(self) -> bool:
        """True when receivers must not block: the clock polls them (:meth:`add_poller`)."""
        ...

    def now(self) -> float: ...
    def wall(self) -> float: ...
    def notify(self) -> None: ...
    def wait_until(self, predicate: Callable[[], bool], deadline: float | None) -> bool: ...
    def sleep(self, seconds: float) -> None: ...
    def participant(self) -> contextlib.AbstractContextManager[None]: ...
    def add_poller(self, poll: Callable[[], bool]) -> None: ...
    def remove_poller(self, poll: Callable[[], bool]) -> None: ...


# The clocks take their lock, never their condition variable, in ``with`` statements: a signal
# handler that raises (Ctrl-C, SIGTERM: the command line's clean-up) runs at the return of a
# Python-level ``__enter__`` such as ``threading.Condition.__enter__``, after the lock was taken
# and before the ``with`` statement guards it, and the lock stays held for good (CPython issue
# 29988). Measured on vcan0: 3 of 120 runs of ``find`` sent SIGINT or SIGTERM during a move hung
# so, the reader thread in ``notify`` and the clean-up's request in ``wait_until``. A lock's own
# ``__enter__`` is C: taking it and the guard leave no gap for a handler.


class WallClock:
    """The wall clock (``time.monotonic``; arrivals stamped with ``time.time``).

    Waiters sleep on a condition variable that :meth:`notify` wakes; each :class:`Device` has its
    own by default. ``with`` statements take the condition's lock itself (see the note above).
    """

    virtual = False

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._cv = threading.Condition(self._lock)

    @staticmethod
    def now() -> float:
        return time.monotonic()

    @staticmethod
    def wall() -> float:
        return time.time()

    def notify(self) -> None:
        with self._lock:
            self._cv.notify_all()

    def wait_until(self, predicate: Callable[[], bool], deadline: float | None) -> bool:
        with self._lock:
            while not predicate():
                if deadline is None:
                    self._cv.wait()
                    continue
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cv.wait(left)
            return True

    @staticmethod
    def sleep(seconds: float) -> None:
        time.sleep(max(0.0, seconds))

    @staticmethod
    def participant() -> contextlib.AbstractContextManager[None]:
        return contextlib.nullcontext()

    def add_poller(self, poll: Callable[[], bool]) -> None:
        """Nothing to do: on the wall clock a receiver has its own thread."""

    def remove_poller(self, poll: Callable[[], bool]) -> None:
        """Nothing to do (see :meth:`add_poller`)."""


class Source(Protocol):
    """Something that acts by itself at known times: a simulated device on a virtual clock."""

    def next_event_s(self) -> float:
        """Clock time of the next thing it will do by itself (it is not called while it has
        something due at the present)."""
        ...

    def run_until(self, t: float) -> bool:
        """Take its input, act and send what is due up to clock time ``t``; return whether it
        took or sent anything."""
        ...


class _Waiter:
    __slots__ = ("deadline_ns", "predicate", "thread")

    def __init__(self, predicate: Callable[[], bool], deadline_ns: int | None) -> None:
        self.predicate = predicate
        self.deadline_ns = deadline_ns
        self.thread = threading.get_ident()


class VirtualClock:
    """Virtual time that jumps to the next event when every party waits.

    Parties: the sources (simulated devices, :meth:`add_source`), the pollers (hosts' receive
    paths, :meth:`add_poller`), the threads waiting in :meth:`wait_until` or :meth:`sleep`, and the
    threads inside :meth:`participant` (which count as working whenever they are not waiting).
    A waiting thread drives the clock, one at a time:

    1. the sources act at the present instant (take commands, send what is due now) and the
       pollers receive what was sent; repeated while anything happens;
    2. then, if every participant waits and no waiter's predicate holds, time moves to the
       earliest of the sources' next events and the waiters' deadlines.

    A party that gives a source or poller something to do (a host that sends a command on a
    link, a control request that changes a simulator) calls :meth:`notify` afterwards, so that
    it is taken at the present instant; so does leaving a :meth:`participant` block.

    Predicates are evaluated by whichever thread drives, with the clock's lock held: they must
    be quick, must not block and must not call the clock. A source or poller that raises is
    detached and its exception kept in :attr:`errors` (a simulator that fails falls silent, as a
    dead simulator thread does on the wall clock).

    Parameters
    ----------
    start_s : float
        The clock's time at creation, s.
    """

    virtual = True

    def __init__(self, start_s: float = 0.0) -> None:
        self._lock = threading.RLock()
        self._cv = threading.Condition(self._lock)
        self._ns = round(start_s * NS_PER_S)
        self._sources: list[Source] = []
        self._pollers: list[Callable[[], bool]] = []
        self._waiters: list[_Waiter] = []
        self._depth: dict[int, int] = {}
        self._driving = False
        self._dirty = True  # a party may have given a source or poller something to do
        self.errors: list[tuple[object, BaseException]] = []
        self.jumps = 0
        """How many times time moved on (a figure for benchmarks)."""

    # -- reading --------------------------------------------------------------------------------
    def now(self) -> float:
        return self._ns / NS_PER_S

    def now_ns(self) -> int:
        """Clock time in whole nanoseconds."""
        return self._ns

    def wall(self) -> float:
        """Arrival stamps on a virtual clock are its own seconds."""
        return self._ns / NS_PER_S

    # -- parties --------------------------------------------------------------------------------
    def add_source(self, source: Source) -> None:
        with self._lock:
            self._sources.append(source)
            self._dirty = True
            self._cv.notify_all()

    def remove_source(self, source: Source) -> None:
        with self._lock:
            if source in self._sources:
                self._sources.remove(source)
            self._cv.notify_all()

    def add_poller(self, poll: Callable[[], bool]) -> None:
        """Call ``poll()`` at every instant (it receives without blocking; True if it got any)."""
        with self._lock:
            self._pollers.append(poll)
            self._dirty = True
            self._cv.notify_all()

    def remove_poller(self, poll: Callable[[], bool]) -> None:
        with self._lock:
            if poll in self._pollers:
                self._pollers.remove(poll)
            self._cv.notify_all()

    @contextlib.contextmanager
    def participant(self) -> Iterator[None]:
        """The calling thread counts as working, except while it waits on this clock."""
        me = threading.get_ident()
        with self._lock:
            self._depth[me] = self._depth.get(me, 0) + 1
        try:
            yield
        finally:
            with self._lock:
                depth = self._depth[me] - 1
                if depth:
                    self._depth[me] = depth
                else:
                    del self._depth[me]
                self._dirty = True  # it may have sent something on its way out
                self._cv.notify_all()

    # -- waiting --------------------------------------------------------------------------------
    def notify(self) -> None:
        """Something changed (a host sent a command, a simulator's settings changed): the
        sources and pollers act at the present and the waiters look at their predicates again."""
        with self._lock:
            self._dirty = True
            self._cv.notify_all()

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of virtual time (letting everything due meanwhile happen)."""
        self.wait_until(lambda: False, self.now() + max(0.0, seconds))

    def wait_until(self, predicate: Callable[[], bool], deadline: float | None) -> bool:
        """Wait until ``predicate()`` holds (True) or the clock reaches ``deadline`` (False)."""
        deadline_ns = None if deadline is None else ns_at_or_after(deadline)
        me = _Waiter(predicate, deadline_ns)
        with self._lock:
            self._waiters.append(me)
            self._cv.notify_all()
            try:
                while True:
                    if predicate():
                        return True
                    if deadline_ns is not None and self._ns >= deadline_ns:
                        return False
                    if self._driving:
                        self._cv.wait(_RECHECK_S)
                        continue
                    self._driving = True
                    try:
                        moved = self._drive_while(me)
                    finally:
                        self._driving = False
                        self._cv.notify_all()
                    if not moved:
                        self._cv.wait(_RECHECK_S)
            finally:
                self._waiters.remove(me)
                self._cv.notify_all()

    # -- driving (the clock's lock held) -----------------------------------------------------------
    def _drive_while(self, me: _Waiter) -> bool:
        """Steps (:meth:`_drive`) while ``me`` is the only waiter, its predicate does not hold
        and its deadline is not reached: nobody else waits on the clock's condition (every
        thread that does is a waiter), so nobody is notified between the steps (the lock is
        held throughout, as between the turns of :meth:`wait_until`'s loop). False when the
        first step could not do anything."""
        if not self._drive(me):
            return False
        deadline_ns = me.deadline_ns
        while (
            len(self._waiters) == 1
            and not me.predicate()
            and (deadline_ns is None or self._ns < deadline_ns)
            and self._drive(me)
        ):
            pass
        return True

    def _drive(self, me: _Waiter) -> bool:
        """One step: act at the present, or move time on. False when nothing could happen."""
        if self._dirty and self._act_now():
            return True
        if not self._may_jump(me):
            return False
        target: int | None = None
        for w in self._waiters:
            if w.deadline_ns is not None and (target is None or w.deadline_ns < target):
                target = w.deadline_ns
        for source in list(self._sources):
            try:
                t_s = source.next_event_s()
                if math.isinf(t_s):
                    continue  # a paused source
                t = ns_at_or_after(t_s)
            except Exception as exc:  # a failing simulator must not take the host; Ctrl-C goes on
                self._detach(source, exc)
                continue
            if target is None or t < target:
                target = t
        if target is None:
            return False  # nothing will ever happen by itself: wait for another thread
        self._ns = max(target, self._ns + 1)
        self.jumps += 1
        self._act_now()
        return True

    def _act_now(self) -> bool:
        """Let the sources act and then the pollers receive at the present; True if any did.

        One round is enough: what the pollers receive gives the sources nothing to do (a host
        that sends in reply does so from its own code, and notifies). The pollers run when a
        source sent or took something, or a party notified: otherwise nothing can have arrived.
        """
        dirty, self._dirty = self._dirty, False
        done = False
        t = self._ns / NS_PER_S
        for source in list(self._sources):
            try:
                if source.run_until(t):
                    done = True
            except Exception as exc:
                self._detach(source, exc)
        if not (done or dirty):
            return False
        for poll in list(self._pollers):
            try:
                if poll():
                    done = True
            except Exception as exc:
                self._detach(poll, exc)
        return done

    def _may_jump(self, me: _Waiter) -> bool:
        """Every participant waits and no other waiter has something to do at the present."""
        if len(self._waiters) == 1:  # me alone: the participants are me or none
            depth = self._depth  # by thread, each once
            return not depth or (len(depth) == 1 and me.thread in depth)
        waiting = {w.thread for w in self._waiters}
        if any(thread not in waiting for thread in self._depth):
            return False
        for w in self._waiters:
            if w is me:
                continue
            if w.deadline_ns is not None and w.deadline_ns <= self._ns:
                return False
            try:
                if w.predicate():
                    return False
            except Exception:  # raised again in its own thread
                return False
        return True

    def _detach(self, party: object, exc: BaseException) -> None:
        self.errors.append((party, exc))
        if party in self._sources:
            self._sources.remove(party)
        if party in self._pollers:
            self._pollers.remove(party)
