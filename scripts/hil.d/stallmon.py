"""Stall monitor: how long the whole machine (the guest, in a VM) stops running its processes.

Sleeps ``--period`` seconds in a loop and records every wake-up later than ``--threshold``
seconds after it was due. Run at the highest real-time priority, nothing inside the machine
delays it, so what it records is the machine itself not running: in a VM, the host not
scheduling the VM or the VM's kernel blocked on the host. Until SIGTERM or SIGINT, then one JSON
line on stdout: ``{"wakeups", "stalls", "stall_ms_max", "stall_ms_total", "stalls_ms": [[t_s, ms],
...]}`` with t_s seconds since the start, and ``clock_call_us``: the cost of one ``time.monotonic()`` call,
timed over 100 calls every ``--cost-every`` seconds (``p50``, ``p90``, ``max`` and the list): a
system call under user-mode Linux, so what the host's load makes every system call of the guest
cost, measured at a priority nothing in the guest can delay.

    python stallmon.py [--period 0.01] [--threshold 0.02] [--cost-every 1.0]
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import sys
import time


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--period", type=float, default=0.01)
    p.add_argument("--threshold", type=float, default=0.02)
    p.add_argument("--cost-every", type=float, default=1.0)
    args = p.parse_args(argv)
    stop = False

    def on_signal(*_: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    clock = time.monotonic
    t0 = due = clock()
    wakeups = 0
    stalls: list[list[float]] = []
    costs: list[float] = []
    next_cost = t0
    while not stop:
        due += args.period
        now = clock()
        if due > now:
            time.sleep(due - now)
            now = clock()
        wakeups += 1
        late = now - due
        if late > args.threshold:
            stalls.append([round(due - t0, 3), round(late * 1e3, 1)])
            due = now  # one stall is one record, not a train of late wake-ups
        if now >= next_cost:
            t = time.perf_counter()
            for _ in range(100):
                clock()
            costs.append(round((time.perf_counter() - t) * 1e4, 2))  # us per call
            next_cost = now + args.cost_every
    deciles = statistics.quantiles(costs, n=10, method="inclusive") if len(costs) > 1 else costs * 9
    print(
        json.dumps(
            {
                "wakeups": wakeups,
                "stalls": len(stalls),
                "stall_ms_max": max((s[1] for s in stalls), default=0.0),
                "stall_ms_total": round(sum(s[1] for s in stalls), 1),
                "stalls_ms": stalls,
                "clock_call_us": {
                    "p50": round(deciles[4], 2) if deciles else None,
                    "p90": round(deciles[8], 2) if deciles else None,
                    "max": max(costs, default=None),
                    "samples": costs,
                },
            }
        ),
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
