"""North finding on a turning table: the demodulating solver over the whole stack (simulated
firmware, wire, driver, in virtual time), its white-noise bound against a Monte Carlo, its sigma
and consistency check, the table's imperfections, and ``find --spin``."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from northfinder.cli import main, spinfind
from northfinder.driver.protocol.units import DPSH, OMEGA_IE
from northfinder.embed import SimulatedInstrument
from northfinder.firmware_sim.batch import simulate_spin
from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import bound_deg, spin_bound_deg
from northfinder.host.errors import GeometryError
from northfinder.host.spin import (
    SpinSamples,
    fitted_rates,
    solve_spin,
    solve_spin_batch,
    spin_samples,
)

IDEAL = load_spec("ideal")
LAT = 34.0


def wrap(a: float) -> float:
    return (float(a) + 180.0) % 360.0 - 180.0


def wrapv(a: np.ndarray) -> np.ndarray:
    return (a + 180.0) % 360.0 - 180.0


def batch_samples(b, r: int) -> SpinSamples:
    return SpinSamples(b.gyro_rps[r], b.accel_mps2[r], b.mu0_rad[r], b.mu1_rad[r], b.time_s)


# ----------------------------------------------------------------------------------------------
# The whole stack, ideal sensors
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("azimuth", "pitch", "roll", "rate"),
    [(42.0, 3.0, -2.0, 10.0), (300.0, -14.0, 14.5, -10.0), (123.4, 0.5, 8.0, 7.5),
     (359.9, 14.9, -14.9, -4.0)],
)  # fmt: skip
def test_ideal_sensors_any_tilt_any_rate_through_the_whole_stack(azimuth, pitch, roll, rate):
    """Firmware, CAN frames, driver and solver in virtual time: 1e-6 deg over one turn."""
    truth = Truth(azimuth_deg=azimuth, pitch_deg=pitch, roll_deg=roll, latitude_deg=LAT)
    with SimulatedInstrument(IDEAL, truth, seed=1, clock="virtual", warmup_s=0) as sim:
        with sim.open_device() as dev:
            dev.wait_ready()
            dev.spin(rate)
            w = dev.acquire(360.0 / abs(rate))
            dev.stop(wait=True)
    data = spin_samples(w.gyro_dph, w.accel_mps2, w.table_deg, w.counter, w.sample_rate_hz,
                        w.validity)  # fmt: skip
    assert data.dropped == 1  # the first: its interval began before the window
    sol = solve_spin(data, latitude_deg=LAT)
    assert abs(wrap(sol.azimuth_deg - azimuth)) < 1e-6
    assert abs(sol.pitch_deg - pitch) < 1e-6 and abs(sol.roll_deg - roll) < 1e-6
    assert sol.consistent and sol.sigma_deg < 1e-4
    assert sol.rate_dps == pytest.approx(rate, rel=1e-6)


@pytest.mark.parametrize("rate", [45.0, -12.0, 3.0, -1.0])
def test_batch_generator_and_batch_solver_are_exact_without_noise(rate):
    rng = np.random.default_rng(1)
    truths = [Truth(azimuth_deg=a, pitch_deg=p, roll_deg=r, latitude_deg=LAT)
              for a, p, r in zip(rng.uniform(0, 360, 8), rng.uniform(-15, 15, 8),
                                 rng.uniform(-15, 15, 8), strict=True)]  # fmt: skip
    spec = IDEAL.with_values({"gyro.bias_dph": (3.0, -2.0, 1.0), "accel.bias_ug": (50, -80, 0)})
    b = simulate_spin(spec, truths, rate, 400.0 / abs(rate), n_runs=8, rng=rng,
                      sample_rate_hz=50.0)  # fmt: skip
    az = solve_spin_batch(b.gyro_rps, b.accel_mps2, b.mu0_rad, b.mu1_rad, latitude_deg=LAT)
    assert_allclose(wrapv(az - b.azimuth_deg), 0.0, atol=1e-9)
    az = solve_spin_batch(b.gyro_rps, b.accel_mps2, b.mu0_rad, b.mu1_rad, latitude_deg=LAT,
                          time_s=b.time_s, drift=True)  # fmt: skip
    assert_allclose(wrapv(az - b.azimuth_deg), 0.0, atol=1e-9)


def test_batch_generator_is_the_instrument_for_every_deterministic_term():
    """Warm-up, temperature, ramps, the table's ripple and wobble and the encoder's periodic error:
    the batch generator's samples and encoder angles are the instrument's, sample by sample."""
    spec = IDEAL.with_values({
        "gyro.warmup_bias_dph": [0.5, -0.3, 0.2], "gyro.rate_ramp_dph_per_h": [0.2, 0.1, 0.0],
        "gyro.temp_coeff_dph_per_c": [0.05, -0.03, 0.0], "thermal.warmup_rise_c": 5.0,
        "accel.warmup_bias_ug": [50.0, -30.0, 0.0], "table.rate_ripple": 0.01,
        "table.rate_ripple_phase_deg": 40.0, "table.wobble_urad": 300.0,
        "table.wobble_phase_deg": 70.0, "table.encoder_error_deg": 0.01,
        "table.encoder_error_harmonic": 2.0, "table.max_accel_dps2": 10.0,
    })  # fmt: skip
    truth = Truth(azimuth_deg=33.0, pitch_deg=2.0, roll_deg=-1.0, latitude_deg=LAT)
    ins = Instrument(spec, truth, np.random.default_rng(4), sample_rate_hz=200.0)
    ins.generate(10)
    steady = ins.table.spin(ins.time_s, 10.0)  # 1 s of acceleration: a whole sample boundary
    assert steady == pytest.approx(1.05)
    ins.generate(210 - 10)
    blk = ins.generate(4000)
    b = simulate_spin(spec, truth, 10.0, 20.0, n_runs=1, rng=np.random.default_rng(0),
                      sample_rate_hz=200.0, start_deg=5.0, start_s=1.05)  # fmt: skip
    assert_allclose(b.gyro_rps[0], blk.gyro_rps, rtol=0, atol=1e-12)  # z: the table rate
    assert_allclose(b.accel_mps2[0], blk.accel_mps2, rtol=0, atol=1e-11)
    enc = np.degrees(b.read1_rad[0]) % 360.0
    assert_allclose(wrapv(enc - blk.table_deg), 0.0, atol=1e-9)


# ----------------------------------------------------------------------------------------------
# The bound and the Monte Carlo
# ----------------------------------------------------------------------------------------------


def test_the_spin_bound_of_whole_turns_is_the_closed_form():
    """N / (Omega_H sqrt(T)): the two-position bound at 180 deg with the same total time."""
    arw, t = 0.0015, 120.0
    closed = math.degrees(arw * DPSH / (OMEGA_IE * math.cos(math.radians(LAT)) * math.sqrt(t)))
    for rate, start in ((6.0, 0.0), (-3.0, 77.0), (12.0, 200.0)):
        assert spin_bound_deg(t, rate, arw, LAT, start_deg=start) == pytest.approx(closed, rel=1e-6)
    assert spin_bound_deg(t, 6.0, arw, LAT) == pytest.approx(
        bound_deg([0.0, 180.0], t / 2, arw, LAT), rel=1e-6
    )
    # The sample rate does not matter; a part turn and a fitted drift cost something.
    assert spin_bound_deg(t, 6.0, arw, LAT, sample_rate_hz=10.0) == pytest.approx(closed, rel=1e-4)
    assert spin_bound_deg(45.0, 6.0, arw, LAT) > 1.01 * spin_bound_deg(45.0, 8.0, arw, LAT)
    assert spin_bound_deg(t, 6.0, arw, LAT, drift=True) > 1.02 * closed  # 1.2 over one turn
    with pytest.raises(GeometryError, match="at least 90 deg"):
        spin_bound_deg(10.0, 6.0, arw, LAT)


def _monte_carlo(spec, n_runs, rate, duration, fs, seed, *, drift=False, tilt=3.0):
    rng = np.random.default_rng(seed)
    errors = []
    for _ in range(n_runs // 500):
        truths = [Truth(azimuth_deg=a, pitch_deg=p, roll_deg=r, latitude_deg=LAT)
                  for a, p, r in zip(rng.uniform(0, 360, 500), rng.uniform(-tilt, tilt, 500),
                                     rng.uniform(-tilt, tilt, 500), strict=True)]  # fmt: skip
        b = simulate_spin(spec, truths, rate, duration, n_runs=500, rng=rng, sample_rate_hz=fs)
        az = solve_spin_batch(b.gyro_rps, b.accel_mps2, b.mu0_rad, b.mu1_rad, latitude_deg=LAT,
                              time_s=b.time_s, drift=drift)  # fmt: skip
        errors.append(wrapv(az - b.azimuth_deg))
    return np.concatenate(errors)


@pytest.mark.slow
@pytest.mark.parametrize(("rate", "drift"), [(6.0, False), (-9.0, True)])
def test_white_noise_rmse_meets_the_spin_bound(rate, drift):
    """10 000 runs of white gyro and accelerometer noise: RMSE / bound in [1.00, 1.05] up to the
    Monte Carlo's own scatter (1 / sqrt(2 n) = 0.7 %): the solver is efficient, and nothing beats
    the bound."""
    spec = IDEAL.with_values({"gyro.arw_dpsh": 0.0015, "accel.vrw_ug_rthz": 20.0,
                              "gyro.turn_on_bias_dph": 0.5, "accel.turn_on_bias_ug": 100.0})  # fmt: skip
    duration = 60.0
    e = _monte_carlo(spec, 10_000, rate, duration, 10.0, seed=7, drift=drift)
    bound = spin_bound_deg(duration, rate, 0.0015, LAT, sample_rate_hz=10.0, vrw_ug_rthz=20.0,
                           drift=drift)  # fmt: skip
    ratio = math.sqrt(np.mean(e**2)) / bound
    se = 1.0 / math.sqrt(2 * e.size)
    assert 1.0 - 3 * se < ratio < 1.05, ratio
    assert abs(e.mean()) < 4 * e.std() / math.sqrt(e.size)


def test_sigma_is_honest_and_the_halves_agree():
    """White noise: the solution's sigma is the bound (to its own scatter) and err / sigma has
    unit RMS; the halves' check passes about as often as 3 sigma says."""
    spec = IDEAL.with_values({"gyro.arw_dpsh": 0.0015, "accel.vrw_ug_rthz": 20.0})
    rng = np.random.default_rng(3)
    truths = [Truth(azimuth_deg=a, latitude_deg=LAT) for a in rng.uniform(0, 360, 300)]
    b = simulate_spin(spec, truths, 6.0, 120.0, n_runs=300, rng=rng, sample_rate_hz=10.0)
    bound = spin_bound_deg(120.0, 6.0, 0.0015, LAT, sample_rate_hz=10.0, vrw_ug_rthz=20.0)
    z: list[float] = []
    white: list[float] = []
    consistent: list[bool | None] = []
    for r in range(300):
        sol = solve_spin(batch_samples(b, r), latitude_deg=LAT)
        z.append(wrap(sol.azimuth_deg - b.azimuth_deg[r]) / sol.sigma_deg)
        white.append(sol.sigma_white_deg)
        consistent.append(sol.consistent)
    assert_allclose(np.mean(white), bound, rtol=0.03)
    rms = math.sqrt(np.mean(np.square(z)))
    assert 0.9 < rms < 1.1
    assert sum(c is True for c in consistent) > 0.97 * len(consistent)


