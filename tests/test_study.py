"""Accuracy studies: batch generator against the instrument, vectorised solvers, bound, planner,
the Monte Carlo engine and the CLI."""

from __future__ import annotations

import json
import math
import pickle

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from northfinder.cli import main
from northfinder.driver.protocol.motion import move_time_s
from northfinder.driver.protocol.units import DPSH as ARW
from northfinder.driver.protocol.units import OMEGA_IE, UG
from northfinder.firmware_sim.batch import plan_timeline, simulate_windows
from northfinder.firmware_sim.imu import Instrument, Truth
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import ErrorModel, _window_mean_cov, bound_deg, predict
from northfinder.host.batch_solve import summarize
from northfinder.host.errors import GeometryError, HostConfigError, InputError, TiltError
from northfinder.host.heading import (
    solve_multi_position,
    solve_two_position,
    two_position_bound_deg,
)
from northfinder.host.kernels import solve_least_squares_batch, solve_two_position_batch
from northfinder.host.montecarlo import StudySettings, monte_carlo, study_rows
from northfinder.host.plan import Plan, TableModel, plan_time_s, window_starts_s
from northfinder.host.plan_search import search_plans, shortest_plan
from northfinder.simwindows import SimulatedWindows, error_model

#: Every random term off, deterministic terms on: closed-form means must agree exactly.
DETERMINISTIC = {
    "gyro.arw_dpsh": 0.0,
    "gyro.bias_instability_dph": 0.0,
    "gyro.turn_on_bias_dph": 0.0,
    "gyro.scale_factor_ppm": 0.0,
    "gyro.misalignment_urad": 0.0,
    "gyro.temp_coeff_dph_per_c": [0.02, -0.01, 0.03],
    "accel.vrw_ug_rthz": 0.0,
    "accel.bias_instability_ug": 0.0,
    "accel.turn_on_bias_ug": 0.0,
    "accel.scale_factor_ppm": 0.0,
    "accel.misalignment_urad": 0.0,
    "table.indexing_error_deg": 0.0,
    "thermal.warmup_rise_c": 5.0,
    "thermal.ramp_c_per_h": 3.0,
}


def instrument_windows(spec, truth, positions, window_s, settle_s, warmup_s, seed, fs=200.0):
    """The same plan stepped through one Instrument: (P, n, 6) samples and mean encoder angles."""
    starts, n, _, _ = plan_timeline(
        spec, positions, window_s, settle_s, warmup_s=warmup_s, sample_rate_hz=fs
    )
    ins = Instrument(
        spec, truth, np.random.default_rng(seed), sample_rate_hz=fs, table_angle_deg=positions[0]
    )
    out, enc = [], []
    for i, p in enumerate(positions):
        if i and p != positions[i - 1]:
            ins.table.move_to(ins.time_s, p)
        ins.generate(int(starts[i] - ins.samples_emitted))
        block = ins.generate(n)
        out.append(np.hstack([block.gyro_rps, block.accel_mps2]))
        enc.append(block.table_deg.mean())
    return np.array(out), np.array(enc)


# ----------------------------------------------------------------------------------------------
# Batch generator against the instrument
# ----------------------------------------------------------------------------------------------


def test_batch_matches_instrument_closed_form():
    # Without the table top's wobble: after a move the two generators' samples through it differ
    # by parts in 1e5 of the Earth rate (before any move they agree to the last bit), an open
    # point; the wobble's effect on the window means is checked by the test below.
    spec = load_spec("paper-rlg").with_values({**DETERMINISTIC, "table.wobble_urad": 0.0})
    truth = Truth(37.0, 34.0, 1.0, -2.0)
    positions = [0.0, 210.0, 90.0, 90.0, 300.0]
    ref, enc = instrument_windows(spec, truth, positions, 10.0, 3.0, 120.0, seed=1)
    batch = simulate_windows(
        spec, truth, positions, 10.0, 3.0, n_runs=2, rng=np.random.default_rng(2), warmup_s=120.0
    )
    got = np.concatenate([batch.gyro_rps, batch.accel_mps2], axis=-1)
    assert got.shape == (2, 5, 2000, 6)
    for r in range(2):
        # Sample by sample, including the post-stop ring-down on gyro z and the temperature drift.
        assert_allclose(got[r][..., :3], ref[..., :3], rtol=0, atol=1e-12)
        assert_allclose(got[r][..., 3:], ref[..., 3:], rtol=0, atol=1e-10)
    res = spec.table.encoder_resolution_deg
    assert_allclose(batch.table_deg[0], enc, atol=1.5 * res)
    assert_allclose(batch.commanded_deg, [0, 210, 90, 90, 300])


