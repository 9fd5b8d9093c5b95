"""A ``northfinder find`` process ended by a real signal during a move, and what the unit reads
afterwards through the simulator's control channel (used by the tests and by
``benchmarks/bench_robustness.py --sections interrupt``).

The simulator (``northfinder sim``) and the host (``northfinder find``) are separate processes
on a pty (serial frames or SLCAN) or on vcan0; the control channel tells the truth of the
simulated unit whatever the host believes.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Any

from simprocess import sim_process

#: ``-X faulthandler``: a host that does not exit after the signal is sent SIGABRT, which makes it
#: write every thread's stack to stderr (in :class:`HostHung`) before it ends.
FIND = [sys.executable, "-X", "faulthandler", "-c",
        "from northfinder.cli import main; raise SystemExit(main())", "find"]  # fmt: skip
#: Seconds a host may take to exit after the signal before it counts as hung.
EXIT_TIMEOUT_S = 30.0


class HostHung(RuntimeError):
    """The host did not exit within :data:`EXIT_TIMEOUT_S` of the signal; the message ends with
    its stderr, every thread's stack among it."""


LINKS = ("serial-pty", "slcan-pty", "socketcan")
VCAN = "vcan0"
#: The plan of the interrupted run: long windows, so that the moves stand out.
PLAN = ["--positions", "0,180,180,0", "--window", "2", "--latitude", "34"]


@dataclass(frozen=True)
class Interrupted:
    """One run: the signal, the host's exit status and last stderr line, the seconds from the
    signal to its exit, and the unit's state and stream as the control channel reads them."""

    link: str
    signum: int
    returncode: int | None
    last_line: str
    exit_s: float
    state: str
    streaming: bool
    table_deg: float
    caught_moving: bool

    @property
    def at_rest(self) -> bool:
        return self.state in ("READY", "SETTLING") and not self.streaming

    def to_dict(self) -> dict[str, Any]:
        name = signal.Signals(self.signum).name if self.signum else "silence"
        return {**self.__dict__, "signal": name}


def sim_link_args(link: str) -> list[str]:
    return {"serial-pty": ["--pty"], "slcan-pty": ["--slcan-pty"]}.get(
        link, ["-i", "socketcan", "-c", VCAN]
    )


def host_link_args(link: str, facts: dict[str, str]) -> list[str]:
    if link == "serial-pty":
        return ["--serial", facts["pty"]]
    if link == "slcan-pty":
        return [
            "-i",
            "slcan",
            "-c",
            facts["pty"],
            "-b",
            "500000",
            "--bus-kwargs",
            "sleep_after_open=0",
        ]
    return ["-i", "socketcan", "-c", VCAN]


#: The spin of an interrupted spin run: 5 deg/s for 20 s.
SPIN = ["--spin", "5", "--spin-time", "20", "--latitude", "34"]
#: A silence of the unit: this many seconds with nothing sent, ordered through the control channel
#: (the link counts as lost after three heartbeat periods, 0.3 s).
SILENCE_S = 0.8


def interrupt_during_move(
    link: str,
    signum: int,
    *,
    seed: int = 1,
    facts: dict[str, str] | None = None,
    spin: bool = False,
) -> Interrupted:
    """Run ``find`` against a simulator on ``link`` (started here unless ``facts`` of a running
    one are given), send ``signum`` once the control channel reads ROTATING (with ``spin``:
    ``find --spin`` and SPINNING), and read the unit's state once the host has exited.

    ``signum`` 0 sends no signal: the unit falls silent for :data:`SILENCE_S` instead (the host's
    link supervision ends the run), with the driver's default supervision time."""
    if facts is None:
        wanted = ("control",) if link == "socketcan" else ("pty", "control")
        args = [*sim_link_args(link), "--warmup", "0", "--seed", str(seed)]
        with sim_process(*args, "--control", "127.0.0.1:0", wanted=wanted, ready=True) as f:
            return interrupt_during_move(link, signum, seed=seed, facts=f, spin=spin)
    from northfinder.firmware_sim.control import ControlClient

    argv = [*FIND, *host_link_args(link, facts), *(SPIN if spin else PLAN)]
    if signum:
        argv += ["--link-timeout", "1"]
    moving = "SPINNING" if spin else "ROTATING"
    with ControlClient(facts["control"]) as ctl:
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60.0
            caught = False
            while proc.poll() is None and time.monotonic() < deadline:
                if ctl.call("status")["state"] == moving:
                    caught = True
                    break
                time.sleep(0.005)
            if spin and caught:
                time.sleep(0.5)  # into the spin's window: the stream runs
            sent_at = time.monotonic()
            if signum:
                proc.send_signal(signum)
            else:
                ctl.call("silent", on=True)
                time.sleep(SILENCE_S)
                ctl.call("silent", on=False)
            try:
                _, err = proc.communicate(timeout=EXIT_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGABRT)
                try:
                    _, err = proc.communicate(timeout=10.0)
                except subprocess.TimeoutExpired:
                    err = "(no stack: the host did not end on SIGABRT either)"
                raise HostHung(
                    f"find did not exit within {EXIT_TIMEOUT_S:g} s of "
                    f"{signal.Signals(signum).name if signum else 'a silence'} "
                    f"(caught moving: {caught}); its stderr:\n"
                    + "\n".join(err.strip().splitlines()[-80:])
                ) from None
            exit_s = time.monotonic() - sent_at
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)
        status = ctl.call("status")
    lines = err.strip().splitlines()
    return Interrupted(
        link, int(signum), proc.returncode, lines[-1] if lines else "", exit_s,
        status["state"], bool(status["streaming"]), float(status["table_deg"]), caught,
    )  # fmt: skip
