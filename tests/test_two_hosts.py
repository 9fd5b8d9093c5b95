"""Two hosts on one CAN bus (python-can ``virtual``, in virtual time): a host never stops what it
did not start, tells another host's IDENTIFY from a device restart, and names another host's
commands when they break its work (protocol.md 13)."""

from __future__ import annotations

import contextlib

import pytest
from conftest import later_on

from northfinder.driver.errors import AnotherHost, DeviceReset, NodeConflict
from northfinder.driver.protocol.constants import DeviceState
from northfinder.embed import SimulatedInstrument


@pytest.fixture
def sim():
    with SimulatedInstrument("ideal", seed=1, clock="virtual", warmup_s=0.0) as s:
        yield s


def _look(sim: SimulatedInstrument) -> None:
    """A second host that connects (IDENTIFY, status, configuration) and leaves."""
    with sim.open_device() as other:
        other.status()


def test_a_host_that_connects_during_a_window_is_no_restart(sim):
    with sim.open_device() as first:
        first.wait_ready(5.0)
        with later_on(first.clock, 1.0, _look, sim):
            window = first.acquire(3.0)  # its IDENTIFY went to both hosts: not a restart
        assert len(window.counter) == 600 and window.missing == 0
        assert first.stats().resets_detected == 0
        assert first.stats().foreign_commands >= 2
        assert sim.firmware.streaming  # the other host left the first one's stream alone
    assert not sim.firmware.streaming  # the first one stops its own


def test_another_hosts_stream_stop_is_named(sim):
    with sim.open_device() as first, sim.open_device() as second:
        first.wait_ready(5.0)
        with (
            pytest.raises(
                AnotherHost, match=r"another host is commanding this unit: it sent STREAM_STOP"
            ),
            later_on(first.clock, 1.0, second.stop_streaming),
        ):
            first.acquire(3.0)


def test_another_hosts_stop_during_a_move_is_named(sim):
    with sim.open_device() as first, sim.open_device() as second:
        first.wait_ready(5.0)
        with (
            pytest.raises(AnotherHost, match=r"another host is commanding this unit: it sent STOP"),
            later_on(first.clock, 1.0, second.stop),
        ):
            first.rotate_to(180.0)
        # The second host stopped the table; the first one has no move of its own to undo.
        assert not first.leave_at_rest().needed or first.leave_at_rest().sent == ("STOP",)


def test_a_real_restart_is_still_a_restart(sim):
    with sim.open_device() as first:
        first.wait_ready(5.0)
        with (
            pytest.raises(DeviceReset, match="restarted"),
            later_on(first.clock, 1.0, sim.firmware.reboot),
        ):
            first.acquire(3.0)


def test_another_hosts_reset_is_a_restart_caused_by_another_host(sim):
    with sim.open_device() as first, sim.open_device() as second:
        first.wait_ready(5.0)
        with (
            pytest.raises(DeviceReset, match="another host sent RESET"),
            later_on(first.clock, 1.0, second.reset, wait=False),
        ):
            first.acquire(3.0)
        assert sim.firmware.state in (DeviceState.BOOT, DeviceState.WARMUP, DeviceState.READY)


# -- two units on one node id -------------------------------------------------------------------


@contextlib.contextmanager
def _twin(sim: SimulatedInstrument, started_after_s: float):
    """A second simulated unit answering as the same node on the same virtual bus, powered on
    ``started_after_s`` later than the first (its counters and clock differ)."""
    import numpy as np

    from northfinder.embed import _DeviceEndBus
    from northfinder.firmware_sim.adapters import CanLink
    from northfinder.firmware_sim.firmware import Firmware, LinkInfo
    from northfinder.firmware_sim.runner import Runner

    sim.clock.sleep(started_after_s)  # type: ignore[union-attr]
    fw = Firmware(sim.spec, sim.truth, np.random.default_rng(2), warmup_s=0.0, node_id=1,
                  link=LinkInfo("can", 500_000))  # fmt: skip
    bus = _DeviceEndBus(channel=sim.channel)
    runner = Runner(fw, CanLink(bus, fw, 1), sim.clock)
    runner.attach()
    try:
        yield fw
    finally:
        runner.detach()
        bus.shutdown()


@pytest.mark.parametrize("started_after_s", [0.0, 0.37])
def test_a_second_unit_on_this_node_id_is_named(sim, started_after_s):
    # In step (0 s) the twins' streams look like one; apart, they break windows and moves in
    # every way (restarts, gaps). Either way the two replies to each command name the cause.
    from northfinder.host.plan import Plan
    from northfinder.host.procedure import find_north

    with _twin(sim, started_after_s), pytest.raises(NodeConflict) as info:
        with sim.open_device() as dev:
            dev.wait_ready(5.0)
            find_north(dev, Plan((0.0, 180.0), 2.0), 34.0)
    text = str(info.value)
    assert "another unit answers as node 1" in text and "own node id" in text


def test_two_hosts_polling_one_unit_are_no_second_unit(sim):
    # Both hosts number their commands from 1: each sees the other's command before its reply,
    # so a reply to the other host's seq is never taken for a second unit.
    with sim.open_device() as first, sim.open_device() as second:
        for _ in range(40):
            first.status()
            second.status()
            first.config()
        assert first.node_conflict() is None and second.node_conflict() is None
        assert first.stats().stray_replies > 0  # the other host's replies did arrive