def test_batch_plan_time_matches_host_plan_time():
    spec = load_spec("paper-rlg")
    batch = simulate_windows(
        spec, Truth(), [0, 30, 60, 90], 10.0, n_runs=1, rng=np.random.default_rng(0)
    )
    plan = Plan((0, 30, 60, 90), 10.0)
    table = error_model(spec).table
    assert abs(batch.plan_time_s - plan_time_s(plan, table)) <= 3 / 200.0
    assert_allclose(
        batch.window_start_s - batch.window_start_s[0], window_starts_s(plan, table), atol=0.01
    )


def test_batch_white_noise_level():
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0015, "accel.vrw_ug_rthz": 10.0})
    batch = simulate_windows(spec, Truth(), [0, 180], 10.0, n_runs=50, rng=np.random.default_rng(3))
    g = batch.gyro_rps - batch.gyro_rps.mean(axis=2, keepdims=True)
    assert_allclose(g.std(axis=(0, 1, 2)), 0.0015 * ARW * math.sqrt(200.0), rtol=0.01)
    a = batch.accel_mps2 - batch.accel_mps2.mean(axis=2, keepdims=True)
    assert_allclose(a.std(axis=(0, 1, 2)), 10.0 * UG * math.sqrt(200.0), rtol=0.01)


def test_batch_slow_noise_matches_the_predicted_covariance():
    """Flicker and rate random walk: the variance of window-mean differences over a plan."""
    spec = load_spec("ideal").with_values(
        {"gyro.bias_instability_dph": 0.05, "gyro.rrw_dphpsh": 0.05}
    )
    batch = simulate_windows(
        spec,
        Truth(),
        [0, 0, 180, 90],
        20.0,
        5.0,
        n_runs=1500,
        rng=np.random.default_rng(4),
        sample_rate_hz=20.0,
    )
    m = batch.gyro_rps[..., :2].mean(axis=2)  # (R, P, 2); the Earth rate is the same every run
    d = (m[:, 1:] - m[:, :1]).reshape(-1, 2 * 3)
    model = ErrorModel(0.0, 0.05, 0.05)
    cov = _window_mean_cov(batch.window_start_s, 20.0, model)
    expected = np.diag(cov)[1:] + cov[0, 0] - 2 * cov[0, 1:]
    got = d.var(axis=0).reshape(3, 2).mean(axis=1)
    assert_allclose(got, expected, rtol=0.12)


@pytest.mark.slow
def test_batch_noise_statistics_match_the_instrument():
    spec = load_spec("fog-0.08").with_values(
        {
            "disturbance.impulse_rate_hz": 0.5,
            "gyro.impulse_dph": 50.0,
            "disturbance.vibration_hz": 35.0,
            "gyro.vibration_dph": 20.0,
        }
    )
    truth = Truth(37.0, 34.0, 1.0, -2.0)
    pos, runs = [0.0, 180.0, 90.0], 200
    ref = np.array([instrument_windows(spec, truth, pos, 10, None, 60, s)[0] for s in range(runs)])
    b = simulate_windows(
        spec, truth, pos, 10, n_runs=runs, rng=np.random.default_rng(5), warmup_s=60
    )
    got = np.concatenate([b.gyro_rps, b.accel_mps2], -1)
    ma, mb = ref.mean(2), got.mean(2)
    for k in (1, 2):
        ratio = (ma[:, k] - ma[:, 0]).std(0) / (mb[:, k] - mb[:, 0]).std(0)
        assert np.all(np.abs(ratio - 1) < 0.25), ratio
    assert_allclose(ref.std(2).mean((0, 1)), got.std(2).mean((0, 1)), rtol=0.03)
    # Means agree within their spread (turn-on and scale-factor draws differ run to run).
    z = (ma - mb).mean(0) / (ma.std(0) / math.sqrt(runs))
    assert np.all(np.abs(z) < 5)