def test_a_heading_change_midway_fails_the_consistency_check():
    spec = IDEAL.with_values({"gyro.arw_dpsh": 0.0015})
    rng = np.random.default_rng(5)
    parts = [simulate_spin(spec, Truth(azimuth_deg=a, latitude_deg=LAT), 6.0, 60.0, n_runs=1,
                           rng=rng, sample_rate_hz=10.0, start_deg=0.0) for a in (40.0, 41.0)]  # fmt: skip
    data = SpinSamples(
        np.concatenate([p.gyro_rps[0] for p in parts]),
        np.concatenate([p.accel_mps2[0] for p in parts]),
        np.concatenate([p.mu0_rad[0] for p in parts]),
        np.concatenate([p.mu1_rad[0] for p in parts]),
        np.concatenate([parts[0].time_s, parts[1].time_s + 60.0]),
    )
    sol = solve_spin(data, latitude_deg=LAT)
    assert sol.consistent is False
    assert (
        sol.halves_deg is not None and abs(wrap(sol.halves_deg[1] - sol.halves_deg[0]) - 1.0) < 0.3
    )
    # Its sigma grows by the halves' disagreement: the 1 deg step is inside it.
    assert sol.halves_sigma_deg is not None
    d = abs(wrap(sol.halves_deg[1] - sol.halves_deg[0])) / math.hypot(*sol.halves_sigma_deg)
    assert_allclose(sol.sigma_scale, d, rtol=1e-12)
    assert sol.sigma_scale > 3 and sol.sigma_deg > 0.25
    assert f"sigma scaled x{sol.sigma_scale:.2f}" in spinfind.text(
        SimpleNamespace(solution=sol, latitude_deg=LAT, latitude_source=None), None
    )
    # The printed result carries find's marker for a heading its data cannot vouch for.
    found = SimpleNamespace(solution=sol, latitude_deg=LAT, latitude_source="--latitude")
    printed = spinfind.text(found, None)
    assert "halves" in printed and "NOT consistent" in printed
    assert "CONSISTENCY CHECK FAILED" in printed
    (warning,) = json.loads(spinfind.as_json(found, None, None))["notes"]
    assert warning.startswith("CONSISTENCY CHECK FAILED") and f"note: {warning}" in printed
    assert "CONSISTENCY CHECK FAILED" not in spinfind.text(
        SimpleNamespace(solution=replace(sol, consistent=True), latitude_deg=LAT,
                        latitude_source=None), None)  # fmt: skip


