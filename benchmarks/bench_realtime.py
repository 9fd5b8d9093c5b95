"""Real-time stream: a 200 Hz sample stream in real time over virtual CAN, a serial pty, an SLCAN
pty or SocketCAN.

Run: ``.venv/bin/python benchmarks/bench_realtime.py [--duration 600] [--window 10]
[--links can,serial,slcan] [--paced-sender] [--bare 120]``.

Links:

- ``can``: the simulated instrument (``Firmware`` + ``CanLink`` driven by a ``Runner`` with
  ``RealTimeClock(1.0)`` on a background thread) and the host :class:`northfinder.driver.device.Device` on the
  same python-can ``virtual`` channel, in this one process (they share its interpreter).
- ``serial``: ``northfinder sim --pty --warmup 0`` as a separate process, the host
  ``Device.open_serial(PATH, 115200)`` on the pty it prints (a pty has no baud rate: bytes move
  as fast as both processes read and write them).
- ``slcan``: ``northfinder sim --slcan-pty``, the host on python-can's ``slcan`` interface.
- ``socketcan``: ``northfinder sim -i socketcan -c vcan0`` and the host on the same interface
  (a kernel with vcan: ``scripts/hil --steps jitter`` runs it in the HIL's virtual machine).

With ``--paced-sender`` the simulators in processes of their own send from their sender process.

All: paper-rlg preset, default configuration (200 Hz, heartbeat 100 ms), stream started once by
the first window. The host collects consecutive ``acquire(window, on_gap="report")`` windows for
``duration`` wall seconds, exactly as a north-finding host would.

What is counted:

- Every sample the driver's reader thread receives is recorded (counter, ``time.time()``) by a
  thin wrapper around the driver's transport (the same instant the driver stamps
  ``Window.arrival_s``), including samples that arrive between two ``acquire`` calls, when the
  driver has no window to put them in.
- ``lost``: ticks between the first and the last counter received that the reader never got
  (lost on the link, dropped by the simulator, or rejected as corrupt). Target 0.
- ``in-window missing``: the sum of ``Window.missing`` (must agree with ``lost`` inside windows).
- ``between windows``: ticks that belong to no window because they arrived while no ``acquire``
  was waiting (received, so not lost; the driver hands them to nobody by design), and how many
  of those were lost.
- Jitter: for every two consecutive ticks (counter + 1) received, ``|dt_arrival - 5 ms|``; p50,
  p99, p99.9 and max over the whole run. Target p99 <= 2 ms. ``Window.arrival_s`` gives the
  same figures within windows (printed as a check).

The machine's 1-minute load average is sampled after every window (shared machine: the figures
depend on it).

References, each measured in the same run:

- A timer loop in a process of its own beside each link, for the same minutes (a thread sleeping
  to 5 ms deadlines): the machine's floor for one wake-up. Ratios are printed over the whole run
  and as the median over ``SLICE_S`` slices (the machine's tails come in bursts).
- Each link's **bare floor** (``--bare`` seconds after the link, with its own timer loop beside
  it): the same link carrying fixed samples, written at their deadlines by the simulator's sender
  process and read by a reader that does nothing else with the link's host library. No
  simulator, no protocol decoding, no ``Device``: what the link itself costs on this machine. A
  link has more wake-ups than a timer loop (the sender's, on a pty the kernel's worker that moves
  the bytes to the reader's side, the reader's), so the bare link's ratio to the timer loop is
  what any implementation of that link can reach, and the link over its bare floor is what the
  instrument and the driver add.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from northfinder.driver.device import Device
from northfinder.driver.errors import DriverError
from northfinder.driver.protocol.messages import Sample
from northfinder.driver.transport import CanTransport, Received, Transport

PERIOD_S = 0.005
TARGET_P99_S = 0.002
#: The SocketCAN interface of the ``socketcan`` link (``--channel``).
CHANNEL = "vcan0"
#: Whether a simulator in a process of its own sends from its sender process (``--paced-sender``).
SENDER = False
_U32 = 0xFFFFFFFF
ROOT = Path(__file__).resolve().parents[1]
#: Generous link timing so that a loaded machine shows up in the figures instead of aborting
#: the run (a stall of the stream is still measured as a long interval or as lost ticks).
DEVICE_OPTIONS: dict[str, Any] = {"reply_timeout": 1.0, "min_supervision_s": 3.0}


class Tap:
    """A transport that records the counter and arrival time of every sample it hands on."""

    def __init__(self, inner: Transport) -> None:
        self.inner = inner
        self.kind = inner.kind
        self.seen: list[tuple[int, float]] = []  # (counter, time.time()); one append per sample

    def recv(self, timeout: float) -> list[Received]:
        items = self.inner.recv(timeout)
        if items:
            wall = time.time()
            for item in items:
                if isinstance(item, Sample):
                    self.seen.append((item.counter, wall))
        return items

    def send(self, command: Any) -> None:
        self.inner.send(command)

    def restart_stream(self) -> Any:
        return self.inner.restart_stream()

    def counters(self) -> dict[str, int]:
        return self.inner.counters()

    def close(self) -> None:
        self.inner.close()


class SendTap:
    """A simulator link that records when each sample left the simulator (same-process links)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.sent: dict[int, float] = {}

    def poll(self, timeout: float) -> int:
        return self.inner.poll(timeout)

    def send(self, outgoing: list[Any]) -> None:
        self.inner.send(outgoing)
        wall = time.time()
        for item in outgoing:
            if isinstance(item.message, Sample):
                self.sent[item.message.counter] = wall