# ----------------------------------------------------------------------------------------------
# Vectorised solvers against northfinder.host.heading
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tilted_batch():
    spec = load_spec("paper-rlg")
    rng = np.random.default_rng(6)
    truths = [Truth(float(a), 34.0, 2.0, -3.0) for a in rng.uniform(0, 360, 6)]
    return simulate_windows(spec, truths, [0, 60, 150, 270], 5.0, n_runs=6, rng=rng)


def test_two_position_batch_matches_scalar_solver(tilted_batch):
    g = tilted_batch.gyro_rps.mean(axis=2)
    a = tilted_batch.accel_mps2.mean(axis=2)
    mu = tilted_batch.table_deg[:, 2] - tilted_batch.table_deg[:, 0]
    got = solve_two_position_batch(
        g[:, 0], g[:, 2], mu, latitude_deg=34.0, accel0=a[:, 0], accel1=a[:, 2]
    )
    level = solve_two_position_batch(g[:, 0], g[:, 2], mu, latitude_deg=34.0)
    for r in range(6):
        ref = solve_two_position(
            g[r, 0], g[r, 2], mu[r], accel0=a[r, 0], accel1=a[r, 2], latitude_deg=34.0
        )
        assert_allclose(got[r], ref.azimuth_deg, atol=1e-9)
        assert_allclose(
            level[r], solve_two_position(g[r, 0], g[r, 2], mu[r]).azimuth_deg, atol=1e-9
        )


def test_least_squares_batch_matches_scalar_solver(tilted_batch):
    g = tilted_batch.gyro_rps.mean(axis=2)
    a = tilted_batch.accel_mps2.mean(axis=2)
    got = solve_least_squares_batch(g, tilted_batch.table_deg, latitude_deg=34.0, accel_means=a)
    for r in range(6):
        ref = solve_multi_position(
            g[r], tilted_batch.table_deg[r], latitude_deg=34.0, accel_means=a[r]
        )
        assert_allclose(got[r], ref.azimuth_deg, atol=1e-8)


# ----------------------------------------------------------------------------------------------
# Bound and Monte Carlo
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mu", [30.0, 90.0, 180.0])
def test_bound_is_the_notes_formula(mu):
    assert_allclose(
        bound_deg([0.0, mu], 10.0, 0.0015, 34.0), two_position_bound_deg(0.0015, 20.0, mu, 34.0)
    )


def test_bound_of_many_positions_is_the_least_squares_covariance():
    pos = [0.0, 45.0, 90.0, 200.0]
    s = 0.0015 * ARW / math.sqrt(10.0)
    on = OMEGA_IE * math.cos(math.radians(34.0))
    g = np.array([[on * math.cos(math.radians(m)), -on * math.sin(math.radians(m))] for m in pos])
    ref = solve_multi_position(g, pos, latitude_deg=34.0, gyro_noise=s).sigma_deg
    assert ref is not None
    assert_allclose(bound_deg(pos, 10.0, 0.0015, 34.0), ref, rtol=1e-9)
    # Notes, section 4: at 34 deg N, ARW 0.0015, 2 x 10 s at 180 deg -> 0.093 deg.
    assert bound_deg([0, 180], 10.0, 0.0015, 34.0) == pytest.approx(0.093, abs=0.001)


@pytest.mark.parametrize(("positions", "tilt"), [((0.0, 180.0), "accel"), ((0.0, 60.0), "level")])
def test_white_noise_rmse_meets_the_bound(positions, tilt):
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0015})
    plan = Plan(positions, 10.0)
    errors = monte_carlo(
        SimulatedWindows(spec), plan, StudySettings(tilt=tilt, warmup_s=0.0), 600, seed=7
    )
    s = summarize(errors)
    ratio = s.rmse_deg / bound_deg(positions, 10.0, 0.0015, 34.0)
    assert 0.9 < ratio < 1.1
    assert abs(s.bias_deg) < 4 * s.std_deg / math.sqrt(s.runs)


def test_least_squares_study_meets_the_bound():
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0015})
    plan = Plan((0.0, 90.0, 180.0, 270.0), 5.0)
    errors = monte_carlo(SimulatedWindows(spec), plan, StudySettings(warmup_s=0.0), 400, seed=8)
    ratio = summarize(errors).rmse_deg / bound_deg(plan.positions_deg, 5.0, 0.0015, 34.0)
    assert 0.88 < ratio < 1.12


