"""Two traps of the simulator (issue: a jam at rest flagged a sample; a coarse lockstep clock made
no progress)."""

from __future__ import annotations

import numpy as np
import pytest
from test_hardening_sim import make_unit

from northfinder.driver.protocol.constants import DeviceState, Validity
from northfinder.driver.protocol.messages import Sample


def test_a_jam_at_rest_flags_nothing_until_the_next_move():
    unit = make_unit()
    unit.run(1.0)
    n0 = len(unit.link.messages(Sample))
    unit.firmware.stall_table(True)  # at rest, mid-sample
    unit.run(1.0)
    samples = unit.link.messages(Sample)[n0:]
    assert len(samples) >= 190
    moving = [s for s in samples if s.validity & (Validity.TABLE_MOVING | Validity.TABLE_SETTLING)]
    assert moving == []
    assert unit.firmware.state == DeviceState.READY


@pytest.mark.parametrize("step_s", [0.05, 0.25, 1.0, 5.0])
def test_a_coarse_lockstep_step_advances_the_unit_in_full(step_s):
    unit = make_unit(streaming=False)  # its run(1.0) in 10 ms steps: through BOOT
    t0 = unit.firmware.now
    n0 = len(unit.link.messages(Sample))
    unit.run(2 * step_s, step=step_s)
    assert unit.firmware.now == pytest.approx(t0 + 2 * step_s, abs=1e-9)
    assert unit.runner.lag.slips == 0
    assert len(unit.link.messages(Sample)) == n0  # nothing streams unless asked


def test_a_coarse_lockstep_clock_boots_the_unit():
    from test_hardening_sim import WireLink

    from northfinder.firmware_sim.firmware import Firmware
    from northfinder.firmware_sim.imu import Truth
    from northfinder.firmware_sim.runner import LockstepClock, Runner
    from northfinder.firmware_sim.sensors import load_spec

    fw = Firmware(load_spec("ideal"), Truth(30.0, 34.0), np.random.default_rng(0), warmup_s=0.0)
    clock = LockstepClock()
    runner = Runner(fw, WireLink(), clock)
    for _ in range(3):
        clock.advance(0.5)  # ten times the old limit
        runner.step()
    assert fw.now == pytest.approx(1.5)
    assert fw.state == DeviceState.READY
