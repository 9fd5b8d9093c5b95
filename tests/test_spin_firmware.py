"""Protocol 1.1 SPIN on the simulated firmware in lockstep: states, refusals, the steady-rate
samples and their angles, and the table's ripple, wobble and encoder error."""

from __future__ import annotations

import math

import lockstep
import numpy as np
import pytest
from lockstep import IDEAL, make, run
from numpy.testing import assert_allclose

from northfinder.driver.protocol.constants import (
    VALIDITY_STEADY_RATE,
    ConfigKey,
    DeviceState,
    Result,
    Validity,
)
from northfinder.driver.protocol.messages import (
    RotateBy,
    Sample,
    SelfTest,
    SetConfig,
    Spin,
    Status,
    Stop,
    StreamStart,
)
from northfinder.firmware_sim.firmware import Firmware
from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.turntable import Turntable


def ask(fw: Firmware, command) -> Result:
    """The result of the one reply to ``command`` (:func:`lockstep.ask`)."""
    return lockstep.ask(fw, command)[0].result


@pytest.mark.parametrize("rate_dps", [6.0, -2.5])
def test_spin_ramps_holds_and_stops(rate_dps):
    fw = make()
    run(fw, 1.0)
    assert ask(fw, StreamStart(1)) == Result.OK
    changes = []
    fw.on_state_change = lambda old, new, t: changes.append((new, t))
    assert ask(fw, Spin(2, round(rate_dps * 1000))) == Result.OK
    accel = fw.instrument.spec.table.max_accel_dps2
    out = run(fw, abs(rate_dps) / accel + 60.0)
    assert fw.state == DeviceState.SPINNING
    samples = [m for m in out if isinstance(m, Sample)]
    steady = [s for s in samples if s.validity & VALIDITY_STEADY_RATE == VALIDITY_STEADY_RATE]
    ramp = [s for s in samples if s.validity & VALIDITY_STEADY_RATE == Validity.TABLE_MOVING]
    assert ramp and len(steady) > 50 * 200
    # The steady samples' angles advance by rate / fs each tick, in the commanded sense.
    angle = np.unwrap(np.radians([s.angle * 1e-6 for s in steady]))
    step = np.degrees(np.diff(angle)) * 200.0
    assert_allclose(step, rate_dps, atol=1e-3)
    # The z gyro reads the table rate (plus the vertical Earth rate), deg/h.
    gz = np.array([s.gyro[2] * 1e-4 for s in steady])
    assert_allclose(gz.mean(), rate_dps * 3600 + 15.041 * math.sin(math.radians(34)), atol=0.01)
    # States: ROTATING while accelerating, SPINNING at the rate; the statuses say so.
    assert [c[0] for c in changes] == [DeviceState.ROTATING, DeviceState.SPINNING]
    assert changes[1][1] - changes[0][1] == pytest.approx(abs(rate_dps) / accel, abs=0.011)
    assert any(isinstance(m, Status) and m.state == DeviceState.SPINNING for m in out)
    # Busy while spinning; STOP brakes (ROTATING), settles, READY.
    assert ask(fw, Spin(3, 1000)) == Result.BUSY
    assert ask(fw, RotateBy(4, 1_000_000)) == Result.BUSY
    assert ask(fw, SelfTest(5)) == Result.BUSY
    assert ask(fw, SetConfig(6, ConfigKey.TABLE_MAX_RATE_MDPS, 5000)) == Result.BUSY
    assert ask(fw, Stop(7)) == Result.OK
    assert fw.state == DeviceState.ROTATING
    out = run(fw, abs(rate_dps) / accel + 0.1)
    assert fw.state == DeviceState.SETTLING
    assert not any(
        isinstance(m, Sample) and m.validity & Validity.TABLE_SETTLING and m.validity & 4
        for m in out[50:]
    )
    run(fw, fw.instrument.spec.table.settle_s + 0.1)
    assert fw.state == DeviceState.READY
    assert not fw._fault