@dataclass
class RunResult:
    link: str
    wall_s: float = 0.0
    windows: list[Any] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    loads: list[float] = field(default_factory=list)
    counters: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    arrivals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stats: Any = None
    tx_dropped: int | None = None
    cpu_s: float | None = None
    sent: dict[int, float] | None = None


def unwrap(counters: list[int]) -> np.ndarray:
    c = np.asarray(counters, dtype=np.int64)
    if len(c) < 2:
        return c
    step = np.diff(c) & _U32
    step = np.where(step >= 1 << 31, step - (1 << 32), step)
    return np.concatenate(([c[0]], c[0] + np.cumsum(step)))


def collect(
    device: Device, tap: Tap, duration_s: float, window_s: float, result: RunResult
) -> None:
    t0 = time.monotonic()
    cpu0 = time.process_time()
    while time.monotonic() - t0 < duration_s:
        try:
            result.windows.append(device.acquire(window_s, on_gap="report"))
        except DriverError as exc:  # recorded and reported; the stream goes on
            result.errors.append(f"{type(exc).__name__}: {exc}")
        result.loads.append(os.getloadavg()[0])
    result.wall_s = time.monotonic() - t0
    result.cpu_s = time.process_time() - cpu0
    result.stats = device.stats()
    try:
        result.tx_dropped = device.status().tx_dropped
    except DriverError as exc:
        result.errors.append(f"final status: {exc}")
    seen = list(tap.seen)  # the reader thread goes on appending until the device is closed
    result.counters = unwrap([c for c, _ in seen])
    result.arrivals = np.array([w for _, w in seen], dtype=np.float64)


def run_can(duration_s: float, window_s: float, seed: int) -> RunResult:
    from northfinder.firmware_sim.adapters import CanLink
    from northfinder.firmware_sim.firmware import Firmware, LinkInfo
    from northfinder.firmware_sim.imu import Truth
    from northfinder.firmware_sim.runner import BackgroundRunner, RealTimeClock, Runner
    from northfinder.firmware_sim.sensors import load_spec

    result = RunResult("virtual CAN, one process")
    channel = f"bench-realtime-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as sim_bus:
        firmware = Firmware(
            load_spec("paper-rlg"),
            Truth(123.0, 34.0),
            np.random.default_rng(seed),
            warmup_s=0.0,
            link=LinkInfo("can", 500_000),
        )
        send_tap = SendTap(CanLink(sim_bus, firmware, 1))
        # The simulator's own loop: in one interpreter with the host it sends on time more
        # often than a thread beside it (BENCHMARKS.md section 4).
        runner = Runner(firmware, send_tap, RealTimeClock(1.0))
        tap = Tap(CanTransport(can.Bus(interface="virtual", channel=channel), 1, own_bus=True))
        with BackgroundRunner(runner) as background, Device(tap, **DEVICE_OPTIONS) as device:
            device.wait_ready(timeout=10.0)
            collect(device, tap, duration_s, window_s, result)
        if background.error is not None:
            result.errors.append(f"simulator: {background.error!r}")
    result.sent = send_tap.sent
    return result


def run_timer(duration_s: float) -> RunResult:
    """No link: a thread that sleeps to 5 ms deadlines, as the simulator's loop does; its wake-up
    times are the floor any link in Python on this machine can reach."""
    result = RunResult("timer loop, no link")
    stamps: list[float] = []
    n = round(duration_s / PERIOD_S)

    def loop() -> None:
        t0 = time.monotonic()
        for k in range(1, n + 1):
            time.sleep(max(0.0, t0 + k * PERIOD_S - time.monotonic()))
            stamps.append(time.time())

    t = threading.Thread(target=loop)
    t0 = time.monotonic()
    t.start()
    t.join()
    result.wall_s = time.monotonic() - t0
    result.loads.append(os.getloadavg()[0])
    result.counters = np.arange(len(stamps), dtype=np.int64)
    result.arrivals = np.asarray(stamps)
    return result