def test_pairwise_study_gives_one_error_per_pair():
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0015})
    plan = Plan((0.0, 90.0, 180.0), 5.0, method="pairwise")
    errors = monte_carlo(SimulatedWindows(spec), plan, StudySettings(), 50, seed=9)
    assert errors.shape == (50, 2)


def test_indexing_error_with_commanded_angles_costs_half_the_stop_error():
    model = ErrorModel(0.0015, table=TableModel(6.0, 60.0, 10.0, 0.01))
    pred = predict(model, Plan((0, 180), 10.0), 34.0, angles="commanded")
    assert pred.parts_deg["indexing"] == pytest.approx(0.005)
    assert "indexing" not in predict(model, Plan((0, 180), 10.0), 34.0).parts_deg


@pytest.mark.slow
def test_paper_rlg_study_follows_the_prediction():
    spec = load_spec("paper-rlg")
    plan = Plan((0.0, 180.0), 10.0)
    settings = StudySettings(angles="commanded")
    errors = monte_carlo(SimulatedWindows(spec), plan, settings, 2000, seed=10)
    pred = predict(error_model(spec), plan, 34.0, warmup_s=120.0, angles="commanded")
    assert summarize(errors).rmse_deg == pytest.approx(pred.sigma_deg, rel=0.06)


# ----------------------------------------------------------------------------------------------
# The engine: results for a seed, excessive tilt, picklable pieces
# ----------------------------------------------------------------------------------------------


def _tilted_runs(pitches):
    """Window means of noise-free runs, one per pitch, at table angles 0, 90, 180, 270 deg."""
    rng = np.random.default_rng(12)
    truths = [
        Truth(float(a), 34.0, p, 1.0) for a, p in zip(rng.uniform(0, 360, 5), pitches, strict=True)
    ]
    batch = simulate_windows(
        load_spec("ideal"), truths, [0, 90, 180, 270], 1.0, n_runs=len(truths), rng=rng
    )
    return batch, batch.gyro_rps.mean(axis=2), batch.accel_mps2.mean(axis=2)


def test_excessive_tilt_is_nan_in_the_batch_and_an_error_in_the_scalar_solvers():
    pitches = [2.0, 16.0, -3.0, 0.0, -20.0]
    beyond = np.array([False, True, False, False, True])
    batch, g, a = _tilted_runs(pitches)
    mu = batch.table_deg[:, 2] - batch.table_deg[:, 0]
    two = solve_two_position_batch(
        g[:, 0], g[:, 2], mu, latitude_deg=34.0, accel0=a[:, 0], accel1=a[:, 2]
    )
    many = solve_least_squares_batch(g, batch.table_deg, latitude_deg=34.0, accel_means=a)
    assert_array_equal(np.isnan(two), beyond)
    assert_array_equal(np.isnan(many), beyond)
    truth = batch.azimuth_deg[~beyond]
    assert np.abs(azimuth_error(many[~beyond], truth)).max() < 1e-6
    assert np.abs(azimuth_error(two[~beyond], truth - batch.table_deg[~beyond, 0])).max() < 1e-6
    for r in np.flatnonzero(beyond):
        with pytest.raises(TiltError, match=r"pitch .* exceeds the limit"):
            solve_two_position(
                g[r, 0], g[r, 2], mu[r], accel0=a[r, 0], accel1=a[r, 2], latitude_deg=34.0
            )
        with pytest.raises(TiltError, match=r"pitch .* exceeds the limit"):
            solve_multi_position(g[r], batch.table_deg[r], latitude_deg=34.0, accel_means=a[r])
    # Accelerometer means that contradict gravity: no tilt at all.
    wrong = a.copy()
    wrong[0, :, 0] = 30.0 * np.cos(np.radians(batch.table_deg[0]))
    wrong[0, :, 1] = -30.0 * np.sin(np.radians(batch.table_deg[0]))
    assert np.isnan(
        solve_least_squares_batch(g, batch.table_deg, latitude_deg=34.0, accel_means=wrong)[0]
    )
    with pytest.raises(TiltError, match="exceeds gravity"):
        solve_multi_position(g[0], batch.table_deg[0], latitude_deg=34.0, accel_means=wrong[0])
    # Assumed level (no accelerometers), nothing is refused.
    assert not np.isnan(solve_two_position_batch(g[:, 0], g[:, 2], mu, latitude_deg=34.0)).any()


