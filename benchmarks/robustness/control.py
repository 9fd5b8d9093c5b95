"""``control``: control-channel abuse of a running simulator (a section of ``bench_robustness.py``).

``control``: control-channel abuse. ``northfinder sim --pty --warmup 0 --control 127.0.0.1:0``
runs as a separate process, as in a rehearsal. A host reads its sample stream on the pty (serial
frames, started with STREAM_START) on a thread for the whole run, and fires at the control
channel, one after the other:

- ``refused``: requests the channel must refuse (non-finite numbers, values beyond the stated
  bounds, wrong types, unknown ops and keys, a sensor specification the device cannot run);
- ``socket``: lines that are not requests: a 100 MB line, 30 000-deep nesting, a 5000-digit
  integer, bytes that are not UTF-8, an empty line; each on a raw socket, expecting one JSON reply
  line and a connection that still answers;
- ``accepted``: the largest requests the channel accepts (the longest impulse burst, the largest
  bias step, vibration at the highest frequency and amplitude);
- ``fault``: faults injected on purpose (drop, corrupt, skip the counter, silent, pause, delayed
  replies, reset), each cleared again. These break the stream by design: only deaths count.

After each case it checks the simulator is alive (its process runs and a new control connection
answers ``status`` within 5 s); a dead or hung simulator counts as a death and is started again,
so that every case meets a live one. Stream gaps (a sample counter step other than +1) and the
samples received against those due at 200 Hz are counted over the ``refused``, ``socket`` and
``accepted`` phases; the stream must also come back after the ``fault`` phase. The simulator's
resident memory is read from /proc before and after.

``listen`` (part of ``control``): ``--control unix:PATH`` on an existing regular file and on a live
socket must be refused with one line and leave the path alone; ``--control [::1]:0`` must start or
give one line.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import serial

from northfinder.driver.protocol.messages import Sample, StreamStart
from northfinder.driver.protocol.serial import Deframer, SerialEncoder
from northfinder.firmware_sim.control import ControlClient, ControlError

SIM = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())"]
NAN, INF = float("nan"), float("inf")
RATE_HZ = 200  # the simulator's default sample rate

REFUSED: list[Any] = [
    {"op": "bias_step", "gyro_dph": [NAN, 0, 0]},
    {"op": "bias_step", "accel_ug": [0, INF, 0]},
    {"op": "bias_step", "gyro_dph": [1e300, 0, 0]},
    {"op": "bias_step", "gyro_dph": "up"},
    {"op": "vibration", "hz": NAN},
    {"op": "vibration", "hz": 1e9},
    {"op": "vibration", "accel_ug": -INF},
    {"op": "impulses", "gyro_dph": NAN},
    {"op": "impulses", "count": 100_000},
    {"op": "impulses", "count": 1_000_000},
    {"op": "impulses", "count": 10_000, "interval_s": 3600},
    {"op": "impulses", "interval_s": 1e-9},
    {"op": "set_truth", "azimuth_deg": NAN},
    {"op": "set_truth", "latitude_deg": 90},
    {"op": "set_truth", "pitch_deg": 89},
    {"op": "set_truth", "heading": 3},
    {"op": "set_sensor", "values": {"gyro.arw_dpsh": NAN}},
    {"op": "set_sensor", "values": {"table.max_rate_dps": 1e300}},
    {"op": "set_sensor", "values": {"gyro.arw_dpsh": 1e300}},
    {"op": "set_sensor", "values": {"table.max_rate_dps": 1e-300}},
    {"op": "set_sensor", "values": {"disturbance.impulse_rate_hz": 1e9}},
    {"op": "set_sensor", "values": {"disturbance.impulse_duration_s": 1e9}},
    {"op": "set_sensor", "values": {"nope.x": 1}},
    {"op": "set_sensor", "values": "gyro"},
    {"op": "speed", "value": NAN},
    {"op": "speed", "value": 0},
    {"op": "speed", "value": 1e300},
    {"op": "speed", "speed": 2},
    {"op": "delay_replies", "seconds": 1e9},
    {"op": "drop", "count": 10**30},
    {"op": "corrupt", "count": -1},
    {"op": "skip_counter", "count": 2**40},
    {"op": "wrong_result", "code": 256},
    {"op": "silent", "on": "no"},
    {"op": "stall", "on": 0},
    {"op": "status", "verbose": True},
    {"op": "exec", "code": "import os"},
    {"op": 7},
    {"nothing": "here"},
    [1, 2, 3],
    "status",
]
ACCEPTED: list[dict[str, Any]] = [
    {"op": "impulses", "count": 10_000, "interval_s": 0.01, "gyro_dph": 1e6, "accel_ug": 1e7},
    {"op": "bias_step", "gyro_dph": [1e6, -1e6, 1e6], "accel_ug": [1e7, -1e7, 1e7]},
    {"op": "bias_step", "gyro_dph": [-1e6, 1e6, -1e6], "accel_ug": [-1e7, 1e7, -1e7]},
    {"op": "vibration", "on": True, "hz": 200.0, "gyro_dph": 1e6, "accel_ug": 1e7},
    {"op": "set_truth", "azimuth_deg": -360, "pitch_deg": 45, "roll_deg": -45},
    {"op": "set_sensor", "values": {"gyro.arw_dpsh": 1e9, "accel.bias_ug": [1e9, 0, 0]}},
    {"op": "set_sensor", "values": {"table.max_rate_dps": 50, "table.max_accel_dps2": 200}},
    {"op": "speed", "value": 1.0},
]
#: Faults on purpose, each with the request that clears it.
FAULTS: list[tuple[dict[str, Any], dict[str, Any] | None]] = [
    ({"op": "drop", "count": 100_000}, {"op": "drop", "count": 0}),
    ({"op": "corrupt", "count": 100_000}, {"op": "corrupt", "count": 0}),
    ({"op": "skip_counter", "count": 1_000_000}, None),
    ({"op": "silent"}, {"op": "silent", "on": False}),
    ({"op": "pause"}, {"op": "resume"}),
    ({"op": "delay_replies", "seconds": 3600}, {"op": "delay_replies", "seconds": 0}),
    ({"op": "stall"}, {"op": "stall", "on": False}),
    ({"op": "reset"}, None),
]


def _socket_cases() -> list[tuple[str, bytes]]:
    return [
        ("100 MB line", b"x" * 100_000_000 + b"\n"),
        ("30000-deep nesting", b"[" * 30_000 + b"]" * 30_000 + b"\n"),
        ("5000-digit integer", b'{"op": "drop", "count": ' + b"9" * 5000 + b"}\n"),
        ("not UTF-8", b"\xff\xfe\xfd\n"),
        ("empty line", b"\n"),
        ("JSON NaN", b'{"op": "speed", "value": NaN}\n'),
        ("1e400", b'{"op": "speed", "value": 1e400}\n'),
        ("64 KiB + 1 of spaces", b"{}" + b" " * 65535 + b"\n"),
    ]


class Stream:
    """Reads the simulator's serial frames on a thread; keeps (arrival, counter) of every sample."""

    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, timeout=0.05)
        self.deframer = Deframer()
        self.samples: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def start(self, timeout: float = 10.0) -> None:
        """STREAM_START until samples arrive (BOOT refuses it for its first half second)."""
        deadline = time.monotonic() + timeout
        seq = 1
        while not self.samples:
            if time.monotonic() > deadline:
                raise RuntimeError("the simulator's stream did not start")
            self.port.write(SerialEncoder().encode(StreamStart(seq)))
            seq += 1
            time.sleep(0.3)

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.port.read(4096)
            except (serial.SerialException, OSError):
                return
            now = time.monotonic()
            for message in self.deframer.feed_messages(data):
                if isinstance(message, Sample):
                    self.samples.append((now, message.counter))

    def gaps(self, t0: float, t1: float) -> tuple[int, int, float]:
        """(counter gaps, samples, longest arrival interval in s) of samples that arrived in [t0, t1]."""
        part = [(t, c) for t, c in self.samples if t0 <= t <= t1]
        gaps = sum(1 for a, b in itertools.pairwise(part) if (b[1] - a[1]) & 0xFFFFFFFF != 1)
        longest = max((b[0] - a[0] for a, b in itertools.pairwise(part)), default=math.inf)
        return gaps, len(part), longest

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.port.close()