#: The timer loop of :func:`run_timer` as a process of its own, run beside a link for the same
#: wall time so that both see the same machine: a thread sleeping to 5 ms deadlines that prints
#: its wake-up times (``time.time()``).
_TIMER_SCRIPT = """
import sys, time
n = int(float(sys.argv[1]) / 0.005)
t0 = time.monotonic()
out = []
for k in range(1, n + 1):
    time.sleep(max(0.0, t0 + k * 0.005 - time.monotonic()))
    out.append(time.time())
sys.stdout.write("\\n".join(repr(x) for x in out))
"""


class TimerBeside:
    """A timer loop in a process of its own for ``duration_s`` wall seconds (a context)."""

    def __init__(self, duration_s: float) -> None:
        self.duration_s = duration_s
        self.result: RunResult | None = None

    def __enter__(self) -> TimerBeside:
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _TIMER_SCRIPT, str(self.duration_s)],
            stdout=subprocess.PIPE,
            text=True,
        )
        return self

    def __exit__(self, *exc: object) -> None:
        out, _ = self._proc.communicate(timeout=self.duration_s + 60)
        stamps = np.array([float(x) for x in out.split()])
        r = RunResult("timer loop beside it")
        r.wall_s = self.duration_s
        r.loads.append(os.getloadavg()[0])
        r.counters = np.arange(len(stamps), dtype=np.int64)
        r.arrivals = stamps
        self.result = r


def run_serial(duration_s: float, window_s: float, seed: int) -> RunResult:
    return run_pty("--pty", duration_s, window_s, seed)


def run_slcan(duration_s: float, window_s: float, seed: int) -> RunResult:
    return run_pty("--slcan-pty", duration_s, window_s, seed)


@contextmanager
def sim_process(*args: str, wait_for: str) -> Iterator[str]:
    """``northfinder sim ARGS --warmup 0`` (with ``--paced-sender`` if asked) as a process of its
    own; yields the first line it prints that starts with ``wait_for``; always stops it."""
    log = open(os.devnull, "wb")  # the simulator logs its state changes on stderr
    sim = subprocess.Popen(
        [
            *(str(ROOT / ".venv/bin/northfinder"), "sim", *args, "--warmup", "0"),
            *(["--paced-sender"] if SENDER else []),
        ],
        stdout=subprocess.PIPE,
        stderr=log,
        text=True,
        cwd=ROOT,
    )
    try:
        assert sim.stdout is not None
        line = next((x for x in sim.stdout if x.startswith(wait_for)), None)
        if line is None:
            raise RuntimeError(f"northfinder sim {' '.join(args)} did not print {wait_for!r}")
        # Keep reading the simulator's stdout so it never blocks on a full pipe.
        threading.Thread(target=sim.stdout.read, daemon=True).start()
        yield line
    finally:
        sim.terminate()
        try:
            sim.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()
        log.close()


def run_socketcan(duration_s: float, window_s: float, seed: int) -> RunResult:
    """``northfinder sim -i socketcan -c CHANNEL`` as a process of its own and the host on the
    same SocketCAN interface (``--channel``, default vcan0: a kernel with vcan, such as the HIL's
    virtual machine: ``scripts/hil --steps jitter``)."""
    result = RunResult(f"SocketCAN {CHANNEL}, two processes")
    args = ("-i", "socketcan", "-c", CHANNEL, "--seed", str(seed), "--azimuth", "123")
    with sim_process(*args, wait_for="truth "):
        bus = can.Bus(interface="socketcan", channel=CHANNEL)
        tap = Tap(CanTransport(bus, 1, own_bus=True))
        with Device(tap, **DEVICE_OPTIONS) as device:
            device.wait_ready(timeout=10.0)
            collect(device, tap, duration_s, window_s, result)
    return result


def run_pty(kind: str, duration_s: float, window_s: float, seed: int) -> RunResult:
    """``northfinder sim --pty`` (binary serial) or ``--slcan-pty`` (a CAN adapter's ASCII
    protocol: python-can's ``slcan`` interface on the host) as a process of its own."""
    from northfinder.driver.transport import SerialTransport, open_serial_port

    slcan = kind == "--slcan-pty"
    result = RunResult("SLCAN pty, two processes" if slcan else "serial pty, two processes")
    with sim_process(kind, "--seed", str(seed), "--azimuth", "123", wait_for="pty ") as line:
        path = line.split()[1]
        # Device.open_serial / a python-can slcan bus, with the transport wrapped by the tap.
        if slcan:
            bus = can.Bus(interface="slcan", channel=path, bitrate=500_000, sleep_after_open=0)
            tap = Tap(CanTransport(bus, 1, own_bus=True))
        else:
            tap = Tap(SerialTransport(open_serial_port(path, 115_200)))
        with Device(tap, **DEVICE_OPTIONS) as device:
            device.wait_ready(timeout=10.0)
            collect(device, tap, duration_s, window_s, result)
    return result


#: The sample every bare link carries (its wire form is what the simulator sends for a tick).
def _bare_sample(counter: int) -> Sample:
    from northfinder.driver.protocol.messages import Validity

    return Sample(counter & _U32, (1, -2, 3), (4, -5, 1_000_000), 7, 2500, Validity(0))


