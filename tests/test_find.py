"""North finding through the whole stack: simulator, wire, driver, procedure, solver, CLI."""

from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from northfinder.cli import main
from northfinder.cli.progress import PlanProgress
from northfinder.driver.protocol.constants import Validity
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import FindProgress, Plan, QualityError, summarise_window
from northfinder.host.recording import Recording

BIASED_IDEAL = """
name = "ideal-biased"
description = "No noise, large constant biases, exact encoder."
[gyro]
bias_dph = [25.0, -40.0, 10.0]
[accel]
bias_ug = [3000.0, -2000.0, 500.0]
[table]
encoder_resolution_deg = 0.0
settle_s = 1.0
max_rate_dps = 30.0
"""


def find_json(capsys, *args: str) -> dict:
    assert main(["find", "--sim", "--json", "--warmup", "0", *args]) == 0
    return json.loads(capsys.readouterr().out)


def wrap(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_ideal_sensors_with_biases_and_tilt_recover_the_truth_to_1e_4_deg(tmp_path, capsys, seed):
    """The wire carries gyro counts of 1e-4 deg/h with the remainder carried, accelerometer counts
    of 1 ug and angles of 1e-6 deg: a 10 s window mean is exact to 5e-8 deg/h, so what limits the
    result is the angle count (about 1e-6 deg in mu, half of it in azimuth)."""
    spec = tmp_path / "biased.toml"
    spec.write_text(BIASED_IDEAL)
    rng = np.random.default_rng(seed)
    az, lat = rng.uniform(0, 360), rng.uniform(-70, 70)
    pitch, roll = rng.uniform(-5, 5, 2)
    mu0, mu = rng.uniform(0, 360), rng.uniform(20, 340)
    out = find_json(
        capsys, "--sensor", str(spec), "--azimuth", f"{az}", "--latitude", f"{lat}", "--pitch", f"{pitch}",
        "--roll", f"{roll}", "--positions", f"{mu0},{mu0 + mu}", "--seed", str(seed),
    )  # fmt: skip
    assert abs(out["error_deg"]) < 1e-4
    assert out["pitch_deg"] == pytest.approx(pitch, abs=1e-4)
    assert out["roll_deg"] == pytest.approx(roll, abs=1e-4)
    assert out["truth"]["azimuth_deg"] == pytest.approx(az)
    assert [w["samples"] for w in out["windows"]] == [2000, 2000]


def test_least_squares_over_four_positions_recovers_the_truth(tmp_path, capsys):
    spec = tmp_path / "biased.toml"
    spec.write_text(BIASED_IDEAL)
    out = find_json(
        capsys, "--sensor", str(spec), "--azimuth", "301.5", "--latitude", "-42", "--pitch", "2",
        "--positions", "10,100,190,280", "--window", "2",
    )  # fmt: skip
    assert out["method"] == "least-squares" and len(out["pairwise_azimuth_deg"]) == 3
    assert abs(out["error_deg"]) < 1e-4
    # noise-free windows pass the check: their rounding is below its noise floor
    assert out["consistent"] is True and out["check"]["dof"] == 5


def test_noisy_gyro_result_is_consistent_with_its_sigma_and_the_bound(capsys):
    out = find_json(capsys, "--sensor", "paper-rlg", "--seed", "5", "--positions", "0,180")
    # paper RLG, 2 x 10 s at 34 deg N, mu = 180: the bound is 0.093 deg
    assert 0.06 < out["sigma_deg"] < 0.13
    assert out["consistent"] is None and "not checked" in out["check"]["summary"]
    assert abs(out["error_deg"]) < 5 * out["sigma_deg"]


def test_the_same_seed_gives_the_same_result_whatever_the_load(capsys):
    """Virtual time: the same seed gives the same frames at the same times and so the same
    result, in this process and as a command of its own (run beside whatever loads the machine)."""
    args = ["--seed", "21", "--positions", "0,90", "--window", "2", "--warmup", "5"]
    first = find_json(capsys, *args)
    done = subprocess.run(
        [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())",
         "find", "--sim", *args, "--json"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    second = json.loads(done.stdout)
    # every figure to the last bit (azimuth, sigma, window means, truth); only the calendar time
    # at which each run began differs
    assert {k for k in first.keys() | second.keys() if first.get(k) != second.get(k)} <= {
        "created_utc"
    }
    assert len(first) > 10 and first["azimuth_deg"] == second["azimuth_deg"]
    assert first["truth"]["speed"] is None  # virtual time, not a speed
    other = find_json(capsys, "--seed", "22", *args[2:])
    assert other["azimuth_deg"] != first["azimuth_deg"]


def test_speed_runs_paced_and_only_with_sim(capsys):
    assert main(["find", "--serial", "/dev/null", "--speed", "5", "--latitude", "34"]) == 2
    assert "--speed: applies to the embedded simulator only (--sim)" in capsys.readouterr().err


def test_record_then_solve_reproduces_find(tmp_path, capsys):
    path = tmp_path / "run.csv"
    assert (
        main(
            [
                "record",
                str(path),
                "--sim",
                "--warmup",
                "0",
                "--seed",
                "8",
                "--sensor",
                "nav-fog",
                "--window",
                "4",
            ]
        )
        == 0
    )
    assert "wrote 4 windows (3200 samples)" in capsys.readouterr().out
    rec = Recording.load(path)
    assert rec.meta["truth"]["sensor"] == "nav-fog" and rec.meta["sample_rate_hz"] == 200
    assert main(["solve", str(path), "--json"]) == 0
    solved = json.loads(capsys.readouterr().out)
    assert abs(solved["error_deg"]) < 5 * solved["sigma_deg"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["find"], "choose exactly one device"),
        (["find", "--sim", "--serial", "/dev/null"], "choose exactly one device"),
        (["find", "--sim", "--positions", "0"], "need at least two table angles"),
        (["find", "--sim", "--positions", "0,2"], "within 5.0 deg"),
        (["find", "--sim", "--window", "0.1"], "window: must be"),
        (["find", "--sim", "--sensor", "nope"], "unknown sensor preset"),
        (["find", "--sim", "--latitude", "90"], "too close to a pole"),
        (["find", "--serial", "/dev/does-not-exist", "--latitude", "34"], "/dev/does-not-exist"),
        (["find", "--serial", "/dev/does-not-exist"], "--latitude"),
        (["record", "out.txt", "--sim"], "must end in .csv or .npz"),
        (["solve", "/nonexistent.npz"], "cannot read"),
    ],
)
def test_bad_arguments_give_one_clear_line(capsys, args, message):
    assert main(args) != 0
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err