def test_a_drift_is_fitted_when_asked():
    rng = np.random.default_rng(2)
    b = simulate_spin(IDEAL, Truth(azimuth_deg=10.0, latitude_deg=LAT), 6.0, 75.0, n_runs=1,
                      rng=rng, sample_rate_hz=20.0)  # fmt: skip
    gyro = b.gyro_rps.copy()
    gyro[0, :, :2] += np.radians(0.5 / 3600.0) * (b.time_s / 75.0)[:, None]  # 0.5 deg/h ramp
    data = SpinSamples(gyro[0], b.accel_mps2[0], b.mu0_rad[0], b.mu1_rad[0], b.time_s)
    plain = solve_spin(data, latitude_deg=LAT)
    fitted = solve_spin(data, latitude_deg=LAT, drift=True)
    assert abs(wrap(plain.azimuth_deg - 10.0)) > 0.05
    assert abs(wrap(fitted.azimuth_deg - 10.0)) < 1e-8


def test_too_little_turn_is_refused_in_one_line():
    b = simulate_spin(IDEAL, Truth(latitude_deg=LAT), 6.0, 10.0, n_runs=1,
                      rng=np.random.default_rng(0), sample_rate_hz=20.0)  # fmt: skip
    with pytest.raises(GeometryError, match="at least 90 deg"):
        solve_spin(batch_samples(b, 0), latitude_deg=LAT)