def test_spin_refusals():
    fw = make(warmup_s=3.0)
    run(fw, 1.0)
    assert ask(fw, Spin(1, 1000)) == Result.NOT_READY  # warming up
    run(fw, 2.5)
    limit = fw.read_config(ConfigKey.TABLE_MAX_RATE_MDPS)
    for rate in (0, limit + 1, -limit - 1, 2**31 - 1, -(2**31)):
        assert ask(fw, Spin(2, rate)) == Result.OUT_OF_RANGE, rate
    assert fw.state == DeviceState.READY
    assert ask(fw, Spin(3, -limit)) == Result.OK
    assert ask(fw, Stop(4)) == Result.OK
    assert ask(fw, Spin(5, 1000)) == Result.BUSY  # braking


def test_stop_while_accelerating_never_marks_steady():
    fw = make()
    run(fw, 1.0)
    ask(fw, StreamStart(1))
    ask(fw, Spin(2, 10_000))
    out = run(fw, 0.2)
    ask(fw, Stop(3))
    out += run(fw, 3.0)
    assert not any(
        isinstance(m, Sample) and m.validity & VALIDITY_STEADY_RATE == VALIDITY_STEADY_RATE
        for m in out
    )
    assert fw.state in (DeviceState.SETTLING, DeviceState.READY)


def test_rate_ripple_is_once_per_turn_and_keeps_the_mean():
    spec = IDEAL.table.__class__(max_rate_dps=30.0, rate_ripple=0.01, rate_ripple_phase_deg=40.0)
    table = Turntable(spec, np.random.default_rng(0))
    t_steady = table.spin(0.0, 20.0)
    t = t_steady + np.linspace(0.0, 18.0, 100_001)  # one turn
    angle, rate = table.state(t)
    assert_allclose(angle[-1] - angle[0], 360.0, atol=1e-9)
    nominal = angle[0] + 20.0 * (t - t[0])
    assert_allclose(rate, 20.0 * (1 + 0.01 * np.cos(np.radians(nominal - 40.0))), atol=1e-12)
    assert_allclose(np.gradient(angle, t)[1:-1], rate[1:-1], rtol=1e-6)


def test_encoder_error_and_wobble_are_off_by_default_and_do_what_they_say():
    base = IDEAL.table
    assert base.rate_ripple == base.wobble_urad == base.encoder_error_deg == 0.0
    spec = base.__class__(encoder_resolution_deg=0.0, encoder_error_deg=0.01)
    table = Turntable(spec, np.random.default_rng(0))
    a = np.array([0.0, 90.0, 180.0, 270.0])
    assert_allclose(table.encoder(a), a + 0.01 * np.sin(np.radians(a)), atol=1e-12)
    # Wobble: a fixed tilt in the sensor frame; a still, level unit's x accelerometer sees
    # g sin(w) when the top leans towards x.
    wob = IDEAL.with_values({"table.wobble_urad": 100.0})
    ins = Instrument(wob, Truth(latitude_deg=34.0), np.random.default_rng(0))
    f = ins.generate(10).accel_mps2.mean(axis=0)
    g = np.linalg.norm(f)
    assert_allclose(f[0] / g, -math.sin(100e-6), atol=1e-12)
    assert_allclose(f[1], 0.0, atol=1e-12)


def test_a_host_of_version_1_0_never_sees_what_1_1_added():
    """Without SPIN, the 1.1 unit sends nothing a 1.0 host does not know: no state SPINNING and
    no sample with the steady-rate pair, through moves, STOP during a move and settling (the
    tick that overlaps the end of a move carries TABLE_MOVING alone)."""
    spec = IDEAL.with_values({"table.overshoot_deg": 0.01, "table.settle_s": 0.5})
    fw = make(spec=spec)
    run(fw, 1.0)
    ask(fw, StreamStart(1))
    out = []
    for seq, delta in enumerate((30_000_000, -170_000_000, 5_000, 0), start=2):
        fw.handle(RotateBy(seq, delta))
        out += run(fw, 20.0)
    fw.handle(RotateBy(10, 90_000_000))
    out += run(fw, 0.5)
    fw.handle(Stop(11))
    out += run(fw, 5.0)
    samples = [m for m in out if isinstance(m, Sample)]
    statuses = [m for m in out if isinstance(m, Status)]
    assert len(samples) > 80 * 200 and statuses
    assert all(s.state != DeviceState.SPINNING for s in statuses)
    pair = int(VALIDITY_STEADY_RATE)
    assert not any(int(s.validity) & pair == pair for s in samples)
    assert any(s.validity & Validity.TABLE_MOVING for s in samples)
    assert any(s.validity & Validity.TABLE_SETTLING for s in samples)
