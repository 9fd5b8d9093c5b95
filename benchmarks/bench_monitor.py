"""The monitor's CPU cost, and its effect on a 200 Hz stream on the pseudo-terminal links.

Run: ``.venv/bin/python benchmarks/bench_monitor.py [--duration 60] [--repeats 3]
[--links slcan,serial]``.

For each link (``slcan``: ``northfinder sim --slcan-pty``; ``serial``: ``northfinder sim --pty``,
each a process of its own, paper-rlg, 200 Hz, warm-up 0) and each host, run ``--duration`` wall
seconds and read the host's process CPU time (user + system, all its threads) over that time:

- ``bare``: a process that opens the driver's ``Device`` on the link, starts the stream and does
  nothing else (the floor: what reading the link costs);
- ``monitor``: ``northfinder monitor`` as a person runs it, drawing to a pseudo-terminal of
  120 x 40 (the screen's bytes are read and thrown away, as a terminal would), at its defaults
  (panels 10 Hz, traces 2 Hz);
- ``monitor-fast``: the same at ``--refresh 30 --plot-rate 10`` (the most it offers);
- ``monitor-record``: ``monitor`` recording every frame (``w`` pressed once it runs, ``w`` again
  before it quits): the CAN log's frames are counted (``log frames``; a 200 Hz stream is 820
  frames a second with its statuses: four a sample, two a status);
- ``monitor-frames``: ``monitor`` showing its frame view (``m``) instead of the panels.

The stream's health is read from both ends: the monitor's own counters (``--summary``: samples,
gaps, ticks lost, partial ticks, late samples) and the simulator's status (``tx_dropped``: frames
it could not send because the host did not read them in time). Target: 0 lost, 0 dropped.

The monitor's CPU time includes its start (imports, the first screen): about a second, so the
figure for a ``--duration`` of 60 s is about 2 points above the steady state. Medians over
``--repeats`` runs; the machine is shared, so the 1-minute load average is printed beside them.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from simprocess import sim_process

from northfinder.firmware_sim.control import ControlClient

PYTHON = sys.executable
SIM_ARGS = {"slcan": "--slcan-pty", "serial": "--pty"}
BARE = """
import sys, time
from northfinder.driver.device import Device
import can
kind, path, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
if kind == "serial":
    dev = Device.open_serial(path, min_supervision_s=1.0)
else:
    dev = Device.from_bus(can.Bus(interface="slcan", channel=path, sleep_after_open=0), own_bus=True,
                          min_supervision_s=1.0)
with dev:
    dev.wait_ready(10)
    dev.start_streaming()
    c0 = time.process_time(); t0 = time.monotonic()
    time.sleep(seconds)
    cpu = time.process_time() - c0; wall = time.monotonic() - t0
    st = dev.stats()
    print(f"{100 * cpu / wall:.2f} {st.samples_received} {st.ticks_lost}")
