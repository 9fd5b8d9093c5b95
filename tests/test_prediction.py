"""The planner's prediction: every error term a sensor spec can hold, through the plan's own solver,
against seeded Monte Carlo studies of the simulated instrument."""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

from northfinder.firmware_sim import error_terms
from northfinder.firmware_sim.sensors import SensorSpec, load_spec, preset_names
from northfinder.host.accuracy import (
    ErrorModel,
    _linearise,
    angle_rms,
    bound_deg,
    budget_bound_deg,
    move_heat,
    predict,
    predict_solutions,
)
from northfinder.host.montecarlo import StudySettings, monte_carlo, study_rows
from northfinder.host.plan import PAPER_SWEEP, Plan, SpinPlan
from northfinder.host.plan_search import search_plans, search_spin_plans
from northfinder.simwindows import SimulatedWindows, error_model

LAT = 34.0

# ----------------------------------------------------------------------------------------------
# Closed forms
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("positions", "tilt"),
    [((0.0, 180.0), "level"), ((0.0, 90.0), "accel"), ((0.0, 90.0, 180.0, 270.0), "accel")],
)
def test_white_noise_alone_is_the_bound(positions, tilt):
    pred = predict(ErrorModel(0.0015), Plan(positions, 10.0), LAT, tilt=tilt)
    assert_allclose(pred.sigma_deg, bound_deg(positions, 10.0, 0.0015, LAT), rtol=1e-6)
    assert_allclose(pred.bound_deg, pred.sigma_deg, rtol=1e-12)


def test_the_budget_bound_is_two_positions_half_a_turn_apart_over_the_whole_budget():
    assert_allclose(budget_bound_deg(160.0, 0.0015, LAT), bound_deg((0, 180), 80.0, 0.0015, LAT))
    assert budget_bound_deg(20.0, 0.0015, LAT) == pytest.approx(0.093, abs=1e-3)  # notes, sec. 4


def test_constant_biases_cancel_in_every_solver():
    # The gradient sums to zero over the windows of each channel: a constant bias cannot move the
    # azimuth (the solvers difference or estimate it).
    for method, pos in [("auto", (0.0, 180.0)), ("auto", (0.0, 120.0, 240.0)), ("pairwise", PAPER_SWEEP.positions_deg)]:  # fmt: skip
        lin = _linearise(pos, LAT, 2.0, -1.0, (0.0, 77.0), method, False)
        assert_allclose(lin.grad[..., :4].sum(axis=2), 0.0, atol=1e-6 * np.abs(lin.grad).max())
        assert_allclose(lin.offset, 0.0, atol=1e-9)  # noise-free means: no error


def test_indexing_error_with_commanded_angles_is_half_the_stop_error_for_two_positions():
    model = ErrorModel(
        0.0, table=dataclasses.replace(ErrorModel(0.0).table, indexing_error_deg=0.01)
    )
    assert predict(model, Plan((0, 180), 10.0), LAT, angles="commanded").sigma_deg == pytest.approx(
        0.005, rel=1e-6
    )


def test_a_fast_move_transient_is_nothing_before_its_move():
    model = ErrorModel(0.001, move_transient_dph_per_rtdeg=0.01, move_transient_tau_s=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow for the windows before a move
        pred = predict(model, Plan((0.0, 90.0, 180.0, 270.0), 60.0), LAT)
    assert pred.parts_deg["moves"] < 1e-9 < pred.sigma_deg


def test_move_heat_is_the_instrument_s():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(5, 50, 9))
    d = rng.uniform(-180, 180, 9)
    for tau in (0.0, 30.0, 100.0):
        assert_allclose(move_heat(t, d, tau), error_terms.move_heat(t, d, tau), rtol=1e-12)


def test_angle_rms_is_the_angle_of_a_noisy_vector():
    rng = np.random.default_rng(4)
    for s in (0.01, 0.2, 0.6, 1.5):
        z = rng.standard_normal((2, 200_000)) * s
        mc = math.sqrt(np.mean(np.arctan2(z[1], 1 + z[0]) ** 2))
        assert angle_rms(s) == pytest.approx(mc, rel=0.01)
    assert angle_rms(50.0) == pytest.approx(math.pi / math.sqrt(3), rel=0.01)


# ----------------------------------------------------------------------------------------------
# Every term of a spec is seen (or stated not to matter)
# ----------------------------------------------------------------------------------------------

