"""The procedure on a stand-in device, in virtual time: settling, solving, refusals."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from northfinder.driver.clock import VirtualClock
from northfinder.driver.protocol.constants import ConfigKey, DeviceState
from northfinder.driver.protocol.units import DPH
from northfinder.firmware_sim.earth import body_rates, mat_table
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import (
    DeviceLike,
    Plan,
    WindowsSolution,
    extra_settle_s,
    find_north,
    solve_windows,
)

AZIMUTH, LATITUDE, SAMPLES = 123.4, 34.0, 200


@dataclass
class StandIn:
    """A still, noise-free instrument that settles on its own in ``settle_ms`` (it says READY)."""

    settle_ms: int = 2000
    angle: float = 0.0
    calls: list[str] = field(default_factory=list)
    rests: int = 0  # how often it was left at rest (after an error)
    _clock: VirtualClock = field(default_factory=VirtualClock)

    def status(self) -> SimpleNamespace:
        return SimpleNamespace(state=DeviceState.READY, angle_deg=self.angle)

    def get_config(self, key: ConfigKey) -> int:
        return {
            ConfigKey.TABLE_MAX_RATE_MDPS: 10_000,
            ConfigKey.SETTLE_TIME_MS: self.settle_ms,
            ConfigKey.SAMPLE_RATE_HZ: 200,
        }[key]

    def rotate_to(self, angle_deg: float, *, wait: bool = True, timeout: float | None = None):
        self.calls.append(f"rotate {angle_deg:g}")
        self.angle = angle_deg

    def acquire(self, seconds: float, *, on_gap: str = "raise") -> SimpleNamespace:
        self.calls.append(f"acquire {seconds:g}")
        omega_b, f_b = body_rates(AZIMUTH, 0.5, -0.7, LATITUDE)
        c = mat_table(math.radians(self.angle))
        ones = np.ones((SAMPLES, 1))
        return SimpleNamespace(
            gyro_dph=ones * (c @ omega_b / DPH),
            accel_mps2=ones * (c @ f_b),
            table_deg=np.full(SAMPLES, self.angle),
            validity=np.full(SAMPLES, 3, dtype=np.uint8),  # GYRO_VALID | ACCEL_VALID
            counter=np.arange(SAMPLES, dtype=np.int64),
            missing=0,
        )

    def stop_streaming(self) -> None:
        self.calls.append("stop")

    # The rest of the device protocol (DeviceLike): a stand-in has it all, as a Device has.
    @property
    def clock(self) -> VirtualClock:
        return self._clock

    @property
    def last_status(self) -> SimpleNamespace:
        return self.status()

    def wait_ready(self, timeout: float = 5.0) -> SimpleNamespace:
        return self.status()

    def release_stream(self) -> None:
        self.stop_streaming()

    def leave_at_rest(self) -> None:
        self.rests += 1


def run(plan: Plan, device: StandIn) -> tuple[float, list[float]]:
    sleeps: list[float] = []
    result, _ = find_north(device, plan, LATITUDE, sleep=sleeps.append, clock=lambda: 0.0)
    return result.azimuth_deg, sleeps


def test_the_procedure_waits_only_what_remains_of_the_plans_settle_time():
    azimuth, sleeps = run(Plan((0.0, 180.0), 1.0, settle_s=5.0), StandIn(settle_ms=2000))
    assert sleeps == [3.0, 3.0]  # the device settled 2 s on its own before READY
    assert abs((azimuth - AZIMUTH + 180.0) % 360.0 - 180.0) < 1e-6
    assert run(Plan((0.0, 180.0), 1.0), StandIn())[1] == []  # None: the device's own
    assert run(Plan((0.0, 180.0), 1.0, settle_s=1.0), StandIn())[1] == []  # less than its own
    assert extra_settle_s(Plan(settle_s=2.5), 2.0) == pytest.approx(0.5)


def test_least_squares_on_the_stand_in():
    azimuth, _ = run(Plan((0.0, 90.0, 180.0, 270.0), 1.0), StandIn())
    assert abs((azimuth - AZIMUTH + 180.0) % 360.0 - 180.0) < 1e-6


def test_what_a_device_cannot_do_is_refused_before_the_table_moves():
    for plan, message in (
        (Plan((0.0, 180.0), 0.1), "window: must be 0.5 to 3600 s"),
        (Plan((0.0, 180.0), 1.0, settle_s=601.0), "settle: must be 0 to 600 s"),
        (Plan((0.0, 90.0, 180.0), 1.0, method="pairwise"), "no single heading"),
    ):
        device = StandIn()
        with pytest.raises(HostConfigError, match=message):
            run(plan, device)
        assert device.calls == []
    with pytest.raises(HostConfigError, match="no single heading"):
        solve_windows([], LATITUDE, Plan(method="pairwise"))


def test_the_device_protocol_is_written_out_in_full():
    """What the procedures call on a device is the protocol's (a Device and the stand-in have
    each method), and solving gives a named solution, not a tuple."""
    from northfinder.driver.device import Device

    names = {n for n in dir(DeviceLike) if not n.startswith("_")}
    assert {"clock", "last_status", "wait_ready", "release_stream", "leave_at_rest"} <= names
    for cls in (Device, StandIn):
        missing = [n for n in names if not hasattr(cls, n)]
        assert not missing, (cls.__name__, missing)
    device = StandIn()
    result, _ = find_north(device, Plan((0.0, 180.0), 1.0), LATITUDE)
    assert "stop" in device.calls  # the stream released by name, never looked up
    solved = solve_windows(result.windows, LATITUDE, Plan((0.0, 180.0), 1.0))
    assert isinstance(solved, WindowsSolution)
    assert solved.azimuth_deg == pytest.approx(result.azimuth_deg, abs=1e-12)