def _can_messages(counter: int) -> list[can.Message]:
    from northfinder.driver.protocol.can import encode_can

    return [
        can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False)
        for f in encode_can(_bare_sample(counter), 1)
    ]


class _Ticks:
    """Counters from the low 8 bits of the tick that each sample carries (a lost sample leaves a
    gap instead of shifting the ones after it)."""

    def __init__(self) -> None:
        self.counters: list[int] = []
        self.stamps: list[float] = []

    def add(self, low8: int, stamp: float) -> None:
        last = self.counters[-1] if self.counters else low8 - 1
        self.counters.append(last + ((low8 - last) & 0xFF or 0x100))
        self.stamps.append(stamp)


def run_bare(link: str, duration_s: float) -> RunResult:
    """The link's own floor: nothing but the wire bytes of a sample written at 5 ms deadlines and
    read by a reader that does nothing else, with the host library of the link.

    The writer is the simulator's sender process (``firmware_sim/sender_child.py``, sleep then spin,
    ``SCHED_FIFO`` where allowed) fed fixed samples; on virtual CAN, where only the one process
    can reach the bus, a thread of this process that sleeps and spins the same way. The reader:
    pyserial (serial), python-can ``slcan`` / ``socketcan`` / ``virtual`` (``recv`` in a loop),
    stamping ``time.time()`` when a sample's last byte or frame is in (its counter from the low
    8 bits of the tick it carries). No simulator, no protocol decoding, no :class:`Device`: what a
    link in Python costs on this machine before any of the instrument's work. It ends when all
    samples came or after 10 s without one (a guest may stall for seconds)."""
    n = round(duration_s / PERIOD_S)
    result = RunResult(f"bare {link}")
    ticks = _Ticks()
    with ExitStack() as stack:
        if link == "can":
            _bare_virtual_can(stack, n, ticks)
        else:
            _bare_process_sender(stack, link, n, ticks, result)
    result.counters = np.asarray(ticks.counters, dtype=np.int64)
    result.arrivals = np.asarray(ticks.stamps, dtype=np.float64)
    if len(ticks.stamps) < n:
        result.errors.append(f"{n - len(ticks.stamps)} of {n} samples did not come")
    return result


def _read_frames(bus: Any, n: int, ticks: _Ticks) -> None:
    """Stamp each sample's last frame as it is received, until ``n`` came or none for 10 s."""
    last_id = _can_messages(0)[-1].arbitration_id  # a sample's last frame
    while len(ticks.stamps) < n and (msg := bus.recv(10.0)) is not None:
        if msg.arbitration_id == last_id:
            ticks.add(msg.data[0], time.time())


def _bare_virtual_can(stack: ExitStack, n: int, ticks: _Ticks) -> None:
    """Virtual CAN: a thread of this process sends (only it can reach the bus), this one reads."""
    from northfinder.firmware_sim.sender_child import SPIN_S

    channel = f"bench-bare-{uuid.uuid4().hex}"
    tx = stack.enter_context(can.Bus(interface="virtual", channel=channel))
    rx = stack.enter_context(can.Bus(interface="virtual", channel=channel))
    stop = threading.Event()
    t_start = time.monotonic() + 0.5

    def send() -> None:
        for k in range(n):
            messages = _can_messages(k)
            due = t_start + k * PERIOD_S
            wait = due - time.monotonic() - SPIN_S
            if stop.is_set():
                return
            if wait > 0:
                time.sleep(wait)
            while time.monotonic() < due:
                pass
            for m in messages:
                tx.send(m)

    sending = threading.Thread(target=send, daemon=True)
    sending.start()
    stack.callback(sending.join)
    stack.callback(stop.set)
    _read_frames(rx, n, ticks)


def _bare_endpoints(
    stack: ExitStack, link: str
) -> tuple[Any, Any, int, Callable[[int], list[bytes]]]:
    """The reader's bus (or serial port), the descriptor the sender writes to, and the bytes of
    sample ``k`` as the sender writes them."""
    from northfinder.driver.protocol.serial import SerialEncoder
    from northfinder.driver.transport import open_serial_port
    from northfinder.firmware_sim.adapters import PseudoTerminal, slcan_line

    bus: Any = None
    port: Any = None
    if link == "socketcan":
        from can.interfaces.socketcan.socketcan import build_can_frame

        tx_bus: Any = stack.enter_context(can.Bus(interface="socketcan", channel=CHANNEL))
        bus = stack.enter_context(can.Bus(interface="socketcan", channel=CHANNEL))
        out_fd = tx_bus.socket.fileno()
        chunks = lambda k: [build_can_frame(m) for m in _can_messages(k)]  # noqa: E731
    else:
        pty = PseudoTerminal()
        stack.callback(pty.close)
        out_fd = pty.master
        if link == "slcan":
            chunks = lambda k: [b"".join(map(slcan_line, _can_messages(k)))]  # noqa: E731
            bus = stack.enter_context(
                can.Bus(interface="slcan", channel=pty.path, bitrate=500_000, sleep_after_open=0)
            )
        else:
            encoder = SerialEncoder()
            chunks = lambda k: [encoder.encode(_bare_sample(k))]  # noqa: E731
            port = open_serial_port(pty.path, 115_200)  # before any byte is written
            stack.callback(port.close)
    return bus, port, out_fd, chunks


