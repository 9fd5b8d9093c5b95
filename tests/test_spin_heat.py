"""The drive's heat while the table spins (northfinder.driver.protocol.heat): off at zero, the
simulated process against its closed form, and the prediction's part against the closed form of
a demodulated Gauss-Markov bias."""

from __future__ import annotations

import math

import numpy as np
import pytest

from northfinder.driver.protocol.heat import spin_heat_sigma, spin_heat_state
from northfinder.driver.protocol.units import DPH, OMEGA_IE
from northfinder.firmware_sim.batch import simulate_spin
from northfinder.firmware_sim.error_terms import ErrorTerms, spin_heat_bias
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import predict
from northfinder.host.plan import SpinPlan
from northfinder.simwindows import error_model

LAT = 34.0
#: A drive whose moves disturb the gyros (paper-prototype's size, tau 10 s), no other noise.
HEATED = {"gyro.move_transient_dph_per_rtdeg": 0.012, "gyro.move_transient_tau_s": 10.0}


def _spec(spin_heat: float, **more: float):
    return load_spec("ideal").with_values({**HEATED, "table.spin_heat": spin_heat, **more})


def test_no_spin_heat_adds_nothing_to_the_samples_or_the_prediction():
    truth = Truth(azimuth_deg=40.0, latitude_deg=LAT)
    off = simulate_spin(_spec(0.0, **{"gyro.arw_dpsh": 0.001}), truth, 6.0, 30.0, n_runs=3,
                        rng=np.random.default_rng(4), sample_rate_hz=20.0)  # fmt: skip
    plain = load_spec("ideal").with_values({**HEATED, "gyro.arw_dpsh": 0.001})
    ref = simulate_spin(plain, truth, 6.0, 30.0, n_runs=3, rng=np.random.default_rng(4),
                        sample_rate_hz=20.0)  # fmt: skip
    np.testing.assert_array_equal(off.gyro_rps, ref.gyro_rps)
    terms = ErrorTerms.from_spec(_spec(0.0))
    assert spin_heat_bias(terms, 6.0, 60.0, 0.0, 100, 20.0, np.random.default_rng(1), 2) is None
    pred = predict(error_model(_spec(0.0)), SpinPlan(6.0, 120.0), LAT, tilt="level")
    assert "spin_heat" not in pred.parts_deg


def test_the_simulated_heat_is_the_closed_form_gauss_markov_process():
    # 2000 runs of the bias alone: where the steady spin starts, the ramp's move decayed over the
    # ramp; after many time constants, transient * sqrt(spin_heat |rate| tau / 2).
    spin_heat, rate, accel, fs = 0.5, 6.0, 3.0, 10.0
    terms = ErrorTerms.from_spec(_spec(spin_heat))
    b = spin_heat_bias(terms, rate, accel, spin_heat, 1000, fs, np.random.default_rng(7), 2000)
    assert b is not None
    assert not b[..., 3:].any()  # only the gyros have move terms
    x = b[..., 0] / DPH
    v0, _ = spin_heat_state(rate, accel, 10.0, spin_heat)
    first = 0.012**2 * (v0 * math.exp(-0.2 / 10.0) + spin_heat * rate * 10.0 / 2.0
                        * (1.0 - math.exp(-0.2 / 10.0)))  # fmt: skip
    assert np.var(x[:, 0]) == pytest.approx(first, rel=0.1)
    steady = spin_heat_sigma(0.012, 10.0, rate, spin_heat)
    assert np.std(x[:, -1]) == pytest.approx(steady, rel=0.05)
    # Correlated over tau: the lag-10 s correlation is exp(-1).
    r = np.corrcoef(x[:, -101], x[:, -1])[0, 1]
    assert r == pytest.approx(math.exp(-1.0), abs=0.05)


@pytest.mark.parametrize("spin_heat", [0.05, 0.5])
def test_the_predicted_heat_part_is_the_demodulated_spectrum(spin_heat):
    # Whole turns, long against tau: a Gauss-Markov bias of variance s^2 and time constant tau
    # acts as white noise of density S = 2 s^2 tau / (1 + (w tau)^2) at the table's frequency w,
    # so the heading's scatter is sqrt(S / T) / Omega_H (the spin bound with N^2 = S).
    rate, turns = 6.0, 10
    plan = SpinPlan(rate, turns * 360.0 / rate)
    pred = predict(error_model(_spec(spin_heat)), plan, LAT, tilt="level", sample_rate_hz=20.0)
    s = spin_heat_sigma(0.012, 10.0, rate, spin_heat) * DPH
    w = math.radians(rate)
    density = 2.0 * s * s * 10.0 / (1.0 + (w * 10.0) ** 2)
    closed = math.degrees(
        math.sqrt(density / plan.spin_s) / (OMEGA_IE * math.cos(math.radians(LAT)))
    )
    assert pred.parts_deg["spin_heat"] == pytest.approx(closed, rel=0.05)
    # More heat, more error: the part grows as sqrt(spin_heat).
    assert pred.parts_deg["spin_heat"] > 0


def test_the_heat_of_a_spin_against_the_monte_carlo():
    from northfinder.host.montecarlo import StudySettings, monte_carlo, study_rows
    from northfinder.simwindows import SimulatedWindows

    spec = _spec(0.2, **{"gyro.arw_dpsh": 0.0003})
    plan = SpinPlan(3.0, 100.0)  # a part turn
    settings = StudySettings(latitude_deg=LAT, warmup_s=60.0, sample_rate_hz=20.0)
    errors = monte_carlo(SimulatedWindows(spec), plan, settings, 400, 5)
    row = study_rows(error_model(spec), plan, settings, errors)[0]
    assert row["rmse_deg"] > 3.0 * row["bound_deg"]  # the heat dominates
    assert 0.9 <= row["predicted_deg"] / row["rmse_deg"] <= 1.1, row
