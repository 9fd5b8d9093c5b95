"""Codec throughput: decode rate in frames per second, median over several repeats.

A saturated 1 Mbit/s CAN bus carries about 9000 frames/s (111-bit 8-byte frames); the codec must
decode well above that. Run: ``.venv/bin/python benchmarks/bench_codec.py [--frames N] [--repeats R]``.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time
from collections.abc import Callable

from northfinder.driver.protocol import DeviceState, Fault, Sample, Status, Validity
from northfinder.driver.protocol.can import CanReceiver, decode_can, encode_can
from northfinder.driver.protocol.serial import Deframer, SerialEncoder

SATURATED_1MBIT_FRAMES_PER_S = 9000


def make_samples(n: int, rng: random.Random) -> list[Sample]:
    """``n`` consecutive sample ticks with random channel values."""

    def r(bits: int) -> int:
        return rng.randrange(-(1 << (bits - 1)), 1 << (bits - 1))

    return [
        Sample(
            k,
            (r(32), r(32), r(32)),
            (r(24), r(24), r(24)),
            rng.randrange(360_000_000),
            r(16),
            Validity.GYRO_VALID | Validity.ACCEL_VALID,
        )
        for k in range(n)
    ]


def time_runs(run: Callable[[], int], repeats: int) -> tuple[float, list[float]]:
    """Median frames/s of ``run`` (which returns the frames it handled) over ``repeats``."""
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        frames = run()
        rates.append(frames / (time.perf_counter() - t0))
    return statistics.median(rates), rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40_000, help="CAN frames per repeat")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    rng = random.Random(0)
    ticks = make_samples(args.frames // 4, rng)
    status = Status(DeviceState.READY, 0, 2500, Fault(0), 0, 0, 0, 0)
    can_frames = [f for s in ticks for f in encode_can(s)]
    encoder = SerialEncoder()
    serial_stream = b"".join(encoder.encode(s) for s in ticks) + encoder.encode(status)
    serial_frames = len(ticks) + 1

    def can_decode() -> int:
        for arbitration_id, data in can_frames:
            decode_can(arbitration_id, data)
        return len(can_frames)

    def can_receive() -> int:
        receiver = CanReceiver(node_id=1)
        for arbitration_id, data in can_frames:
            receiver.feed(arbitration_id, data)
        assert receiver.ticks.complete == len(ticks)
        return len(can_frames)

    def serial_receive() -> int:
        deframer = Deframer()
        out = []
        for i in range(0, len(serial_stream), 256):  # UART-like 256-byte reads
            out += deframer.feed_messages(serial_stream[i : i + 256])
        assert len(out) == serial_frames
        return serial_frames

    print(
        f"{len(can_frames)} CAN frames / {serial_frames} serial frames per run, "
        f"median of {args.repeats} runs"
    )
    for name, run in (
        ("CAN decode_can (one frame -> message)", can_decode),
        ("CAN CanReceiver (decode + tick reassembly)", can_receive),
        ("serial Deframer.feed_messages (frames)", serial_receive),
    ):
        median, rates = time_runs(run, args.repeats)
        spread = f"{min(rates):,.0f}..{max(rates):,.0f}"
        print(
            f"{name:45s} {median:12,.0f} frames/s  (runs {spread}; "
            f"{median / SATURATED_1MBIT_FRAMES_PER_S:.0f}x a saturated 1 Mbit/s bus)"
        )


if __name__ == "__main__":
    main()