#: Each error term of a spec alone (on a quiet base) and the part of the prediction it feeds.
TERMS: dict[str, tuple[dict[str, object], str]] = {
    "gyro.arw_dpsh": ({"gyro.arw_dpsh": 0.01}, "white"),
    "gyro.bias_instability_dph": ({"gyro.bias_instability_dph": 0.05}, "slow_noise"),
    "gyro.rrw_dphpsh": ({"gyro.rrw_dphpsh": 0.5}, "slow_noise"),
    "gyro.scale_factor_ppm": ({"gyro.scale_factor_ppm": 1000.0}, "misalignment"),
    "gyro.misalignment_urad": ({"gyro.misalignment_urad": 1000.0}, "misalignment"),
    "gyro.lsb_dph": ({"gyro.lsb_dph": 1.0}, "quantisation"),
    "gyro.temp_coeff_dph_per_c": (
        {"gyro.temp_coeff_dph_per_c": [0.05, -0.03, 0.0], "thermal.warmup_rise_c": 5.0},
        "drift",
    ),
    "gyro.warmup_bias_dph": ({"gyro.warmup_bias_dph": [0.5, -0.3, 0.0]}, "drift"),
    "gyro.rate_ramp_dph_per_h": ({"gyro.rate_ramp_dph_per_h": [0.5, -0.3, 0.0]}, "drift"),
    "gyro.move_walk_dph_per_rtdeg": ({"gyro.move_walk_dph_per_rtdeg": 0.01}, "moves"),
    "gyro.move_transient_dph_per_rtdeg": ({"gyro.move_transient_dph_per_rtdeg": 0.01}, "moves"),
    "gyro.impulse_dph": (
        {"gyro.impulse_dph": 50.0, "disturbance.impulse_rate_hz": 0.5},
        "impulses",
    ),
    "gyro.vibration_dph": (
        {"gyro.vibration_dph": 5.0, "disturbance.vibration_hz": 0.05},
        "vibration",
    ),
    "accel.vrw_ug_rthz": ({"accel.vrw_ug_rthz": 100.0}, "tilt"),
    "accel.bias_instability_ug": ({"accel.bias_instability_ug": 100.0}, "tilt"),
    "accel.random_walk_ug_rts": ({"accel.random_walk_ug_rts": 10.0}, "tilt"),
    "accel.scale_factor_ppm": ({"accel.scale_factor_ppm": 1000.0}, "misalignment"),
    "accel.misalignment_urad": ({"accel.misalignment_urad": 1000.0}, "misalignment"),
    "accel.lsb_ug": ({"accel.lsb_ug": 1000.0}, "quantisation"),
    "accel.temp_coeff_ug_per_c": (
        {"accel.temp_coeff_ug_per_c": [50.0, -30.0, 0.0], "thermal.warmup_rise_c": 5.0},
        "drift",
    ),
    "accel.warmup_bias_ug": ({"accel.warmup_bias_ug": [500.0, -300.0, 0.0]}, "drift"),
    "accel.ramp_ug_per_h": ({"accel.ramp_ug_per_h": [500.0, -300.0, 0.0]}, "drift"),
    "accel.move_walk_ug_per_rtdeg": ({"accel.move_walk_ug_per_rtdeg": 50.0}, "moves"),
    "accel.move_transient_ug_per_rtdeg": ({"accel.move_transient_ug_per_rtdeg": 50.0}, "moves"),
    "accel.impulse_ug": (
        {"accel.impulse_ug": 5000.0, "disturbance.impulse_rate_hz": 0.5},
        "impulses",
    ),
    "accel.vibration_ug": (
        {"accel.vibration_ug": 500.0, "disturbance.vibration_hz": 0.05},
        "vibration",
    ),
    "thermal.ramp_c_per_h": (
        {"thermal.ramp_c_per_h": 3.0, "gyro.temp_coeff_dph_per_c": [0.05, -0.03, 0.0]},
        "drift",
    ),
    "table.encoder_resolution_deg": ({"table.encoder_resolution_deg": 0.01}, "encoder"),
    "table.encoder_error_deg": (
        # Four cycles a turn: the same misreading at each of four positions 90 deg apart.
        {
            "table.encoder_error_deg": 0.05,
            "table.encoder_error_harmonic": 4.0,
            "table.encoder_error_phase_deg": 30.0,
        },
        "drift",
    ),
}
#: Fields that are no error term of the x/y solution, or only scale or time another one.
NOT_TERMS = {
    # The same in every window: differenced or estimated away by every solver.
    "gyro.bias_dph", "gyro.turn_on_bias_dph", "accel.bias_ug", "accel.turn_on_bias_ug",
    # Limits and time constants of terms above, and the instrument's own timing.
    "gyro.range_dps", "accel.range_g", "gyro.warmup_tau_s", "accel.warmup_tau_s",
    "gyro.move_transient_tau_s", "accel.move_transient_tau_s", "thermal.ambient_c",
    "thermal.warmup_rise_c", "thermal.warmup_tau_s", "disturbance.impulse_rate_hz",
    "disturbance.impulse_duration_s", "disturbance.vibration_hz", "table.max_rate_dps",
    "table.max_accel_dps2", "table.settle_s", "table.heat_tau_s",
    # Seen with commanded angles only (test_indexing_error_...).
    "table.indexing_error_deg",
    # The ring-down after a stop: damped to 0.03 % of its amplitude by the end of settling.
    "table.overshoot_deg", "table.overshoot_hz",
    # A spinning table's (docs/spin.md): the rate ripple and the drive's heat act only while
    # spinning; the wobble is a fixed tilt in the sensor frame (constant offsets, estimated away).
    # (A spin's prediction sees them: tests/test_spin_study.py.)
    "table.rate_ripple", "table.rate_ripple_phase_deg", "table.wobble_urad",
    "table.wobble_phase_deg", "table.spin_heat",
    # Shape of the periodic encoder error (a term above).
    "table.encoder_error_harmonic", "table.encoder_error_phase_deg",
}  # fmt: skip


