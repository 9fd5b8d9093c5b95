"""The virtual-time engine's cost per 200 Hz tick against the floor of python-can's ``virtual`` bus.

Run: ``.venv/bin/python benchmarks/bench_engine_floor.py [--ticks 200000] [--repeats 5]
[--windows 30,150] [--engine-repeats 3]``.

A tick of the stream is four CAN frames (SAMPLE_X, _Y, _Z, _AUX). The floor is what carrying
those frames over python-can's ``virtual`` bus costs with nothing else done, per tick, in this
process's CPU time (``time.process_time``: the machine is shared, so wall time says little):

- ``bare loop``: an empty ``for`` loop, one turn a tick;
- ``python-can send/recv``: four ``can.Message`` built, ``bus.send`` for each (python-can copies
  every message for every receiver), the receiver's ``recv(0)`` until it has none;
- ``virtual bus, batch``: four ``can.Message`` built and put on the receiver's queue of the same
  channel as they are (the embedded simulator's device end does so: one message shared, no copy),
  taken by the receiver in a batch (its first by ``recv(0)``, the rest from its queue), nothing
  decoded. This is the cheapest way the frames can travel over the bus: the floor.

The engine's figure is marginal: ``northfinder find --sim --positions 0,90 --window W`` run in
this process for two window lengths, the difference of their CPU times over the difference of
their ticks (two windows each), so the start-up, warm-up, moves and settling cancel out. Medians
of the repeats; the ratio to the floor is engine over ``virtual bus, batch``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import time
import uuid
from collections.abc import Callable

import can
from can.interfaces.virtual import VirtualBus

from northfinder.driver.protocol.can import CanFunction
from northfinder.driver.protocol.constants import Validity
from northfinder.driver.protocol.messages import Sample

RATE_HZ = 200
NODE = 1
#: The stream's four frames of one tick (ids and data of a real sample).
_SAMPLE = Sample(
    12345, (1000, -2000, 300000), (-4000, 5000, 1 << 20), 90_000_000, 2500, Validity(0x3F)
)
FRAMES = list(
    zip(
        [f | NODE for f in (CanFunction.SAMPLE_X, CanFunction.SAMPLE_Y, CanFunction.SAMPLE_Z,
                            CanFunction.SAMPLE_AUX)],
        _SAMPLE.can_payloads(),
        strict=True,
    )
)  # fmt: skip


def bare_loop(ticks: int) -> float:
    t0 = time.process_time()
    for _ in range(ticks):
        pass
    return time.process_time() - t0


def _pair() -> tuple[VirtualBus, VirtualBus]:
    channel = f"floor-{uuid.uuid4().hex}"
    return VirtualBus(channel=channel), VirtualBus(channel=channel)


def python_can(ticks: int) -> float:
    tx, rx = _pair()
    message = can.Message
    try:
        t0 = time.process_time()
        for _ in range(ticks):
            for arbitration_id, data in FRAMES:
                tx.send(message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
            while rx.recv(0.0) is not None:
                pass
        return time.process_time() - t0
    finally:
        tx.shutdown()
        rx.shutdown()


def virtual_batch(ticks: int) -> float:
    tx, rx = _pair()
    message = can.Message
    (q,) = [q for q in tx.channel if q is not tx.queue]  # the receiver's queue
    try:
        t0 = time.process_time()
        for _ in range(ticks):
            for arbitration_id, data in FRAMES:
                q.put(message(arbitration_id=arbitration_id, data=data, is_extended_id=False))
            out = [rx.recv(0.0)]
            while not q.empty():
                out.append(q.get_nowait())
        return time.process_time() - t0
    finally:
        tx.shutdown()
        rx.shutdown()


FLOORS: dict[str, Callable[[int], float]] = {
    "bare loop": bare_loop,
    "python-can send/recv": python_can,
    "virtual bus, batch": virtual_batch,
}


def engine_cpu(window_s: float, seed: int) -> float:
    """CPU seconds of ``find --sim --positions 0,90 --window W`` run in this process."""
    from northfinder.cli import main as cli_main

    args = ["find", "--sim", "--seed", str(seed), "--positions", "0,90",
            "--window", f"{window_s:g}", "--json"]  # fmt: skip
    t0 = time.process_time()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli_main(args)
    cpu = time.process_time() - t0
    if rc not in (0, None):
        raise SystemExit(f"northfinder {' '.join(args)} failed ({rc})")
    return cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=200_000, help="ticks of each floor run")
    ap.add_argument("--repeats", type=int, default=5, help="runs of each floor (median)")
    ap.add_argument("--windows", default="30,150", help="the engine's two window lengths, s")
    ap.add_argument("--engine-repeats", type=int, default=3, help="runs of each window (median)")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    us: dict[str, float] = {}
    for name, run in FLOORS.items():
        runs = [run(a.ticks) / a.ticks * 1e6 for _ in range(a.repeats)]
        us[name] = statistics.median(runs)
        print(json.dumps({"floor": name, "us_per_tick": runs}))
    w1, w2 = (float(w) for w in a.windows.split(","))
    engine_cpu(10.0, a.seed)  # the first run's imports and caches
    cpu = {w: [engine_cpu(w, a.seed + k) for k in range(a.engine_repeats)] for w in (w1, w2)}
    print(json.dumps({"engine_cpu_s": cpu}))
    extra_ticks = 2 * (w2 - w1) * RATE_HZ
    engine = (statistics.median(cpu[w2]) - statistics.median(cpu[w1])) / extra_ticks * 1e6
    floor = us["virtual bus, batch"]
    print(
        f"{'per 200 Hz tick, CPU (median)':40} {'us':>8} {'x floor':>8} {'x real at this cost':>20}"
    )
    for name, cost in [*us.items(), (f"engine: find --window {w1:g} -> {w2:g}", engine)]:
        print(f"{name:40} {cost:8.2f} {cost / floor:8.2f} {1e6 / RATE_HZ / cost:20.0f}")


if __name__ == "__main__":
    main()
