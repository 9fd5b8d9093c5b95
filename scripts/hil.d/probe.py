"""HIL step "probe": what the guest costs, measured where the other steps run.

- ``python_loop_2e6_s``: a pure-Python loop of 2e6 additions (CPU speed of the interpreter);
- ``monotonic_call_us``: one ``time.monotonic()`` call (a system call where there is no vDSO,
  as under user-mode Linux, where every system call is a round trip through the tracing kernel);
- ``socketcan_send_ms``: one python-can SocketCAN ``send`` on the interface, back to back, with no
  other listener; ``socketcan_send_fps`` its inverse.

    python probe.py --out DIR [--channel vcan0] [--frames 4000]

Writes DIR/result.json; exits 0 unless the interface cannot be opened. Uses only python-can and
the standard library.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def loop_seconds(n: int) -> float:
    t = time.perf_counter()
    s = 0
    for i in range(n):
        s += i
    return time.perf_counter() - t


def monotonic_us(n: int) -> float:
    f = time.monotonic
    t = time.perf_counter()
    for _ in range(n):
        f()
    return (time.perf_counter() - t) / n * 1e6


def send_ms(channel: str, frames: int) -> float:
    import can

    with can.Bus(interface="socketcan", channel=channel, receive_own_messages=False) as bus:
        msg = can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False)
        t = time.perf_counter()
        for _ in range(frames):
            bus.send(msg)
        return (time.perf_counter() - t) / frames * 1e3


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=".")
    p.add_argument("--channel", default=os.environ.get("HIL_CAN_IF", "vcan0"))
    p.add_argument("--frames", type=int, default=4000)
    args = p.parse_args(argv)
    result: dict = {
        "step": "probe",
        "python_loop_2e6_s": round(min(loop_seconds(2_000_000) for _ in range(3)), 3),
        "monotonic_call_us": round(min(monotonic_us(20_000) for _ in range(3)), 2),
    }
    ms = send_ms(args.channel, args.frames)
    result.update(socketcan_send_ms=round(ms, 4), socketcan_send_fps=round(1e3 / ms))
    with open(os.path.join(args.out, "result.json"), "w") as f:
        json.dump(result, f, indent=2)
        f.write("\n")
    print(
        f"probe: 2e6-iteration loop {result['python_loop_2e6_s']} s, time.monotonic "
        f"{result['monotonic_call_us']} us, SocketCAN send {result['socketcan_send_ms']} ms "
        f"({result['socketcan_send_fps']} frames/s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
