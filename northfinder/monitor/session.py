"""The monitor's link to a unit: active (a driver :class:`~northfinder.driver.device.Device`
that sends commands) or passive (a CAN bus only listened to), and a find run on it.

Neither knows about the screen. Each feeds a :class:`~northfinder.monitor.observer.LinkObserver`
with every frame of the link. An active session reopens its device in the background when the
link is lost (a port or bus that failed) and says so in the log; a passive one reopens its bus.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any

import can

from northfinder.driver.clock import Clock, WallClock
from northfinder.driver.device import Device
from northfinder.driver.errors import DriverError, LinkError, LinkLost, ReplyTimeout, StreamGap
from northfinder.driver.framelog import FrameLog
from northfinder.driver.protocol.constants import DeviceState
from northfinder.driver.transport import enlarge_receive_buffer
from northfinder.host.errors import HostError
from northfinder.host.heading import heading_text
from northfinder.host.plan import Plan
from northfinder.host.procedure import (
    MAX_REMEASURE,
    FindProgress,
    FindResult,
    PositionWindow,
    find_north,
)
from northfinder.monitor.observer import LinkObserver

__all__ = ["ActiveSession", "FindRun", "MonitorSession", "PassiveSession"]

#: Seconds between two attempts to reopen a lost link.
REOPEN_EVERY_S = 2.0

Tap = Callable[[can.Message], None]
#: Opens the unit with a tap and yields the device and the simulated truth (None for a unit).
DeviceOpener = Callable[[Tap], AbstractContextManager[tuple[Device, dict[str, Any] | None]]]


class MonitorSession:
    """What the screen needs of a link. See :class:`ActiveSession` and :class:`PassiveSession`."""

    passive = False
    observer: LinkObserver
    clock: Clock
    description: str = ""
    truth: dict[str, Any] | None = None
    latitude_deg: float | None = None

    def __init__(self) -> None:
        self._recorder: FrameLog | None = None
        self._record_lock = threading.Lock()
        self.record_path: str | None = None
        self.connected = False
        self.lost_reason: str | None = None

    def _tap(self, msg: can.Message) -> None:
        self.observer.tap(msg)
        rec = self._recorder
        if rec is not None:
            with self._record_lock:
                if self._recorder is not None:
                    self._recorder(msg)

    def poll(self) -> None:
        """Decode what came; watch the link (called by the screen a few times a second)."""
        self.observer.drain()

    def link_stats(self) -> dict[str, int] | None:
        """The driver's counters (:class:`~northfinder.driver.device_link.LinkStats`), None passively."""
        return None

    # -- recording ----------------------------------------------------------------------------
    def start_recording(self, path: str) -> None:
        """Write every frame of the link from now on to a CAN log (python-can's format for the
        file's ending; ``northfinder solve`` reads it back).

        Raises
        ------
        LinkError
            The file cannot be written, or its ending names no log format.
        """
        log = FrameLog(path)
        if self.clock.virtual:
            log.use_clock(self.clock)  # the log's times are the instrument's, not the CPU's
        # The lock only swaps the writer (the link's reader takes it for every frame): the
        # file is opened before and the previous log closed after, never while it is held.
        with self._record_lock:
            old, self._recorder = self._recorder, log
            self.record_path = path
        if old is not None:
            old.close()

    def stop_recording(self) -> str | None:
        """Close the CAN log; return its path (None if none was open).

        Raises
        ------
        LinkError
            A write failed: the log is incomplete (it is closed all the same).
        """
        with self._record_lock:
            log, self._recorder = self._recorder, None
            path, self.record_path = self.record_path, None
        if log is not None:
            log.close()
        return path

    def close(self) -> None:
        self.stop_recording()


