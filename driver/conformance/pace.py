"""The host's own pace, measured beside the link, and the rule that says when a timing check that
failed is not judged.

A timing check judges the unit by when its messages arrive on the host. A host that cannot keep
pace (other processes holding the cores, a stalled scheduler) makes a correct unit look late or
slow: a heartbeat read late, a reply read late, a simulated unit on the same host that is itself
starved. So the suite measures the host in the same run, apart from the unit:

- a **timer loop**: a thread that wants to wake every :data:`PERIOD_S` and records each wake and
  how late it was (what the scheduler does to a thread that only wants to run on time, as a
  reader or a simulated unit does); a wake later than a period restarts its schedule, so the
  wakes it did not get are time it lost, as a simulated unit loses simulated time;
- the **reader's lateness**: how much longer than asked each receive on the link took (the suite's
  own thread not running when its data was there).

- the **scheduler's own figures** (Linux, ``/proc/.../schedstat``): how long the suite's reader
  thread waited on a run queue for a CPU, and, when the unit is a process on this host (a
  simulator: found by itself on a pseudo-terminal, or given by its pid), how long the unit's
  threads waited. A thread that sleeps 5 ms between wakes is favoured by the scheduler and keeps
  pace where a CPU-hungry reader or simulator does not: their own waits show what they suffered.

From these, for any interval of the run, :meth:`HostPace.during` gives the worst single lateness
(a stall) and the time lost: the timer loop's missing wakes times its period, and the reader's
latenesses beyond :data:`GRACE_S` summed; the larger counts.
:func:`excused` is the rule of ``docs/conformance.md``: a failed timing check is **not judged**
when the host lost, inside the interval the check judged, at least as much time as the unit is
late beyond its limit (a reply, a first sample, a move), or, for the checks over the observation
window (rate, period, jitter), when the host did not keep pace in the window (:data:`STALL_S`,
:data:`LOST_FRACTION`) while the unit's own counters show nothing wrong (the checks themselves
look at the counters first). Frames lost on the link are excused when the reader was further
behind the unit's stream than the link can hold (:data:`TTY_BUFFER_BYTES`) while the host did not
keep pace: a full buffer drops what comes next. A late reply (or sample, or move) is also
excused when the unit's messages came late by the unit's own clock (the sample counters of its
statuses and samples against their arrival: :meth:`~.session.Session.lag`) by as much as the
excess while the host did not keep pace: the reader was behind, or a unit on this host was
starved. On a virtual clock nothing is measured: the host always keeps pace.
"""

from __future__ import annotations

import bisect
import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from northfinder.driver.clock import Clock

__all__ = [
    "GRACE_S",
    "LOST_FRACTION",
    "PERIOD_S",
    "STALL_S",
    "TTY_BUFFER_BYTES",
    "WAIT_FRACTION",
    "HostPace",
    "PaceFigures",
    "excused",
    "process_tree",
    "pty_peer_pids",
]

PERIOD_S = 0.005
"""Period of the timer loop, wall s: the sample period of a unit at 200 Hz."""
STALL_S = 0.020
"""A wake (or a read) later than this is a stall: twice the heartbeat jitter the protocol allows
at the default period (10 % of 100 ms) would not fit in it. A quiet host wakes the loop within
1 to 5 ms (p99) and never this late."""
LOST_FRACTION = 0.02
"""A host that lost this share of a window (or more) did not keep pace in it: twice the default
rate tolerance (1 %), the bias such a loss can put on a rate or period measured on arrival times.
A quiet host loses well under 1 %; with two CPU-bound processes on two cores the loop measured
50 % and more."""
TTY_BUFFER_BYTES = 4096
"""What a link to a unit holds at the least while its reader is away, bytes: the line discipline's
buffer of a Linux tty (``N_TTY_BUF_SIZE``), which a serial port, a USB adapter and a
pseudo-terminal all pass through (a pseudo-terminal holds 16 to 21 KB in all, measured: 0.9 to
1.2 s of the SLCAN stream at 200 Hz). A reader behind the stream by more than this may have let
the buffer fill, and a full buffer drops what the unit sends next; a reader behind by less cannot
have lost a frame that way."""
WAIT_FRACTION = 0.05
"""A thread that waited on a run queue this share of an interval (or more) was starved in it: the
suite's reader, or a unit that is a process on this host. A thread on a free core runs within
microseconds of waking (well under 1 %); with two CPU-bound processes and a third at nice 19
beside the suite on two cores (load 10 to 15) the SLCAN reader waited 71 to 77 % of a whole run
and a simulator at twice real time 43 to 58 %."""
SCHED_EVERY = 4
"""The timer loop reads the scheduler's figures every this many wakes (every 20 ms)."""
REFRESH_EVERY = 25
"""It asks again which processes and threads are the unit's every this many readings (0.5 s)."""
GRACE_S = 0.005
"""A read later than asked by less than this is not counted as lost: Python hands its interpreter
lock between threads every 5 ms (``sys.getswitchinterval``), so the suite's own threads delay each
other that much on any host."""