def _bare_process_sender(
    stack: ExitStack, link: str, n: int, ticks: _Ticks, result: RunResult
) -> None:
    """The simulator's sender process writes fixed samples at their deadlines; this process reads."""
    from northfinder.firmware_sim.sender import ProcessSender
    from northfinder.firmware_sim.sender_child import DROPPED, FAILED, SLIP

    bus, port, out_fd, chunks = _bare_endpoints(stack, link)
    sender = ProcessSender(out_fd)
    stack.callback(sender.close)
    deadline = time.monotonic() + 30.0
    while sender.priority is None and sender.alive and time.monotonic() < deadline:
        sender.reports()  # its first report says it runs (a Python start: seconds in a VM)
        time.sleep(0.01)
    t_start = time.monotonic() + 0.5
    stop = threading.Event()

    def feed() -> None:
        """Blocks while the sender's pipe is full: it takes them as they fall due."""
        try:
            for k in range(n):
                if stop.is_set():
                    return
                sender.put(t_start + k * PERIOD_S, chunks(k))
        except Exception as exc:  # the sender ended: its samples do not arrive
            result.errors.append(f"feeding the sender: {exc}")

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    # Closed in this order: the feeder stops before the sender's pipe closes.
    stack.callback(feeder.join, 5.0)
    stack.callback(stop.set)
    if bus is not None:
        _read_frames(bus, n, ticks)
    else:
        _read_serial(port, n, ticks)
    for kind, value in sender.reports():
        if kind == SLIP:
            result.errors.append(f"the sender slipped {value / 1e6:.1f} ms")
        elif kind == DROPPED:
            result.errors.append(f"the sender dropped {value} chunks (link full)")
        elif kind == FAILED:
            result.errors.append(f"the sender failed (errno {value})")


def _read_serial(port: Any, n: int, ticks: _Ticks) -> None:
    """Stamp each sample as its last byte is read, until ``n`` came or none for 10 s."""
    from northfinder.driver.protocol.serial import HEADER_SIZE, SerialEncoder

    size = len(SerialEncoder().encode(_bare_sample(0)))
    buf = bytearray()
    port.timeout = 10.0
    while len(ticks.stamps) < n:
        data = port.read(1)
        if not data:
            break
        waiting = port.in_waiting
        buf += data + (port.read(waiting) if waiting else b"")
        stamp = time.time()
        while len(buf) >= size:
            ticks.add(buf[HEADER_SIZE], stamp)  # the payload's first byte: the tick's low 8 bits
            del buf[:size]


def jitter(arrivals: np.ndarray, counters: np.ndarray) -> np.ndarray:
    """|interval - period| of consecutive ticks, s."""
    if len(counters) < 2:
        return np.zeros(0)
    consecutive = np.diff(counters) == 1
    return np.abs(np.diff(arrivals)[consecutive] - PERIOD_S)


def chunk_phase_share(arrivals: np.ndarray, counters: np.ndarray) -> tuple[int, float]:
    """Late intervals (|dt - 5 ms| > 2 ms) and the share of them in the 3 busiest consecutive
    tick phases of the firmware's look-ahead chunk (LOOKAHEAD_S x 200 Hz ticks)."""
    from northfinder.firmware_sim.firmware import LOOKAHEAD_S

    chunk = round(LOOKAHEAD_S / PERIOD_S)
    if len(counters) < 2:
        return 0, float("nan")
    consecutive = np.diff(counters) == 1
    late = consecutive & (np.abs(np.diff(arrivals) - PERIOD_S) > TARGET_P99_S)
    n = int(late.sum())
    if not n:
        return 0, float("nan")
    hist = np.bincount(counters[1:][late] % chunk, minlength=chunk)
    busiest = max(hist[k] + hist[(k + 1) % chunk] + hist[(k + 2) % chunk] for k in range(chunk))
    return n, float(busiest / n)


