"""What the monitor knows about a unit, read from the frames of its link alone.

:class:`LinkObserver` takes every CAN frame the link carries, both ways (the driver's ``tap`` of
an active session, or every frame of a bus watched passively), stamped by the session's clock,
and decodes them with the protocol's own receiver (:class:`~northfinder.driver.protocol.can.CanReceiver`):
statuses, identify, samples, tick losses, commands and their replies. A serial link taps the CAN
frames of the same messages, so one decoder serves every link.

Taking a frame (:meth:`LinkObserver.tap`) only appends it to a queue: it runs in the link's
reader thread, which must never wait for the screen. The screen's thread decodes what came
(:meth:`LinkObserver.drain`) a few times a second and reads a :class:`View`. Nothing here reads
the wall clock: times are the session clock's (virtual in tests), so a view is the same for the
same frames.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from northfinder.driver.protocol.can import CanReceiver, TickLoss
from northfinder.driver.protocol.constants import (
    HEARTBEAT_PERIOD_DEFAULT_MS,
    ConfigKey,
    DeviceState,
    Fault,
    Opcode,
    Result,
)
from northfinder.driver.protocol.messages import (
    Command,
    Home,
    Identify,
    Reply,
    RotateBy,
    RotateTo,
    Sample,
    SetConfig,
    Spin,
    Status,
)
from northfinder.driver.window import CountScales

__all__ = [
    "LATE_AFTER_S",
    "TRACE_SECONDS",
    "FrameRow",
    "LinkObserver",
    "LogEntry",
    "Traces",
    "View",
]

#: Seconds of samples the traces hold.
TRACE_SECONDS = 10.0
#: Highest sample rate the trace buffer is sized for, Hz (the protocol's rates stay below it).
TRACE_MAX_RATE_HZ = 1000
#: A sample counts as late when it is read this much later than its tick's time, s (the tick's
#: time: its counter over the rate, placed by the earliest arrival of the stream). A link that
#: carries samples in batches (an SLCAN adapter, a busy host) delays them by up to a batch.
LATE_AFTER_S = 0.25
#: Lines the command log keeps.
LOG_LINES = 500
#: How many heartbeat periods without a status make the link silent (protocol.md 6)...
SILENT_AFTER_PERIODS = 3
#: ...and not less than this, s, by default: on a busy host a status is often read a few tenths
#: of a second late, and a screen that flickers SILENT says nothing.
SILENT_AFTER_S = 1.0
#: The table's rate is measured over the statuses of about this span, s (ten heartbeats).
TABLE_RATE_SPAN_S = 1.0
#: The unit's pace (its seconds per second of the session's clock) is measured over the statuses
#: of about this span, s, once they span at least PACE_MIN_SPAN_S (a read late by a tenth of a
#: second then moves it by a few percent at most).
PACE_SPAN_S = 20.0
PACE_MIN_SPAN_S = 3.0


#: A frame's rate in the frame view is counted over the last this many seconds of arrivals.
FRAME_RATE_SPAN_S = 2.0


@dataclass(frozen=True)
class FrameRow:
    """One CAN id of the link as the frame view shows it (as ``cantools monitor`` does)."""

    arbitration_id: int
    is_extended_id: bool
    count: int
    rate_hz: float | None
    last_s: float
    data: bytes
    is_rx: bool


class _FrameStats:
    __slots__ = ("arrivals", "count", "data", "is_rx", "last_s")

    def __init__(self) -> None:
        self.count = 0
        self.last_s = 0.0
        self.data = b""
        self.is_rx = True
        # arrival times of the last frames: the rate over FRAME_RATE_SPAN_S (sized for 1 kHz)
        self.arrivals: deque[float] = deque(maxlen=4096)


@dataclass(frozen=True)
class _GaveUp:
    """The driver's verdict on a command, queued in order with the frames."""

    opcode: int


@dataclass(frozen=True)
class LogEntry:
    """One line of the command log: a command and its reply (at the reply's time, with the
    delay since the command), a command left without reply, or an event."""

    time_s: float
    text: str
    level: str = "info"  # "info", "ok", "refused", "warn", "error"


@dataclass(frozen=True)
class Traces:
    """The last seconds of samples, decimated to at most ``points`` rows for drawing.

    Times are seconds relative to the newest sample (<= 0); rates deg/h, specific force m/s^2.
    """

    time_s: np.ndarray
    gyro_dph: np.ndarray  # (n, 3)
    accel_mps2: np.ndarray  # (n, 3)
    mean_gyro_dph: tuple[float, float, float]
    mean_accel_mps2: tuple[float, float, float]
    sem_gyro_dph: tuple[float, float, float]
    seconds: float
    samples: int