@dataclass(frozen=True)
class PaceFigures:
    """The host's pace over an interval, wall seconds.

    Attributes
    ----------
    seconds : float
        Length of the interval.
    wakes : int
        Wakes of the timer loop in it.
    timer_max_s, timer_lost_s : float
        The timer loop's worst lateness, and the wakes it missed times its period.
    reader_max_s, reader_lost_s : float
        The suite's reads of the link: the worst lateness, and the latenesses beyond
        :data:`GRACE_S` summed.

    reader_wait_s, unit_wait_s : float or None
        How long the suite's reader thread, and the most starved thread of a unit that is a
        process on this host, waited on a run queue for a CPU (the scheduler's own figures); None
        where not measured (no ``/proc``, a unit elsewhere).
    """

    seconds: float = 0.0
    wakes: int = 0
    timer_max_s: float = 0.0
    timer_lost_s: float = 0.0
    reader_max_s: float = 0.0
    reader_lost_s: float = 0.0
    reader_wait_s: float | None = None
    unit_wait_s: float | None = None

    @property
    def stall_s(self) -> float:
        """The worst single lateness, timer or reader."""
        return max(self.timer_max_s, self.reader_max_s)

    @property
    def lost_s(self) -> float:
        """Time lost: the larger of the timer's and the reader's sums (at most the interval: a
        read that began in it may end after it)."""
        return min(self.seconds, max(self.timer_lost_s, self.reader_lost_s))

    @property
    def lost_fraction(self) -> float:
        return self.lost_s / self.seconds if self.seconds > 0 else 0.0

    @property
    def wait_fraction(self) -> float:
        """The larger share of the interval the reader or a local unit waited for a CPU."""
        waits = [w for w in (self.reader_wait_s, self.unit_wait_s) if w is not None]
        return max(waits, default=0.0) / self.seconds if self.seconds > 0 else 0.0

    @property
    def kept_pace(self) -> bool:
        """No stall of :data:`STALL_S`, less than :data:`LOST_FRACTION` lost, and neither the
        reader nor a unit on this host waited :data:`WAIT_FRACTION` of the interval for a CPU."""
        return (
            self.stall_s < STALL_S
            and self.lost_fraction < LOST_FRACTION
            and self.wait_fraction < WAIT_FRACTION
        )

    def text(self) -> str:
        """``host lost 1.2 s of 3.0 s (40 %), worst stall 88 ms (timer loop, 412 wakes), reader
        late by 30 ms at most``."""
        return (
            f"host lost {self.lost_s:.2f} s of {self.seconds:.2f} s ({self.lost_fraction:.0%}), "
            f"worst stall {self.stall_s * 1e3:.0f} ms (timer loop: {self.wakes} wakes, "
            f"{self.timer_lost_s:.2f} s lost, worst {self.timer_max_s * 1e3:.0f} ms; reader: "
            f"{self.reader_lost_s:.2f} s lost, worst {self.reader_max_s * 1e3:.0f} ms)"
            + self._waits_text()
        )

    def _waits_text(self) -> str:
        parts = [
            f"{who} waited {w:.2f} s for a CPU ({w / self.seconds:.0%})"
            for who, w in (("the reader", self.reader_wait_s), ("the unit", self.unit_wait_s))
            if w is not None and self.seconds > 0
        ]
        return ", " + ", ".join(parts) if parts else ""