# ----------------------------------------------------------------------------------------------
# The table's imperfections (the instrument's physics, without the wire)
# ----------------------------------------------------------------------------------------------


def _instrument_spin(spec, truth=None, rate=9.0, turns=1.0):
    truth = truth or Truth(azimuth_deg=33.0, pitch_deg=2.0, roll_deg=-1.0, latitude_deg=LAT)
    ins = Instrument(spec, truth, np.random.default_rng(4), sample_rate_hz=200.0)
    ins.generate(10)
    steady = ins.table.spin(ins.time_s, rate)
    ins.generate(math.ceil((steady - ins.time_s) * 200.0) + 1)
    blk = ins.generate(round(turns * 360.0 / abs(rate) * 200.0))
    data = spin_samples(np.degrees(blk.gyro_rps) * 3600.0, blk.accel_mps2, blk.table_deg,
                        blk.counter, 200.0)  # fmt: skip
    return solve_spin(data, latitude_deg=LAT), truth


def test_rate_ripple_alone_leaves_the_heading_exact():
    """The samples are tagged with the encoder's angle, so an uneven rate does not matter."""
    spec = IDEAL.with_values({"table.rate_ripple": 0.02, "table.rate_ripple_phase_deg": 30.0,
                              "table.encoder_resolution_deg": 0.0})  # fmt: skip
    sol, truth = _instrument_spin(spec)
    assert abs(wrap(sol.azimuth_deg - truth.azimuth_deg)) < 1e-5