def summarise(r: RunResult) -> dict[str, Any]:
    c = r.counters
    uniq = np.unique(c)
    span = int(c[-1] - c[0] + 1) if len(c) else 0
    lost = span - len(uniq)
    in_window = sum(len(w) for w in r.windows)
    win_missing = sum(w.missing for w in r.windows)
    # Ticks between one window's last and the next window's first counter.
    between = between_lost = 0
    received = set(uniq.tolist())
    for a, b in zip(r.windows, r.windows[1:], strict=False):
        if len(a) and len(b):
            lo, hi = int(a.counter[-1]) + 1, int(b.counter[0])
            between += max(0, hi - lo)
            between_lost += sum(1 for k in range(lo, hi) if k not in received)
    j = jitter(r.arrivals, c)
    jw = np.concatenate([jitter(w.arrival_s, w.counter) for w in r.windows] or [np.zeros(0)])
    pct = lambda a, q: float(np.percentile(a, q)) * 1e3 if len(a) else float("nan")  # noqa: E731
    sent_p99 = latency_p50 = latency_p99 = float("nan")
    sent_late = (0, float("nan"))
    if r.sent:
        sc = np.array(sorted(r.sent), dtype=np.int64)
        st = np.array([r.sent[k] for k in sc])
        sent_p99 = pct(jitter(st, sc), 99)
        sent_late = chunk_phase_share(st, sc)
        raw = np.asarray(r.counters) & _U32
        have = np.array([k in r.sent for k in raw.tolist()])
        lat = r.arrivals[have] - np.array([r.sent[k] for k in raw[have].tolist()])
        latency_p50, latency_p99 = pct(lat, 50), pct(lat, 99)
    return {
        "link": r.link,
        "wall_s": r.wall_s,
        "windows": len(r.windows),
        "span": span,
        "received": len(c),
        "duplicates": len(c) - len(uniq),
        "lost": lost,
        "in_window": in_window,
        "win_missing": win_missing,
        "between": between,
        "between_lost": between_lost,
        "p50_ms": pct(j, 50),
        "p99_ms": pct(j, 99),
        "p999_ms": pct(j, 99.9),
        "max_ms": float(j.max()) * 1e3 if len(j) else float("nan"),
        "over_2ms": float(np.mean(j > TARGET_P99_S)) if len(j) else float("nan"),
        "zero_gap": float(np.mean(j > PERIOD_S - 1e-4)) if len(j) else float("nan"),
        "win_p50_ms": pct(jw, 50),
        "win_p99_ms": pct(jw, 99),
        "sent_p99_ms": sent_p99,
        "sent_late": sent_late,
        "late": chunk_phase_share(r.arrivals, c),
        "latency_p50_ms": latency_p50,
        "latency_p99_ms": latency_p99,
        "load_min": min(r.loads) if r.loads else float("nan"),
        "load_max": max(r.loads) if r.loads else float("nan"),
        "load_mean": float(np.mean(r.loads)) if r.loads else float("nan"),
        "cpu_pct": 100.0 * r.cpu_s / r.wall_s if r.cpu_s and r.wall_s else float("nan"),
        "errors": r.errors,
        "stats": r.stats,
        "tx_dropped": r.tx_dropped,
        "arrivals": r.arrivals,
        "counters": c,
    }


#: Length of the slices of :func:`sliced_ratio`, wall s.
SLICE_S = 10.0


def sliced_ratio(link: dict[str, Any], timer: dict[str, Any]) -> tuple[float, int]:
    """The median over :data:`SLICE_S` wall-clock slices of (the link's p99 jitter in the slice
    over the p99 of the timer loop beside it in the same slice), and the number of slices.

    The machine's wake-up tails come and go in bursts (other jobs, other virtual machines on the
    host): the timer loop's p99 changes tenfold from one minute to the next, and one p99 over a
    whole run compares whichever bursts fell in it. Slice by slice, the link and the timer loop
    see the same bursts; the median says what holds most of the time."""
    a, c = link["arrivals"], link["counters"]
    ta, tc = timer["arrivals"], timer["counters"]
    if len(a) < 2 or len(ta) < 2:
        return float("nan"), 0
    start = max(a[0], ta[0])
    end = min(a[-1], ta[-1])
    ratios = []
    t = start
    while t + SLICE_S <= end:
        m = (a >= t) & (a < t + SLICE_S)
        tm = (ta >= t) & (ta < t + SLICE_S)
        j, tj = jitter(a[m], c[m]), jitter(ta[tm], tc[tm])
        if len(j) > 100 and len(tj) > 100:
            ratios.append(np.percentile(j, 99) / np.percentile(tj, 99))
        t += SLICE_S
    return (float(np.median(ratios)) if ratios else float("nan")), len(ratios)


