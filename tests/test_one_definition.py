"""Concepts written once: the simulator, the driver and the host agree because they share one
definition (table limits, the move profile, the counter wrap, the default latitude, solver names,
the white-noise bound)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import serial

from northfinder.driver.protocol.motion import TableLimits, move_phases_s, move_time_s
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.driver.transport import SerialTransport
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import TableSpec
from northfinder.firmware_sim.turntable import Turntable
from northfinder.host.accuracy import bound_deg
from northfinder.host.batch_solve import chunk_errors
from northfinder.host.errors import HostConfigError
from northfinder.host.heading import two_position_bound_deg
from northfinder.host.montecarlo import StudySettings
from northfinder.host.plan import HEADING_SOLVERS, SOLVERS, Plan, TableModel, resolve_solver
from northfinder.host.procedure import METHOD_CHOICES


def test_the_table_defaults_are_the_same_on_every_side():
    limits, model, spec = TableLimits(), TableModel(), TableSpec()
    for name in ("max_rate_dps", "max_accel_dps2", "settle_s"):
        assert getattr(limits, name) == getattr(model, name) == getattr(spec, name), name
    assert isinstance(model, TableLimits) and model.indexing_error_deg == spec.indexing_error_deg


@pytest.mark.parametrize("distance", [0.25, 0.6, 3.0, 30.0, 179.9, 187.3])
def test_the_simulated_table_ends_its_move_when_the_plans_say(distance):
    spec = TableSpec(max_rate_dps=6.0, max_accel_dps2=60.0, encoder_resolution_deg=0.0)
    table = Turntable(spec, np.random.default_rng(0))
    end = table.move_by(1.5, distance)
    assert end - 1.5 == pytest.approx(move_time_s(distance, 6.0, 60.0), abs=1e-12)
    accel_s, cruise_s = move_phases_s(distance, 6.0, 60.0)
    triangular = distance <= 6.0 * 6.0 / 60.0
    assert (cruise_s == 0.0) == triangular
    rate = table.state(1.5 + accel_s + cruise_s / 2)[1]
    assert float(rate) == pytest.approx(6.0 if not triangular else 60.0 * accel_s)


def _serial_transport_fed(counters):
    """The tick losses a serial transport reports for samples with these counters."""
    transport = SerialTransport(serial.serial_for_url("loop://", timeout=0))
    try:
        losses = [loss for c in counters for loss in transport._check_counter(c)]
        return losses, transport.counter_restarts
    finally:
        transport.close()


def test_the_serial_sample_counter_wraps_as_the_protocol_counts():
    losses, restarts = _serial_transport_fed([0xFFFFFFFE, 0xFFFFFFFF, 0, 3])
    assert [(x.first_counter, x.count) for x in losses] == [(1, 2)] and restarts == 0
    losses, restarts = _serial_transport_fed([5, 4, 4])
    assert losses == [] and restarts == 2


def test_one_default_latitude():
    assert Truth().latitude_deg == StudySettings().latitude_deg == DEFAULT_LATITUDE_DEG == 34.0


def test_solver_names_come_from_one_table():
    assert set(HEADING_SOLVERS) < set(SOLVERS) and METHOD_CHOICES == HEADING_SOLVERS
    assert resolve_solver("auto", 2) == Plan((0, 180)).solver == "two-position"
    assert resolve_solver("auto", 4) == Plan((0, 90, 180, 270)).solver == "least-squares"
    gyro = np.zeros((1, 3, 4, 3))
    with pytest.raises(HostConfigError, match="needs exactly two positions"):
        chunk_errors(gyro, None, [0, 90, 180], [0.0], 34.0, solver="two-position")
    with pytest.raises(HostConfigError, match="unknown"):
        chunk_errors(gyro, None, [0, 90, 180], [0.0], 34.0, solver="fastest")


@pytest.mark.parametrize("mu", [30.0, 90.0, 180.0, 210.0])
def test_the_two_position_bound_is_the_plan_bound(mu):
    assert two_position_bound_deg(0.0015, 20.0, mu, 34.0) == bound_deg(
        (0.0, mu), 10.0, 0.0015, 34.0
    )
    # the closed form of notes section 4
    n = 0.0015 * np.pi / 180 / 60
    omega_h = 7.292115e-5 * np.cos(np.radians(34.0))
    closed = np.degrees(n / (omega_h * abs(np.sin(np.radians(mu) / 2)) * np.sqrt(20.0)))
    assert two_position_bound_deg(0.0015, 20.0, mu, 34.0) == pytest.approx(closed, rel=1e-12)


# -- protocol.dbc: one database, installed with the codec --------------------------------------
def test_the_installed_dbc_is_the_repository_s_protocol_dbc():
    """The repository's protocol.dbc is the one edited; driver/protocol/protocol.dbc is the copy
    that installs with the codec (package data). They must not drift apart."""
    from pathlib import Path

    from northfinder.driver.protocol import dbc_path

    root = Path(__file__).resolve().parents[1]
    installed = dbc_path()
    assert installed.is_file()
    assert installed.read_bytes() == (root / "protocol.dbc").read_bytes(), (
        "driver/protocol/protocol.dbc differs from protocol.dbc: after editing protocol.dbc, "
        "copy it: cp protocol.dbc driver/protocol/protocol.dbc"
    )


def test_the_dbc_resolves_through_importlib_resources_and_loads():
    from importlib import resources

    import cantools

    from northfinder.driver.protocol import DBC_NODE, CanFunction

    with resources.as_file(resources.files("northfinder.driver.protocol") / "protocol.dbc") as path:
        db = cantools.database.load_file(str(path))
    assert isinstance(db, cantools.database.can.Database)
    for function in CanFunction:  # every frame of the protocol has its message
        assert db.get_message_by_frame_id(function | DBC_NODE).name == function.name


@pytest.mark.subprocess
def test_an_installed_northfinder_dumps_with_its_own_dbc(tmp_path):
    """The package as setuptools builds it for a wheel (build_py: packages and package data,
    from pyproject.toml) holds protocol.dbc; run from that tree, away from the checkout,
    ``dump`` decodes with it."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    built = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-c", "import setuptools; setuptools.setup()", "-q", "build_py",
         "--build-lib", str(built)],
        cwd=root, check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    dbc = built / "northfinder" / "driver" / "protocol" / "protocol.dbc"
    assert dbc.read_bytes() == (root / "protocol.dbc").read_bytes()
    assert (built / "northfinder" / "firmware_sim" / "presets" / "paper-rlg.toml").is_file()
    log = tmp_path / "one.log"
    log.write_text("(1796388050.226000) can0 101#0540E20100D20400\n")  # protocol.md's example
    script = (
        "import sys, northfinder; from northfinder.cli import main; "
        f"assert northfinder.__file__.startswith({str(built)!r}), northfinder.__file__; "
        f"sys.exit(main(['dump', {str(log)!r}]))"
    )
    env = {**os.environ, "PYTHONPATH": str(built)}
    res = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert ":: SAMPLE_X(Tick: 5, " in res.stdout


