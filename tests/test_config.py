"""The command line and a script configure a run the same way: ``find``'s options are parsed once
into the typed objects of :mod:`northfinder.config`, which a script builds by hand and runs
through :mod:`northfinder.session` (``northfinder.find``) to the same result."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest

import northfinder
from northfinder.cli import build_parser, find, main
from northfinder.config import DEFAULT_PLAN, default_of
from northfinder.host.errors import HostConfigError

nf = northfinder


def parsed(*argv: str) -> nf.FindConfig:
    """The configuration ``northfinder find ARGV`` runs."""
    args = build_parser(only="find").parse_args(["find", *argv])
    return find.find_config(args)


SIM1 = nf.LinkConfig(sim=nf.SimConfig(seed=1))

# Each command line, and the configuration a script writes for it.
CASES = [
    (["--sim", "--seed", "1"], nf.FindConfig(SIM1)),
    (
        [
            "--sim",
            "--seed",
            "7",
            "--warmup",
            "0",
            "--sensor",
            "nav-fog",
            "--azimuth",
            "42",
            "--pitch",
            "1.5",
            "--roll",
            "-2",
            "--speed",
            "50",
        ],
        nf.FindConfig(
            nf.LinkConfig(
                sim=nf.SimConfig(
                    sensor="nav-fog",
                    seed=7,
                    speed=50.0,
                    warmup_s=0.0,
                    azimuth_deg=42.0,
                    pitch_deg=1.5,
                    roll_deg=-2.0,
                )
            )
        ),
    ),
    (
        [
            "--sim",
            "--seed",
            "1",
            "--positions",
            "0,180",
            "--window",
            "2",
            "--settle",
            "1",
            "--solver",
            "two-position",
            "--latitude",
            "45",
            "--on-gap",
            "report",
            "--timeout",
            "30",
        ],
        nf.FindConfig(
            SIM1,
            plan=nf.Plan((0.0, 180.0), 2.0, 1.0, "none", "two-position"),
            latitude_deg=45.0,
            on_gap="report",
            ready_timeout_s=30.0,
        ),
    ),
    (
        ["--sim", "--seed", "1", "--spin", "6", "--spin-time", "120", "--spin-drift"],
        nf.FindConfig(SIM1, spin=nf.SpinConfig(6.0, 120.0, drift=True)),
    ),
    (
        [
            "--sim",
            "--seed",
            "1",
            "--json",
            "--nmea",
            "-",
            "--nmea-rate",
            "2",
            "--nmea-count",
            "0",
            "--link-timeout",
            "5",
            "--reply-timeout",
            "1",
        ],
        nf.FindConfig(
            nf.LinkConfig(sim=nf.SimConfig(seed=1), link_timeout_s=5.0, reply_timeout_s=1.0),
            output=nf.OutputConfig(json=True, nmea=nf.NmeaConfig("-", rate_hz=2.0, count=0)),
        ),
    ),
    (
        ["-i", "virtual", "-c", "bench", "--node-id", "3", "--latitude", "51.5"],
        nf.FindConfig(
            nf.LinkConfig(bus={"interface": "virtual", "channel": "bench"}, node_id=3),
            latitude_deg=51.5,
        ),
    ),
    (
        ["--serial", "/dev/ttyUSB0", "--baud", "115200", "--latitude", "-33"],
        nf.FindConfig(nf.LinkConfig(serial="/dev/ttyUSB0", baud=115200), latitude_deg=-33.0),
    ),
]


@pytest.mark.parametrize(("argv", "config"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_the_command_line_and_a_script_build_the_same_configuration(argv, config):
    assert parsed(*argv) == config


def test_a_changed_option_gives_a_different_configuration():
    """The comparison above can fail: one option more is another configuration."""
    assert parsed("--sim", "--seed", "1", "--window", "5") != nf.FindConfig(SIM1)
    assert parsed("--sim", "--seed", "2") != nf.FindConfig(SIM1)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seed", "1", "--latitude", "3"], "choose exactly one device"),
        (["--sim", "--serial", "/dev/null"], "choose exactly one device"),
        (["-i", "virtual", "-c", "x", "--seed", "1", "--latitude", "3"], "--seed: applies"),
        (["-i", "virtual", "-c", "x"], "--latitude: give the site's latitude"),
    ],
)
def test_a_configuration_is_checked_once_as_it_is_parsed(argv, message):
    with pytest.raises(HostConfigError, match=message):
        parsed(*argv)


def test_the_defaults_are_the_owners(capsys):
    """The command line's defaults are the configuration's, which are the lower layers'."""
    from northfinder.driver.protocol.units import DEFAULT_WARMUP_S
    from northfinder.firmware_sim.sensors import DEFAULT_SENSOR
    from northfinder.host.procedure import DEFAULT_ON_GAP, READY_TIMEOUT_S

    config = parsed("--sim", "--seed", "1")
    assert config.plan == DEFAULT_PLAN and config.link.sim is not None
    assert config.link.sim.warmup_s == DEFAULT_WARMUP_S == default_of(nf.SimConfig, "warmup_s")
    assert config.link.sim.sensor == DEFAULT_SENSOR
    assert (config.on_gap, config.ready_timeout_s) == (DEFAULT_ON_GAP, READY_TIMEOUT_S)
    assert main(["find", "--help"]) == 0
    text = capsys.readouterr().out
    assert f"--sim warm-up time (default {DEFAULT_WARMUP_S:g})" in " ".join(text.split())
    assert f"(default: {DEFAULT_SENSOR})" in text