def _spec_fields() -> set[str]:
    spec = SensorSpec()
    return {
        f"{section}.{f.name}"
        for section in ("gyro", "accel", "thermal", "disturbance", "table")
        for f in dataclasses.fields(getattr(spec, section))
    }


def test_every_field_of_a_spec_is_a_term_of_the_prediction_or_stated_not_to_be():
    assert _spec_fields() == set(TERMS) | NOT_TERMS


@pytest.mark.parametrize("name", sorted(TERMS))
def test_each_term_feeds_its_part(name):
    values, part = TERMS[name]
    base = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.001})
    plan = Plan((0.0, 90.0, 180.0, 270.0), 10.0)
    quiet = predict(error_model(base), plan, LAT, warmup_s=60.0)
    pred = predict(error_model(base.with_values(values)), plan, LAT, warmup_s=60.0, pitch_deg=3.0)
    assert pred.parts_deg.get(part, 0.0) > 1e-6, pred.parts_deg
    assert pred.sigma_deg > quiet.sigma_deg


# ----------------------------------------------------------------------------------------------
# Against the simulated instrument
# ----------------------------------------------------------------------------------------------

PRESETS = [p for p in preset_names() if p != "ideal"]
#: Stop-and-go plans of every kind: two positions, four, a symmetric order against drift, the
#: paper's sweep solved at once and (below) pair by pair.
PLANS = [
    Plan((0.0, 180.0), 10.0),
    Plan((0.0, 90.0, 180.0, 270.0), 30.0),
    Plan((0.0, 180.0, 180.0, 0.0), 40.0),
    Plan(PAPER_SWEEP.positions_deg, 10.0),
]
RUNS = 400
"""Runs per plan: the Monte Carlo RMSE is then within about 3.5 % (1 sigma) of its limit, so a
prediction off by the 15 % the test allows stands out by four sigma."""


def _check(spec, plan, settings, seed):
    errors = monte_carlo(SimulatedWindows(spec), plan, settings, RUNS, seed)
    rows = study_rows(error_model(spec), plan, settings, errors)
    for row in rows:
        ratio = row["predicted_deg"] / row["rmse_deg"]
        assert 0.85 <= ratio <= 1.15, (spec.name, plan.label(), row.get("mu_deg"), ratio)
    return rows