def azimuth_error(a, b):
    return (np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0


def test_study_counts_the_runs_beyond_the_tilt_limit_and_summarises_the_others():
    # At a true pitch of exactly the limit, accelerometer noise puts about half the estimates
    # beyond it.
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0015, "accel.vrw_ug_rthz": 50.0})
    plan = Plan((0.0, 180.0), 10.0)
    settings = StudySettings(pitch_deg=15.0, warmup_s=0.0)
    errors = monte_carlo(SimulatedWindows(spec), plan, settings, 200, seed=13)
    row = study_rows(error_model(spec), plan, settings, errors)[0]
    rejected = int(np.isnan(errors).sum())
    assert 40 < rejected < 160
    assert row["rejected"] == rejected and row["runs"] == 200 - rejected
    assert np.all(np.abs(errors[~np.isnan(errors)]) < 1.0)
    assert math.isfinite(row["rmse_deg"]) and row["rmse_deg"] > 0.0
    # Beyond the limit for certain: no statistics, one clear error.
    far = StudySettings(pitch_deg=20.0, warmup_s=0.0)
    with pytest.raises(InputError, match=r"no solution .*tilt beyond"):
        summarize(monte_carlo(SimulatedWindows(spec), plan, far, 20, seed=13))


def test_generator_and_error_model_pickle_and_give_the_same_study():
    spec = load_spec("fog-0.08")
    generator = pickle.loads(pickle.dumps(SimulatedWindows(spec)))
    model = pickle.loads(pickle.dumps(error_model(spec)))
    assert model.drift_rps is not None
    plan = Plan((0.0, 90.0, 180.0), 5.0)
    settings = pickle.loads(pickle.dumps(StudySettings(denoise_accel=True)))
    assert_array_equal(
        monte_carlo(generator, plan, settings, 4, 11),
        monte_carlo(SimulatedWindows(spec), plan, settings, 4, 11),
    )
    assert predict(model, plan, 34.0, warmup_s=120.0) == predict(
        error_model(spec), plan, 34.0, warmup_s=120.0
    )


# ----------------------------------------------------------------------------------------------
# Plans
# ----------------------------------------------------------------------------------------------


def test_settle_is_the_time_from_the_end_of_a_move_to_the_next_window():
    table = TableModel(max_rate_dps=10.0, max_accel_dps2=20.0, settle_s=2.0)
    move = move_time_s(90.0, 10.0, 20.0)
    tables_own = Plan((0.0, 90.0, 90.0), 10.0)
    longer = Plan((0.0, 90.0, 90.0), 10.0, settle_s=5.0)
    assert_allclose(window_starts_s(tables_own, table), [0.0, 10.0 + move + 2.0, 20.0 + move + 2.0])
    assert_allclose(window_starts_s(longer, table), [0.0, 10.0 + move + 5.0, 20.0 + move + 5.0])
    assert plan_time_s(longer, table) == pytest.approx(30.0 + move + 5.0)


def test_plan_validation():
    with pytest.raises(HostConfigError, match="unknown method 'magic'"):
        Plan(denoise="magic")
    with pytest.raises(HostConfigError, match="unknown value 'best'"):
        Plan(method="best")
    with pytest.raises(HostConfigError, match="needs exactly two positions"):
        Plan((0.0, 90.0, 180.0), method="two-position")
    with pytest.raises(HostConfigError, match="pairs"):
        Plan(denoise="moving-average", denoise_options=("window",))  # type: ignore[arg-type]
    assert Plan(denoise_options=[["window", 5]]).denoise_options == (("window", 5),)  # type: ignore[arg-type]
    assert Plan((0.0, 120.0, 240.0)).solver == "least-squares"
    assert Plan().solver == "two-position"


# ----------------------------------------------------------------------------------------------
# Planner
# ----------------------------------------------------------------------------------------------


def test_planner_prefers_180_at_equal_dwell():
    model = error_model(load_spec("paper-rlg"))
    sigmas = {
        mu: predict(model, Plan((0.0, mu), 10.0), 34.0).sigma_deg for mu in (30, 60, 90, 120, 180)
    }
    assert min(sigmas, key=lambda mu: sigmas[mu]) == 180
    two = [(0.0, float(mu)) for mu in (30, 60, 90, 120, 150, 180)]
    best = search_plans(model, 34.0, 120.0, geometries=two)[0]
    assert best.plan.positions_deg == (0.0, 180.0)