"""


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (all its threads), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_monitor(
    kind: str, path: str, seconds: float, extra: list[str], keys: bytes = b"", end_keys: bytes = b""
) -> dict[str, Any]:
    """``northfinder monitor`` on a pty of 120 x 40 for ``seconds``, ``keys`` typed once it runs
    and ``end_keys`` before it quits; its summary, CPU and the frames of its CAN log."""
    link = (
        ["-i", "slcan", "-c", path, "--bus-kwargs", "sleep_after_open=0"]
        if kind == "slcan"
        else ["--serial", path]
    )
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    with tempfile.TemporaryDirectory() as tmp:
        summary = Path(tmp) / "summary.json"
        record = Path(tmp) / "monitor.log"
        env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "120", "LINES": "40"}
        proc = subprocess.Popen(
            [PYTHON, "-c", "from northfinder.cli import main; raise SystemExit(main())",
             "monitor", *link, "--latitude", "34",
             "--link-timeout", "1", "--summary", str(summary), "--record", str(record),
             *extra],
            stdin=slave, stdout=slave, stderr=slave, env=env, start_new_session=True,
        )  # fmt: skip
        os.close(slave)
        drawn = [0]

        def drain() -> None:  # the terminal: read what the screen draws
            while True:
                try:
                    data = os.read(master, 65536)
                except OSError:
                    return
                if not data:
                    return
                drawn[0] += len(data)

        reader = threading.Thread(target=drain, daemon=True)
        reader.start()
        t0 = time.monotonic()
        time.sleep(3.0)  # its start: imports, the first screen, the stream started
        if keys:
            os.write(master, keys)
        c_start, t_start = _cpu_s(proc.pid), time.monotonic()
        time.sleep(seconds)
        cpu = _cpu_s(proc.pid) - c_start
        wall = time.monotonic() - t_start
        if end_keys:
            os.write(master, end_keys)
            time.sleep(1.0)
        t_quit = time.monotonic()
        os.write(master, b"q")
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        quit_s = time.monotonic() - t_quit
        os.close(master)
        reader.join(2)
        data = json.loads(summary.read_text()) if summary.exists() else {}
        data["quit_s"] = quit_s
        if record.exists():
            data["log_frames"] = sum(1 for line in record.open() if line.strip())
    data["steady_cpu_percent"] = 100.0 * cpu / wall
    data["screen_kib_per_s"] = drawn[0] / 1024.0 / (time.monotonic() - t0)
    data["exit"] = proc.returncode
    return data


def run_bare(kind: str, path: str, seconds: float) -> dict[str, Any]:
    out = subprocess.run(
        [PYTHON, "-c", BARE, kind, path, str(seconds)], capture_output=True, text=True, timeout=seconds + 60
    )  # fmt: skip
    if out.returncode:
        raise RuntimeError(out.stderr)
    cpu, samples, lost = out.stdout.split()
    return {"steady_cpu_percent": float(cpu), "samples": int(samples), "ticks_lost": int(lost)}


def one(kind: str, host: str, seconds: float) -> dict[str, Any]:
    with sim_process(
        SIM_ARGS[kind], "--warmup", "0", "--control", "127.0.0.1:0", ready=True
    ) as facts:
        if host == "bare":
            r = run_bare(kind, facts["pty"], seconds)
        else:
            extra = ["--refresh", "30", "--plot-rate", "10"] if host == "monitor-fast" else []
            keys, end_keys = {"monitor-record": (b"w", b"w"), "monitor-frames": (b"m", b"")}.get(
                host, (b"", b"")
            )
            r = run_monitor(kind, facts["pty"], seconds, extra, keys, end_keys)
        with ControlClient(facts["control"]) as ctl:
            st = ctl.call("status")
        r["sim_tx_dropped"] = st.get("tx_dropped", st.get("counters", {}).get("tx_dropped"))
    return r


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--duration", type=float, default=60.0, help="wall seconds per run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--links", default="slcan,serial")
    ap.add_argument("--hosts", default="bare,monitor,monitor-fast,monitor-record,monitor-frames")
    args = ap.parse_args()
    print(f"{os.cpu_count()} cores; {args.duration:g} s per run, medians of {args.repeats}")
    print(f"{'link':<7} {'host':<14} {'CPU %':>6} {'samples':>8} {'lost':>5} {'gaps':>5} "
          f"{'partial':>7} {'late':>5} {'dropped':>7} {'log frames':>10} {'quit s':>6} "
          f"{'load':>5}")  # fmt: skip
    for kind in args.links.split(","):
        for host in args.hosts.split(","):
            runs = [one(kind, host, args.duration) for _ in range(args.repeats)]
            load = os.getloadavg()[0]

            def med(key: str, runs: list[dict[str, Any]] = runs) -> Any:
                values = [r[key] for r in runs if r.get(key) is not None]
                return statistics.median(values) if values else "-"

            quit_s = med("quit_s")
            print(
                f"{kind:<7} {host:<14} {med('steady_cpu_percent'):>6.1f} {med('samples'):>8} "
                f"{med('ticks_lost'):>5} {med('gaps'):>5} {med('ticks_incomplete'):>7} "
                f"{med('late'):>5} {med('sim_tx_dropped'):>7} {med('log_frames'):>10} "
                f"{quit_s if quit_s == '-' else f'{quit_s:.2f}':>6} {load:>5.2f}",
                flush=True,
            )
            for r in runs:
                if r.get("exit") not in (None, 0):
                    print(f"  a monitor run exited {r['exit']}", flush=True)


if __name__ == "__main__":
    main()