def print_table(rows: list[dict[str, Any]], duration_s: float, window_s: float) -> None:
    print(
        f"\n200 Hz stream, {duration_s:g} s per link, consecutive acquire({window_s:g} s, "
        "on_gap='report') windows; jitter = |inter-arrival interval - 5 ms| of consecutive ticks\n"
    )
    print(
        "| link | wall s | ticks | received | lost | in-window missing | between windows "
        "(lost) | jitter p50 ms | p99 ms | p99.9 ms | max ms | > 2 ms | load avg 1 min |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for s in rows:
        print(
            f"| {s['link']} | {s['wall_s']:.0f} | {s['span']} | {s['received']} | {s['lost']} | "
            f"{s['win_missing']} | {s['between']} ({s['between_lost']}) | {s['p50_ms']:.3f} | "
            f"{s['p99_ms']:.3f} | {s['p999_ms']:.2f} | {s['max_ms']:.1f} | "
            f"{100 * s['over_2ms']:.2f} % | {s['load_min']:.1f} .. {s['load_max']:.1f} "
            f"(mean {s['load_mean']:.1f}) |"
        )
    print()
    for s in rows:
        st = s["stats"]
        print(
            f"{s['link']}: {s['windows']} windows ({s['in_window']} samples in windows); "
            f"window arrival_s jitter p50 {s['win_p50_ms']:.3f} ms, p99 {s['win_p99_ms']:.3f} ms; "
            f"intervals of 0 (two ticks in one read) {100 * s['zero_gap']:.2f} %; "
            f"duplicates {s['duplicates']}; device tx_dropped {s['tx_dropped']}; host process CPU "
            f"{s['cpu_pct']:.0f} % of one core"
        )
        if s["sent_p99_ms"] == s["sent_p99_ms"]:
            print(
                f"  simulator send times: jitter p99 {s['sent_p99_ms']:.3f} ms, {s['sent_late'][0]} "
                f"intervals > 2 ms off, {100 * s['sent_late'][1]:.0f} % of them at 3 of the 40 tick "
                f"phases of the look-ahead chunk; send to arrival latency p50 "
                f"{s['latency_p50_ms']:.3f} ms, p99 {s['latency_p99_ms']:.3f} ms"
            )
        n_late, share = s["late"]
        if s["windows"]:
            print(
                f"  arrivals: {n_late} intervals > 2 ms off, {100 * share:.0f} % of them at 3 of the "
                "40 tick phases of the look-ahead chunk (uniform: 7.5 %)"
            )
        if st is not None:
            print(
                f"  driver stats: frames {st.frames_received}, rejected {st.frames_rejected}, "
                f"frames lost {st.frames_lost}, ticks lost {st.ticks_lost}, incomplete "
                f"{st.ticks_incomplete}, samples {st.samples_received}, retries {st.retries}, "
                f"reply timeouts {st.reply_timeouts}"
            )
        for e in s["errors"]:
            print(f"  error: {e}")
    for s in rows:
        if not s["windows"]:
            continue  # the timer loop: a reference, not a link
        verdict_lost = "met" if s["lost"] == 0 and not s["errors"] else "MISSED"
        verdict_jit = "met" if s["p99_ms"] <= TARGET_P99_S * 1e3 else "MISSED"
        print(
            f"{s['link']}: lost {s['lost']} (target 0: {verdict_lost}); jitter p99 "
            f"{s['p99_ms']:.3f} ms (target <= 2 ms: ratio {s['p99_ms'] / 2.0:.2f}, {verdict_jit})"
        )


def main() -> None:
    ap = _parser()
    args = ap.parse_args()
    global SENDER, CHANNEL
    SENDER = args.paced_sender
    CHANNEL = args.channel
    runners = {"can": run_can, "serial": run_serial, "slcan": run_slcan, "socketcan": run_socketcan}
    links = [s.strip() for s in args.links.split(",") if s.strip()]
    for link in links:
        if link not in runners:
            ap.error(f"--links: unknown link {link!r}; choose from {', '.join(runners)}")
    print(
        f"{time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, load average "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}, Python {sys.version.split()[0]}"
    )
    rows, timers, beside, bare = _run_links(args, runners, links)
    print_table(rows, args.duration, args.window)
    # name -> (median of the slices' ratios over the timer loop beside it, slices)
    sliced = {s["link"]: sliced_ratio(s, beside[s["link"]]) for s in rows if s["link"] in beside}
    _print_over_beside(rows, beside, sliced)
    _print_over_bare(rows, beside, bare, sliced)
    _print_over_timer(rows, timers)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--duration", type=float, default=600.0, help="wall seconds per link")
    ap.add_argument("--window", type=float, default=10.0, help="acquire window, s")
    ap.add_argument(
        "--links",
        default="can,serial,slcan",
        help="comma-separated: can, serial, slcan, socketcan (needs a kernel with vcan0)",
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--baseline",
        type=float,
        default=60.0,
        help="seconds of the timer loop without a link (0: skip)",
    )
    ap.add_argument(
        "--paced-sender",
        action="store_true",
        help="the simulator sends from a process of its own (the links of other processes)",
    )
    ap.add_argument("--channel", default="vcan0", help="SocketCAN interface of the socketcan link")
    ap.add_argument(
        "--bare",
        type=float,
        default=None,
        help="seconds of each link's bare floor (fixed samples, a reader that only reads) run "
        "after the link with a timer loop beside it (default: --duration; 0: skip)",
    )
    return ap