SCRIPT = """
import json, northfinder as nf
config = nf.FindConfig(
    nf.LinkConfig(sim=nf.SimConfig(seed=5, warmup_s=1.0, azimuth_deg=123.0)),
    plan=nf.Plan((0.0, 180.0), 1.0),
)
m = nf.find(config)
print(json.dumps([repr(m.result.azimuth_deg), repr(m.result.sigma_deg), m.truth.seed]))
"""


def test_a_script_runs_what_the_command_line_runs(capsys):
    """``python -c "import northfinder; ..."`` with the configuration the command line builds
    gives the command's result to the last digit."""
    argv = ["--sim", "--seed", "5", "--warmup", "1", "--azimuth", "123", "--positions",
            "0,180", "--window", "1"]  # fmt: skip
    config = nf.FindConfig(
        nf.LinkConfig(sim=nf.SimConfig(seed=5, warmup_s=1.0, azimuth_deg=123.0)),
        plan=nf.Plan((0.0, 180.0), 1.0, 0.0),
    )
    assert parsed(*argv) == dataclasses.replace(config)
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300, check=True
    )
    azimuth, sigma, seed = json.loads(done.stdout)
    assert main(["find", *argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert seed == 5
    assert float(azimuth) == out["azimuth_deg"]
    assert float(sigma) == out["sigma_deg"]


def test_the_simulated_truth_is_typed_and_written_as_the_json_states_it(capsys, tmp_path):
    """``Measured.truth`` is a :class:`SimTruth`; ``find --json`` and a recording's metadata
    write its ``as_dict()``, in that order of keys."""
    argv = ["--sim", "--seed", "3", "--warmup", "0", "--pitch", "1", "--positions", "0,180",
            "--window", "1"]  # fmt: skip
    measured = nf.find(parsed(*argv))
    truth = measured.truth
    assert isinstance(truth, nf.SimTruth) and isinstance(truth.truth, nf.Truth)
    assert (truth.seed, truth.sensor, truth.speed, truth.pitch_deg) == (3, "paper-rlg", None, 1.0)
    assert list(truth.as_dict()) == [
        "azimuth_deg", "latitude_deg", "pitch_deg", "roll_deg", "sensor", "speed", "seed",
    ]  # fmt: skip
    # read as the mapping of version 0.2 too
    assert (truth["azimuth_deg"], truth.get("sensor")) == (truth.azimuth_deg, "paper-rlg")
    assert main(["find", *argv, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["truth"] == truth.as_dict()
    path = tmp_path / "run.npz"
    assert main(["record", str(path), *argv]) == 0
    from northfinder.host.recording import Recording

    assert Recording.load(path).meta["truth"] == truth.as_dict()


def sim_parsed(command: str, *argv: str) -> tuple[nf.SimConfig, float]:
    """The simulated instrument and latitude ``northfinder sim|simulate ARGV`` runs."""
    from northfinder.cli.simulated import simulated

    return simulated(build_parser(only=command).parse_args([command, *argv]))


SIM_CASES = [
    (
        ("sim", "--pty"),
        (nf.SimConfig(speed=1.0, warmup_s=120.0), 34.0),
    ),
    (
        ("sim", "--pty", "--seed", "3", "--azimuth", "10", "--pitch", "1", "--roll", "-0.5",
         "--sensor", "nav-fog", "--warmup", "0", "--speed", "20", "--latitude", "-12"),
        (nf.SimConfig("nav-fog", 3, 20.0, 0.0, 10.0, 1.0, -0.5), -12.0),
    ),
    (
        ("simulate", "--seed", "2", "--latitude", "50", "--azimuth", "42"),
        (nf.SimConfig(seed=2, azimuth_deg=42.0), 50.0),
    ),
]  # fmt: skip


@pytest.mark.parametrize(("argv", "config"), SIM_CASES, ids=[" ".join(a) for a, _ in SIM_CASES])
def test_the_simulator_commands_build_the_same_configuration(argv, config):
    assert sim_parsed(*argv) == config


def test_conformance_sim_builds_the_same_link():
    from northfinder.cli import conformance

    def link(*argv: str) -> nf.LinkConfig:
        return conformance.sim_link(build_parser(only="conformance").parse_args(argv))

    level = nf.SimConfig(seed=4, warmup_s=0.0, azimuth_deg=0.0)
    assert link("conformance", "--sim", "--seed", "4") == nf.LinkConfig(sim=level)
    assert link("conformance", "--sim", "--seed", "4", "--sensor", "nav-fog", "--node-id", "3") == (
        nf.LinkConfig(node_id=3, sim=dataclasses.replace(level, sensor="nav-fog"))
    )
    assert link("conformance", "--sim", "--seed", "5") != nf.LinkConfig(sim=level)


def test_a_seed_gives_the_same_truth_in_every_simulator_command(capsys):
    """``sim``, ``simulate`` and ``find --sim`` draw the truth of a seed the same way."""
    from northfinder import session

    sim, latitude = sim_parsed("simulate", "--seed", "11")
    truth, seed, _ = session.draw_truth(sim, latitude)
    _, facts = session.simulated_instrument(nf.LinkConfig(sim=sim), sim, latitude)
    assert (facts.truth, facts.seed) == (truth, seed) == (truth, 11)
    assert main(["simulate", "--seed", "11", "--json", "--window", "0.1"]) == 0
    assert json.loads(capsys.readouterr().out)["truth"] == dataclasses.asdict(truth)
    assert session.draw_truth(dataclasses.replace(sim, seed=12), latitude)[0] != truth


def test_the_command_line_checks_a_run_once_and_a_script_s_run_is_checked(monkeypatch, capsys):
    from northfinder import session

    calls: list[object] = []
    real = session.check_log_rotation

    def counted(*a: object) -> None:
        calls.append(a)
        real(*a)  # type: ignore[arg-type]

    monkeypatch.setattr(session, "check_log_rotation", counted)
    argv = ["find", "--sim", "--seed", "1", "--warmup", "0", "--positions", "0,180", "--window",
            "1", "--json"]  # fmt: skip
    assert main(argv) == 0
    capsys.readouterr()
    assert len(calls) == 1
    with pytest.raises(HostConfigError, match="--latitude: give the site's latitude"):
        nf.find(nf.FindConfig(nf.LinkConfig(serial="/dev/null")))
    with pytest.raises(HostConfigError, match="choose exactly one device"):
        nf.find(nf.FindConfig(nf.LinkConfig()))