def test_argument_parser_refuses_bad_values(capsys):
    for args in (
        ["find", "--sim", "--positions", "a,b"],
        ["find", "--sim", "--denoise", "magic"],
        ["find", "--sim", "--window", "nan"],
    ):
        assert main(args) == 2
    assert "invalid" in capsys.readouterr().err


class _Window:
    def __init__(self, n=2000, **over):
        rng = np.random.default_rng(0)
        self.counter = np.arange(n)
        self.time_s = self.counter / 200.0
        self.gyro_dph = rng.normal(0, 1, (n, 3)) + np.array([10.0, 5.0, 8.0])
        self.accel_mps2 = rng.normal(0, 1e-4, (n, 3)) + np.array([0, 0, 9.8])
        self.table_deg = np.full(n, 90.0)
        self.temperature_c = np.full(n, 20.0)
        self.validity = np.full(n, int(Validity.GYRO_VALID | Validity.ACCEL_VALID), dtype=np.uint8)
        self.missing = 0
        self.__dict__.update(over)


def test_window_quality_checks():
    good = summarise_window(_Window(), 90.0, "none")
    assert good.samples == 2000 and good.encoder_deg == pytest.approx(90.0)
    # the standard error from batch means agrees with sigma / sqrt(n) for white noise
    assert good.gyro_sem_dph[0] == pytest.approx(1 / math.sqrt(2000), rel=0.4)
    moved = _Window(table_deg=np.linspace(90.0, 90.5, 2000))
    with pytest.raises(QualityError, match=r"table moved 0\.5"):
        summarise_window(moved, 90.0, "none")
    flagged = _Window()
    flagged.validity[100:110] |= int(Validity.TABLE_SETTLING)
    with pytest.raises(QualityError, match=r"10 of 2000 samples unusable \(flagged"):
        summarise_window(flagged, 90.0, "none")
    with pytest.raises(QualityError, match="missing 3 samples"):
        summarise_window(_Window(missing=3), 90.0, "none")
    # an encoder that reads either side of zero: its mean is near 0 deg, not near 180 deg
    wrapped = _Window(table_deg=np.where(np.arange(2000) % 2, 359.9995, 0.0004))
    encoder = summarise_window(wrapped, 0.0, "none").encoder_deg
    assert abs((encoder + 180.0) % 360.0 - 180.0) < 1e-3, encoder
    bumped = _Window()
    bumped.gyro_dph[::50, 0] += 200.0
    assert "impulsive samples" in summarise_window(bumped, 90.0, "none").notes[0]