@dataclass(frozen=True)
class View:
    """Everything a screen shows at one moment (see :meth:`LinkObserver.view`)."""

    now_s: float
    t0_s: float
    identity: Identify | None
    status: Status | None
    status_age_s: float | None
    silent: bool
    state: str
    angle_deg: float | None
    target_deg: float | None
    temperature_c: float | None
    faults: str
    table_rate_dps: float | None
    """The table's rate from the latest statuses while it turns (ROTATING, SPINNING,
    SETTLING), deg/s, positive counter-clockwise; None at rest or before two statuses."""
    spin_rate_dps: float | None
    """The rate the SPIN command seen on the link asked for while the unit spins (ROTATING
    up to the rate, SPINNING), deg/s; None otherwise."""
    sample_counter: int | None
    samples: int
    rate_hz: float | None
    configured_rate_hz: int | None
    streaming: bool
    gaps: int
    ticks_lost: int
    ticks_incomplete: int
    late: int
    commands: int
    replies: int
    refused: int
    unanswered: int
    device_rejected: int | None
    device_tx_dropped: int | None
    device_rx_malformed: int | None
    frames: int
    frames_unknown: int
    frames_malformed: int
    frames_other_node: int
    log: tuple[LogEntry, ...] = field(default=())


def _fault_text(faults: int) -> str:
    if not faults:
        return "none"
    return "|".join(f.name or "?" for f in Fault if faults & f)