@contextlib.contextmanager
def simulator(*extra: str) -> Iterator[tuple[subprocess.Popen, dict[str, str]]]:
    cmd = [*SIM, "sim", "--pty", "--warmup", "0", "--seed", "1", *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        facts: dict[str, str] = {}
        while "truth" not in facts:
            line = proc.stdout.readline() if proc.stdout else ""
            if not line:
                raise RuntimeError("the simulator did not start")
            key, _, value = line.strip().partition(" ")
            facts[key] = value
        yield proc, facts
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def rss_mb(pid: int) -> float:
    """Resident memory of a process, MB (NaN once it has ended)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return math.nan


def alive(proc: subprocess.Popen, address: str) -> bool:
    if proc.poll() is not None:
        return False
    try:
        with ControlClient(address, timeout=5.0) as client:
            return client.call("status")["ok"] is True
    except ControlError:
        return False


def send_raw(address: str, request: Any) -> dict[str, Any]:
    """Send one JSON value (any, also not an object) and return the reply object."""
    host, _, port = address.rpartition(":")
    with socket.create_connection((host.strip("[]"), int(port)), timeout=10) as sock:
        sock.sendall(json.dumps(request).encode() + b"\n")
        return json.loads(sock.makefile("rb").readline())


def refused(address: str, request: Any) -> bool:
    return send_raw(address, request)["ok"] is False


def accepted(address: str, request: Any) -> bool:
    return send_raw(address, request)["ok"] is True


def answered(address: str, line: bytes) -> bool:
    return all(send_line(address, line))


def fault(address: str, request: dict[str, Any], clear: dict[str, Any] | None) -> bool:
    """Inject a fault, let it act, clear it again."""
    ok = send_raw(address, request)["ok"]
    time.sleep(0.3)
    return ok and (clear is None or send_raw(address, clear)["ok"])


def send_line(address: str, line: bytes) -> tuple[bool, bool]:
    """(one JSON reply line came back, the same connection answers ``status`` after it)."""
    host, _, port = address.rpartition(":")
    with socket.create_connection((host.strip("[]"), int(port)), timeout=30) as sock:
        reader = sock.makefile("rb")
        sender = threading.Thread(target=sock.sendall, args=(line,), daemon=True)
        sender.start()
        reply = reader.readline()
        sender.join(30)
        try:
            one = reply.endswith(b"\n") and isinstance(json.loads(reply), dict)
        except ValueError:
            one = False
        sock.sendall(b'{"op": "status"}\n')
        try:
            after = json.loads(reader.readline()).get("ok") is True
        except ValueError:
            after = False
    return one, after


@dataclass
class Tally:
    cases: int = 0
    as_expected: int = 0
    deaths: int = 0
    worst_s: float = 0.0
    notes: list[str] = field(default_factory=list)


class Running:
    """``northfinder sim`` with a control channel and its stream read; started again if it dies,
    so that every case is tried on a live simulator."""

    def __init__(self) -> None:
        self.streams: list[Stream] = []
        self.rss_start_mb = math.nan
        self._start()

    def _start(self) -> None:
        self._ctx = simulator("--control", "127.0.0.1:0")
        self.proc, facts = self._ctx.__enter__()
        self.address = facts["control"]
        self.stream = Stream(facts["pty"])
        self.streams.append(self.stream)
        self.stream.start()
        time.sleep(0.5)
        if math.isnan(self.rss_start_mb):
            self.rss_start_mb = rss_mb(self.proc.pid)

    def alive(self) -> bool:
        return alive(self.proc, self.address)

    def restart(self) -> None:
        self.close()
        self._start()

    def close(self) -> None:
        self.stream.close()
        self._ctx.__exit__(None, None, None)

    def gaps(self, t0: float, t1: float) -> tuple[int, int, float]:
        """Counter gaps, samples and longest arrival interval over all streams in [t0, t1]."""
        parts = [stream.gaps(t0, t1) for stream in self.streams]
        longest = max((p[2] for p in parts if p[1] > 1), default=math.inf)
        return sum(p[0] for p in parts), sum(p[1] for p in parts), longest


def control_abuse(args: argparse.Namespace) -> dict[str, Any]:
    tallies = {name: Tally() for name in ("refused", "socket", "accepted", "fault")}
    phases: dict[str, tuple[float, float]] = {}
    sim = Running()
    try:

        def case(phase: str, label: str, fire: Callable[[str], bool]) -> None:
            tally = tallies[phase]
            t0 = time.monotonic()
            error = "not as expected"
            try:
                ok = fire(sim.address)
            except (OSError, ValueError, ControlError) as exc:
                ok, error = False, str(exc)
            tally.worst_s = max(tally.worst_s, time.monotonic() - t0)
            tally.cases += 1
            tally.as_expected += bool(ok)
            if not ok:
                tally.notes.append(f"{label}: {error}")
            time.sleep(args.seconds_per_case)  # a request that kills does so at the next sample
            if not sim.alive():
                tally.deaths += 1
                tally.notes.append(f"{label}: simulator dead or hung (started again)")
                sim.restart()

        start = time.monotonic()
        for request in REFUSED:
            case("refused", json.dumps(request)[:50], partial(refused, request=request))
        phases["refused"] = (start, time.monotonic())
        start = time.monotonic()
        for label, line in _socket_cases():
            case("socket", label, partial(answered, line=line))
        phases["socket"] = (start, time.monotonic())
        start = time.monotonic()
        for request in ACCEPTED:
            case("accepted", json.dumps(request)[:50], partial(accepted, request=request))
        time.sleep(2.0)  # the largest burst and vibration run through the stream
        phases["accepted"] = (start, time.monotonic())
        in_phase = {name: sim.gaps(*span) for name, span in phases.items()}
        rss_end = rss_mb(sim.proc.pid)
        for request, clear in FAULTS:
            case("fault", json.dumps(request)[:50], partial(fault, request=request, clear=clear))
        sim.stream.samples.clear()  # a reset switches the stream off: start it again
        try:
            sim.stream.start()
            time.sleep(1.5)
            resumed = sim.stream.gaps(time.monotonic() - 1.0, time.monotonic())
        except (RuntimeError, serial.SerialException):  # the simulator has died
            resumed = (0, 0, math.inf)
        lost = sum(stream.deframer.lost_frames for stream in sim.streams)
    finally:
        sim.close()
    listen = listen_checks()
    print("control channel abuse (northfinder sim --pty --control 127.0.0.1:0, real time)")
    print(f"{'phase':<10} {'cases':>6} {'as expected':>12} {'deaths':>7} {'slowest case s':>15} "
          f"{'stream gaps':>12} {'samples/due':>12} {'longest interval ms':>20}")  # fmt: skip
    summary: dict[str, Any] = {}
    for name, tally in tallies.items():
        gaps, n, longest = in_phase.get(name, (None, None, None))
        due = round(RATE_HZ * (phases[name][1] - phases[name][0])) if name in phases else None
        shown = "-" if gaps is None else str(gaps)
        count = "-" if n is None else f"{n}/{due}"
        print(f"{name:<10} {tally.cases:>6} {tally.as_expected:>12} {tally.deaths:>7} "
              f"{tally.worst_s:>15.2f} {shown:>12} {count:>12} "
              f"{'-' if longest is None else f'{longest * 1e3:.1f}':>20}")  # fmt: skip
        summary[name] = {**tally.__dict__, "stream_gaps": gaps, "samples": n, "due": due}
    print(f"stream after the faults: {resumed[1]} samples in the last 1 s, {resumed[0]} gaps")
    print(f"serial frames lost over the whole run (faults on purpose included): {lost}")
    print(
        f"simulator resident memory: {sim.rss_start_mb:.0f} MB at start, {rss_end:.0f} MB after "
        f"the abuse (the last simulator started)"
    )
    for name, (ok, text) in listen.items():
        print(f"listen {name}: {'as expected' if ok else 'NOT as expected'}: {text}")
    for tally in tallies.values():
        for note in tally.notes:
            print(f"  note: {note}")
    summary.update(resumed=resumed[:2], rss_mb=(sim.rss_start_mb, rss_end), listen=listen)
    return summary


def listen_checks() -> dict[str, tuple[bool, str]]:
    """``--control`` addresses that must be refused in one line, leaving the path alone."""
    out: dict[str, tuple[bool, str]] = {}
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        precious = os.path.join(tmp, "notes.txt")
        with open(precious, "w") as f:
            f.write("keep")
        res = subprocess.run(
            [*SIM, "sim", "--pty", "--duration", "1", "--control", f"unix:{precious}"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        err = res.stderr.strip().splitlines()
        kept = os.path.exists(precious) and open(precious).read() == "keep"
        out["unix:existing file"] = (
            res.returncode != 0 and kept and "Traceback" not in res.stderr,
            f"exit {res.returncode}, file kept {kept}: {err[-1] if err else ''}",
        )
        live = os.path.join(tmp, "live.sock")
        with simulator("--control", f"unix:{live}"):
            res = subprocess.run(
                [*SIM, "sim", "--pty", "--duration", "1", "--control", f"unix:{live}"],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            err = res.stderr.strip().splitlines()
            still = os.path.exists(live)
            out["unix:live socket"] = (
                res.returncode != 0 and still and "Traceback" not in res.stderr,
                f"exit {res.returncode}, socket kept {still}: {err[-1] if err else ''}",
            )
    res = subprocess.run(
        [*SIM, "sim", "--pty", "--warmup", "0", "--duration", "1", "--control", "[::1]:0"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    control = [line for line in res.stdout.splitlines() if line.startswith("control ")]
    err = [line for line in res.stderr.splitlines() if "error" in line]
    out["[::1]:0"] = (
        "Traceback" not in res.stderr
        and ((res.returncode == 0 and bool(control)) or len(err) == 1),
        control[0] if control else (err[0] if err else f"exit {res.returncode}"),
    )
    return out