def _run_links(
    args: argparse.Namespace, runners: dict[str, Any], links: list[str]
) -> tuple[
    list[dict[str, Any]], list[dict[str, Any]], dict[str, dict[str, Any]], dict[str, dict[str, Any]]
]:
    """Every link (and its bare floor) with a timer loop beside it, between two timer loops of
    their own: the rows of the table, the timer loops', the loops beside and the bare floors."""
    rows = []
    timers = []
    if args.baseline > 0:
        timers.append(summarise(run_timer(args.baseline)))
        rows.append(timers[-1])
    beside: dict[str, dict[str, Any]] = {}
    bare: dict[str, dict[str, Any]] = {}  # a link's name -> its bare floor's row
    bare_s = args.duration if args.bare is None else args.bare
    for link in links:
        with TimerBeside(args.duration) as timer:
            r = runners[link](args.duration, args.window, args.seed)
        rows.append(summarise(r))
        if timer.result is not None:
            beside[r.link] = summarise(timer.result)
            beside[r.link]["link"] = f"timer loop beside {r.link}"
            rows.append(beside[r.link])
        print(f"{r.link}: done ({r.wall_s:.0f} s)", flush=True)
        if bare_s > 0:
            with TimerBeside(bare_s) as timer:
                b = run_bare(link, bare_s)
            bare[r.link] = summarise(b)
            rows.append(bare[r.link])
            if timer.result is not None:
                beside[b.link] = summarise(timer.result)
                beside[b.link]["link"] = f"timer loop beside {b.link}"
                rows.append(beside[b.link])
            print(f"{b.link}: done ({bare_s:.0f} s)", flush=True)
    if args.baseline > 0:
        # The floor again after the links, so that a change of the machine's load during the
        # run shows: each link's ratio is against the mean of the two.
        timers.append(summarise(run_timer(args.baseline)))
        timers[-1]["link"] += " (after the links)"
        rows.append(timers[-1])
    return rows, timers, beside, bare


def _print_over_beside(
    rows: list[dict[str, Any]], beside: dict[str, dict[str, Any]], sliced: dict[str, Any]
) -> None:
    if beside:
        print("jitter p99 over that of a timer loop in a process of its own beside the link, for the "
              "same minutes (goal <= 1.2):")  # fmt: skip
        for s in rows:
            if s["link"] in beside:
                t = beside[s["link"]]
                med, k = sliced[s["link"]]
                print(
                    f"  {s['link']}: {s['p99_ms']:.3f} / {t['p99_ms']:.3f} = "
                    f"{s['p99_ms'] / t['p99_ms']:.2f}; median over {k} slices of {SLICE_S:g} s "
                    f"{med:.2f}; lost {s['lost']}"
                )


def _print_over_bare(
    rows: list[dict[str, Any]],
    beside: dict[str, dict[str, Any]],
    bare: dict[str, dict[str, Any]],
    sliced: dict[str, Any],
) -> None:
    if bare:
        print(
            "jitter p99 over the bare link's (the same link carrying fixed samples, a reader that "
            "only reads; goal <= 1.2), and both over the timer loop beside each:"
        )
        for s in rows:
            f = bare.get(s["link"])
            if f is None:
                continue
            t_link, t_bare = beside.get(s["link"]), beside.get(f["link"])
            both = ""
            if t_link is not None and t_bare is not None:
                own = s["p99_ms"] / t_link["p99_ms"]
                floor_ratio = f["p99_ms"] / t_bare["p99_ms"]
                own_s, floor_s = sliced[s["link"]][0], sliced[f["link"]][0]
                both = (
                    f"; over the timer loop: link {own:.2f}, bare link {floor_ratio:.2f} "
                    f"(link over bare, each against its timer: {own / floor_ratio:.2f}); medians "
                    f"of {SLICE_S:g} s slices: link {own_s:.2f}, bare link {floor_s:.2f} "
                    f"({own_s / floor_s:.2f})"
                )
            print(
                f"  {s['link']}: {s['p99_ms']:.3f} / {f['p99_ms']:.3f} = "
                f"{s['p99_ms'] / f['p99_ms']:.2f}{both}; bare lost {f['lost']}"
                + "".join(f"; bare: {e}" for e in f["errors"])
            )


def _print_over_timer(rows: list[dict[str, Any]], timers: list[dict[str, Any]]) -> None:
    if timers:
        floor = float(np.mean([t["p99_ms"] for t in timers]))
        floors = ", ".join(f"{t['p99_ms']:.3f}" for t in timers)
        print(f"jitter p99 over the timer loop's (mean of {floors} ms; goal <= 1.2):")
        for s in rows:
            if s not in timers and not s["link"].startswith("timer loop"):
                print(
                    f"  {s['link']}: {s['p99_ms']:.3f} / {floor:.3f} = {s['p99_ms'] / floor:.2f}; "
                    f"lost {s['lost']}"
                )


if __name__ == "__main__":
    main()