class ActiveSession(MonitorSession):
    """A unit driven by this monitor through the driver.

    Parameters
    ----------
    opener : callable
        Called with the tap; a context manager that yields ``(device, truth)``. Called again
        to reopen a lost link.
    node_id : int
    description : str
        The link as the header names it.
    latitude_deg : float, optional
        The site's latitude (a find needs it; a simulated unit gives its own).
    trace_seconds : float
    stream : bool
        Start the unit's stream on opening (the traces need it).
    clock : Clock, optional
        The clock of the devices the opener yields (default the wall clock; a virtual clock
        in tests): it stamps every frame, also those of the opening.
    """

    def __init__(
        self,
        opener: DeviceOpener,
        *,
        node_id: int = 1,
        description: str = "",
        latitude_deg: float | None = None,
        trace_seconds: float = 10.0,
        stream: bool = True,
        clock: Clock | None = None,
    ) -> None:
        super().__init__()
        self._opener = opener
        self._stream = stream
        self._starter: threading.Thread | None = None
        self._next_stream_try = -math.inf
        self.description = description
        self._stack: contextlib.ExitStack | None = None
        self._reopening: threading.Thread | None = None
        self._next_reopen = 0.0
        self._lock = threading.Lock()
        self.device: Device | None = None
        self.find: FindRun | None = None
        self.clock = WallClock() if clock is None else clock
        self.observer = LinkObserver(self._now, node_id, trace_seconds=trace_seconds)
        try:
            self._open()
        except LinkError:
            raise  # the port or bus cannot be opened at all: the command's error
        except DriverError as exc:
            # The link opens but the unit does not answer: the screen says so and the
            # session keeps trying, as for a link lost later.
            self.lost_reason = f"the unit does not answer: {exc}"
            self.observer.note(self.lost_reason, "error")
            self._next_reopen = self.clock.now() + REOPEN_EVERY_S
        if latitude_deg is None and self.truth is not None:
            latitude_deg = self.truth.get("latitude_deg")
        self.latitude_deg = latitude_deg

    def _now(self) -> float:
        return self.clock.now()

    def _open(self) -> None:
        stack = contextlib.ExitStack()
        try:
            device, truth = stack.enter_context(self._opener(self._tap))
        except BaseException:
            stack.close()
            raise
        with self._lock:
            self._stack, self.device, self.truth = stack, device, truth
            self.connected, self.lost_reason = True, None

    def poll(self) -> None:
        super().poll()
        dev = self.device
        if dev is not None and dev.lost is not None and self.connected:
            self.connected = False
            self.lost_reason = str(dev.lost)
            self.observer.note(f"link lost: {dev.lost}", "error")
            self._next_reopen = self.clock.now()
        if not self.connected and self._reopening is None:
            if self.clock.now() >= self._next_reopen:
                self._reopening = threading.Thread(
                    target=self._reopen, name="northfinder-monitor-reopen", daemon=True
                )
                self._reopening.start()
        elif self._reopening is not None and not self._reopening.is_alive():
            self._reopening = None
        # A command's reply is waited for as the driver waits for it (its deadline judged after
        # a read that began once it had passed): no second deadline on this thread's clock,
        # which a busy host reads late. The driver's verdict comes with its ReplyTimeout
        # (:meth:`report`).
        if self.device is not None and self.connected:
            self._start_stream(self.device)

    def report(self, label: str, exc: Exception) -> None:
        """Put a failed device call in the log (one line), with the driver's verdict on a reply
        it stopped waiting for."""
        if isinstance(exc, ReplyTimeout):
            self.observer.driver_gave_up(exc.opcode)
        if isinstance(exc, (DriverError, HostError)):
            self.observer.note(f"{label}: {exc}", "error")
        else:  # never a traceback on the screen
            self.observer.note(f"{label}: internal error {exc!r}", "error")

    def _start_stream(self, device: Device) -> None:
        """Start the stream once the unit is READY, if asked (a unit refuses it while it
        warms up); in a thread, so that the screen never waits for the reply."""
        st = self.observer.status
        if not self._stream or device.streaming or st is None or st.state != DeviceState.READY:
            return
        if self.find is not None and not self.find.finished:
            return  # the find starts and stops the stream for its windows
        if self._starter is not None and self._starter.is_alive():
            return
        if self.clock.now() < self._next_stream_try:
            return
        self._next_stream_try = self.clock.now() + REOPEN_EVERY_S

        def start() -> None:
            try:
                device.start_streaming()
            except DriverError as exc:
                if isinstance(exc, ReplyTimeout):
                    self.observer.driver_gave_up(exc.opcode)
                self.observer.note(f"stream not started: {exc}", "warn")

        self._starter = threading.Thread(target=start, name="northfinder-monitor-stream")
        self._starter.daemon = True
        self._starter.start()

    def stream_on_ready(self, on: bool) -> None:
        """Whether the session starts the stream whenever the unit is READY and it is off."""
        self._stream = on

    def _reopen(self) -> None:
        with self._lock:
            stack, self._stack, self.device = self._stack, None, None
        if stack is not None:
            with contextlib.suppress(Exception):
                stack.close()
        try:
            self._open()
        except Exception as exc:
            self.lost_reason = str(exc)
            self._next_reopen = self.clock.now() + REOPEN_EVERY_S
        else:
            if self.latitude_deg is None and self.truth is not None:
                self.latitude_deg = self.truth.get("latitude_deg")
            self.observer.note("link back: the unit answers", "ok")

    def link_stats(self) -> dict[str, int] | None:
        dev = self.device
        return None if dev is None else dataclasses.asdict(dev.stats())

    def require(self) -> Device:
        """The device, or LinkLost while it is being reopened."""
        dev = self.device
        if dev is None or not self.connected:
            raise LinkLost(f"the link is lost ({self.lost_reason or 'reopening'})")
        return dev

    def close(self) -> None:
        super().close()
        with self._lock:
            stack, self._stack, self.device = self._stack, None, None
        if stack is not None:
            stack.close()