def excused(
    p: PaceFigures,
    excess_s: float | None,
    behind_s: float | None = None,
    lag_s: float | None = None,
    lag_pace: PaceFigures | None = None,
) -> bool:
    """Whether a timing failure judged over the interval of ``p`` is the host's doing.

    ``excess_s``: how late the unit was beyond its limit, wall s (a reply, a sample, a move); the
    host excuses it when it stood still, or lost in all, at least that long in the interval.
    None for a window check whose unit counters agreed: the host excuses it when it did not keep
    pace in the window.
    ``behind_s``: for frames lost on the link, how far the reader was behind the unit's stream when
    they went missing (by the unit's own sample counters), wall s; ``excess_s`` is then the time
    the link holds (:data:`TTY_BUFFER_BYTES` of the stream). The loss is excused when the
    reader was at least that far behind, whatever the host's figures over the interval: a reader
    behind by more than the link holds lost the frames itself (the link was full), and the
    scheduler's figures over a check's window can miss a stall of the reader's own.
    ``lag_s``: how late the unit's messages came in the interval by the unit's own clock (its
    sample counters against their arrival), wall s: a unit late by ``excess_s`` beyond its limit
    is excused when its messages all came that late while the host did not keep pace (the
    reader behind the link, or a unit on this host starved, as its own waits show). A unit that
    stalls on its own while the host keeps pace is not excused. ``lag_pace``: the host's pace
    over the span the lag was measured on (from before the interval: a reader starved then is
    still behind in it), by default ``p``.
    """
    if behind_s is not None:
        return excess_s is not None and behind_s >= excess_s
    if excess_s is None:
        return not p.kept_pace
    if p.stall_s >= excess_s or p.lost_s >= excess_s:
        return True
    return lag_s is not None and lag_s >= excess_s and not (lag_pace or p).kept_pace


def pty_peer_pids(path: str | os.PathLike[str]) -> tuple[int, ...]:
    """The processes on this host (other than this one) that hold the other end of the
    pseudo-terminal ``path`` (a unit simulated on this host), by the ``tty-index`` of their
    ``/dev/ptmx`` file descriptors (Linux); () for anything else or where they cannot be seen."""
    try:
        real = Path(path).resolve()
    except (OSError, RuntimeError):
        return ()
    if real.parent != Path("/dev/pts") or not real.name.isdigit():
        return ()
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            for fd in (proc / "fd").iterdir():
                if os.readlink(fd) not in ("/dev/ptmx", "/dev/pts/ptmx"):
                    continue
                info = (proc / "fdinfo" / fd.name).read_text()
                if f"tty-index:\t{real.name}\n" in info:
                    found.append(int(proc.name))
                    break
        except OSError:
            continue
    return tuple(found)


def process_tree(pid: int) -> tuple[int, ...]:
    """``pid`` and every process it started, and they started, still running (Linux:
    ``/proc/<pid>/task/<tid>/children``); ``(pid,)`` where they cannot be seen."""
    found, todo = [pid], [pid]
    while todo:
        parent = todo.pop()
        try:
            tids = os.listdir(f"/proc/{parent}/task")
        except OSError:
            continue
        for tid in tids:
            try:
                with open(f"/proc/{parent}/task/{tid}/children") as f:
                    kids = [int(k) for k in f.read().split()]
            except (OSError, ValueError):
                continue
            new = [k for k in kids if k not in found]
            found += new
            todo += new
    return tuple(found)


def _run_delay_s(path: str) -> float | None:
    """The run-queue wait of one thread so far, s (field 2 of its ``schedstat``), or None."""
    try:
        with open(path) as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