def test_the_periodic_encoder_error_of_a_stop_and_go_plan_against_the_monte_carlo():
    # Two positions: the azimuth is off by the mean of the two misreadings (their difference
    # moves mu, their mean the reference of the first window), so a once-per-turn error cancels
    # at 0 and 180 deg and not at 0 and 90.
    spec = load_spec("ideal").with_values(
        {"gyro.arw_dpsh": 0.0005, "table.encoder_error_deg": 0.05,
         "table.encoder_error_phase_deg": 30.0}
    )  # fmt: skip
    model = error_model(spec)
    assert predict(model, Plan((0.0, 180.0), 20.0), LAT).parts_deg["drift"] < 1e-9
    plan = Plan((0.0, 90.0), 20.0)
    expected = 0.05 * (math.sin(math.radians(30.0)) + math.sin(math.radians(120.0))) / 2.0
    assert predict(model, plan, LAT).parts_deg["drift"] == pytest.approx(expected, rel=1e-3)
    settings = StudySettings(latitude_deg=LAT, sample_rate_hz=20.0)
    errors = monte_carlo(SimulatedWindows(spec), plan, settings, 400, 5)
    row = study_rows(model, plan, settings, errors)[0]
    assert abs(row["bias_deg"] - expected) < 3 * row["std_deg"] / math.sqrt(400)
    assert 0.9 <= row["predicted_deg"] / row["rmse_deg"] <= 1.1


def test_ideal_sensors_predict_nothing():
    pred = predict(error_model(load_spec("ideal")), PLANS[1], LAT, warmup_s=120.0)
    assert pred.sigma_deg < 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_prediction_within_15_percent_of_the_monte_carlo(preset):
    """400 runs a plan (the RMSE within about 3.5 %, 1 sigma), at 50 Hz as the spin test: the
    window means, and so the prediction, depend on the rate only through the quantisation (a
    carried count per window: larger at 50 Hz, so better seen) and the window's rounding to
    whole samples; the paper's sweep below runs at the instrument's 200 Hz for every preset."""
    spec = load_spec(preset)
    settings = StudySettings(latitude_deg=LAT, warmup_s=120.0, sample_rate_hz=50.0)
    for k, plan in enumerate(PLANS):
        _check(spec, plan, settings, seed=k)
    # The planner's own choice for a budget.
    best = search_plans(error_model(spec), LAT, 160.0, warmup_s=120.0, sample_rate_hz=50.0)[0]
    _check(spec, best.plan, settings, seed=11)


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_paper_sweep_pair_by_pair_within_15_percent(preset):
    # The paper's procedure (mu 30 .. 210 deg against the first position): every pair is
    # predicted on the sweep's own timeline (its later pairs follow more moves).
    rows = _check(load_spec(preset), PAPER_SWEEP, StudySettings(latitude_deg=LAT), seed=21)
    assert [r["mu_deg"] for r in rows] == [30, 60, 90, 120, 150, 180, 210]


#: Spin plans of every kind: one whole turn, a part turn with a drift fitted, several turns the
#: other way (the planner's best spin of a budget is added per preset).
SPIN_PLANS = [SpinPlan(6.0, 60.0), SpinPlan(4.5, 100.0, drift=True), SpinPlan(-6.0, 150.0)]


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_spin_prediction_within_15_percent_of_the_monte_carlo(preset):
    """The same 400 runs a plan as the stop-and-go test (the RMSE within about 3.5 %, 1 sigma),
    at 50 Hz (the prediction at the study's own rate), 120 s after power-on."""
    spec = load_spec(preset)
    settings = StudySettings(latitude_deg=LAT, warmup_s=120.0, sample_rate_hz=50.0)
    best = search_spin_plans(error_model(spec), LAT, 160.0, warmup_s=120.0, sample_rate_hz=50.0)
    for k, plan in enumerate([*SPIN_PLANS, best[0].plan]):
        rows = _check(spec, plan, settings, seed=31 + k)
        assert rows[0]["rmse_deg"] > 0.9 * rows[0]["bound_deg"]  # nothing beats the bound


def test_pairwise_predictions_follow_the_sweep_s_timeline():
    # The transient of the moves before a late pair makes it worse than the same pair alone.
    model = error_model(load_spec("paper-prototype"))
    sweep = predict_solutions(model, PAPER_SWEEP, LAT, warmup_s=120.0)
    alone = predict(model, Plan((0.0, 180.0), 10.0, method="pairwise"), LAT, warmup_s=120.0)
    assert len(sweep) == 7
    assert sweep[5].sigma_deg > 2 * alone.sigma_deg


def test_plan_search_states_the_bound_of_its_budget(capsys):
    import json

    from northfinder.cli import main

    rc = main(["study", "--sensor", "paper-rlg", "--plan-budget", "160", "--runs", "0", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["budget_bound_deg"] == pytest.approx(budget_bound_deg(160.0, 0.0015, LAT))
    assert all(p["bound_deg"] > out["budget_bound_deg"] for p in out["plans"])