class PassiveSession(MonitorSession):
    """A CAN bus listened to: nothing is sent. The frames of another host's session with the
    unit (its commands, the unit's replies, statuses and samples) are decoded as they pass.

    Parameters
    ----------
    open_bus : callable
        Returns a new python-can bus (called again to reopen it after an error).
    clock : Clock, optional
        What stamps the frames (default the wall clock). With a virtual clock the bus is read at
        every instant of it (a poller) instead of by a thread, so that a test is deterministic.
    """

    passive = True

    def __init__(
        self,
        open_bus: Callable[[], can.BusABC],
        *,
        node_id: int = 1,
        description: str = "",
        clock: Clock | None = None,
        latitude_deg: float | None = None,
        trace_seconds: float = 10.0,
    ) -> None:
        super().__init__()
        self._open_bus = open_bus
        self.description = description
        self.clock = WallClock() if clock is None else clock
        self.latitude_deg = latitude_deg
        self.observer = LinkObserver(self.clock.now, node_id, trace_seconds=trace_seconds)
        self._stop = threading.Event()
        self.bus: can.BusABC | None = self._open()
        self.connected = True
        self._thread: threading.Thread | None = None
        if self.clock.virtual:
            self.clock.add_poller(self._poll_bus)
        else:
            self._thread = threading.Thread(
                target=self._read, name="northfinder-monitor-listen", daemon=True
            )
            self._thread.start()

    def _open(self) -> can.BusABC:
        bus = self._open_bus()
        # A SocketCAN socket's default buffer holds a fraction of a second of the stream: a
        # screen that stalls the reader that long would lose frames (the driver does the same).
        enlarge_receive_buffer(bus)
        return bus

    def _poll_bus(self) -> bool:
        got = False
        bus = self.bus
        while bus is not None:
            msg = bus.recv(0)
            if msg is None:
                break
            self._tap(msg)
            got = True
        return got

    def _read(self) -> None:
        while not self._stop.is_set():
            bus = self.bus
            try:
                if bus is None:
                    bus = self.bus = self._open()
                    self.connected, self.lost_reason = True, None
                    self.observer.note("bus back: listening again", "ok")
                msg = bus.recv(0.1)
                while msg is not None:
                    self._tap(msg)
                    msg = bus.recv(0)
            except (can.CanError, OSError, ValueError, DriverError, HostError) as exc:
                if self._stop.is_set():
                    return
                if self.connected:
                    self.connected, self.lost_reason = False, str(exc)
                    self.observer.note(f"bus lost: {exc}", "error")
                if bus is not None:
                    with contextlib.suppress(Exception):
                        bus.shutdown()
                self.bus = None
                self._stop.wait(REOPEN_EVERY_S)

    def close(self) -> None:
        super().close()
        self._stop.set()
        if self.clock.virtual:
            self.clock.remove_poller(self._poll_bus)
        if self._thread is not None:
            self._thread.join(2.0)
        bus, self.bus = self.bus, None
        if bus is not None:
            bus.shutdown()


@dataclass(frozen=True)
class Solution:
    """The heading from the windows measured so far."""

    windows: int
    azimuth_deg: float
    sigma_deg: float | None
    consistent: bool | None


