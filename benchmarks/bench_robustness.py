"""Robustness: bad input and faults never crash, hang or silently break the simulated instrument.

Run: ``.venv/bin/python benchmarks/bench_robustness.py [--sections control] [--seconds-per-case 0.3]``.

Each section is one function in :data:`SECTIONS` that prints its table and returns a summary
dict; add a section by adding a function there.

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
import io
import itertools
import json
import math
import os
import random
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

from northfinder.driver.protocol.constants import Validity
from northfinder.driver.protocol.messages import Sample, StreamStart
from northfinder.driver.protocol.serial import Deframer, SerialEncoder
from northfinder.firmware_sim.control import ControlClient, ControlError

SIM = [sys.executable, "-c", "from northfinder.host.cli import main; raise SystemExit(main())"]
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


# ----------------------------------------------------------------------------------------------
# The wire codec
# ----------------------------------------------------------------------------------------------


def _sample_frames(rng: random.Random, count: int, seq0: int = 0) -> list[bytes]:
    from northfinder.driver.protocol.serial import SerialEncoder

    enc = SerialEncoder(seq0)

    def i32() -> int:
        return rng.randrange(-(2**31), 2**31)

    return [
        enc.encode(
            Sample(rng.randrange(2**32), (i32(), i32(), i32()), (i32(), i32(), i32()),
                   rng.randrange(2**32), rng.randrange(-(2**15), 2**15), Validity(rng.randrange(256)))
        )
        for _ in range(count)
    ]


def codec_fuzz(args: argparse.Namespace) -> dict[str, Any]:
    """Random and mutated input into every decoder; what is not a typed error, and what
    resynchronisation loses."""
    from northfinder.driver.errors import ProtocolError
    from northfinder.driver.protocol import (
        Command,
        Identify,
        IdentifyPage,
        Reply,
        SampleAux,
        SampleX,
        Status,
        StatusCounters,
        StatusMain,
    )  # fmt: skip
    from northfinder.driver.protocol.can import CanReceiver, decode_can
    from northfinder.driver.protocol.serial import Deframer

    rng = random.Random(args.seed)
    n = args.fuzz_inputs
    untyped: dict[str, int] = {}
    counts: dict[str, int] = {}

    def guard(name: str, call: Callable[[], Any]) -> None:
        counts[name] = counts.get(name, 0) + 1
        try:
            call()
        except ProtocolError:
            pass
        except Exception:
            untyped[name] = untyped.get(name, 0) + 1

    types: list[Any] = [Command, Reply, Sample, SampleX, SampleAux, Status, StatusMain, StatusCounters,
             Identify, IdentifyPage]  # fmt: skip
    for _ in range(n):
        kind = types[rng.randrange(len(types))]
        data = rng.randbytes(rng.randrange(0, 80))
        guard("payload decoders", partial(kind.decode, data))
    receiver = CanReceiver(node_id=1)
    for _ in range(n):
        ident = rng.choice([rng.randrange(0x800), 0x100 + rng.randrange(0x100)])
        data = rng.randbytes(rng.randrange(0, 9))
        guard("CAN frames (decode_can)", partial(decode_can, ident, data))
        guard("CAN frames (CanReceiver)", partial(receiver.feed, ident, data))
    deframer = Deframer()
    chunks = 0
    for _ in range(n // 10):
        data = rng.randbytes(rng.randrange(1, 200))
        guard("serial bytes (Deframer)", partial(deframer.feed_messages, data))
        chunks += 1
    # Resynchronisation: a frame, a mutated frame, then the stream goes on; the frame before
    # and the two after the mutated one must come through.
    mutations = ("delete a byte", "flip a byte", "insert a byte", "truncate", "last byte lost (0xA5)")
    lost = {m: 0 for m in mutations}
    false = {m: 0 for m in mutations}  # damaged frames that passed the CRC
    trials = {m: 0 for m in mutations}
    # The case the CRC cannot see: a frame whose CRC high byte is A5 loses it, and the next
    # frame's first sync byte completes it (one frame in 256 has such a CRC).
    a5_pool = [f for f in _sample_frames(rng, 256 * 64) if f[-1] == 0xA5]
    for t in range(args.fuzz_frames):
        how = mutations[t % len(mutations)]
        if how == "last byte lost (0xA5)":
            frames = _sample_frames(rng, 5, rng.randrange(256))
            frames[1] = a5_pool[rng.randrange(len(a5_pool))]
            middle = frames[1][:-1]
        else:
            frames = _sample_frames(rng, 5, rng.randrange(256))
            b = bytearray(frames[1])
            k = rng.randrange(len(b))
            if how == "delete a byte":
                del b[k]
            elif how == "flip a byte":
                b[k] ^= 1 << rng.randrange(8)
            elif how == "insert a byte":
                b.insert(k, rng.randrange(256))
            else:
                del b[k:]
            middle = bytes(b)
        d = Deframer()
        # two more frames after them, as a stream goes on (a false candidate may wait for them)
        got = [f.payload for f in d.feed(frames[0] + middle + b"".join(frames[2:]))]
        want = [frames[0][5:-2], frames[2][5:-2], frames[3][5:-2]]
        trials[how] += 1
        lost[how] += sum(1 for w in want if w not in got)
        false[how] += sum(1 for g in got if g not in (*want, frames[1][5:-2], frames[4][5:-2]))
    print(f"codec fuzz (seed {args.seed}): inputs and exceptions other than ProtocolError")
    for name, count in counts.items():
        print(f"  {name:<28} {count:>9} inputs   {untyped.get(name, 0)} untyped exceptions")
    print("resynchronisation: frame, mutated frame, frames; good frames lost, damaged frames "
          "delivered (passed the CRC)")  # fmt: skip
    for how in mutations:
        print(f"  {how:<28} {trials[how]:>9} trials   {lost[how]} good frames lost   "
              f"{false[how]} damaged frames delivered")  # fmt: skip
    return {"inputs": counts, "untyped": untyped, "resync_trials": trials, "resync_lost": lost,
            "damaged_delivered": false}  # fmt: skip


# ----------------------------------------------------------------------------------------------
# Faults injected during find
# ----------------------------------------------------------------------------------------------

#: Control-channel faults injected during a run of ``find`` (each with the request that clears it
#: a moment later, or None when it stays).
FIND_FAULTS: list[tuple[str, dict[str, Any], dict[str, Any] | None]] = [
    ("drop 5 frames", {"op": "drop", "count": 5}, None),
    ("drop 200 frames", {"op": "drop", "count": 200}, None),
    ("corrupt 5 frames", {"op": "corrupt", "count": 5}, None),
    ("corrupt 200 frames", {"op": "corrupt", "count": 200}, None),
    ("skip the counter by 3", {"op": "skip_counter", "count": 3}, None),
    ("delay replies 0.3 s", {"op": "delay_replies", "seconds": 0.3}, {"op": "delay_replies", "seconds": 0}),
    ("delay replies 5 s", {"op": "delay_replies", "seconds": 5}, None),
    ("wrong result once", {"op": "wrong_result", "code": 7}, None),
    ("silent", {"op": "silent"}, None),
    ("silent 0.2 s", {"op": "silent"}, {"op": "silent", "on": False}),
    ("pause 0.2 s", {"op": "pause"}, {"op": "resume"}),
    ("stall the table", {"op": "stall"}, None),
    ("reset", {"op": "reset"}, None),
    ("bias step 0.05 deg/h x", {"op": "bias_step", "gyro_dph": [0.05, 0, 0]}, None),
    ("bias step 0.5 deg/h x", {"op": "bias_step", "gyro_dph": [0.5, 0, 0]}, None),
    ("bias step 5 deg/h y", {"op": "bias_step", "gyro_dph": [0, 5.0, 0]}, None),
    ("bias step 100 ug x", {"op": "bias_step", "accel_ug": [100.0, 0, 0]}, None),
    ("10 impulses of 50 deg/h", {"op": "impulses", "count": 10, "interval_s": 0.2}, None),
    ("vibration 35 Hz 5 deg/h", {"op": "vibration", "on": True}, None),
    ("base turned 1 deg", {"op": "set_truth", "azimuth_deg": None}, None),
    ("ARW x10", {"op": "set_sensor", "values": {"gyro.arw_dpsh": 0.015}}, None),
    ("speed x0.5", {"op": "speed", "value": 50.0}, None),
]
#: When a fault is injected: as the window of position 2 begins, or as the table leaves for it.
FIND_MOMENTS = ("acquire", "rotate")


def _find_with_fault(label: str, request: dict[str, Any], clear: dict[str, Any] | None,
                     moment: str, seed: int) -> dict[str, Any]:  # fmt: skip
    from northfinder.driver.errors import DriverError
    from northfinder.firmware_sim.imu import Truth
    from northfinder.host.embed import RELAXED_DEVICE_OPTIONS, SimulatedInstrument
    from northfinder.host.errors import HostError
    from northfinder.host.procedure import Plan, find_north

    truth = Truth(azimuth_deg=(37.0 * seed) % 360.0)
    plan = Plan((0.0, 180.0, 180.0, 0.0), 4.0)
    op = dict(request)
    if op["op"] == "set_truth":
        op["azimuth_deg"] = (truth.azimuth_deg + 1.0) % 360.0
    with SimulatedInstrument("paper-rlg", truth, seed=seed, speed=100, warmup_s=0,
                             control="127.0.0.1:0") as sim:  # fmt: skip
        control = sim.control
        assert control is not None
        try:
            with sim.open_device(**RELAXED_DEVICE_OPTIONS) as dev:
                fired: list[float] = []

                def progress(p: Any) -> None:
                    if p.phase == moment and p.position == 2 and not fired:
                        fired.append(time.monotonic())
                        name = op.pop("op")
                        control.call(name, **op)
                        if clear is not None:
                            threading.Timer(0.2, lambda: control.call(**clear)).start()

                result, _ = find_north(dev, plan, truth.latitude_deg, progress=progress)
        except (DriverError, HostError) as exc:
            return {"fault": label, "moment": moment, "outcome": "error",
                    "detail": f"{type(exc).__name__}: {str(exc)[:90]}"}  # fmt: skip
        sim.check()
        # The heading is judged against where the instrument stands when the result is given
        # (a base turned during the run stands at its new heading).
        final = float(control.call("get_truth")["truth"]["azimuth_deg"])
    err = (result.azimuth_deg - final + 180.0) % 360.0 - 180.0
    z = abs(err) / result.sigma_deg if result.sigma_deg else math.inf
    warned = result.consistent is False or any("impulsive" in n for n in result.notes)
    if warned:
        outcome = "warning"
    elif z <= 3.0:
        outcome = "right"
    else:
        outcome = "SILENTLY WRONG"
    return {"fault": label, "moment": moment, "outcome": outcome, "error_deg": err,
            "sigma_deg": result.sigma_deg, "z": z,
            "detail": next((n for n in result.notes if "CONSISTENCY" in n or "impulsive" in n), "")}  # fmt: skip


def find_faults(args: argparse.Namespace) -> dict[str, Any]:
    """Every control-channel fault injected during ``find`` (0,180,180,0, 4 s windows,
    paper-rlg, embedded simulator at 100x): a named error, a stated warning, or a heading within
    3 sigma of where the instrument stands at the end; never a wrong heading without a word."""
    rows = []
    for i, (label, request, clear) in enumerate(FIND_FAULTS):
        for moment in FIND_MOMENTS:
            rows.append(_find_with_fault(label, request, clear, moment, seed=100 + i))
    print("faults injected during find (0,180,180,0, 4 s windows, paper-rlg, 100x), at the start "
          "of window 2 (acquire) or of the move to it (rotate)")  # fmt: skip
    print(f"{'fault':<26} {'moment':<8} {'outcome':<15} {'error deg':>10} {'z':>6}  detail")
    for r in rows:
        e = f"{r['error_deg']:+10.4f}" if "error_deg" in r else f"{'-':>10}"
        z = f"{r['z']:6.1f}" if "z" in r else f"{'-':>6}"
        print(f"{r['fault']:<26} {r['moment']:<8} {r['outcome']:<15} {e} {z}  {r['detail'][:110]}")
    tally = {k: sum(r["outcome"] == k for r in rows) for k in ("error", "warning", "right", "SILENTLY WRONG")}
    print(f"runs {len(rows)}: {tally}")
    return {"rows": rows, "tally": tally}


# ----------------------------------------------------------------------------------------------
# Bad input on the command line
# ----------------------------------------------------------------------------------------------

#: Options that make ``--sim`` runs short (no warm-up, 1 s windows, fast).
QUICK = ["--sim", "--warmup", "0", "--window", "1", "--speed", "500", "--seed", "1"]


@dataclass(frozen=True)
class CliCase:
    """One bad-input case: the arguments, the exit status it must give and a word the error line
    must contain (the argument or field it names), case-insensitive."""

    command: str
    argv: tuple[str, ...]
    exit: int
    names: str


def _files(tmp: str) -> dict[str, str]:
    """Bad input files for the sweep: sensor TOMLs and mutated recordings, by name."""
    import numpy as np

    from northfinder.host.cli import main as cli

    out: dict[str, str] = {}

    def write(name: str, text: str) -> str:
        path = os.path.join(tmp, name)
        with open(path, "w") as f:
            f.write(text)
        out[name] = path
        return path

    for name, body in {
        "rate-tiny.toml": "[table]\nmax_rate_dps = 1e-300\n",
        "rate-huge.toml": "[table]\nmax_rate_dps = 1e300\n",
        "impulses.toml": "[disturbance]\nimpulse_rate_hz = 1e9\n[gyro]\nimpulse_dph = 10\n",
        "arw-huge.toml": "[gyro]\narw_dpsh = 1e300\n",
        "not-toml.toml": "this is = = not toml\n",
        "unknown-field.toml": "[gyro]\nwarp_factor = 9\n",
        "string-value.toml": '[gyro]\narw_dpsh = "small"\n',
        "section-value.toml": "gyro = 3\n",
        "nan.toml": "[gyro]\narw_dpsh = nan\n",
        "negative.toml": "[table]\nsettle_s = -1\n",
        "vec.toml": "[gyro]\nbias_dph = [1, 2]\n",
        "empty.csv": "",
    }.items():
        write(name, body)
    good = os.path.join(tmp, "good.csv")
    good4 = os.path.join(tmp, "good4.npz")
    with contextlib.redirect_stdout(io.StringIO()):
        cli(["record", good, *QUICK, "--window", "2", "--positions", "0,180"])
        cli(["record", good4, *QUICK, "--window", "2", "--positions", "0,180,180,0"])
    out["good.csv"], out["good4.npz"] = good, good4
    text = open(good).read()
    head, _, body = text.partition("window,")
    body = "window," + body

    def meta(key: str, value: str | None, name: str) -> None:
        lines = [ln for ln in head.splitlines() if not ln.startswith(f"# {key} =")]
        if value is not None:
            lines.append(f"# {key} = {value}")
        write(name, "\n".join(lines) + "\n" + body)

    meta("sample_rate_hz", "0", "rate-0.csv")
    meta("sample_rate_hz", '"fast"', "rate-string.csv")
    meta("sample_rate_hz", "-200", "rate-negative.csv")
    meta("sample_rate_hz", "1e300", "rate-huge.csv")
    meta("sample_rate_hz", None, "rate-missing.csv")
    meta("truth", "[1, 2]", "truth-list.csv")
    meta("truth", '{"azimuth_deg": "north"}', "truth-string.csv")
    meta("truth", '{"pitch_deg": 0}', "truth-partial.csv")
    meta("truth", '{"azimuth_deg": 1e400}', "truth-inf.csv")
    meta("latitude_deg", None, "latitude-missing.csv")
    meta("latitude_deg", "95", "latitude-95.csv")
    meta("latitude_deg", '"34N"', "latitude-string.csv")
    meta("plan", "7", "plan-number.csv")
    meta("format", '"other"', "format-other.csv")
    meta("version", "99", "version-99.csv")
    write("meta-not-json.csv", head + "# broken = {\n" + body)
    write("no-header.csv", head)
    write("header-only.csv", head + body.splitlines()[0] + "\n")
    rows = body.splitlines()

    def cell(column: int, value: str, name: str, row: int = 5) -> None:
        mutated = list(rows)
        parts = mutated[row].split(",")
        parts[column] = value
        mutated[row] = ",".join(parts)
        write(name, head + "\n".join(mutated) + "\n")

    cell(2, "nan", "counter-nan.csv")
    cell(2, "1.5", "counter-fraction.csv")
    cell(2, "1e30", "counter-huge.csv")
    cell(12, "300", "validity-300.csv")
    cell(12, "-1", "validity-negative.csv")
    cell(12, "2.5", "validity-fraction.csv")
    cell(0, "-1", "window-negative.csv")
    cell(0, "0.5", "window-fraction.csv")
    cell(1, "nan", "commanded-nan.csv")
    cell(4, "nan", "gyro-nan.csv")
    cell(4, "1e300", "gyro-huge.csv")
    cell(4, "abc", "gyro-text.csv")
    cell(10, "1e300", "table-huge.csv")
    write("short-row.csv", head + "\n".join([*rows[:6], rows[6][:20], *rows[7:]]) + "\n")
    one = [r for r in rows[1:] if r.startswith("0,")]
    write("one-window.csv", head + rows[0] + "\n" + "\n".join(one) + "\n")
    close = [r.replace(",180.000000,", ",0.500000,", 1) for r in rows[1:]]
    write("positions-close.csv", head + rows[0] + "\n" + "\n".join(close) + "\n")
    flagged = [",".join([*r.split(",")[:12], "0"]) for r in rows[1:]]
    write("validity-clear.csv", head + rows[0] + "\n" + "\n".join(flagged) + "\n")
    with np.load(good4) as data:
        arrays = {k: data[k] for k in data.files}
    for name, meta_json in {
        "meta-list.npz": "[1, 2, 3]",
        "meta-string.npz": '"hello"',
        "meta-broken.npz": "{",
    }.items():
        np.savez(os.path.join(tmp, name), **{**arrays, "meta_json": np.array(meta_json)})
        out[name] = os.path.join(tmp, name)
    np.savez(os.path.join(tmp, "gyro-shape.npz"), **{**arrays, "gyro_dph": arrays["gyro_dph"][:, :2]})
    out["gyro-shape.npz"] = os.path.join(tmp, "gyro-shape.npz")
    np.savez(os.path.join(tmp, "counter-float.npz"),
             **{**arrays, "counter": arrays["counter"].astype(float) + 0.5})  # fmt: skip
    out["counter-float.npz"] = os.path.join(tmp, "counter-float.npz")
    np.savez(os.path.join(tmp, "no-meta.npz"), **{k: v for k, v in arrays.items() if k != "meta_json"})
    out["no-meta.npz"] = os.path.join(tmp, "no-meta.npz")
    write("garbage.npz", "PK\x03\x04 not really a zip")
    return out


def cli_cases(f: dict[str, str], control: str, silent: str, tmp: str) -> list[CliCase]:
    """Every bad-input case of the sweep. ``control``: a live simulator's control address;
    ``silent``: a TCP address that accepts connections and never answers."""
    c: list[CliCase] = []

    def add(command: str, argv: list[str], exit: int, names: str) -> None:
        c.append(CliCase(command, (command, *argv), exit, names))

    missing_dir = os.path.join(tmp, "no", "such", "dir")
    # find and record share the device and plan options: every case is run for both.
    for cmd, lead in (("find", []), ("record", [os.path.join(tmp, "out.npz")])):
        for argv, exit, names in [
            ([], 2, "choose exactly one device"),
            (["--sim", "--serial", "/dev/null"], 2, "choose exactly one device"),
            (["--serial", "/dev/null"], 2, "--latitude"),
            (["-i", "virtual", "-c", "nf-sweep"], 2, "--latitude"),
            (["--serial", os.path.join(tmp, "no-port")], 2, "--latitude"),
            (["--serial", os.path.join(tmp, "no-port"), "--latitude", "34"], 1, "no-port"),
            (["--serial", "/dev/null", "--latitude", "34"], 1, "/dev/null"),
            (["-i", "virtual", "-c", "nf-sweep", "--latitude", "34"], 1, "reply"),
            (["-i", "no-such-interface", "-c", "x", "--latitude", "34"], 2, "interface"),
            (["--serial", "/dev/null", "--latitude", "34", "--reply-timeout", "0.05"], 2,
             "--reply-timeout"),
            (["--serial", "/dev/null", "--latitude", "34", "--reply-timeout", "1e300"], 2,
             "--reply-timeout"),
            (["--serial", "/dev/null", "--latitude", "34", "--link-timeout", "1e300"], 2,
             "--link-timeout"),
            (["--serial", "/dev/null", "--latitude", "34", "--link-timeout", "0"], 2,
             "--link-timeout"),
            (["--serial", "/dev/null", "--latitude", "34", "--speed", "5"], 2, "--speed"),
            (["--serial", "/dev/null", "--latitude", "34", "--sensor", "mems"], 2, "--sensor"),
            (["--serial", "/dev/null", "--latitude", "91"], 2, "latitude"),
            (["--serial", "/dev/null", "--latitude", "nan"], 2, "--latitude"),
            ([*QUICK, "--positions", "0,1"], 2, "positions"),
            ([*QUICK, "--positions", ","], 2, "--positions"),
            ([*QUICK, "--positions", "0,nan"], 2, "--positions"),
            ([*QUICK, "--positions", "0,1e400"], 2, "--positions"),
            ([*QUICK, "--positions", ",".join(["0", "180"] * 200)], 2, "positions"),
            ([*QUICK, "--window", "0"], 2, "--window"),
            ([*QUICK, "--window", "0.01"], 2, "window"),
            ([*QUICK, "--window", "1e7"], 2, "window"),
            ([*QUICK, "--window", "abc"], 2, "--window"),
            ([*QUICK, "--settle", "-1"], 2, "settle"),
            ([*QUICK, "--settle", "1e9"], 2, "settle"),
            ([*QUICK, "--speed", "0"], 2, "--speed"),
            ([*QUICK, "--speed", "1e300"], 2, "speed"),
            ([*QUICK, "--warmup", "-1"], 2, "--warmup"),
            ([*QUICK, "--warmup", "1e300"], 2, "warmup"),
            ([*QUICK, "--timeout", "0"], 2, "--timeout"),
            ([*QUICK, "--timeout", "1e300"], 2, "timeout"),
            ([*QUICK, "--latitude", "91"], 2, "latitude"),
            ([*QUICK, "--latitude", "89.99"], 2, "latitude"),
            ([*QUICK, "--pitch", "40"], 1, "pitch"),
            ([*QUICK, "--azimuth", "inf"], 2, "--azimuth"),
            ([*QUICK, "--seed", "-1"], 2, "--seed"),
            ([*QUICK, "--seed", "1.5"], 2, "--seed"),
            ([*QUICK, "--node-id", "0"], 2, "--node-id"),
            ([*QUICK, "--baud", "0"], 2, "--baud"),
            ([*QUICK, "--sensor", "no-such-preset"], 2, "no-such-preset"),
            ([*QUICK, "--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
            ([*QUICK, "--sensor", f["rate-huge.toml"]], 2, "max_rate_dps"),
            ([*QUICK, "--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
            ([*QUICK, "--sensor", f["arw-huge.toml"]], 2, "arw_dpsh"),
            ([*QUICK, "--sensor", f["not-toml.toml"]], 2, "not-toml"),
            ([*QUICK, "--sensor", f["unknown-field.toml"]], 2, "warp_factor"),
            ([*QUICK, "--sensor", f["string-value.toml"]], 2, "arw_dpsh"),
            ([*QUICK, "--sensor", f["section-value.toml"]], 2, "gyro"),
            ([*QUICK, "--sensor", f["nan.toml"]], 2, "arw_dpsh"),
            ([*QUICK, "--sensor", f["negative.toml"]], 2, "settle_s"),
            ([*QUICK, "--sensor", f["vec.toml"]], 2, "bias_dph"),
            ([*QUICK, "--sensor", tmp], 2, "sensor"),
            ([*QUICK, "--denoise", "magic"], 2, "--denoise"),
            ([*QUICK, "--method", "pairwise"], 2, "--method"),
            ([*QUICK, "--method", "two-position", "--positions", "0,90,180"], 2, "two-position"),
            ([*QUICK, "--reply-timeout", "0.05"], 2, "--reply-timeout"),
            ([*QUICK, "--reply-timeout", "1e300"], 2, "--reply-timeout"),
            ([*QUICK, "--link-timeout", "1e300"], 2, "--link-timeout"),
            ([*QUICK, "--no-such-option"], 2, "unrecognized"),
        ]:
            add(cmd, [*lead, *argv], exit, names)
    add("find", [*QUICK, "--record", os.path.join(tmp, "x.txt")], 2, "--record")
    add("find", [*QUICK, "--record", os.path.join(missing_dir, "x.csv")], 2, "--record")
    add("record", [os.path.join(tmp, "x.txt"), *QUICK], 2, "x.txt")
    add("record", [os.path.join(missing_dir, "x.npz"), *QUICK], 2, "x.npz")
    add("record", [tmp + "/", *QUICK], 2, "file")
    add("record", [], 2, "file")

    # solve: every broken recording
    bad_recordings = {
        "rate-0.csv": "sample_rate_hz", "rate-string.csv": "sample_rate_hz",
        "rate-negative.csv": "sample_rate_hz", "rate-huge.csv": "sample_rate_hz",
        "rate-missing.csv": "sample_rate_hz", "truth-list.csv": "truth",
        "truth-string.csv": "truth", "truth-partial.csv": "truth", "truth-inf.csv": "truth",
        "latitude-missing.csv": "--latitude", "latitude-95.csv": "latitude",
        "latitude-string.csv": "latitude", "plan-number.csv": "plan",
        "format-other.csv": "format", "version-99.csv": "version",
        "meta-not-json.csv": "line", "no-header.csv": "header", "header-only.csv": "samples",
        "empty.csv": "empty.csv", "counter-nan.csv": "counter", "counter-fraction.csv": "counter",
        "counter-huge.csv": "counter", "validity-300.csv": "validity",
        "validity-negative.csv": "validity", "validity-fraction.csv": "validity",
        "window-negative.csv": "window", "window-fraction.csv": "window",
        "commanded-nan.csv": "commanded_deg", "gyro-nan.csv": "gyro",
        "gyro-huge.csv": "gyro", "gyro-text.csv": "gyro_x_dph", "table-huge.csv": "table_deg",
        "short-row.csv": "line", "one-window.csv": "two positions",
        "positions-close.csv": "positions", "meta-list.npz": "meta_json",
        "meta-string.npz": "meta_json", "meta-broken.npz": "meta_json",
        "gyro-shape.npz": "gyro_dph", "counter-float.npz": "counter", "no-meta.npz": "meta_json",
        "garbage.npz": "garbage.npz",
    }  # fmt: skip
    for name, names in bad_recordings.items():
        add("solve", [f[name]], 2, names)
    add("solve", [f["validity-clear.csv"]], 1, "unusable")
    add("solve", [os.path.join(tmp, "absent.csv")], 2, "absent.csv")
    add("solve", [os.path.join(tmp, "run.txt")], 2, "run.txt")
    add("solve", [tmp + "/x.csv"], 2, "x.csv")
    add("solve", [f["good.csv"], "--latitude", "95"], 2, "latitude")
    add("solve", [f["good.csv"], "--latitude", "inf"], 2, "--latitude")
    add("solve", [f["good4.npz"], "--method", "two-position"], 2, "two-position")
    add("solve", [f["good.csv"], "--denoise", "magic"], 2, "--denoise")
    add("solve", [f["good.csv"], "--plot", os.path.join(missing_dir, "p.png")], 2, "--plot")
    add("solve", [], 2, "file")

    # study
    for argv, exit, names in [
        (["--set", "gyro.arw_dpsh=1e300"], 2, "arw_dpsh"),
        (["--set", "gyro.arw_dpsh=abc"], 2, "arw_dpsh"),
        (["--set", "gyro.arw_dpsh=-1"], 2, "arw_dpsh"),
        (["--set", "gyro.warp=1"], 2, "warp"),
        (["--set", "nothing=1"], 2, "nothing"),
        (["--set", "=1"], 2, "--set"),
        (["--set", "table.max_rate_dps=1e-300"], 2, "max_rate_dps"),
        (["--set", "disturbance.impulse_rate_hz=1e9"], 2, "impulse_rate_hz"),
        (["--denoise", "moving-average", "--denoise-option", "window=abc"], 2, "window"),
        (["--denoise", "moving-average", "--denoise-option", "window=0"], 2, "window"),
        (["--denoise", "moving-average", "--denoise-option", "window=1e9"], 2, "window"),
        (["--denoise", "moving-average", "--denoise-option", "window=5", "--denoise-option",
          "nope=1"], 2, "nope"),
        (["--denoise", "wavelet-2p", "--denoise-option", "level=99"], 2, "level"),
        (["--denoise-option", "window=5"], 2, "window"),
        (["--runs", "0"], 2, "--runs"),
        (["--runs", "-5"], 2, "--runs"),
        (["--runs", "100000000000"], 2, "--runs"),
        (["--runs", "1e3"], 2, "--runs"),
        (["--window", "1e7"], 2, "window"),
        (["--window", "0"], 2, "--window"),
        (["--rate", "1e9"], 2, "rate"),
        (["--rate", "0"], 2, "--rate"),
        (["--warmup", "1e300"], 2, "warmup"),
        (["--settle", "1e300"], 2, "settle"),
        (["--positions", "0,1"], 2, "positions"),
        (["--positions", ",".join(["0", "180"] * 200)], 2, "positions"),
        (["--latitude", "90"], 2, "latitude"),
        (["--pitch", "40"], 2, "pitch"),
        (["--seed", "-1"], 2, "--seed"),
        (["--bias-step", "1e300"], 2, "--bias-step"),
        (["--plan-budget", "1e300"], 2, "--plan-budget"),
        (["--plan-budget", "0.001"], 0, ""),  # an answer: no plan fits
        (["--plan-target", "1e-9", "--runs", "0"], 0, ""),
        (["--top", "0"], 2, "--top"),
        (["--top", "100000000"], 2, "--top"),
        (["--sweep", "0,-1", "--plot", os.path.join(tmp, "s.png")], 2, "--sweep"),
        (["--plot", os.path.join(missing_dir, "s.png")], 2, "--plot"),
        (["--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        (["--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        (["--plan", "no-such-plan"], 2, "--plan"),
        (["--solver", "pairwise", "--positions", "0,180"], 0, ""),
    ]:
        add("study", [*argv, "--runs", "20"] if "--runs" not in argv else argv, exit, names)

    # simulate
    for argv, exit, names in [
        (["--window", "1e7"], 2, "window"),
        (["--window", "-1"], 2, "--window"),
        (["--rate", "1e9"], 2, "rate"),
        (["--rate", "0"], 2, "--rate"),
        (["--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        (["--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        (["--sensor", f["rate-huge.toml"]], 2, "max_rate_dps"),
        (["--sensor", f["arw-huge.toml"]], 2, "arw_dpsh"),
        (["--positions", ",".join(["0", "180"] * 200)], 2, "positions"),
        (["--positions", "0,nan"], 2, "--positions"),
        (["--latitude", "95"], 2, "latitude"),
        (["--pitch", "60"], 2, "pitch"),
        (["--seed", "-1"], 2, "--seed"),
        (["--azimuth", "1e400"], 2, "--azimuth"),
    ]:
        add("simulate", argv, exit, names)

    # sim
    for argv, exit, names in [
        ([], 2, "choose exactly one link"),
        (["--pty", "--slcan-pty"], 2, "choose exactly one link"),
        (["--pty", "--baud", "0"], 2, "--baud"),
        (["--pty", "--baud", "-9600"], 2, "--baud"),
        (["--pty", "--speed", "0"], 2, "--speed"),
        (["--pty", "--speed", "1e300"], 2, "speed"),
        (["--pty", "--duration", "1e300"], 2, "duration"),
        (["--pty", "--duration", "0"], 2, "--duration"),
        (["--pty", "--warmup", "-5"], 2, "--warmup"),
        (["--pty", "--warmup", "1e300"], 2, "warmup"),
        (["--pty", "--latitude", "95"], 2, "latitude"),
        (["--pty", "--pitch", "60"], 2, "pitch"),
        (["--pty", "--seed", "-1"], 2, "--seed"),
        (["--pty", "--node-id", "16"], 2, "--node-id"),
        (["--pty", "--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        (["--pty", "--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        (["--pty", "--sensor", "nope"], 2, "nope"),
        (["--pty", "--control", "8.8.8.8:7700"], 2, "loopback"),
        (["--pty", "--control", "127.0.0.1:99999"], 2, "port"),
        (["--pty", "--control", "nonsense"], 2, "control"),
        (["--pty", "--control", f"unix:{f['good.csv']}"], 2, "not a socket"),
        (["--pty", "--control", "unix:" + os.path.join(missing_dir, "s")], 2, "cannot listen"),
        (["--serial", os.path.join(tmp, "no-port")], 1, "no-port"),
        (["-i", "no-such-interface", "-c", "x"], 2, "interface"),
    ]:
        add("sim", argv, exit, names)

    # simctl, against a live simulator and a listener that never answers
    for argv, exit, names in [
        ([], 2, "address"),
        ([control], 2, "op"),
        ([control, "warp"], 2, "warp"),
        ([control, "drop", "count"], 2, "count"),
        ([control, "drop", "count=abc"], 2, "count"),
        ([control, "drop", "count=-1"], 2, "count"),
        ([control, "drop", "count=1e30"], 2, "count"),
        ([control, "drop", "speed=3"], 2, "speed"),
        ([control, "bias_step", "gyro_dph=[NaN,0,0]"], 2, "gyro_dph"),
        ([control, "vibration", "hz=NaN"], 2, "hz"),
        ([control, "impulses", "count=1000000"], 2, "count"),
        ([control, "impulses", "gyro_dph=NaN"], 2, "gyro_dph"),
        ([control, "set_sensor", "values={\"gyro.arw_dpsh\": -1}"], 2, "arw_dpsh"),
        ([control, "set_sensor", "values={\"table.max_rate_dps\": 1e300}"], 2, "max_rate_dps"),
        ([control, "set_truth", "latitude_deg=95"], 2, "latitude_deg"),
        ([control, "speed", "value=0"], 2, "value"),
        (["nonsense", "status"], 2, "nonsense"),
        (["8.8.8.8:7700", "status"], 2, "loopback"),
        (["127.0.0.1:1", "status"], 1, "127.0.0.1:1"),
        (["unix:" + os.path.join(tmp, "absent.sock"), "status"], 1, "absent.sock"),
        ([silent, "status"], 1, "no reply"),
    ]:
        add("simctl", argv, exit, names)

    # conformance
    for argv, exit, names in [
        ([], 2, "choose exactly one link"),
        (["--serial", os.path.join(tmp, "no-port")], 1, "no-port"),
        (["--serial", "/dev/null", "--only", "no.such.check"], 2, "no.such.check"),
        (["--serial", "/dev/null", "--time-scale", "0"], 2, "--time-scale"),
        (["--serial", "/dev/null", "--time-scale", "1e300"], 2, "time-scale"),
        (["--serial", "/dev/null", "--stream-seconds", "1e9"], 2, "stream-seconds"),
        (["--serial", "/dev/null", "--angles", "0,nan"], 2, "--angles"),
        (["--serial", "/dev/null", "--reply-limit-ms", "0"], 2, "--reply-limit-ms"),
        (["--serial", "/dev/null", "--ready-timeout", "1e300"], 2, "ready-timeout"),
        (["--serial", "/dev/null", "--junit", os.path.join(missing_dir, "j.xml")], 2, "--junit"),
        (["-i", "no-such-interface", "-c", "x"], 2, "interface"),
        (["-i", "virtual", "-c", "x", "--node-id", "99"], 2, "--node-id"),
    ]:
        add("conformance", argv, exit, names)

    # calibrate
    for argv, exit, names in [
        ([], 2, "recording"),
        ([os.path.join(tmp, "absent.npz")], 2, "absent.npz"),
        ([f["counter-nan.csv"]], 2, "counter"),
        ([f["meta-list.npz"]], 2, "meta_json"),
        ([f["rate-0.csv"]], 2, "sample_rate_hz"),
        ([f["good.csv"], "--move-tau", "0"], 2, "--move-tau"),
        ([f["good.csv"], "--heat-tau", "nan"], 2, "--heat-tau"),
        ([f["good.csv"], "--heat-tau", "-1"], 2, "--heat-tau"),
        ([f["good.csv"], "--base", "no-such-preset"], 2, "no-such-preset"),
        ([f["good.csv"], "--base", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        ([f["good.csv"], "-o", os.path.join(missing_dir, "x.toml")], 2, "--output"),
        ([f["good.csv"], "--report", os.path.join(missing_dir, "r.txt")], 2, "--report"),
        ([f["good.csv"], "--between", "nowhere"], 2, "--between"),
        ([f["validity-clear.csv"]], 1, "good samples"),  # a valid file whose data are unusable
    ]:
        add("calibrate", argv, exit, names)
    return c


@contextlib.contextmanager
def silent_listener() -> Iterator[str]:
    """A loopback TCP address that accepts connections and never answers (for simctl)."""
    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []
    stop = threading.Event()

    def accept() -> None:
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
                held.append(conn)
            except OSError:
                continue

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(2)
        for conn in held:
            conn.close()
        server.close()


def run_case(case: CliCase, timeout_s: float) -> dict[str, Any]:
    """Run one case as its own process; what came back."""
    t0 = time.monotonic()
    try:
        res = subprocess.run(
            [*SIM, *case.argv], capture_output=True, text=True, timeout=timeout_s,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
    except subprocess.TimeoutExpired:
        return {"case": case, "hang": True, "exit": None, "line": "", "seconds": timeout_s}
    err = [line for line in res.stderr.splitlines() if line.strip()]
    # The one line: argparse's "error:" line or ours; log lines of `sim` come before it.
    lines = [line for line in err if "error" in line]
    return {
        "case": case,
        "hang": False,
        "exit": res.returncode,
        "traceback": "Traceback" in res.stderr,
        "internal": "internal error" in res.stderr,
        "lines": len(lines),
        "line": lines[-1] if lines else (err[-1] if err else ""),
        "seconds": time.monotonic() - t0,
    }


def cli_sweep(args: argparse.Namespace) -> dict[str, Any]:
    """Bad input over every subcommand, each case its own process."""
    from concurrent.futures import ThreadPoolExecutor

    with tempfile.TemporaryDirectory(dir="/tmp") as tmp, silent_listener() as silent, \
            simulator("--control", "127.0.0.1:0") as (_, facts):  # fmt: skip
        files = _files(tmp)
        cases = cli_cases(files, facts["control"], silent, tmp)
        if args.only_cli:
            cases = [c for c in cases if args.only_cli in " ".join(c.argv)]
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            results = list(pool.map(lambda c: run_case(c, args.case_timeout), cases))
    by_command: dict[str, dict[str, int]] = {}
    problems: list[str] = []
    for r in results:
        case: CliCase = r["case"]
        row = by_command.setdefault(
            case.command,
            {"cases": 0, "clean": 0, "tracebacks": 0, "internal": 0, "hangs": 0, "wrong_exit": 0,
             "unnamed": 0},
        )  # fmt: skip
        row["cases"] += 1
        line = r["line"]
        if r["hang"]:
            row["hangs"] += 1
            problems.append(f"HANG    {' '.join(case.argv)[:150]}")
            continue
        bad = []
        if r["traceback"]:
            row["tracebacks"] += 1
            bad.append("traceback")
        if r["internal"]:
            row["internal"] += 1
            bad.append("internal error")
        if r["exit"] != case.exit:
            row["wrong_exit"] += 1
            bad.append(f"exit {r['exit']} (want {case.exit})")
        if case.exit and (r["lines"] != 1 or case.names.lower() not in line.lower()):
            row["unnamed"] += 1
            bad.append(f"line does not name {case.names!r}")
        if bad:
            problems.append(f"{', '.join(bad)}: {' '.join(case.argv)[:120]}\n        -> {line[:200]}")
        else:
            row["clean"] += 1
    print("bad-input sweep (each case its own `northfinder` process, "
          f"{args.case_timeout:g} s limit per case)")  # fmt: skip
    print(f"{'command':<12} {'cases':>6} {'clean':>6} {'tracebacks':>11} {'internal':>9} "
          f"{'hangs':>6} {'wrong exit':>11} {'unnamed':>8}")  # fmt: skip
    total = {k: 0 for k in ("cases", "clean", "tracebacks", "internal", "hangs", "wrong_exit",
                            "unnamed")}  # fmt: skip
    for command, row in by_command.items():
        print(f"{command:<12} {row['cases']:>6} {row['clean']:>6} {row['tracebacks']:>11} "
              f"{row['internal']:>9} {row['hangs']:>6} {row['wrong_exit']:>11} {row['unnamed']:>8}")  # fmt: skip
        for k in total:
            total[k] += row[k]
    print(f"{'all':<12} {total['cases']:>6} {total['clean']:>6} {total['tracebacks']:>11} "
          f"{total['internal']:>9} {total['hangs']:>6} {total['wrong_exit']:>11} {total['unnamed']:>8}")  # fmt: skip
    slowest = max(results, key=lambda r: r["seconds"]) if results else None
    if slowest is not None:
        print(f"slowest case {slowest['seconds']:.1f} s: {' '.join(slowest['case'].argv)[:100]}")
    for p in problems:
        print(f"  {p}")
    return {"by_command": by_command, "total": total, "problems": problems}


#: Section name -> function(args) that prints its table and returns a summary.
SECTIONS: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    "codec": codec_fuzz,
    "control": control_abuse,
    "cli": cli_sweep,
    "find": find_faults,
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS), help="comma-separated")
    parser.add_argument("--seconds-per-case", type=float, default=0.3)
    parser.add_argument("--seed", type=int, default=1, help="codec: random seed")
    parser.add_argument("--fuzz-inputs", type=int, default=200_000, help="codec: per decoder")
    parser.add_argument("--fuzz-frames", type=int, default=300_000, help="codec: mutated frames")
    parser.add_argument("--case-timeout", type=float, default=60.0, help="cli: s per case")
    parser.add_argument("--jobs", type=int, default=2, help="cli: cases run at once")
    parser.add_argument("--only-cli", default="", help="cli: only cases whose argv contains this")
    parser.add_argument("--json", metavar="FILE", help="also write the summaries as JSON")
    args = parser.parse_args()
    names = [s for s in args.sections.split(",") if s]
    unknown = [s for s in names if s not in SECTIONS]
    if unknown:
        parser.error(f"unknown section {unknown[0]!r}; sections are {', '.join(SECTIONS)}")
    results = {name: SECTIONS[name](args) for name in names}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
