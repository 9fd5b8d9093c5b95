"""Protocol 1.1 SPIN through the driver, in virtual time: Device.spin, angle-tagged windows while
spinning, STOP, and the driver's own refusals."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from northfinder.driver.errors import ArgumentError, DeviceRefused
from northfinder.driver.protocol.constants import VALIDITY_STEADY_RATE, DeviceState
from northfinder.embed import SimulatedInstrument
from northfinder.firmware_sim.imu import Truth


@pytest.fixture
def device():
    with (
        SimulatedInstrument(
            "ideal", Truth(azimuth_deg=42.0), seed=1, clock="virtual", warmup_s=0
        ) as sim,
        sim.open_device() as dev,
    ):
        dev.wait_ready()
        yield dev


@pytest.mark.parametrize("rate_dps", [5.0, -2.5])
def test_spin_gives_angle_tagged_steady_samples(device, rate_dps):
    st = device.spin(rate_dps)
    assert st is not None and st.state == DeviceState.SPINNING
    w = device.acquire(10.0)
    assert np.all(w.validity & VALIDITY_STEADY_RATE == VALIDITY_STEADY_RATE)
    step = (np.diff(w.table_deg) + 180.0) % 360.0 - 180.0
    assert_allclose(step * w.sample_rate_hz, rate_dps, atol=1e-3)
    assert_allclose(w.gyro_dph[:, 2].mean(), rate_dps * 3600.0, atol=20.0)
    with pytest.raises(DeviceRefused, match="BUSY"):
        device.rotate_by(10.0)
    with pytest.raises(DeviceRefused, match="BUSY"):
        device.spin(1.0)
    st = device.stop(wait=True)
    assert st is not None and st.state == DeviceState.READY


@pytest.mark.parametrize(
    ("rate", "message"),
    [(0.0, "0.001 to"), (1e-4, "0.001 to"), (1e6, "rate limit"), (float("nan"), "rate_dps")],
)
def test_spin_refuses_rates_out_of_range_in_one_line(device, rate, message):
    with pytest.raises(ArgumentError, match=message):
        device.spin(rate)
    assert device.status().state == DeviceState.READY