@dataclass
class FindRun:
    """A find started from the monitor: its progress, each window, the solution as it forms.

    The worker thread writes; the screen reads (each attribute is replaced whole, never
    changed in place).
    """

    plan: Plan
    latitude_deg: float
    truth_deg: float | None = None
    on_gap: str = "remeasure"
    progress: FindProgress | None = None
    progress_at: float = 0.0
    """The session clock's time of :attr:`progress`."""
    gaps: tuple[str, ...] = ()
    """Each gap of a window (ticks lost) and what it cost, one line each."""
    windows: tuple[PositionWindow, ...] = ()
    solutions: tuple[Solution, ...] = ()
    result: FindResult | None = None
    error: str | None = None
    started_at: float = 0.0
    finished: bool = False
    notes: tuple[str, ...] = field(default=())
    _session: Any = field(default=None, repr=False)

    def run(self, session: ActiveSession) -> None:
        """Run the plan on the session's device (in a worker thread)."""
        device = session.require()
        clock = device.clock
        self._session = session
        self.started_at = clock.now()
        session.find = self
        session.observer.note(
            f"find: positions {', '.join(f'{p:g}' for p in self.plan.positions_deg)} deg, "
            f"{self.plan.window_s:g} s windows"
        )
        try:
            if device.streaming:
                # Each window then starts its own stream: a log of the run (w, --can-log)
                # holds every window from its STREAM_START, as northfinder solve reads it.
                device.release_stream()
            result, _ = find_north(
                _Watched(device, self),
                self.plan,
                self.latitude_deg,
                progress=self._progress,
                sleep=clock.sleep,
                clock=clock.now,
                latitude_source="monitor",
                on_gap=self.on_gap,
            )
        except (DriverError, HostError) as exc:
            self.error = str(exc)
            session.report("find failed", exc)
            raise
        finally:
            self.finished = True
        self.result = result
        sigma = "" if result.sigma_deg is None else f" +- {result.sigma_deg:.3f}"
        session.observer.note(
            f"find: azimuth {heading_text(result.azimuth_deg, 3)}{sigma} deg", "ok"
        )

    def _progress(self, p: FindProgress) -> None:
        self.progress_at = self._session.clock.now()
        self.progress = p

    def seconds_left(self, now: float, pace: float | None) -> float | None:
        """Seconds of the session's clock until the plan is done: what the procedure said was
        left of the plan's device time at its last step, less the unit's time since then (the
        session clock's time times ``pace``, the unit's seconds per second; 1 when not
        measured), over the pace. None while the procedure has not said (the warm-up)."""
        p = self.progress
        if p is None or p.seconds_left is None:
            return None
        pace = pace if pace and pace > 0 else 1.0
        return max(0.0, p.seconds_left / pace - (now - self.progress_at))

    def gap(self, window: int, attempt: int, exc: StreamGap, seconds: float) -> None:
        """A window lost ticks (``on_gap`` remeasure or fail): say which and what it cost."""
        first = exc.gaps[0][0] if exc.gaps else None
        where = "" if first is None else f" from counter {first}"
        what = f"window {window}: {exc.missing} tick(s) lost{where}"
        if self.on_gap == "remeasure" and attempt < MAX_REMEASURE:
            cost = f"measured again (attempt {attempt + 2}), {seconds:.1f} s lost"
            p = self.progress
            if p is not None and p.seconds_left is not None:
                # the time left counts the window measured again
                self.progress = dataclasses.replace(
                    p, seconds_left=p.seconds_left + self.plan.window_s
                )
        elif self.on_gap == "remeasure":
            cost = f"lost again after {MAX_REMEASURE} remeasures: the run stops"
        else:
            cost = "the run stops (on-gap fail)"
        self._gap_line(f"{what}; {cost}")

    def kept_gap(self, window: int, missing: int, gaps: tuple[tuple[int, int], ...]) -> None:
        """A window kept with ticks missing (``on_gap`` report)."""
        first = f" from counter {gaps[0][0]}" if gaps else ""
        self._gap_line(
            f"window {window}: {missing} tick(s) lost{first} in {len(gaps)} gap(s); kept "
            "and reported in the result (on-gap report)"
        )

    def _gap_line(self, text: str) -> None:
        self.gaps = (*self.gaps, text)
        self._session.observer.note(f"find: {text}", "warn")

    def window_done(self, summary: PositionWindow) -> None:
        """A window was measured: keep it and solve with the windows so far."""
        from northfinder.host.procedure import result_from_windows

        self.windows = (*self.windows, summary)
        k = len(self.windows)
        if k < 2:
            return
        partial = dataclasses.replace(self.plan, positions_deg=self.plan.positions_deg[:k])
        try:
            r = result_from_windows(self.windows, self.latitude_deg, partial)
        except HostError as exc:  # positions too close so far: no heading yet
            self.notes = (*self.notes, f"after {k} windows: {exc}")
            return
        self.solutions = (*self.solutions, Solution(k, r.azimuth_deg, r.sigma_deg, r.consistent))


class _Watched:
    """The device as :func:`~northfinder.host.procedure.find_north` uses it, telling the run of
    every window it acquires."""

    def __init__(self, device: Device, run: FindRun) -> None:
        self._device = device
        self._run = run
        self.clock = device.clock
        self._positions = iter(run.plan.positions_deg)
        self._window = 1
        self._attempt = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._device, name)

    def acquire(self, seconds: float, **options: Any) -> Any:
        from northfinder.host.procedure import summarise_window

        began = self.clock.now()
        try:
            window = self._device.acquire(seconds, **options)
        except StreamGap as exc:
            self._run.gap(self._window, self._attempt, exc, self.clock.now() - began)
            self._attempt += 1
            raise
        if getattr(window, "missing", 0):
            self._run.kept_gap(self._window, window.missing, tuple(window.gaps))
        self._window += 1
        self._attempt = 0
        target = next(self._positions, 0.0)
        plan = self._run.plan
        try:
            self._run.window_done(
                summarise_window(
                    window,
                    target,
                    plan.denoise,
                    dict(plan.denoise_options),
                    allow_gaps=self._run.on_gap == "report",
                )
            )
        except HostError:
            pass  # the procedure summarises it again and raises what is wrong
        return window
