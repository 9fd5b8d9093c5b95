"""Physics of the simulated instrument: closed forms, error terms, Allan statistics, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from numpy.typing import ArrayLike

from northfinder.driver.protocol.motion import move_time_s
from northfinder.driver.protocol.units import normal_gravity
from northfinder.firmware_sim.batch import plan_timeline, simulate_windows
from northfinder.firmware_sim.earth import OMEGA_IE, check_latitude, gravity
from northfinder.firmware_sim.error_terms import (
    FLICKER_STD,
    FLICKER_TAUS_S,
    FLICKER_VARIANCE,
    ErrorTerms,
    move_heat,
    quantise_carry,
    temperature_c,
)
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.imu import Instrument, SampleBlock, Truth
from northfinder.firmware_sim.sensors import (
    AccelSpec,
    DisturbanceSpec,
    GyroSpec,
    SensorSpec,
    TableSpec,
    ThermalSpec,
    load_spec,
    preset_names,
    spec_from_dict,
)
from northfinder.firmware_sim.turntable import TableBusyError
from northfinder.host.allan import allan_deviation

DPH = math.pi / 180 / 3600
IDEAL = load_spec("ideal")


def paper_gyro(az_deg, pitch_deg, roll_deg, lat_deg, mu_deg):
    """Seed 000 eqs. 1, 2, 6, 7 (and z) written out independently of the matrices; rad/s."""
    a, t, g = -math.radians(az_deg), math.radians(pitch_deg), math.radians(roll_deg)
    mu = math.radians(mu_deg)
    w_nor, w_u = (
        OMEGA_IE * math.cos(math.radians(lat_deg)),
        OMEGA_IE * math.sin(math.radians(lat_deg)),
    )
    wx0 = w_nor * math.cos(a) * math.cos(t) - w_u * math.sin(t)
    wy0 = w_nor * (
        math.cos(a) * math.sin(t) * math.sin(g) - math.sin(a) * math.cos(g)
    ) + w_u * math.cos(t) * math.sin(g)
    wz0 = w_nor * (
        math.cos(a) * math.sin(t) * math.cos(g) + math.sin(a) * math.sin(g)
    ) + w_u * math.cos(t) * math.cos(g)
    return np.array(
        [math.cos(mu) * wx0 + math.sin(mu) * wy0, -math.sin(mu) * wx0 + math.cos(mu) * wy0, wz0]
    )


def specific_force(pitch_deg, roll_deg, lat_deg, mu_deg):
    """What a level-referenced accelerometer triad reads (z up reads +g), m/s^2."""
    t, g, mu = math.radians(pitch_deg), math.radians(roll_deg), math.radians(mu_deg)
    grav = gravity(math.radians(lat_deg))
    fx0, fy0, fz0 = (
        -grav * math.sin(t),
        grav * math.cos(t) * math.sin(g),
        grav * math.cos(t) * math.cos(g),
    )
    return np.array(
        [math.cos(mu) * fx0 + math.sin(mu) * fy0, -math.sin(mu) * fx0 + math.cos(mu) * fy0, fz0]
    )


def window_at(ins: Instrument, mu_deg: float, seconds: float = 10.0) -> SampleBlock:
    """Turn to ``mu_deg``, wait for the table to settle, and record a window."""
    end = ins.table.move_to(ins.time_s, mu_deg)
    ins.advance(end - ins.time_s + ins.table.spec.settle_s)
    return ins.advance(seconds)


def test_somigliana_and_earth_rate():
    assert gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert gravity(math.pi / 2) == pytest.approx(9.8321849378, abs=1e-9)
    assert OMEGA_IE == 7.292115e-5
    assert gravity is normal_gravity  # one definition of normal gravity


@pytest.mark.parametrize("seed", range(8))
def test_noise_free_window_means_equal_the_closed_form(seed):
    rng = np.random.default_rng(seed)
    truth = Truth(
        azimuth_deg=float(rng.uniform(0, 360)),
        latitude_deg=float(rng.uniform(-80, 80)),
        pitch_deg=float(rng.uniform(-10, 10)),
        roll_deg=float(rng.uniform(-10, 10)),
    )
    mu = float(rng.uniform(-360, 360))
    ins = Instrument(IDEAL, truth, rng)
    first = ins.advance(10.0)
    second = window_at(ins, mu)
    args = (truth.azimuth_deg, truth.pitch_deg, truth.roll_deg, truth.latitude_deg)
    for block, angle in ((first, 0.0), (second, mu)):
        assert_allclose(
            block.gyro_rps.mean(axis=0), paper_gyro(*args, angle), rtol=1e-9, atol=1e-9 * OMEGA_IE
        )
        f = specific_force(truth.pitch_deg, truth.roll_deg, truth.latitude_deg, angle)
        assert_allclose(block.accel_mps2.mean(axis=0), f, rtol=1e-9, atol=1e-9 * 9.8)
        assert_allclose(block.table_deg, angle % 360.0, atol=1e-9)


def test_level_accelerometer_reads_plus_g_on_z():
    ins = Instrument(IDEAL, Truth(latitude_deg=45.0), np.random.default_rng(0))
    f = ins.generate(10).accel_mps2
    assert_allclose(f, np.tile([0.0, 0.0, gravity(math.radians(45.0))], (10, 1)), atol=1e-12)


def test_constant_biases_cancel_in_position_differences():
    spec = IDEAL.with_values(
        {
            "gyro.bias_dph": [3.0, -2.0, 1.0],
            "gyro.turn_on_bias_dph": 0.5,
            "accel.bias_ug": [500.0, -300.0, 100.0],
        }
    )
    truth = Truth(azimuth_deg=123.0, latitude_deg=34.0, pitch_deg=2.0, roll_deg=-1.5)
    biased, clean = (
        Instrument(spec, truth, np.random.default_rng(3)),
        Instrument(IDEAL, truth, np.random.default_rng(3)),
    )
    diffs = []
    for ins in (biased, clean):
        w0 = ins.advance(10.0)
        w1 = window_at(ins, 70.0)
        diffs.append(
            (
                w0.gyro_rps.mean(0) - w1.gyro_rps.mean(0),
                w0.accel_mps2.mean(0) - w1.accel_mps2.mean(0),
            )
        )
        if ins is biased:
            offset = w0.gyro_rps.mean(0) - paper_gyro(123.0, 2.0, -1.5, 34.0, 0.0)
    assert np.abs(offset[:2]).max() > 1.0 * DPH  # the biases are really there
    assert_allclose(diffs[0][0], diffs[1][0], atol=1e-15)
    assert_allclose(diffs[0][1], diffs[1][1], atol=1e-12)


def test_table_rate_appears_in_the_gyro_and_the_profile_respects_the_limits():
    spec = IDEAL.with_values({"table.max_rate_dps": 8.0, "table.max_accel_dps2": 16.0})
    ins = Instrument(spec, Truth(), np.random.default_rng(0))
    ins.advance(1.0)
    start = ins.time_s
    end = ins.table.move_by(start, 100.0)
    assert end - start == pytest.approx(move_time_s(100.0, 8.0, 16.0))
    assert end - start == pytest.approx(8.0 / 16.0 + 100.0 / 8.0)
    block = ins.advance(end - start + 1.0)
    earth_z = paper_gyro(0.0, 0.0, 0.0, 34.0, 0.0)[2]
    table_rate = np.degrees(block.gyro_rps[:, 2] - earth_z)
    assert table_rate.max() == pytest.approx(8.0, abs=1e-9)
    assert_allclose(table_rate, block.table_rate_dps, atol=1e-9)
    # The gyro integrates to the angle turned: each sample is the mean rate over its interval.
    assert table_rate.sum() / ins.sample_rate_hz == pytest.approx(100.0, abs=1e-9)
    accel = np.diff(block.table_rate_dps) * ins.sample_rate_hz
    assert np.abs(accel).max() <= 16.0 * (1 + 1e-9)
    assert block.table_deg[-1] == pytest.approx(100.0, abs=1e-9)


def test_short_moves_are_triangular_and_a_busy_table_refuses():
    spec = TableSpec(
        max_rate_dps=10.0, max_accel_dps2=10.0, settle_s=1.0, encoder_resolution_deg=0.0
    )
    ins = Instrument(SensorSpec(table=spec), Truth(), np.random.default_rng(0))
    end = ins.table.move_to(0.0, 2.5)
    assert end == pytest.approx(2 * math.sqrt(2.5 / 10.0))
    with pytest.raises(TableBusyError):
        ins.table.move_by(0.1, 5.0)
    ins.advance(end + 0.5)
    assert not ins.table.is_settled(ins.time_s)
    ins.advance(0.6)
    assert ins.table.is_settled(ins.time_s)


def test_move_to_takes_the_shorter_way_and_stop_decelerates():
    spec = TableSpec(max_rate_dps=10.0, max_accel_dps2=20.0, encoder_resolution_deg=0.0)
    ins = Instrument(SensorSpec(table=spec), Truth(), np.random.default_rng(0))
    end = ins.table.move_to(0.0, 350.0)
    block = ins.advance(end + 0.1)
    assert block.table_rate_dps.min() < 0 and block.table_rate_dps.max() <= 0
    assert block.table_deg[-1] == pytest.approx(350.0, abs=1e-9)
    ins.table.move_by(ins.time_s, 90.0)
    ins.advance(2.0)
    stop_at = ins.table.stop(ins.time_s)
    assert stop_at - ins.time_s == pytest.approx(10.0 / 20.0)
    ins.advance(1.0)
    assert not ins.table.is_moving(ins.time_s)
    assert ins.table.state(ins.time_s)[1] == 0.0


def test_indexing_error_shows_in_the_encoder_and_encoder_is_quantised():
    spec = TableSpec(indexing_error_deg=0.05, encoder_resolution_deg=0.001)
    ins = Instrument(SensorSpec(table=spec), Truth(), np.random.default_rng(5))
    window = window_at(ins, 30.0)
    assert abs(window.table_deg[-1] - 30.0) > 1e-4
    assert_allclose(window.table_deg / 0.001, np.round(window.table_deg / 0.001), atol=1e-6)


def test_quantisation_carries_its_remainder():
    spec = IDEAL.with_values({"gyro.lsb_dph": 0.5, "accel.lsb_ug": 20.0})
    truth = Truth(azimuth_deg=40.0)
    q = Instrument(spec, truth, np.random.default_rng(0)).generate(2000)
    exact = Instrument(IDEAL, truth, np.random.default_rng(0)).generate(2000)
    lsb = np.array([0.5 * DPH] * 3)
    assert_allclose(q.gyro_rps / lsb, np.round(q.gyro_rps / lsb), atol=1e-6)
    assert np.abs(q.gyro_rps - exact.gyro_rps).max() > 0.1 * lsb[0]
    # window sums are exact to one count
    assert np.all(np.abs(q.gyro_rps.sum(0) - exact.gyro_rps.sum(0)) <= lsb)


def test_warm_up_temperature_impulse_and_vibration_terms_appear_and_switch_off():
    spec = IDEAL.with_values(
        {
            "gyro.warmup_bias_dph": [1.0, 0.0, 0.0],
            "gyro.warmup_tau_s": 10.0,
            "gyro.temp_coeff_dph_per_c": [0.0, 0.1, 0.0],
            "thermal.ramp_c_per_h": 36.0,
        }
    )
    ins = Instrument(spec, Truth(), np.random.default_rng(0))
    clean = Instrument(IDEAL, Truth(), np.random.default_rng(0))
    d = (ins.generate(200 * 60).gyro_rps - clean.generate(200 * 60).gyro_rps) / DPH
    t = np.arange(1, 200 * 60 + 1) / 200.0
    assert_allclose(d[:, 0], np.exp(-t / 10.0), atol=1e-9)
    assert_allclose(d[:, 1], 0.1 * 36.0 * t / 3600.0, atol=1e-9)  # the linear trend
    dist = IDEAL.with_values(
        {
            "disturbance.impulse_rate_hz": 1.0,
            "gyro.impulse_dph": 100.0,
            "disturbance.vibration_hz": 35.0,
            "gyro.vibration_dph": 3.0,
        }
    )
    ins = Instrument(dist, Truth(), np.random.default_rng(1))
    g = ins.generate(200 * 20).gyro_rps / DPH - clean.generate(200 * 20).gyro_rps / DPH
    assert np.abs(g).max() > 20.0  # impulses
    spectrum = np.abs(np.fft.rfft(g[:, 0]))
    assert np.argmax(spectrum[1:]) + 1 == pytest.approx(35.0 * 20, abs=2)  # 35 Hz line
    ins.set_vibration(False)
    ins.set_spec(ins.spec.with_values({"disturbance.impulse_rate_hz": 0.0}))
    ins.generate(200)  # let the last impulse pass
    quiet = ins.generate(2000).gyro_rps / DPH - clean.generate(2200).gyro_rps[200:] / DPH
    assert np.abs(quiet).max() < 1e-9


def test_injected_bias_step_and_impulse_burst():
    ins = Instrument(IDEAL, Truth(), np.random.default_rng(0))
    before = ins.generate(100).gyro_rps.mean(0)
    ins.inject_bias_step(gyro_dph=(0.0, 2.0, 0.0))
    after = ins.generate(100).gyro_rps.mean(0)
    assert_allclose((after - before) / DPH, [0.0, 2.0, 0.0], atol=1e-9)
    ins.inject_impulses(3, interval_s=0.2, gyro_dph=40.0, accel_ug=0.0)
    burst = ins.generate(200).gyro_rps / DPH - after / DPH
    assert np.linalg.norm(burst, axis=1).max() == pytest.approx(40.0, rel=0.05)


def test_identical_seeds_identical_output_and_blocks_equal_steps():
    spec = load_spec("fog-0.08").with_values(
        {"disturbance.impulse_rate_hz": 0.5, "gyro.impulse_dph": 30.0}
    )
    truth = Truth(azimuth_deg=200.0, latitude_deg=-20.0, pitch_deg=1.0)
    whole = Instrument(spec, truth, np.random.default_rng(42)).generate(4000)
    stepped = Instrument(spec, truth, np.random.default_rng(42))
    parts = [stepped.advance(0.005) for _ in range(1000)] + [
        stepped.advance(0.37) for _ in range(40)
    ]
    parts.append(stepped.generate(4000 - sum(len(p) for p in parts)))
    joined = SampleBlock.concat(parts)
    assert_allclose(joined.gyro_rps, whole.gyro_rps, rtol=0, atol=0)
    assert_allclose(joined.accel_mps2, whole.accel_mps2, rtol=0, atol=0)
    assert_allclose(joined.counter, np.arange(4000))
    other = Instrument(spec, truth, np.random.default_rng(43)).generate(4000)
    assert not np.allclose(other.gyro_rps, whole.gyro_rps)


def test_allan_deviation_reads_the_configured_arw_at_one_second():
    arw = 0.0015
    rate_dph = gyro_hours_dph(GyroSpec(arw_dpsh=arw), seed=7, hours=1.0, fs=200.0)
    _, adev = allan_deviation(rate_dph, 200.0, [1.0])
    # sigma_A(1 s) = N / sqrt(1 s); N in deg/h/sqrt(Hz) = ARW deg/sqrt(h) * 60
    assert_allclose(adev[0], arw * 60.0, rtol=0.05)


def gyro_hours_dph(gyro: GyroSpec, seed: int, hours: float = 4.0, fs: float = 20.0):
    """``hours`` of gyro output of a still, level instrument at ``fs``, deg/h."""
    ins = Instrument(SensorSpec(gyro=gyro), Truth(), np.random.default_rng(seed), sample_rate_hz=fs)
    return ins.generate(round(fs * 3600 * hours)).gyro_rps / DPH


def test_allan_floor_matches_the_bias_instability():
    b = 0.05
    rate = gyro_hours_dph(GyroSpec(bias_instability_dph=b), seed=11)
    _, adev = allan_deviation(rate, 20.0, [10.0, 20.0, 50.0, 100.0, 200.0])
    floor = adev.mean(axis=0)
    assert_allclose(floor, 0.664 * b, rtol=0.15)


def test_rate_random_walk_has_a_half_slope():
    k = 0.1
    rate = gyro_hours_dph(GyroSpec(rrw_dphpsh=k), seed=2)
    taus, adev = allan_deviation(rate, 20.0, [10.0, 20.0, 50.0, 100.0, 200.0, 300.0])
    slopes = np.polyfit(np.log(taus), np.log(adev), 1)[0]
    assert_allclose(slopes, 0.5, atol=0.1)
    # level: K sqrt(tau / 3), K in deg/h/sqrt(s) = RRW / 60
    assert_allclose(adev[1], k / 60.0 * math.sqrt(20.0 / 3.0), rtol=0.2)


def test_every_preset_loads_and_ideal_has_no_error_term():
    names = preset_names()
    assert {"ideal", "paper-rlg", "fog-0.08", "nav-fog", "tactical-fog", "mems"} <= set(names)
    for name in names:
        assert load_spec(name).name == name
    d = IDEAL.to_dict()
    for section in ("gyro", "accel"):
        for key, value in d[section].items():
            if key.startswith("range") or key.endswith("tau_s"):
                continue
            assert not np.any(value), f"ideal {section}.{key} = {value}"
    assert IDEAL.table.encoder_resolution_deg == 0 and IDEAL.table.indexing_error_deg == 0


def test_spec_round_trips_through_a_toml_file(tmp_path):
    spec = load_spec("nav-fog")
    lines = [f'name = "{spec.name}"', f'description = "{spec.description}"']
    for section, values in spec.to_dict().items():
        if isinstance(values, dict):
            lines.append(f"[{section}]")
            lines += [f"{k} = {v!r}" for k, v in values.items()]
    path = tmp_path / "mine.toml"
    path.write_text("\n".join(lines))
    assert load_spec(str(path)) == spec


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"gyro": {"arw_dpsh": -0.1}}, "gyro.arw_dpsh: must not be negative"),
        ({"gyro": {"arw_dpsh": float("nan")}}, "gyro.arw_dpsh: must be finite"),
        ({"gyro": {"arw": 0.1}}, "gyro.arw: unknown field"),
        ({"accel": {"bias_ug": [1.0, 2.0]}}, "accel.bias_ug: expected a list of three numbers"),
        ({"table": {"max_rate_dps": 0.0}}, "table.max_rate_dps: must be positive"),
        ({"thermal": {"ambient_c": "warm"}}, "thermal.ambient_c: expected a number"),
        ({"gyros": {}}, "unknown section or key 'gyros'"),
    ],
)
def test_bad_specs_name_the_field(data, message):
    with pytest.raises(SimConfigError, match=message.replace("[", r"\[")):
        spec_from_dict(data, source="test.toml")


def test_bad_presets_files_latitudes_and_rates(tmp_path):
    with pytest.raises(
        SimConfigError, match=r"unknown sensor preset 'rlg'; presets are .*paper-rlg"
    ):
        load_spec("rlg")
    bad = tmp_path / "bad.toml"
    bad.write_text("[gyro\narw_dpsh = 1")
    with pytest.raises(SimConfigError, match="not valid TOML"):
        load_spec(bad)
    with pytest.raises(SimConfigError, match="cannot read"):
        load_spec(tmp_path / "missing.toml")
    with pytest.raises(SimConfigError, match="too close to a pole"):
        Truth(latitude_deg=90.0)
    with pytest.raises(SimConfigError, match="must lie in"):
        check_latitude(91.0)
    with pytest.raises(SimConfigError, match="finite"):
        Truth(azimuth_deg=float("nan"))
    with pytest.raises(SimConfigError, match="pitch_deg"):
        Truth(pitch_deg=60.0)
    with pytest.raises(SimConfigError, match="sample_rate_hz: 5000 Hz cannot be honoured"):
        Instrument(IDEAL, Truth(), np.random.default_rng(0), sample_rate_hz=5000)
    with pytest.raises(SimConfigError, match="sample_rate_hz"):
        Instrument(IDEAL, Truth(), np.random.default_rng(0), sample_rate_hz=float("nan"))
    with pytest.raises(SimConfigError, match="not a sensor field"):
        IDEAL.with_values({"arw": 1.0})


def test_saturation_is_flagged():
    spec = SensorSpec(
        gyro=GyroSpec(range_dps=5.0),
        accel=AccelSpec(range_g=2.0),
        table=TableSpec(max_rate_dps=10.0),
    )
    ins = Instrument(spec, Truth(), np.random.default_rng(0))
    ins.table.move_by(0.0, 90.0)
    block = ins.advance(5.0)
    assert block.gyro_saturated.any() and not block.accel_saturated.any()
    assert np.degrees(block.gyro_rps[:, 2]).max() <= 5.0 + 1e-12


def test_unused_spec_sections_have_defaults():
    spec = SensorSpec()
    assert spec.thermal == ThermalSpec() and spec.disturbance == DisturbanceSpec()


# ----------------------------------------------------------------------------------------------
# The error terms shared by the instrument and the batch generator
# ----------------------------------------------------------------------------------------------


def test_error_terms_convert_datasheet_units_to_si():
    spec = IDEAL.with_values(
        {
            "gyro.bias_dph": [1.0, -2.0, 0.5],
            "gyro.arw_dpsh": 0.06,
            "gyro.rrw_dphpsh": 0.6,
            "gyro.bias_instability_dph": 0.01,
            "gyro.range_dps": 90.0,
            "gyro.scale_factor_ppm": 20.0,
            "accel.misalignment_urad": 30.0,
            "accel.vrw_ug_rthz": 10.0,
            "accel.random_walk_ug_rts": 2.0,
            "accel.lsb_ug": 5.0,
            "accel.range_g": 2.0,
        }
    )
    terms = ErrorTerms.from_spec(spec)
    ug = 9.80665e-6
    assert_allclose(terms.bias, [DPH, -2 * DPH, 0.5 * DPH, 0, 0, 0], rtol=1e-15)
    # 0.06 deg/sqrt(h) = 0.001 deg/sqrt(s); per sample at 400 Hz: times sqrt(400).
    assert_allclose(terms.white_sigma(400.0)[:3], math.radians(0.001) * 20.0, rtol=1e-15)
    assert_allclose(terms.white_sigma(400.0)[3:], 10.0 * ug * 20.0, rtol=1e-15)
    # 0.6 deg/h/sqrt(h) = 0.01 deg/h/sqrt(s).
    assert_allclose(terms.walk_k, [0.01 * DPH] * 3 + [2.0 * ug] * 3, rtol=1e-15)
    assert_allclose(terms.flicker_b[:3], 0.01 * DPH, rtol=1e-15)
    assert_allclose(terms.range, [math.pi / 2] * 3 + [2.0 * 9.80665] * 3, rtol=1e-15)
    assert_allclose(terms.lsb, [0.0] * 3 + [5.0 * ug] * 3, rtol=1e-15)
    assert_allclose(terms.scale_factor, [20e-6, 0.0])
    assert_allclose(terms.misalignment, [0.0, 30e-6])
    assert terms.has_matrix and not ErrorTerms.from_spec(IDEAL).has_matrix


def test_flicker_components_sum_to_a_one_over_f_spectrum():
    """Gauss-Markov components of variance c spaced by sqrt(10) sum to the PSD B^2 / (pi f)."""
    assert FLICKER_STD**2 == pytest.approx(FLICKER_VARIANCE)
    assert_allclose(np.diff(np.log10(FLICKER_TAUS_S)), 0.5)
    # Inside the band the components cover (corners 1 / (2 pi tau): 1.6e-5 to 0.16 Hz).
    f = np.logspace(-3.5, -2.0, 31)
    tau = FLICKER_TAUS_S[:, None]
    # One-sided PSD of a first-order Gauss-Markov process of unit B: 4 c tau / (1 + (2 pi f tau)^2).
    psd = (4.0 * FLICKER_VARIANCE * tau / (1.0 + (2 * math.pi * f * tau) ** 2)).sum(axis=0)
    assert_allclose(psd, 1.0 / (math.pi * f), rtol=0.03)


def test_drift_is_the_warm_up_transient_plus_the_temperature_term():
    spec = SensorSpec(
        gyro=GyroSpec(warmup_bias_dph=(2.0, 0.0, 0.0), warmup_tau_s=30.0),
        accel=AccelSpec(temp_coeff_ug_per_c=(0.0, 0.0, 4.0)),
        thermal=ThermalSpec(
            ambient_c=15.0, warmup_rise_c=6.0, warmup_tau_s=300.0, ramp_c_per_h=1.8
        ),
    )
    t = np.array([0.0, 30.0, 600.0, 3600.0])
    rise = 6.0 * (1.0 - np.exp(-t / 300.0)) + 1.8 * t / 3600.0
    assert_allclose(temperature_c(spec.thermal, t), 15.0 + rise, rtol=1e-15)
    drift = ErrorTerms.from_spec(spec).drift(t, spec.thermal)
    assert drift.shape == (4, 6)
    assert_allclose(drift[:, 0], 2.0 * DPH * np.exp(-t / 30.0), rtol=1e-14)
    assert_allclose(drift[:, 5], 4.0 * 9.80665e-6 * rise, rtol=1e-12, atol=1e-20)
    assert not np.any(drift[:, 1:5])


def test_quantise_carry_keeps_every_run_sum_within_one_count():
    rng = np.random.default_rng(0)
    values = rng.normal(0.0, 3.0, (4, 1000))  # four channels, runs along the last axis
    whole, rem = quantise_carry(values, np.zeros(4))
    assert_allclose(whole, np.round(whole), atol=0)
    # Cumulative sums never stray by more than half a count; the remainder is what is left.
    assert np.abs(np.cumsum(whole - values, axis=-1)).max() <= 0.5 + 1e-9
    assert_allclose(rem, values.sum(-1) - whole.sum(-1), atol=1e-9)
    # Carrying the remainder over a split gives the same counts as one run.
    first, mid = quantise_carry(values[:, :333], np.zeros(4))
    second, end = quantise_carry(values[:, 333:], mid)
    assert_allclose(np.hstack([first, second]), whole, atol=0)
    assert_allclose(end, rem, atol=0)
    # The same along axis 0, and an empty run leaves the remainder alone.
    by_rows, rem0 = quantise_carry(values.T, np.zeros(4), axis=0)
    assert_allclose(by_rows, whole.T, atol=0)
    assert_allclose(rem0, rem, atol=0)
    empty, kept = quantise_carry(np.empty((4, 0)), rem)
    assert empty.shape == (4, 0) and np.array_equal(kept, rem)


def test_one_batch_run_draws_the_same_power_on_as_the_instrument():
    """Same seed, same error terms: turn-on bias, scale factor, misalignment, indexing error of
    every move, the bias steps and transients that moves start, warm-up, temperature and rate
    ramp come out alike sample by sample from both generators, over several moves and a repeated
    position (no move: the table keeps its last stop)."""
    spec = IDEAL.with_values(
        {
            "gyro.bias_dph": [0.3, -0.2, 0.1],
            "gyro.turn_on_bias_dph": 0.5,
            "gyro.scale_factor_ppm": 300.0,
            "gyro.misalignment_urad": 200.0,
            "gyro.warmup_bias_dph": [1.0, -1.0, 0.5],
            "gyro.temp_coeff_dph_per_c": [0.02, 0.01, 0.0],
            "gyro.rate_ramp_dph_per_h": [0.5, -0.3, 0.2],
            "gyro.move_walk_dph_per_rtdeg": 0.01,
            "gyro.move_transient_dph_per_rtdeg": 0.05,
            "gyro.move_transient_tau_s": 4.0,
            "accel.turn_on_bias_ug": 50.0,
            "accel.scale_factor_ppm": 100.0,
            "accel.misalignment_urad": 100.0,
            "accel.temp_coeff_ug_per_c": [2.0, -1.0, 0.5],
            "accel.move_walk_ug_per_rtdeg": 2.0,
            "accel.move_transient_ug_per_rtdeg": 3.0,
            "thermal.warmup_rise_c": 4.0,
            "table.indexing_error_deg": 0.01,
            "table.heat_tau_s": 60.0,
        }
    )
    truth = Truth(azimuth_deg=75.0, latitude_deg=40.0, pitch_deg=1.5, roll_deg=-0.5)
    positions = [0.0, 120.0, 120.0, 30.0, 300.0]
    starts, n, _, _ = plan_timeline(spec, positions, 5.0, warmup_s=30.0)
    batch = simulate_windows(
        spec, truth, positions, 5.0, n_runs=1, rng=np.random.default_rng(9), warmup_s=30.0
    )
    ins = Instrument(spec, truth, np.random.default_rng(9))
    for i, p in enumerate(positions):
        if i:
            ins.table.move_to(ins.time_s, p)
        ins.generate(int(starts[i] - ins.samples_emitted))
        block = ins.generate(n)
        assert_allclose(batch.gyro_rps[0, i], block.gyro_rps, rtol=0, atol=1e-12 * OMEGA_IE)
        assert_allclose(batch.accel_mps2[0, i], block.accel_mps2, rtol=0, atol=1e-12 * 9.8)
        assert_allclose(batch.table_deg[0, i], block.table_deg, atol=0)
    assert len(ins.table.moves) == 3  # the repeated position is no move
    assert batch.table_deg[0, 2] == batch.table_deg[0, 1] != 120.0
    # The error terms are really there: far from the ideal instrument.
    ideal = Instrument(IDEAL, truth, np.random.default_rng(9)).generate(10).gyro_rps
    first = simulate_windows(spec, truth, [0.0], 0.05, n_runs=1, rng=np.random.default_rng(9))
    assert np.abs(first.gyro_rps[0, 0] - ideal).max() > 0.1 * DPH


def stop_errors_deg(reached: ArrayLike, commanded: ArrayLike) -> np.ndarray:
    return (np.asarray(reached) - np.asarray(commanded) + 180.0) % 360.0 - 180.0


def assert_fresh_stop_errors(err: np.ndarray, sigma: float) -> None:
    """Stop errors (moves along the last axis) scatter by ``sigma`` and adjacent ones do not
    correlate: a stop error carried into the next move gives sqrt(2) sigma and +0.5."""
    n = err.size
    # The sample std of n normal values is within 4 standard errors (sigma / sqrt(2 n)).
    assert abs(err.std() / sigma - 1.0) < 4.0 / math.sqrt(2 * n), err.std()
    a, b = err[..., :-1].ravel(), err[..., 1:].ravel()
    assert abs(np.corrcoef(a, b)[0, 1]) < 4.0 / math.sqrt(a.size)


def test_turntable_stop_errors_are_fresh_for_every_move():
    sigma = 0.01
    spec = TableSpec(indexing_error_deg=sigma, encoder_resolution_deg=0.0, settle_s=0.0)
    ins = Instrument(SensorSpec(table=spec), Truth(), np.random.default_rng(14))
    table, t = ins.table, 0.0
    targets = (30.0 * np.arange(1, 801)) % 360.0
    reached = []
    for target in targets:
        t = table.move_to(t, target) + 0.5
        reached.append(float(table.state(t)[0]))
    assert_fresh_stop_errors(stop_errors_deg(reached, targets), sigma)
    # Going where the table was last sent is no move: the error of the last stop stays.
    before = float(table.state(t)[0])
    assert table.move_to(t, targets[-1]) == t
    assert float(table.state(t + 5.0)[0]) == before and len(table.moves) == len(targets)


def test_batch_stop_errors_are_fresh_for_every_move():
    sigma = 0.01
    spec = IDEAL.with_values({"table.indexing_error_deg": sigma, "table.settle_s": 0.0})
    positions = [0.0, 30.0, 60.0, 60.0, 90.0, 120.0, 150.0, 180.0, 210.0]
    batch = simulate_windows(
        spec, Truth(), positions, 0.1, n_runs=300, rng=np.random.default_rng(15)
    )
    err = stop_errors_deg(batch.table_deg, batch.commanded_deg)
    assert np.all(err[:, 0] == 0.0)  # no move before the first window
    assert np.array_equal(err[:, 3], err[:, 2])  # the repeated position keeps its stop
    assert_fresh_stop_errors(np.delete(err, [0, 3], axis=1), sigma)


def test_move_terms_scatter_window_means_as_specified():
    """Window-mean bias differences across many runs: the lasting step adds
    move_walk^2 |d| to the variance, the transient sqrt(|d|) move_transient times its mean
    decay over the window; both scale with the square root of the angle turned. At 20 Hz: the
    terms are functions of time (the expected variances below are on the batch's own sample
    grid), so the rate changes nothing they are compared with, and 4000 runs cost a tenth."""
    walk, transient, tau = 0.02, 0.3, 5.0
    spec = IDEAL.with_values(
        {
            "gyro.move_walk_dph_per_rtdeg": walk,
            "gyro.move_transient_dph_per_rtdeg": transient,
            "gyro.move_transient_tau_s": tau,
            "table.settle_s": 6.0,
            "table.max_rate_dps": 10.0,
            "table.max_accel_dps2": 100.0,
        }
    )
    positions, window = [0.0, 30.0, 150.0], 10.0
    starts, n, _, delta = plan_timeline(spec, positions, window, sample_rate_hz=20.0)
    runs = 4000
    batch = simulate_windows(
        spec, Truth(), positions, window, n_runs=runs, rng=np.random.default_rng(16),
        sample_rate_hz=20.0,
    )  # fmt: skip
    means = batch.gyro_rps.mean(axis=2) / DPH  # (runs, positions, 3)
    dev = means - means.mean(axis=0)  # the Earth rate is the same in every run
    fs = batch.sample_rate_hz
    # Moves start at the ends of windows 0 and 1; window p averages exp(-(t - t0) / tau).
    t0 = [(starts[0] + n) / fs, (starts[1] + n) / fs]
    t = (starts[:, None] + 1 + np.arange(n)) / fs

    def decay(p: int, m: int) -> float:
        return float(np.exp(-(t[p] - t0[m]) / tau).mean())

    size = np.abs(delta[1:])
    var1 = size[0] * (walk**2 + transient**2 * decay(1, 0) ** 2)
    var2 = size[0] * (walk**2 + transient**2 * decay(2, 0) ** 2) + size[1] * (
        walk**2 + transient**2 * decay(2, 1) ** 2
    )
    cov12 = size[0] * (walk**2 + transient**2 * decay(1, 0) * decay(2, 0))
    tol = 4.0 * math.sqrt(2.0 / runs)  # 4 standard errors of a variance ratio, about 9 %
    for axis in range(3):
        assert np.abs(dev[:, 0, axis]).max() < 1e-9  # nothing before the first move
        assert abs(dev[:, 1, axis].var() / var1 - 1.0) < tol
        assert abs(dev[:, 2, axis].var() / var2 - 1.0) < tol
        c = np.mean(dev[:, 1, axis] * dev[:, 2, axis])
        assert abs(c - cov12) < 4.0 * math.sqrt(var1 * var2 / runs)
    # The accelerometers are left alone (their move terms are zero).
    assert np.ptp(batch.accel_mps2.mean(axis=2), axis=0).max() == 0.0


def test_the_move_transient_decays_with_its_time_constant_and_the_ramp_is_linear():
    spec = IDEAL.with_values(
        {
            "gyro.move_transient_dph_per_rtdeg": 1.0,
            "gyro.move_transient_tau_s": 3.0,
            "gyro.rate_ramp_dph_per_h": [0.0, 0.0, 36.0],
            "table.settle_s": 0.0,
        }
    )
    ins = Instrument(spec, Truth(), np.random.default_rng(17))
    clean = Instrument(IDEAL, Truth(), np.random.default_rng(17))
    ins.advance(1.0)
    clean.advance(1.0)
    t0 = ins.time_s
    end = ins.table.move_by(t0, 90.0)
    assert clean.table.move_by(t0, 90.0) == end
    d = (ins.advance(end - t0 + 20.0).gyro_rps - clean.advance(end - t0 + 20.0).gyro_rps) / DPH
    t = t0 + np.arange(1, len(d) + 1) / ins.sample_rate_hz
    # Less the ramp on z (36 deg/h per hour = 0.01 deg/h per second since power-on), what is
    # left is one random amplitude per axis decaying as exp(-(t - t0) / 3 s) from the move start.
    d[:, 2] -= 0.01 * t
    shape = np.exp(-(t - t0) / 3.0)
    amp = d / shape[:, None]
    assert_allclose(amp, np.broadcast_to(amp[0], amp.shape), rtol=1e-8)
    assert np.all(np.abs(amp[0]) > 0.01)  # sqrt(90) x N(0, 1) deg/h: not zero


def test_move_heat_sizes_the_move_disturbance_by_the_angles_turned_and_their_age():
    start = np.array([0.0, 20.0, 50.0])
    angle = np.array([30.0, -90.0, 10.0])
    assert_allclose(move_heat(start, angle, 0.0), [30.0, 90.0, 10.0])
    e = math.exp
    expected = [
        30.0,
        90.0 + 30.0 * e(-20.0 / 40.0),
        10.0 + 90.0 * e(-30.0 / 40.0) + 30.0 * e(-50.0 / 40.0),
    ]
    assert_allclose(move_heat(start, angle, 40.0), expected, rtol=1e-14)
    assert_allclose(move_heat(start, angle, 40.0, last=1), expected[-1:], rtol=1e-14)


def test_turn_on_bias_scatters_between_power_ons_as_specified():
    """turn_on_bias_dph is the power-on to power-on repeatability: one draw per run."""
    sigma = 0.002
    spec = IDEAL.with_values({"gyro.turn_on_bias_dph": sigma, "accel.turn_on_bias_ug": 20.0})
    runs = 2000
    batch = simulate_windows(spec, Truth(), [0.0], 1.0, n_runs=runs, rng=np.random.default_rng(18))
    gyro = batch.gyro_rps.mean(axis=2) / DPH
    accel = batch.accel_mps2.mean(axis=2) / 9.80665e-6
    tol = 4.0 / math.sqrt(2 * runs)
    assert_allclose(gyro.std(axis=0).ravel() / sigma, 1.0, atol=tol)
    assert_allclose(accel.std(axis=0).ravel() / 20.0, 1.0, atol=tol)
    # Within one power-on it does not change.
    assert np.ptp(batch.gyro_rps[:, 0], axis=1).max() < 1e-12 * DPH


def test_the_instrument_and_the_batch_refuse_the_same_sample_rates():
    for make in (
        lambda fs: Instrument(IDEAL, Truth(), np.random.default_rng(0), sample_rate_hz=fs),
        lambda fs: plan_timeline(IDEAL, [0.0, 180.0], 10.0, sample_rate_hz=fs),
    ):
        with pytest.raises(SimConfigError, match=r"sample_rate_hz: 5 Hz .* from 10 to 2000 Hz"):
            make(5)
        make(10.0)
        make(2000.0)


def test_short_runs_of_the_slow_noise_recursion_equal_lfilter_to_the_bit():
    """The instrument filters its few look-ahead steps without scipy; the batch generator's long
    runs use lfilter: both must give the same numbers."""
    import northfinder.firmware_sim.error_terms as terms
    from northfinder.firmware_sim.firmware import LOOKAHEAD_S, VIRTUAL_LOOKAHEAD_S

    # every look-ahead chunk is a short run (a longer one would import scipy on the stream's path)
    assert max(LOOKAHEAD_S, VIRTUAL_LOOKAHEAD_S) / terms.FLICKER_GRID_S + 1 <= terms._SHORT_RUN

    rng = np.random.default_rng(1)
    k = len(terms.FLICKER_PHI)
    for shape in [(6,), (3, 6)]:
        for m in (1, 2, terms._SHORT_RUN):
            w = rng.standard_normal((m, k + 1, *shape))
            state, walk = rng.standard_normal((k, *shape)), rng.standard_normal(shape)
            short = terms.slow_noise_steps(w, state, walk)
            saved = terms._SHORT_RUN
            terms._SHORT_RUN = 0
            try:
                long = terms.slow_noise_steps(w, state, walk)
            finally:
                terms._SHORT_RUN = saved
            for a, b in zip(short, long, strict=True):
                np.testing.assert_array_equal(a, b)
