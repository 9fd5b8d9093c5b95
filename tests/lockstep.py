"""The simulated firmware in lockstep, for the tests: a unit at a known truth, stepped by hand."""

from __future__ import annotations

from typing import Any

import numpy as np

from northfinder.driver.protocol.messages import Reply
from northfinder.firmware_sim.firmware import Firmware
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import SensorSpec, load_spec

IDEAL = load_spec("ideal")


def make(warmup_s: float = 0.0, seed: int = 0, spec: SensorSpec = IDEAL, **kw: Any) -> Firmware:
    """Firmware of ``spec`` heading 30 deg at 34 deg N, seeded, warm after ``warmup_s``."""
    return Firmware(
        spec,
        Truth(azimuth_deg=30.0, latitude_deg=34.0),
        np.random.default_rng(seed),
        warmup_s=warmup_s,
        **kw,
    )


def run(fw: Firmware, seconds: float, step: float = 0.01) -> list[Any]:
    """Step ``fw`` through ``seconds`` in steps of ``step``; the messages it sent, in order."""
    out = []
    for _ in range(round(seconds / step)):
        out += [o.message for o in fw.process(step)]
    return out


def ask(fw: Firmware, command: Any, seconds: float = 0.02) -> tuple[Any, list[Any]]:
    """Hand ``fw`` one command and step ``seconds``: its one reply (matched by sequence number)
    and everything it sent meanwhile."""
    fw.handle(command)
    out = run(fw, seconds)
    replies = [m for m in out if isinstance(m, Reply) and m.seq == command.seq]
    assert len(replies) == 1, out
    return replies[0], out