class _Series:
    """(time, lateness) records in time order, appended by one thread, read by another."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.late: list[float] = []
        self._lock = threading.Lock()

    def add(self, t: float, late: float) -> None:
        with self._lock:
            self.t.append(t)
            self.late.append(late)

    def between(self, t0: float, t1: float) -> list[float]:
        with self._lock:
            i, j = bisect.bisect_left(self.t, t0), bisect.bisect_right(self.t, t1)
            return self.late[i:j]

    def growth(self, t0: float, t1: float) -> float | None:
        """For a running total: how much it grew over ``[t0, t1]``, from the last record at or
        before ``t0`` (else the first after) to the first record at or after ``t1`` (else the
        last), at most the span between those records; None without two records."""
        with self._lock:
            if len(self.t) < 2:
                return None
            i = max(0, bisect.bisect_right(self.t, t0) - 1)
            j = min(len(self.t) - 1, bisect.bisect_left(self.t, t1))
            if j <= i:
                return None
            return min(self.late[j] - self.late[i], self.t[j] - self.t[i])


class HostPace:
    """A timer loop and the reader's lateness, recorded over a run (wall clock only).

    Parameters
    ----------
    clock : Clock
        The session's clock; on a virtual clock nothing runs and every interval kept pace.
    period_s : float
        Period of the timer loop, wall s.
    unit_pids : tuple of int, or a callable returning them
        Processes on this host that are the unit (a simulator): their threads' waits for a CPU
        are measured too. A callable is asked again every :data:`REFRESH_EVERY` readings of the
        scheduler's figures (processes that come and go: :func:`process_tree`).
    own_threads : callable, optional
        Returns native ids of threads of this process whose waits count as the unit's (a
        driver's reader thread), asked as ``unit_pids``.
    """

    def __init__(
        self,
        clock: Clock,
        period_s: float = PERIOD_S,
        unit_pids: tuple[int, ...] | Callable[[], Iterable[int]] = (),
        own_threads: Callable[[], Iterable[int]] | None = None,
    ) -> None:
        self.clock = clock
        self.period_s = period_s
        self.timer = _Series()
        self.reader = _Series()
        self._pids = unit_pids if callable(unit_pids) else None
        self._own_threads = own_threads
        self._tids: tuple[int, ...] = ()
        self._readings = 0
        self.unit_pids: tuple[int, ...] = () if callable(unit_pids) else tuple(unit_pids)
        """Processes on this host that are the unit (a simulator), whose waits for a CPU count."""
        self.reader_waits = _Series()
        """(time, the reader thread's run-queue wait so far): the scheduler's figures."""
        self.unit_waits: dict[int, _Series] = {}
        """Per thread of the unit: (time, its run-queue wait so far)."""
        self._reader_stat: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def measuring(self) -> bool:
        return self._thread is not None

    def start(self) -> HostPace:
        if self.clock.virtual or self._thread is not None:
            return self
        # The thread that starts the pace is the one that reads the link (the suite's).
        self._reader_stat = f"/proc/self/task/{threading.get_native_id()}/schedstat"
        self._sample_waits(self.clock.now())
        self._thread = threading.Thread(target=self._loop, name="host-pace", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)

    def __enter__(self) -> HostPace:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _loop(self) -> None:
        clock, period = self.clock, self.period_s
        due = clock.now() + period
        wakes = 0
        while not self._stop.is_set():
            left = due - clock.now()
            if left > 0:
                clock.sleep(left)
            now = clock.now()
            late = max(0.0, now - due)
            self.timer.add(now, late)
            wakes += 1
            if wakes % SCHED_EVERY == 0:
                self._sample_waits(now)
            # A wake later than a period starts the schedule again from now: the time lost is
            # counted once, not again at every wake that follows.
            due = (now if late > period else due) + period

    def _sample_waits(self, now: float) -> None:
        """Record the scheduler's figures: the reader's and each unit thread's wait so far."""
        if self._reader_stat is not None:
            w = _run_delay_s(self._reader_stat)
            if w is not None:
                self.reader_waits.add(now, w)
        if self._readings % REFRESH_EVERY == 0:
            if self._pids is not None:
                self.unit_pids = tuple(self._pids())
            if self._own_threads is not None:
                self._tids = tuple(self._own_threads())
        self._readings += 1
        for own in self._tids:
            w = _run_delay_s(f"/proc/self/task/{own}/schedstat")
            if w is not None:
                self.unit_waits.setdefault(own, _Series()).add(now, w)
        for pid in self.unit_pids:
            try:
                tids = os.listdir(f"/proc/{pid}/task")
            except OSError:
                continue
            for tid in tids:
                w = _run_delay_s(f"/proc/{pid}/task/{tid}/schedstat")
                if w is not None:
                    self.unit_waits.setdefault(int(tid), _Series()).add(now, w)

    def read(self, t: float, asked_s: float, took_s: float) -> None:
        """The suite's read of the link at ``t`` asked for ``asked_s`` and took ``took_s``."""
        if self.measuring and took_s > asked_s:
            self.reader.add(t, took_s - asked_s)

    def during(self, t0: float, t1: float) -> PaceFigures:
        """The figures of ``[t0, t1]`` (clock seconds)."""
        if not self.measuring or t1 <= t0:
            return PaceFigures(max(0.0, t1 - t0))
        timer = self.timer.between(t0, t1)
        reader = self.reader.between(t0, t1)
        # A copy: the timer thread adds the threads it sees first while this runs.
        waits = list(self.unit_waits.values())
        unit = [w for w in (s.growth(t0, t1) for s in waits) if w is not None]
        return PaceFigures(
            t1 - t0,
            len(timer),
            max(timer, default=0.0),
            max(0.0, (t1 - t0) - len(timer) * self.period_s),
            max(reader, default=0.0),
            sum(late - GRACE_S for late in reader if late > GRACE_S),
            _at_most(self.reader_waits.growth(t0, t1), t1 - t0),
            _at_most(max(unit, default=None), t1 - t0) if self.unit_waits else None,
        )


def _at_most(w: float | None, seconds: float) -> float | None:
    return None if w is None else min(w, seconds)
