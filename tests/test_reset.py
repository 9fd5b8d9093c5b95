"""``northfinder reset`` and ``Device.reset()`` bring a unit out of FAULT."""

from __future__ import annotations

import subprocess
import sys

import pytest
from simprocess import sim_process

from northfinder.driver.device import Device
from northfinder.driver.errors import DeviceFault
from northfinder.driver.protocol.constants import DeviceState
from northfinder.embed import SimulatedInstrument

CLI = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())"]


def _jam_and_move(dev, fw) -> None:
    """A move with the table jammed: the drive supervision sets FAULT."""
    fw.apply(lambda: fw.instrument.table.stall(fw.now, True))
    with pytest.raises(DeviceFault):
        dev.rotate_to(90.0)
    fw.apply(lambda: fw.instrument.table.stall(fw.now, False))


def test_device_reset_clears_a_fault_in_virtual_time():
    with (
        SimulatedInstrument("ideal", clock="virtual", warmup_s=0.0) as sim,
        sim.open_device() as dev,
    ):
        dev.wait_ready(5.0)
        _jam_and_move(dev, sim.firmware)
        assert dev.status().state == DeviceState.FAULT
        st = dev.reset()
        assert st is not None and st.state in (DeviceState.WARMUP, DeviceState.READY)
        assert not st.faults
        dev.wait_ready(5.0)
        dev.rotate_to(90.0)  # moves again


@pytest.mark.realtime(alone=False)  # commands and states, no timing: green beside CPU-bound work
def test_northfinder_reset_brings_a_unit_out_of_fault():
    args = ["--pty", "--warmup", "0", "--control", "127.0.0.1:0"]
    with sim_process(*args, ready=True) as facts:
        from northfinder.firmware_sim.control import ControlClient

        with ControlClient(facts["control"]) as ctl, Device.open_serial(facts["pty"]) as dev:
            ctl.call("stall", on=True)
            with pytest.raises(DeviceFault):
                dev.rotate_to(90.0)
            ctl.call("stall", on=False)
            assert ctl.call("status")["state"] == "FAULT"
        done = subprocess.run(
            [*CLI, "reset", "--serial", facts["pty"]], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        assert done.stdout.startswith("reset: the unit was FAULT")
        assert "it now reads READY" in done.stdout or "it now reads WARMUP" in done.stdout
        with ControlClient(facts["control"]) as ctl:
            assert ctl.call("status")["state"] in ("READY", "WARMUP", "BOOT")


def test_reset_needs_exactly_one_link(capsys):
    from northfinder.cli import main

    assert main(["reset"]) == 2
    assert "choose exactly one device" in capsys.readouterr().err
