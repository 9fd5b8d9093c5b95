"""``interrupt``: ``northfinder find`` ended by a real signal or by the unit's silence during a
move and during a spin (a section of ``bench_robustness.py``).

For each link (``serial-pty``, ``slcan-pty``; ``socketcan`` where vcan0 exists, as in
``scripts/hil``) one ``northfinder sim`` process runs at real time; ``northfinder find`` runs
against it in another process ``--interrupt-runs`` times per signal (SIGINT and SIGTERM), and
each run is sent the signal as soon as the simulator's control channel reads ROTATING (``find
--spin 5``: SPINNING, then half a second into the spin's window). A third case per mode is no
signal but the unit's silence: nothing sent for 0.8 s, ordered through the control channel, which
ends the run by the host's link supervision (three heartbeat periods, 0.3 s). Counted: runs caught
moving, exit statuses as stated (130, 143; 1 for the lost link), and the unit's state read
through the control channel after the host exited: READY or SETTLING with the stream off is at
rest; ROTATING, SPINNING or a stream left on is not. The median time from the signal to the host's exit is printed too.
A run that fails for another reason (the simulator died: it is started again) counts as an error,
with the simulator's last log line.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import statistics
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))

from interruption import (
    LINKS,
    VCAN,
    HostHung,
    Interrupted,
    interrupt_during_move,
    sim_link_args,
)
from simprocess import sim_process

SIGNALS = (signal.SIGINT, signal.SIGTERM, 0)  # 0: the unit's silence instead of a signal
MODES = ("move", "spin")


def interrupt_runs(args: argparse.Namespace) -> dict[str, Any]:
    n = args.interrupt_runs
    links = [x for x in LINKS if x != "socketcan" or os.path.exists(f"/sys/class/net/{VCAN}")]
    if args.interrupt_links:
        links = [x for x in args.interrupt_links.split(",") if x]
    print(f"find interrupted during a move and a spin ({n} runs per link, mode and signal or "
          "silence; the unit's state read through the control channel after the host exited)")  # fmt: skip
    print(f"{'link':<11} {'mode':<5} {'signal':<8} {'runs':>4} {'moving':>6} {'status ok':>9} {'at rest':>7} "
          f"{'moving':>8} {'streaming':>9} {'exit s (median)':>15} {'errors':>6}")  # fmt: skip
    rows = []
    for link in links:
        wanted = ("control",) if link == "socketcan" else ("pty", "control")
        sim_args = [*sim_link_args(link), "--warmup", "0", "--control", "127.0.0.1:0"]
        stack = contextlib.ExitStack()
        facts: dict[str, str] | None = None
        for mode, signum in [(m, s) for m in MODES for s in SIGNALS]:
            runs: list[Interrupted] = []
            errors: list[str] = []
            while len(runs) + len(errors) < n:
                try:
                    if facts is None:
                        facts = stack.enter_context(
                            sim_process(*sim_args, wanted=wanted, ready=True, check_exit=False)
                        )
                    runs.append(
                        interrupt_during_move(link, signum, facts=facts, spin=mode == "spin")
                    )
                except Exception as exc:  # a simulator that died: counted, started again
                    stack.close()
                    log = (facts or {}).get("stderr", "").strip().splitlines()
                    what = str(exc) if isinstance(exc, HostHung) else repr(exc)
                    errors.append(f"{what}\nsimulator: {log[-1] if log else '?'}")
                    facts, stack = None, contextlib.ExitStack()
            row = {
                "link": link,
                "mode": mode,
                "signal": signal.Signals(signum).name if signum else "silence",
                "runs": len(runs),
                "errors": errors,
                "caught_moving": sum(r.caught_moving for r in runs),
                "status_ok": sum(r.returncode == (128 + signum if signum else 1) for r in runs),
                "at_rest": sum(r.at_rest for r in runs),
                "rotating": sum(r.state in ("ROTATING", "SPINNING") for r in runs),
                "streaming": sum(r.streaming for r in runs),
                "exit_s_median": statistics.median(r.exit_s for r in runs) if runs else math.nan,
                "states": sorted({r.state for r in runs}),
                "not_at_rest": [r.to_dict() for r in runs if not r.at_rest],
            }
            rows.append(row)
            print(f"{link:<11} {mode:<5} {row['signal']:<8} {len(runs):>4} {row['caught_moving']:>6} "
                  f"{row['status_ok']:>9} {row['at_rest']:>7} {row['rotating']:>8} "
                  f"{row['streaming']:>9} {row['exit_s_median']:>15.3f} {len(errors):>6}",
                  flush=True)  # fmt: skip
            for e in errors:
                print("  error: " + e.replace("\n", "\n    "), flush=True)
        stack.close()
    return {"rows": rows}