def test_the_drive_s_heat_is_defined_once():
    from northfinder.driver.protocol import heat
    from northfinder.firmware_sim import error_terms
    from northfinder.host import accuracy

    assert error_terms.move_heat is heat.move_heat
    assert accuracy.move_heat is heat.move_heat


def _default(function, name):
    import inspect

    return inspect.signature(function).parameters[name].default


def test_one_warm_up_default():
    """The simulated warm-up (the paper's 2 min) is written once and read by every side."""
    from northfinder.config import SimConfig
    from northfinder.driver.protocol.units import DEFAULT_WARMUP_S
    from northfinder.embed import SimulatedInstrument
    from northfinder.firmware_sim.firmware import Firmware
    from northfinder.simwindows import write_recordings

    sides = {
        "firmware": _default(Firmware, "warmup_s"),
        "embed": _default(SimulatedInstrument, "warmup_s"),
        "study": StudySettings().warmup_s,
        "recordings": _default(write_recordings, "warmup_s"),
        "config": SimConfig().warmup_s,
    }
    assert set(sides.values()) == {DEFAULT_WARMUP_S}, sides


def test_one_default_sensor():
    from northfinder.config import SimConfig
    from northfinder.embed import SimulatedInstrument
    from northfinder.firmware_sim.sensors import DEFAULT_SENSOR, preset_names

    assert DEFAULT_SENSOR in preset_names()
    assert _default(SimulatedInstrument, "sensor") == SimConfig().sensor == DEFAULT_SENSOR


def test_one_set_of_plan_defaults():
    """The plan options of ``find`` and ``record`` default to the configuration's plan, and
    ``find --spin`` refuses a change from the same defaults."""
    from northfinder.cli import build_parser, find
    from northfinder.cli.measure import plan_from_args
    from northfinder.config import DEFAULT_PLAN, FindConfig

    for command in ("find", "record"):
        argv = [command, "out.npz"] if command == "record" else [command]
        args = build_parser(only=command).parse_args(argv)
        assert plan_from_args(args) == DEFAULT_PLAN == FindConfig(None).plan  # type: ignore[arg-type]
        assert {name: getattr(args, name) for name in find.PLAN_DEFAULTS} == find.PLAN_DEFAULTS


def test_one_name_one_thing():
    """No two public classes of the packages share a name (two ``Clock``s, two ``Progress``es,
    two ``Session``s were three pairs of different things), and the plan's settle bound of a
    device has a name of its own."""
    import ast
    from collections import defaultdict
    from pathlib import Path

    import northfinder
    from northfinder.host import procedure

    root = Path(northfinder.__file__).resolve().parent.parent
    where: dict[str, list[str]] = defaultdict(list)
    for package in ("driver", "firmware_sim", "host", "northfinder"):
        for path in sorted((root / package).rglob("*.py")):
            for node in ast.parse(path.read_text()).body:
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                    where[node.name].append(str(path.relative_to(root)))
    assert len(where) > 100  # the packages were read
    twice = {name: paths for name, paths in where.items() if len(paths) > 1}
    assert not twice, twice
    assert not hasattr(procedure, "MAX_SETTLE_S") and procedure.MAX_DEVICE_SETTLE_S == 600.0


@pytest.mark.parametrize("name", ["MAX_RATE_HZ", "MAX_WINDOW_S"])
def test_the_simulated_window_limits_are_defined_once(name):
    """The longest simulated window and the highest simulated sample rate are the simulator
    windows' (northfinder.simwindows), and every command that takes them reads them there."""
    import re
    from pathlib import Path

    import northfinder
    from northfinder import simwindows
    from northfinder.cli import simulate, study, sweep

    root = Path(northfinder.__file__).parent
    assignment = re.compile(rf"^{name}\s*[:=]", re.MULTILINE)
    defined = [p.relative_to(root).as_posix() for p in sorted(root.rglob("*.py"))
               if assignment.search(p.read_text(encoding="utf-8"))]  # fmt: skip
    assert defined == ["simwindows.py"]
    for module in (simulate, study, sweep):
        assert getattr(module, name) is getattr(simwindows, name), module.__name__
