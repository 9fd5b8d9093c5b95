"""Spin plans in the accuracy study and the planner: ``study --spin``, the spin search of
``study --plan-budget`` against the stop-and-go plans of the same budget, and the prediction of a
spin term by term."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from northfinder.cli import main
from northfinder.cli.study_planner import _best_of_budget
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.accuracy import ErrorModel, budget_bound_deg, predict, spin_bound_deg
from northfinder.host.errors import GeometryError, HostConfigError
from northfinder.host.montecarlo import StudySettings, monte_carlo, study_rows
from northfinder.host.plan import SpinPlan, TableModel, plan_time_s, spin_start_deg
from northfinder.host.plan_search import search_plans, search_spin_plans
from northfinder.simwindows import SimulatedWindows, error_model

LAT = 34.0


def test_a_spin_plan_counts_both_ramps_and_refuses_too_little_turn():
    table = TableModel(max_rate_dps=6.0, max_accel_dps2=10.0)
    assert plan_time_s(SpinPlan(6.0, 60.0), table) == pytest.approx(61.2)
    assert spin_start_deg(SpinPlan(-6.0, 60.0), table) == pytest.approx(-1.8)
    with pytest.raises(GeometryError, match="at least 90 deg"):
        SpinPlan(6.0, 10.0)
    with pytest.raises(HostConfigError, match="rate limit"):
        plan_time_s(SpinPlan(10.0, 60.0), table)


def test_white_noise_alone_predicts_the_spin_bound():
    for plan in (SpinPlan(6.0, 60.0), SpinPlan(-3.0, 100.0, drift=True), SpinPlan(2.0, 70.0)):
        pred = predict(ErrorModel(0.0015), plan, LAT, tilt="level", sample_rate_hz=50.0)
        start = spin_start_deg(plan, TableModel())
        bound = spin_bound_deg(plan.spin_s, plan.rate_dps, 0.0015, LAT, sample_rate_hz=50.0,
                               start_deg=start, drift=plan.drift)  # fmt: skip
        assert pred.sigma_deg == pytest.approx(bound, rel=1e-4)


def test_a_spin_starts_no_move_transient_and_cancels_constant_biases():
    # paper-prototype's error budget is its move transient: a spin has none (and nothing of the
    # turn-on bias), so its prediction holds no "moves" part.
    model = error_model(load_spec("paper-prototype"))
    pred = predict(model, SpinPlan(6.0, 120.0), LAT, warmup_s=120.0)
    assert "moves" not in pred.parts_deg
    quiet = predict(ErrorModel(model.arw_dpsh), SpinPlan(6.0, 120.0), LAT, tilt="level")
    assert pred.parts_deg["white"] == pytest.approx(quiet.sigma_deg, rel=1e-6)


#: Table terms alone (with a gyro misalignment for the ripple to leak through) and the part of a
#: spin's prediction each feeds.
TABLE_TERMS = [
    ({"table.rate_ripple": 0.01, "gyro.misalignment_urad": 300.0}, "misalignment"),
    ({"table.encoder_error_deg": 0.01}, "drift"),
    ({"table.wobble_urad": 300.0, "table.rate_ripple": 0.01}, "drift"),
    ({"table.encoder_resolution_deg": 0.05}, "encoder"),
]


@pytest.mark.parametrize(("values", "part"), TABLE_TERMS)
def test_each_table_term_feeds_the_spin_prediction(values, part):
    base = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.001})
    plan = SpinPlan(6.0, 80.0)  # a part turn: a once-per-turn error does not average out
    pred = predict(error_model(base.with_values(values)), plan, LAT)
    assert pred.parts_deg.get(part, 0.0) > 1e-5, pred.parts_deg


@pytest.mark.parametrize(
    "values",
    [
        {"table.rate_ripple": 0.01, "table.rate_ripple_phase_deg": 30.0,
         "gyro.misalignment_urad": 300.0},
        {"table.encoder_error_deg": 0.2, "table.encoder_error_phase_deg": 20.0},
        {"table.wobble_urad": 500.0, "table.wobble_phase_deg": 40.0, "table.rate_ripple": 0.02},
        {"gyro.rate_ramp_dph_per_h": [0.3, -0.2, 0.0], "gyro.bias_instability_dph": 0.01},
    ],
)  # fmt: skip
def test_table_and_drift_terms_of_a_spin_against_the_monte_carlo(values):
    """Each term large against white noise: the prediction within 10 % of 400 runs (a part turn:
    the table's once-per-turn errors do not average out)."""
    spec = load_spec("ideal").with_values({"gyro.arw_dpsh": 0.0005, **values})
    plan = SpinPlan(6.0, 80.0)
    settings = StudySettings(latitude_deg=LAT, warmup_s=60.0, sample_rate_hz=20.0)
    errors = monte_carlo(SimulatedWindows(spec), plan, settings, 400, 3)
    row = study_rows(error_model(spec), plan, settings, errors)[0]
    assert 0.9 <= row["predicted_deg"] / row["rmse_deg"] <= 1.1, (values, row)
    assert row["rmse_deg"] >= 0.95 * row["bound_deg"]


def test_study_spin_reports_rmse_bound_and_prediction(capsys):
    args = ["study", "--sensor", "paper-rlg", "--spin", "-6", "--spin-time", "60", "--runs",
            "300", "--rate", "20", "--seed", "2", "--json"]  # fmt: skip
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    plan, row = out["plan"], out["results"][0]
    assert plan["kind"] == "spin" and plan["rate_dps"] == -6.0 and plan["turns"] == 1.0
    assert plan["plan_time_s"] == pytest.approx(60.0 + 2 * 6.0 / 60.0)  # paper-rlg: 60 deg/s^2
    assert out["solver"] == "spin" and row["runs"] == 300
    assert row["bound_deg"] == pytest.approx(spin_bound_deg(60.0, -6.0, 0.0015, LAT,
                                             sample_rate_hz=20.0, start_deg=-0.3), rel=1e-6)  # fmt: skip
    se = row["rmse_rel_se"]
    assert 1.0 - 3 * se < row["ratio"] < 1.3
    assert 0.85 < row["predicted_deg"] / row["rmse_deg"] < 1.15
    # The same seed, the same runs.
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["results"][0]["rmse_deg"] == row["rmse_deg"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--spin", "6", "--window", "5"], "--window: a stop-and-go plan option"),
        (["--spin", "6", "--plan", "paper-30deg-sweep"], "--plan: a stop-and-go plan option"),
        (["--spin", "6", "--angles", "commanded"], "--angles: a stop-and-go plan option"),
        (["--spin-drift"], "--spin-drift: needs --spin"),
        (["--spin", "60"], "rate limit"),
        (["--spin", "6", "--spin-time", "5"], "at least 90 deg"),
        (["--spin", "6", "--plan-budget", "60"], "--spin: give it without --plan-budget"),
    ],
)
def test_study_spin_refuses_bad_input_in_one_line(capsys, args, message):
    assert main(["study", "--sensor", "paper-rlg", "--runs", "10", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_plan_budget_compares_spins_with_stop_and_go_on_the_same_budget(capsys):
    rc = main(["study", "--sensor", "paper-prototype", "--plan-budget", "60", "--runs", "0",
               "--json"])  # fmt: skip
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    bound = budget_bound_deg(60.0, load_spec("paper-prototype").gyro.arw_dpsh, LAT)
    assert out["budget_bound_deg"] == pytest.approx(bound)
    spins = out["spin_plans"]
    assert spins and all(s["kind"] == "spin" and s["plan_time_s"] <= 60.0 + 1e-9 for s in spins)
    assert all(s["bound_deg"] >= bound * (1 - 1e-9) for s in spins)
    assert all(s["predicted_deg"] >= s["bound_deg"] * (1 - 1e-9) for s in spins)
    best = out["best"]
    assert best["judged_by"] == "prediction"
    assert best["spin"]["predicted_deg"] == spins[0]["predicted_deg"]
    assert best["stop_and_go"]["predicted_deg"] == out["plans"][0]["predicted_deg"]
    # The drive's heat while turning (the move transient read as heat): stop-and-go wins for
    # this gyro; without it the spin does.
    assert best["overall"] == "stop_and_go"
    assert "resolved" not in best  # judged by the prediction: no intervals
    rc = main(["study", "--sensor", "paper-prototype", "--plan-budget", "60", "--runs", "0",
               "--json", "--set", "table.spin_heat=0"])  # fmt: skip
    assert rc == 0
    assert json.loads(capsys.readouterr().out)["best"]["overall"] == "spin"


def test_spin_search_fills_the_budget_within_the_table_limit():
    model = error_model(load_spec("nav-fog"))
    for budget in (30.0, 160.0):
        cands = search_spin_plans(model, LAT, budget, warmup_s=120.0)
        assert cands
        for c in cands:
            assert abs(c.plan.rate_dps) <= model.table.max_rate_dps
            assert c.plan_time_s <= budget * (1 + 1e-9)
            assert c.plan.turns >= 0.25
        assert [c.sigma_deg for c in cands] == sorted(c.sigma_deg for c in cands)
    assert not search_spin_plans(model, LAT, 0.5)  # no quarter turn within half a second
    assert search_plans(model, LAT, 0.5) == []
    assert math.isfinite(cands[0].sigma_deg) and np.isfinite(cands[0].prediction.bound_deg)


def test_plan_budget_with_runs_verifies_the_best_of_each_kind(capsys):
    args = ["study", "--sensor", "paper-prototype", "--plan-budget", "60", "--runs", "40",
            "--rate", "20", "--seed", "4"]  # fmt: skip
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    v, vs = out["verified"], out["verified_spin"]
    assert vs["kind"] == "spin" and vs["runs"] == 40 and vs["plan_time_s"] <= 60.0 + 1e-9
    assert (vs["rate_dps"], vs["spin_s"]) == (
        out["spin_plans"][0]["rate_dps"],
        out["spin_plans"][0]["spin_s"],
    )
    best = out["best"]
    assert best["judged_by"] == "monte-carlo"
    assert best["spin"]["rmse_deg"] == vs["rmse_deg"]
    assert best["stop_and_go"]["rmse_deg"] == v["rmse_deg"]
    assert best["overall"] == ("spin" if vs["rmse_deg"] < v["rmse_deg"] else "stop_and_go")
    # Each RMSE with its 95 % interval; resolved when they are apart.
    (lo1, hi1), (lo2, hi2) = best["intervals_deg"]["stop_and_go"], best["intervals_deg"]["spin"]
    assert lo1 < v["rmse_deg"] < hi1 and lo2 < vs["rmse_deg"] < hi2
    assert best["resolved"] == (hi1 < lo2 or hi2 < lo1)
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "Monte Carlo of the first spin (40 runs" in text
    overall = "spin" if best["overall"] == "spin" else "stop-and-go"
    how = ", 95 % intervals apart" if best["resolved"] else "; not resolved"
    assert f"Best overall: {overall} (by the monte-carlo{how}" in text
    # Two close RMSEs of 40 runs each cannot be told apart.
    assert not _best_of_budget({
        "plans": [{"predicted_deg": 1.0}], "spin_plans": [{"predicted_deg": 1.0}],
        "verified": {"rmse_deg": 1.0, "runs": 40}, "verified_spin": {"rmse_deg": 1.1, "runs": 40},
    })["resolved"]  # fmt: skip
