"""Shared fixtures: the simulated instrument on every link it offers, and a driver connected to it.

``sim`` (one simulator per link for the test module) and ``link`` (a fresh
:class:`northfinder.driver.device.Device` per test, with the simulator's control channel) are parametrised
over the links of ``LINKS``:

- ``virtual``: python-can's ``virtual`` bus, the simulator's runner in a thread of this process;
- ``serial-pty``: ``northfinder sim --pty`` in another process, the driver on the pty with pyserial;
- ``slcan-pty``: ``northfinder sim --slcan-pty`` in another process, the driver through python-can's
  ``slcan`` interface;
- ``socketcan``: ``northfinder sim -i socketcan -c vcan0``; skipped where the kernel has no vcan0.

The simulators run ``SPEED`` times faster than real time (``SPEEDS`` per link; a test may change
the speed through the control channel; the ``link`` fixture restores it and resets the simulated
device afterwards).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from simprocess import sim_process

SPEED = 5.0
"""Simulated seconds per wall second for the simulators of the driver tests."""
SPEEDS = {"slcan-pty": 1.0, "socketcan": 1.0}
"""Exceptions to ``SPEED``: python-can's ``slcan`` reads its port one byte per call, which keeps
up with about four times the real-time stream (820 frames/s) on an idle machine and about twice
on a loaded one, and less when the whole suite runs; beyond that the pseudo-terminal fills, and
statuses and replies queue behind samples until the driver declares the link lost. Real time
keeps the margin. ``socketcan`` runs where vcan0 exists, in practice the HIL's one-CPU virtual
machine, where every system call is a round trip through the tracing kernel: five times the
stream (3000 frames/s) saturates it and replies miss their deadline."""
LINKS = ("virtual", "serial-pty", "slcan-pty", "socketcan")
VCAN = "vcan0"


@dataclass
class SimHandle:
    """A running simulator: how to reach it, and how to stop it."""

    kind: str
    open_device: Callable[[], Any]
    control: Any  # northfinder.firmware_sim.control.ControlClient
    speed: float = SPEED
    closers: list[Callable[[], None]] = field(default_factory=list)

    def close(self) -> None:
        for close in reversed(self.closers):
            try:
                close()
            except Exception as exc:  # teardown goes on; the message shows in the log
                print(f"simulator teardown: {exc!r}", file=sys.stderr)


def _start_in_process(speed: float) -> SimHandle:
    from northfinder.firmware_sim.imu import Truth
    from northfinder.host.embed import SimulatedInstrument

    sim = SimulatedInstrument(
        "paper-rlg",
        Truth(azimuth_deg=30.0, latitude_deg=34.0),
        seed=3,
        speed=speed,
        warmup_s=0.0,
        control="127.0.0.1:0",
    ).start()
    handle = SimHandle("virtual", sim.open_device, sim.control, speed)
    handle.closers.append(sim.close)
    return handle


def _start_subprocess(kind: str, speed: float, seed: int) -> SimHandle:
    from northfinder.driver.device import Device
    from northfinder.firmware_sim.control import ControlClient

    link_args = {
        "serial-pty": ["--pty"],
        "slcan-pty": ["--slcan-pty"],
        "socketcan": ["-i", "socketcan", "-c", VCAN],
    }[kind]
    args = [*link_args, "--warmup", "0", "--seed", str(seed), "--speed", str(speed)]
    args += ["--azimuth", "30", "--control", "127.0.0.1:0"]
    wanted = {"control"} if kind == "socketcan" else {"pty", "control"}
    process = contextlib.ExitStack()
    try:
        facts = process.enter_context(sim_process(*args, wanted=wanted, check_exit=False))
        control = ControlClient(facts["control"])
    except BaseException:
        process.close()
        raise
    if kind == "serial-pty":
        path = facts["pty"]
        opener: Callable[[], Any] = lambda: Device.open_serial(path)  # noqa: E731
    elif kind == "slcan-pty":
        path = facts["pty"]
        opener = lambda: Device.open_can("slcan", path, 500_000, sleep_after_open=0)  # noqa: E731
    else:
        opener = lambda: Device.open_can("socketcan", VCAN)  # noqa: E731
    handle = SimHandle(kind, opener, control, speed)
    handle.closers += [process.close, control.close]
    return handle


@pytest.fixture(scope="module", params=LINKS)
def sim(request: pytest.FixtureRequest) -> Iterator[SimHandle]:
    """A simulator on one link, shared by the tests of a module (warm-up 0, ``SPEED`` x)."""
    kind = request.param
    speed = SPEEDS.get(kind, SPEED)
    if kind == "socketcan" and not os.path.exists(f"/sys/class/net/{VCAN}"):
        pytest.skip(
            f"no {VCAN}: this kernel has no SocketCAN/vcan (`scripts/hil --steps driver` runs "
            "these tests in a VM whose kernel has it)"
        )
    if kind == "virtual":
        handle = _start_in_process(speed)
    else:
        handle = _start_subprocess(kind, speed, seed=LINKS.index(kind) + 10)
    try:
        yield handle
    finally:
        handle.close()


@pytest.fixture
def link(sim: SimHandle) -> Iterator[tuple[Any, Any]]:
    """A connected ``(Device, ControlClient)`` pair with the device READY.

    Afterwards the device is closed, and the simulated device is reset (faults cleared, defaults
    back) at the fixture's speed.
    """
    sim.control.call("speed", value=sim.speed)
    device = sim.open_device()
    try:
        device.wait_ready(timeout=5.0)
        yield device, sim.control
    finally:
        device.close()
        sim.control.call("speed", value=sim.speed)
        sim.control.call("reset")