@pytest.mark.parametrize("budget", [30.0, 120.0, 600.0])
def test_planner_respects_the_budget(budget):
    model = error_model(load_spec("nav-fog"))
    cands = search_plans(model, 34.0, budget)
    assert cands
    assert all(c.plan_time_s <= budget + 1e-6 for c in cands)
    assert [c.sigma_deg for c in cands] == sorted(c.sigma_deg for c in cands)


def test_planner_stops_lengthening_windows_beyond_the_allan_minimum():
    # Rate random walk K against ARW N: the Allan minimum of one window is near 3 N^2 / K^2.
    model = ErrorModel(arw_dpsh=0.01, rrw_dphpsh=0.5)
    best = search_plans(model, 34.0, 3600.0, geometries=[(0.0, 180.0)])[0]
    assert best.allan_limited
    assert best.plan_time_s < 1800.0
    assert search_plans(ErrorModel(arw_dpsh=0.01), 34.0, 3600.0)[0].allan_limited is False


def test_shortest_plan_meets_the_target_and_is_short():
    model = error_model(load_spec("paper-rlg"))
    cand = shortest_plan(model, 34.0, 0.05)
    assert cand is not None and cand.sigma_deg <= 0.05
    shorter = Plan(cand.plan.positions_deg, cand.plan.window_s * 0.95, cand.plan.settle_s)
    assert predict(model, shorter, 34.0).sigma_deg > 0.05
    assert shortest_plan(error_model(load_spec("mems")), 34.0, 0.05) is None


def test_plan_refuses_bad_geometry():
    with pytest.raises(GeometryError, match="at least 2 positions"):
        Plan((0.0,), 10.0)
    with pytest.raises(GeometryError, match="apart"):
        Plan((0.0, 2.0), 10.0)
    with pytest.raises(HostConfigError):
        search_plans(ErrorModel(0.001), 34.0, -1.0)


# ----------------------------------------------------------------------------------------------
# CLI
# ----------------------------------------------------------------------------------------------


def test_cli_json(capsys):
    rc = main(
        ["study", "--sensor", "ideal", "--set", "gyro.arw_dpsh=0.0015", "--runs", "200",
         "--positions", "0,90", "--window", "5", "--json"]
    )  # fmt: skip
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    row = out["results"][0]
    assert row["runs"] == 200
    assert row["bound_deg"] == pytest.approx(bound_deg([0, 90], 5.0, 0.0015, 34.0))
    assert 0.8 < row["ratio"] < 1.2
    assert out["plan"]["plan_time_s"] > 10.0


def test_cli_planner_json(capsys):
    rc = main(["study", "--sensor", "nav-fog", "--plan-budget", "120", "--runs", "0", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["plans"] and all(p["plan_time_s"] <= 120.0 + 1e-6 for p in out["plans"])


def test_cli_errors(capsys):
    # every one a wrong request: exit status 2 (northfinder.cli.exits)
    assert main(["study", "--positions", "0", "--runs", "10"]) == 2
    assert "at least 2 positions" in capsys.readouterr().err
    assert main(["study", "--runs", "1"]) == 2
    assert "at least 2 runs" in capsys.readouterr().err
    assert main(["study", "--sensor", "no-such-sensor"]) == 2
    assert "presets are" in capsys.readouterr().err
    assert main(["study", "--denoise", "magic"]) == 2
    assert "invalid choice" in capsys.readouterr().err
    assert main(["study", "--window", "-3"]) == 2


def test_cli_plot_without_matplotlib_says_what_to_install(capsys, tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name.startswith("matplotlib"):
            raise ImportError("no matplotlib")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    rc = main(
        ["study", "--sensor", "ideal", "--set", "gyro.arw_dpsh=0.0015", "--runs", "20",
         "--window", "2", "--sweep", "1,2", "--plot", str(tmp_path / "e.png")]
    )  # fmt: skip
    assert rc == 2  # refused before any simulation: the request cannot be met
    assert "northfinder[plot]" in capsys.readouterr().err
