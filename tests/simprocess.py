"""``northfinder sim`` as a subprocess, for the tests: started, its facts read, always stopped."""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

COMMAND = [
    sys.executable,
    "-c",
    "from northfinder.cli import main; raise SystemExit(main())",
    "sim",
]


def _pump(stream: IO[str], into: queue.SimpleQueue[str] | list[str]) -> None:
    for line in stream:
        if isinstance(into, list):
            into.append(line)
        else:
            into.put(line)


def _wait_ready(control: str, deadline: float, errors: list[str]) -> None:
    from northfinder.firmware_sim.control import ControlClient

    with ControlClient(control) as ctl:
        while (state := ctl.call("status")["state"]) != "READY":
            if time.monotonic() > deadline:
                raise RuntimeError(f"the simulator was still {state}: {''.join(errors)}")
            time.sleep(0.02)


@contextmanager
def sim_process(
    *args: str,
    wanted: Collection[str] = ("pty", "control"),
    timeout: float = 20.0,
    check_exit: bool = True,
    ready: bool = False,
) -> Iterator[dict[str, str]]:
    """Start ``northfinder sim ARGS`` and yield the ``key value`` facts it prints on stdout (once
    every name in ``wanted`` was seen); on leaving stop it with SIGTERM (then ``facts["stderr"]``
    holds its log).

    Parameters
    ----------
    check_exit : bool
        Assert that it exits with status 0 (its stderr is the message).
    ready : bool
        Yield only once the device reports READY on its control channel (past BOOT and warm-up;
        however long a busy machine takes to start it), within ``timeout``.

    Raises
    ------
    RuntimeError
        The facts did not come within ``timeout`` wall seconds (the message has its stderr).
    """
    proc = subprocess.Popen(
        [*COMMAND, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1
    )
    assert proc.stdout is not None and proc.stderr is not None
    lines: queue.SimpleQueue[str] = queue.SimpleQueue()
    errors: list[str] = []
    # Threads, not select(): the text wrapper may hold several lines already read from the pipe;
    # stderr is read all along so that the simulator's log never fills the pipe.
    readers = [
        threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True),
        threading.Thread(target=_pump, args=(proc.stderr, errors), daemon=True),
    ]
    for r in readers:
        r.start()
    facts: dict[str, str] = {}
    try:
        deadline = time.monotonic() + timeout
        while not set(wanted) <= set(facts):
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise RuntimeError(
                    f"the simulator did not print {sorted(wanted)} in {timeout} s "
                    f"(exit status {proc.poll()}): {''.join(errors)}"
                ) from None
            key, _, value = line.strip().partition(" ")
            facts[key] = value
        facts["pid"] = str(proc.pid)
        if ready:
            _wait_ready(facts["control"], deadline, errors)
        yield facts
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        for r in readers:
            r.join(5)
        facts["stderr"] = "".join(errors)  # its log, for a test to read after the block
        proc.stdout.close()
        proc.stderr.close()
    if check_exit:
        assert proc.returncode == 0, "".join(errors)


#: The tests' fast table: moves in well under a second, so a conformance run on a pseudo-terminal
#: spends its wall time on what it checks.
FAST_TABLE = {
    "max_rate_dps": 45.0,
    "max_accel_dps2": 200.0,
    "settle_s": 0.5,
    "indexing_error_deg": 0.005,
    "overshoot_deg": 0.0,
}


def fast_sensor_file(folder: Path) -> Path:
    """The nav-fog preset with :data:`FAST_TABLE`, as a TOML file for ``northfinder sim --sensor``."""
    text = Path(__file__).parents[1].joinpath("firmware_sim/presets/nav-fog.toml").read_text()
    head, _, _ = text.partition("[table]")
    table = "\n".join(f"{k} = {v}" for k, v in FAST_TABLE.items())
    path = folder / "fast-table.toml"
    path.write_text(f"{head}[table]\n{table}\n")
    return path