class LinkObserver:
    """Decodes one unit's frames into the monitor's state.

    Parameters
    ----------
    clock : callable
        The session's clock, s (``device.clock.now``): stamps each frame as it is taken.
    node_id : int
        The unit's CAN node id (frames of other nodes are counted, not shown).
    trace_seconds : float
        Seconds of samples the traces hold.
    silent_after_s : float
        Least time without a status before the link is shown silent, s (it is never shown
        silent before three heartbeat periods, protocol.md 6).
    """

    def __init__(
        self,
        clock: Callable[[], float],
        node_id: int = 1,
        *,
        trace_seconds: float = TRACE_SECONDS,
        silent_after_s: float = SILENT_AFTER_S,
    ) -> None:
        self.clock = clock
        self.t0 = clock()
        self.node_id = node_id
        self.trace_seconds = float(trace_seconds)
        self.silent_after_s = float(silent_after_s)
        self._queue: deque[tuple[float, can.Message | _GaveUp]] = deque()
        self.receiver = CanReceiver(node_id=node_id)
        self.scales = CountScales()
        self.identity: Identify | None = None
        self.status: Status | None = None
        self.status_at: float | None = None
        self.heartbeat_s = HEARTBEAT_PERIOD_DEFAULT_MS / 1000.0
        self.configured_rate_hz: int | None = None
        self.target_deg: float | None = None
        self.spin_rate_dps: float | None = None
        # (unit time, table angle deg) of the latest statuses: the table's rate.
        self._angles: deque[tuple[float, float]] = deque(maxlen=64)
        self.streaming = False
        # The trace ring: counter, arrival time, gyro x/y/z, accel x/y/z (in counts).
        cap = int(TRACE_MAX_RATE_HZ * self.trace_seconds)
        self._ring = np.zeros((cap, 8), dtype=np.float64)
        self._ring_n = 0  # samples written in all
        self.samples = 0
        self.last_counter: int | None = None
        self.gaps = 0
        self.ticks_lost = 0
        self.ticks_incomplete = 0
        self.late = 0
        self._late_base: float | None = None  # earliest arrival - counter / rate of the stream
        self.commands = 0
        self.replies = 0
        self.refused = 0
        self.unanswered = 0
        self._pending: dict[int, tuple[float, Command]] = {}
        # Commands the driver stopped waiting for (their sequence numbers): a reply that comes
        # later is still theirs, said so, not a reply without a command.
        self._abandoned: set[int] = set()
        # (session clock, unit seconds from the status's sample counter) of the latest statuses:
        # the pace of the unit's time against the session's clock.
        self._unit_times: deque[tuple[float, float]] = deque(maxlen=256)
        self.log: deque[LogEntry] = deque(maxlen=LOG_LINES)
        self.last_frame_at: float | None = None
        self._frames: dict[tuple[int, bool], _FrameStats] = {}

    # -- taking frames (any thread) -----------------------------------------------------------
    def tap(self, msg: can.Message) -> None:
        """Take one frame (the link's reader thread, or a sending thread); never blocks."""
        self._queue.append((self.clock(), msg))

    def note(self, text: str, level: str = "info") -> None:
        """Put an event of the session in the log (any thread)."""
        self.log.append(LogEntry(self.clock(), text, level))

    def driver_gave_up(self, opcode: int) -> None:
        """The driver raised :class:`~northfinder.driver.errors.ReplyTimeout` for a command of
        ``opcode`` (any thread): the latest such command seen waits no more. The driver's
        judgement (its deadline, after a read that began once the deadline had passed) is the
        one the monitor keeps; a reply that comes later is shown as the late reply it is."""
        self._queue.append((self.clock(), _GaveUp(int(opcode))))

    # -- decoding (the screen's thread) -------------------------------------------------------
    def drain(self) -> int:
        """Decode every frame taken so far; return how many."""
        n = 0
        queue = self._queue
        feed = self.receiver.feed
        while queue:
            t, msg = queue.popleft()
            n += 1
            if isinstance(msg, _GaveUp):
                self._gave_up(msg.opcode)
                continue
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            self.last_frame_at = t
            key = (msg.arbitration_id, msg.is_extended_id)
            row = self._frames.get(key)
            if row is None:
                row = self._frames[key] = _FrameStats()
            row.count += 1
            row.last_s = t
            row.data = bytes(msg.data)
            row.is_rx = msg.is_rx
            row.arrivals.append(t)
            for item in feed(msg.arbitration_id, msg.data, is_extended_id=msg.is_extended_id):
                self._take(item, t)
        return n

    def _take(self, item: Any, t: float) -> None:
        if isinstance(item, Sample):
            self._sample(item, t)
        elif isinstance(item, TickLoss):
            if item.incomplete:
                self.ticks_incomplete += item.count
            else:
                self.gaps += 1
                self.ticks_lost += item.count
        elif isinstance(item, Status):
            self._status(item, t)
        elif isinstance(item, Command):
            self._command(item, t)
        elif isinstance(item, Reply):
            self._reply(item, t)
        elif isinstance(item, Identify):
            self.identity = item
            self.scales = CountScales.of(item)
            self.log.append(
                LogEntry(t, f"IDENTIFY {item.model} #{item.serial_number} "
                         f"fw {'.'.join(map(str, item.firmware_version))}")
            )  # fmt: skip

    def _sample(self, s: Sample, t: float) -> None:
        ring = self._ring
        i = self._ring_n % len(ring)
        ring[i, 0] = s.counter
        ring[i, 1] = t
        ring[i, 2:5] = s.gyro
        ring[i, 5:8] = s.accel
        self._ring_n += 1
        self.samples += 1
        self.last_counter = s.counter
        self.streaming = True
        rate = self.configured_rate_hz
        if rate:
            offset = t - s.counter / rate
            if self._late_base is None or offset < self._late_base:
                self._late_base = offset
            elif offset - self._late_base > LATE_AFTER_S:
                self.late += 1

    def _status(self, st: Status, t: float) -> None:
        previous = self.status
        self.status, self.status_at = st, t
        # The unit's own time where the sample rate is known (the counter in the status counts
        # its ticks whether it streams or not): arrival times carry the link's jitter.
        rate = self.configured_rate_hz
        when = st.sample_counter / rate if rate else t
        if self._angles and not when > self._angles[-1][0]:
            self._angles.clear()  # a restart, or the time base changed
        if rate:
            if self._unit_times and not when > self._unit_times[-1][1]:
                self._unit_times.clear()
            self._unit_times.append((t, when))
        self._angles.append((when, st.angle * self.scales.angle_deg))
        if st.state not in (DeviceState.ROTATING, DeviceState.SPINNING):
            self.spin_rate_dps = None
        if previous is not None and previous.state != st.state:
            level = "error" if st.state == DeviceState.FAULT else "info"
            text = f"state {previous.state.name} -> {st.state.name}"
            if st.state == DeviceState.FAULT:
                text += f" (faults {_fault_text(int(st.faults))})"
            self.log.append(LogEntry(t, text, level))
            if st.state == DeviceState.BOOT:
                self._restart_stream()
        if st.state not in (DeviceState.ROTATING, DeviceState.SETTLING):
            if st.state != DeviceState.READY or previous is None or previous.state in (
                DeviceState.ROTATING, DeviceState.SETTLING,
            ):  # fmt: skip
                self.target_deg = None

    def _gave_up(self, opcode: int) -> None:
        waiting = [
            (t0, seq)
            for seq, (t0, c) in self._pending.items()
            if c.opcode == opcode and seq not in self._abandoned
        ]
        if waiting:
            self._abandoned.add(max(waiting)[1])
        self.unanswered += 1

    def _restart_stream(self) -> None:
        self.streaming = False
        self._late_base = None
        self.receiver.ticks.restart()

    def _command(self, c: Command, t: float) -> None:
        self.commands += 1
        self._pending[c.seq] = (t, c)
        self._abandoned.discard(c.seq)
        # Commands the host sends while streaming (status polls) would flood the log: shown are
        # those that change something.
        sc = self.scales.angle_deg
        angle = self.status.angle * sc if self.status is not None else 0.0
        if isinstance(c, RotateTo):
            self.target_deg = (c.angle * sc) % 360.0
        elif isinstance(c, RotateBy):
            self.target_deg = (angle + c.delta * sc) % 360.0
        elif isinstance(c, Home):
            self.target_deg = 0.0
        elif isinstance(c, Spin):
            self.spin_rate_dps = c.rate * 1e-3
        if c.opcode in (Opcode.STREAM_START, Opcode.STREAM_STOP) or (
            isinstance(c, SetConfig) and c.key == ConfigKey.STREAMING
        ):
            self._restart_stream()
        if len(self._pending) > 64:  # replies never seen: keep the table small
            oldest = min(self._pending, key=lambda k: self._pending[k][0])
            self._pending.pop(oldest)
            if oldest in self._abandoned:
                self._abandoned.discard(oldest)  # counted when the driver gave up
            else:
                self.unanswered += 1

    def _reply(self, r: Reply, t: float) -> None:
        self.replies += 1
        sent = self._pending.pop(r.seq, None)
        name = r.opcode.name if isinstance(r.opcode, Opcode) else f"opcode {r.opcode}"
        ok = r.result == Result.OK
        if not ok:
            self.refused += 1
        result = r.result.name if isinstance(r.result, Result) else f"result {r.result}"
        if sent is None or sent[1].opcode != r.opcode:
            self.log.append(LogEntry(t, f"{name} -> {result} (no command seen)", "warn"))
            return
        t0, c = sent
        if ok:
            self._config_reply(c, r)
        if r.seq in self._abandoned:
            self._abandoned.discard(r.seq)
            done = "carried out" if ok else "refused"
            self.log.append(
                LogEntry(t, f"{_command_text(c, self.scales)} -> {result} in "
                         f"{1000.0 * (t - t0):.1f} ms, after the driver had stopped waiting "
                         f"(it was {done})", "warn")
            )  # fmt: skip
            return
        if not ok or c.opcode not in (Opcode.GET_STATUS, Opcode.GET_CONFIG):
            self.log.append(
                LogEntry(t, f"{_command_text(c, self.scales)} -> {result} "
                         f"in {1000.0 * (t - t0):.1f} ms", "ok" if ok else "refused")
            )  # fmt: skip

    def _config_reply(self, c: Command, r: Reply) -> None:
        if c.opcode not in (Opcode.GET_CONFIG, Opcode.SET_CONFIG):
            if c.opcode == Opcode.STREAM_START:
                self.streaming = True
            elif c.opcode in (Opcode.STREAM_STOP, Opcode.RESET):
                self.streaming = False
            return
        try:
            key, value = r.config_value()
        except Exception:  # a reply without its data: counted by the receiver, nothing to keep
            return
        if key == ConfigKey.SAMPLE_RATE_HZ:
            self.configured_rate_hz = int(value)
            self._late_base = None
            self._angles.clear()
            self._unit_times.clear()
        elif key == ConfigKey.HEARTBEAT_PERIOD_MS and value > 0:
            self.heartbeat_s = value / 1000.0
        elif key == ConfigKey.STREAMING:
            self.streaming = bool(value)

    def expire(self, timeout_s: float) -> None:
        """Count commands whose reply did not come within ``timeout_s`` as unanswered."""
        now = self.clock()
        for seq, (t0, c) in list(self._pending.items()):
            if now - t0 > timeout_s:
                del self._pending[seq]
                self.unanswered += 1
                self.log.append(
                    LogEntry(t0, f"{_command_text(c, self.scales)} -> no reply", "warn")
                )

    # -- reading ------------------------------------------------------------------------------
    def table_rate_dps(self) -> float | None:
        """The table's rate over the statuses of the last :data:`TABLE_RATE_SPAN_S` (at least
        the last two), their angles unwrapped step by step, deg/s; None with fewer than two."""
        pts = list(self._angles)
        if len(pts) < 2:
            return None
        t_end = pts[-1][0]
        first = len(pts) - 2
        while first > 0 and t_end - pts[first - 1][0] <= TABLE_RATE_SPAN_S:
            first -= 1
        turned = sum(
            (b[1] - a[1] + 180.0) % 360.0 - 180.0
            for a, b in zip(pts[first:-1], pts[first + 1 :], strict=True)
        )
        return turned / (t_end - pts[first][0])

    def frame_rows(self) -> list[FrameRow]:
        """One row per CAN id seen on the link (both ways), by id: its frame count, its rate
        over the last :data:`FRAME_RATE_SPAN_S` of arrivals, when it was last seen and its last
        data (call :meth:`drain` first)."""
        now = self.clock()
        rows = []
        for (cid, ext), st in sorted(self._frames.items()):
            recent = 0
            for a in reversed(st.arrivals):  # newest first: only the recent ones are read
                if a < now - FRAME_RATE_SPAN_S:
                    break
                recent += 1
            rate = recent / FRAME_RATE_SPAN_S if recent else None
            rows.append(FrameRow(cid, ext, st.count, rate, st.last_s, st.data, st.is_rx))
        return rows

    def unit_seconds(self) -> float | None:
        """The unit's time at its latest status, s since it started (its sample counter over
        the configured rate); None before both are known."""
        st, rate = self.status, self.configured_rate_hz
        return None if st is None or not rate else st.sample_counter / rate

    def pace(self) -> float | None:
        """The unit's seconds per second of the session's clock, measured over the statuses of
        the last :data:`PACE_SPAN_S` (1 for a unit; the speed of a paced simulator); None until
        they span :data:`PACE_MIN_SPAN_S`."""
        pts = self._unit_times
        if len(pts) < 2:
            return None
        t_end, u_end = pts[-1]
        first = next((p for p in pts if t_end - p[0] <= PACE_SPAN_S), pts[0])
        dt = t_end - first[0]
        if dt < PACE_MIN_SPAN_S:
            return None
        return (u_end - first[1]) / dt

    def rate_hz(self) -> float | None:
        """Samples per second of the stream over the last two seconds of arrivals (None: fewer
        than two samples in that time, or the stream is off)."""
        rows = self._rows()
        if len(rows) < 2:
            return None
        t_last = rows[-1, 1]
        recent = rows[rows[:, 1] >= t_last - 2.0]
        if len(recent) < 2:
            return None
        span = recent[-1, 0] - recent[0, 0]
        dt = recent[-1, 1] - recent[0, 1]
        if dt <= 0:
            return float(self.configured_rate_hz) if self.configured_rate_hz else None
        # Ticks per second of arrival time, over the samples that came: a rate the sender
        # keeps, not the rate of a burst of samples read together.
        return float(span / dt) if span > 0 else None

    def _rows(self) -> np.ndarray:
        cap = len(self._ring)
        n = self._ring_n
        if n <= cap:
            return self._ring[:n]
        i = n % cap
        return np.concatenate((self._ring[i:], self._ring[:i]))

    def traces(self, points: int = 200) -> Traces | None:
        """The last :attr:`trace_seconds` of samples, block-averaged to at most ``points`` rows
        (a mean keeps the signal a plot shows; a stride would alias vibration)."""
        rows = self._rows()
        if not len(rows):
            return None
        rate = self.configured_rate_hz or self.rate_hz() or 0.0
        last = rows[-1, 0]
        span = self.trace_seconds * rate if rate else len(rows)
        rows = rows[rows[:, 0] > last - span]
        n = len(rows)
        gyro = rows[:, 2:5] * self.scales.gyro_dph
        accel = rows[:, 5:8] * self.scales.accel_mps2
        times = (rows[:, 0] - last) / rate if rate else np.arange(-n + 1, 1, dtype=np.float64)
        mean_g = gyro.mean(axis=0)
        sem_g = gyro.std(axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.full(3, math.nan)
        block = max(1, math.ceil(n / points))
        m = n // block
        if block > 1 and m:
            cut = n - m * block  # the oldest samples that do not fill a block
            times = times[cut:].reshape(m, block).mean(axis=1)
            gyro_d = gyro[cut:].reshape(m, block, 3).mean(axis=1)
            accel_d = accel[cut:].reshape(m, block, 3).mean(axis=1)
        else:
            gyro_d, accel_d = gyro, accel
        return Traces(
            time_s=times,
            gyro_dph=gyro_d,
            accel_mps2=accel_d,
            mean_gyro_dph=tuple(float(v) for v in mean_g),  # type: ignore[arg-type]
            mean_accel_mps2=tuple(float(v) for v in accel.mean(axis=0)),  # type: ignore[arg-type]
            sem_gyro_dph=tuple(float(v) for v in sem_g),  # type: ignore[arg-type]
            seconds=float(n / rate) if rate else 0.0,
            samples=n,
        )

    def view(self, log_lines: int = 200) -> View:
        """The state now (call :meth:`drain` first)."""
        now = self.clock()
        st = self.status
        sc = self.scales
        age = None if self.status_at is None else max(0.0, now - self.status_at)
        silent = age is None or age > max(
            SILENT_AFTER_PERIODS * self.heartbeat_s, self.silent_after_s
        )
        moving = st is not None and st.state in (DeviceState.ROTATING, DeviceState.SETTLING)
        turning = st is not None and st.state in (
            DeviceState.ROTATING, DeviceState.SPINNING, DeviceState.SETTLING,
        )  # fmt: skip
        return View(
            now_s=now,
            t0_s=self.t0,
            identity=self.identity,
            status=st,
            status_age_s=age,
            silent=silent,
            state="no status" if st is None else st.state.name,
            angle_deg=None if st is None else st.angle * sc.angle_deg,
            target_deg=self.target_deg if moving else None,
            temperature_c=None if st is None else sc.temperature(st.temperature),
            faults="" if st is None else _fault_text(int(st.faults)),
            table_rate_dps=self.table_rate_dps() if turning else None,
            spin_rate_dps=self.spin_rate_dps,
            sample_counter=self.last_counter if st is None else st.sample_counter,
            samples=self.samples,
            rate_hz=self.rate_hz() if self.streaming else None,
            configured_rate_hz=self.configured_rate_hz,
            streaming=self.streaming,
            gaps=self.gaps,
            ticks_lost=self.ticks_lost,
            ticks_incomplete=self.ticks_incomplete,
            late=self.late,
            commands=self.commands,
            replies=self.replies,
            refused=self.refused,
            unanswered=self.unanswered,
            device_rejected=None if st is None else st.cmd_rejected,
            device_tx_dropped=None if st is None else st.tx_dropped,
            device_rx_malformed=None if st is None else st.rx_malformed,
            frames=self.receiver.frames,
            frames_unknown=self.receiver.unknown_id,
            frames_malformed=self.receiver.malformed,
            frames_other_node=self.receiver.other_node,
            log=tuple(self.log)[-log_lines:],
        )

    def counters(self) -> dict[str, Any]:
        """The stream's and the link's counters, for a summary (JSON)."""
        v = self.view(log_lines=0)
        keep = (
            "samples", "gaps", "ticks_lost", "ticks_incomplete", "late", "commands", "replies",
            "refused", "unanswered", "frames", "frames_unknown", "frames_malformed",
            "frames_other_node", "sample_counter", "configured_rate_hz", "state",
        )  # fmt: skip
        return {k: getattr(v, k) for k in keep} | {"rate_hz": v.rate_hz}


def _command_text(c: Command, scales: CountScales) -> str:
    """A command as a bench user reads it (``ROTATE_TO 90.000 deg``)."""
    name = c.opcode.name
    if isinstance(c, RotateTo):
        return f"{name} {c.angle * scales.angle_deg:.3f} deg"
    if isinstance(c, RotateBy):
        return f"{name} {c.delta * scales.angle_deg:+.3f} deg"
    if isinstance(c, Spin):
        return f"{name} {c.rate * 1e-3:+.3f} deg/s"
    if isinstance(c, SetConfig):
        key = c.key.name.lower() if isinstance(c.key, ConfigKey) else str(c.key)
        return f"{name} {key}={c.value}"
    fields = {f.name: getattr(c, f.name) for f in dataclasses.fields(c) if f.name != "seq"}
    if fields:
        return f"{name} " + " ".join(f"{k}={getattr(v, 'name', v)}" for k, v in fields.items())
    return name