def test_wobble_is_a_fixed_tilt_the_biases_absorb():
    spec = IDEAL.with_values({"table.wobble_urad": 200.0, "table.wobble_phase_deg": 60.0,
                              "table.encoder_resolution_deg": 0.0})  # fmt: skip
    sol, truth = _instrument_spin(spec)
    assert abs(wrap(sol.azimuth_deg - truth.azimuth_deg)) < 1e-4


def test_ripple_through_misalignment_is_a_systematic_error_and_encoder_error_averages_out():
    """A once-per-turn rate ripple leaks into the x gyro through the z-to-x misalignment: a
    sinusoid at the Earth rate's frequency, hence a heading error (the planner must know it);
    a once-per-turn encoder error over whole turns averages out to first order."""
    rippled = IDEAL.with_values({"table.rate_ripple": 0.01, "gyro.misalignment_urad": 300.0,
                                 "table.encoder_resolution_deg": 0.0})  # fmt: skip
    aligned = rippled.with_values({"table.rate_ripple": 0.0})
    sol_r, truth = _instrument_spin(rippled)
    sol_a, _ = _instrument_spin(aligned)  # the same misalignment draws (the same seed)
    # Misalignment alone moves the heading's reference (x-y non-orthogonality, notes 4); the
    # ripple adds to it through the table rate.
    assert abs(wrap(sol_r.azimuth_deg - sol_a.azimuth_deg)) > 1e-3
    enc = IDEAL.with_values({"table.encoder_error_deg": 0.01, "table.encoder_resolution_deg": 0.0})
    sol_e, _ = _instrument_spin(enc, turns=2.0)
    assert abs(wrap(sol_e.azimuth_deg - truth.azimuth_deg)) < 2e-4


# ----------------------------------------------------------------------------------------------
# find --spin
# ----------------------------------------------------------------------------------------------