def test_plan_validation_and_progress_line(monkeypatch):
    with pytest.raises(HostConfigError, match="unknown method"):
        Plan(denoise="magic")
    with pytest.raises(HostConfigError, match="needs exactly two positions"):
        Plan(positions_deg=(0.0, 90.0, 180.0), method="two-position")
    assert Plan(positions_deg=(0.0, 120.0, 240.0)).solver == "least-squares"

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

        def fileno(self) -> int:
            return 99

    monkeypatch.setattr(os, "get_terminal_size", lambda fd: os.terminal_size((100, 30)))
    out = Tty()
    bar = PlanProgress(stream=out)
    bar(FindProgress("acquire", 1, 2, 12.5, 40.0))
    bar(FindProgress("solve", 2, 2, 180.0, 10.0))
    assert bar._bar.n == pytest.approx(30.0) and bar._bar.total == pytest.approx(40.0)
    bar(FindProgress("done", 2, 2, 180.0, 0.0))
    text = out.getvalue()
    # tqdm draws it: the phase, position and table angle, and wall-clock elapsed and remaining.
    assert "acquire  position 1/2 table 12.500 deg" in text
    assert "solve    position 2/2 table 180.000 deg  75%" in text
    assert " elapsed, ~" in text and " left" in text
    plain = io.StringIO()  # not a terminal: one line per step
    bar = PlanProgress(stream=plain)
    for p in (("rotate", 1), ("rotate", 1), ("acquire", 1), ("rotate", 2)):
        bar(FindProgress(*p, 2, None, None))
    assert plain.getvalue().splitlines() == [
        "find: rotate position 1/2",
        "find: acquire position 1/2",
        "find: rotate position 2/2",
    ]
    off = Tty()
    PlanProgress(stream=off, enabled=False)(FindProgress("rotate", 1, 2, None, None))
    assert off.getvalue() == ""


def test_a_simulator_that_fails_is_named_as_the_cause(capsys, monkeypatch):
    """In virtual time a simulator that raises falls silent; find then names the simulator's
    failure, not a silent device or a lost link."""
    from northfinder.firmware_sim.firmware import Firmware

    process = Firmware.process

    def failing(self, dt):
        if self.now > 3.0:
            raise ZeroDivisionError("a defect in the simulator")
        return process(self, dt)

    monkeypatch.setattr(Firmware, "process", failing)
    code = main(["find", "--sim", "--seed", "1", "--warmup", "5", "--window", "1"])
    err = capsys.readouterr().err
    assert code != 0
    assert "simulated instrument is not running" in err and "ZeroDivisionError" in err, err