def test_find_spin_on_the_embedded_simulator(capsys):
    args = ["find", "--sim", "--warmup", "0", "--sensor", "ideal", "--azimuth", "77",
            "--pitch", "2", "--roll", "-3", "--spin", "-6", "--json"]  # fmt: skip
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["solver"] == "spin" and out["device"]["protocol_version"] == "1.1"
    assert abs(out["error_deg"]) < 1e-6 and out["consistent"] is True
    assert out["spin"]["rate_dps"] == pytest.approx(-6.0)
    assert out["spin"]["duration_s"] == pytest.approx(60.0, abs=0.01)  # one whole turn


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--spin", "6", "--window", "5"], "--window: a stop-and-go plan option"),
        (["--spin-time", "60"], "--spin-time: needs --spin"),
        (["--spin", "600"], "rate limit"),
        (["--spin", "6", "--spin-time", "5"], "at least 90 deg"),
    ],
)
def test_find_spin_refuses_bad_input_in_one_line(capsys, args, message):
    assert main(["find", "--sim", "--warmup", "0", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_record_then_solve_a_spin_reproduces_find(tmp_path, capsys, suffix):
    path = str(tmp_path / f"spin{suffix}")
    common = ["--sim", "--warmup", "0", "--sensor", "nav-fog", "--seed", "4", "--spin", "-6"]
    assert main(["find", *common, "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    assert main(["record", path, *common]) == 0
    assert "wrote a spin of 12000 samples" in capsys.readouterr().out
    assert main(["solve", path, "--json"]) == 0
    solved = json.loads(capsys.readouterr().out)
    assert solved["command"] == "solve" and solved["solver"] == "spin"
    assert solved["azimuth_deg"] == pytest.approx(found["azimuth_deg"], abs=1e-9)
    # The white-noise sigma is a residual scatter: the CSV's digits move it by parts in 1e9.
    assert solved["sigma_deg"] == pytest.approx(found["sigma_deg"], rel=1e-8)
    assert main(["solve", path, "--spin-drift", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["spin"]["drift"] is True
    assert main(["solve", path, "--denoise", "hampel"]) == 2
    assert "--denoise: not available for a spin recording" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------
# The fit on its samples, and find --spin --plot
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("drift", [False, True])
def test_the_fitted_rates_are_the_samples_without_noise(drift):
    rng = np.random.default_rng(5)
    truth = Truth(azimuth_deg=211.0, pitch_deg=4.0, roll_deg=-6.0, latitude_deg=LAT)
    spec = IDEAL.with_values({"gyro.bias_dph": (3.0, -2.0, 1.0)})
    b = simulate_spin(spec, truth, -6.0, 90.0, n_runs=1, rng=rng, sample_rate_hz=20.0)
    gyro = b.gyro_rps[0].copy()
    if drift:
        gyro[:, :2] += np.radians(np.array([0.4, -0.3]) / 3600.0) * (b.time_s / 90.0)[:, None]
    data = SpinSamples(gyro, b.accel_mps2[0], b.mu0_rad[0], b.mu1_rad[0], b.time_s)
    sol = solve_spin(data, latitude_deg=LAT, drift=drift)
    model, demod, h = fitted_rates(data, sol, LAT)
    earth_h = OMEGA_IE * math.cos(math.radians(LAT))
    # The model is the samples; demodulated, every sample is the Earth rate at table angle 0.
    assert_allclose(model, gyro[:, :2], rtol=0, atol=1e-9 * earth_h)
    assert_allclose(demod, np.broadcast_to(h, demod.shape), rtol=0, atol=1e-9 * earth_h)
    # A solution one degree off does not fit: the demodulated rates turn away from its h.
    _, demod_wrong, h_wrong = fitted_rates(data, replace(sol, azimuth_deg=sol.azimuth_deg + 1), LAT)
    assert np.max(np.abs(demod_wrong - h_wrong)) > 1e-3 * earth_h


def test_find_spin_plots_the_fit_and_solve_plots_the_recording(tmp_path, capsys):
    common = ["--sim", "--warmup", "0", "--sensor", "nav-fog", "--seed", "4", "--spin", "-6"]
    png, rec = tmp_path / "spin.png", tmp_path / "spin.npz"
    assert main(["find", *common, "--plot", str(png)]) == 0
    assert "error" in capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert main(["record", str(rec), *common]) == 0
    svg = tmp_path / "solved.svg"
    assert main(["solve", str(rec), "--plot", str(svg)]) == 0
    assert svg.read_text().lstrip().startswith("<?xml") and "<svg" in svg.read_text()
    capsys.readouterr()
    # A file that cannot be written is refused before the run, in one line, exit 2.
    assert main(["find", *common, "--plot", str(tmp_path / "spin.nope")]) == 2
    err = capsys.readouterr().err
    assert ".nope is no plot format" in err and len(err.strip().splitlines()) == 1
    # --record stays refused with --spin (record --spin writes spin recordings).
    assert main(["find", *common, "--record", str(tmp_path / "x.npz")]) == 2
    assert "northfinder record --spin" in capsys.readouterr().err
