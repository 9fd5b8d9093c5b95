"""The paths users expect: CAN logs in and out, cantools on the DBC, NMEA 0183, the pytest plugin,
the JSON schema, the figure, a C host on the pty.

Everything runs against the embedded simulator in virtual time; where another process is the
point (a ``northfinder sim`` subprocess on a pty, the conformance command on its own bus) the
simulator is paced and the test is marked ``realtime``. Nothing asserts on wall-clock time.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import textwrap
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any

import can
import cantools
import jsonschema
import numpy as np
import pynmea2
import pytest
from clirun import run_cli, run_json
from simprocess import sim_process

from northfinder.cli import main
from northfinder.driver.framelog import FrameLog, log_suffix
from northfinder.driver.protocol.can import decode_can
from northfinder.driver.protocol.messages import RotateTo, SampleX
from northfinder.host.canlog import is_can_log, read_can_log
from northfinder.host.heading import heading_text
from northfinder.host.nmea import HeadingFix, hdt_sentence, nfdh_sentence
from northfinder.host.results import SIMULATOR_MODEL, schema

ROOT = Path(__file__).resolve().parents[1]
DBC = ROOT / "protocol.dbc"
FORMATS = (".log", ".asc", ".blf", ".csv", ".db", ".trc")
"""Every CAN log format python-can both writes and reads without an extra library."""
FAST = ["--sim", "--warmup", "0", "--window", "2", "--seed", "7"]  # virtual time
FAST += ["--azimuth", "42.5", "--positions", "0,180"]


@pytest.fixture(scope="module")
def validator() -> jsonschema.protocols.Validator:
    s = schema()
    jsonschema.Draft202012Validator.check_schema(s)
    return jsonschema.Draft202012Validator(s)


# -- CAN logs ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def logged_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, dict[str, Any]]]:
    """``find --sim --can-log`` once per format: the log and find's JSON result."""
    d = tmp_path_factory.mktemp("logs")
    out = {}
    for suffix in FORMATS:
        path = d / f"run{suffix}"
        out[suffix] = (path, run_json("find", *FAST, "--can-log", str(path)))
    return out


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_logged_find_solves_again_to_the_same_heading(logged_runs, suffix, validator):
    path, found = logged_runs[suffix]
    assert is_can_log(path)
    solved = run_json("solve", str(path), "--latitude", "34", "--window", "2")
    validator.validate(solved)
    assert solved["azimuth_deg"] == pytest.approx(found["azimuth_deg"], abs=1e-9)
    assert solved["sigma_deg"] == pytest.approx(found["sigma_deg"], rel=1e-9)
    assert solved["pitch_deg"] == pytest.approx(found["pitch_deg"], abs=1e-9)
    assert [w["samples"] for w in solved["windows"]] == [400, 400]
    assert [w["commanded_deg"] for w in solved["windows"]] == pytest.approx([0.0, 180.0])
    # The identity comes from the log's own IDENTIFY frames.
    assert solved["device"]["model"] == SIMULATOR_MODEL
    assert solved["device"]["simulated"] is True
    assert solved["source"]["format"] == "can-log"


@pytest.mark.parametrize("suffix", [".log", ".blf"])
def test_a_virtual_time_log_carries_the_instruments_time(logged_runs, suffix):
    """In virtual time the frames are stamped by the shared clock: the samples of a window are
    5 ms apart in the log, whatever the CPU's speed (the wall clock would crowd them)."""
    import can

    path, _ = logged_runs[suffix]
    with can.LogReader(str(path)) as reader:
        stamps = [m.timestamp for m in reader]
    # Every frame of a tick is logged at the tick's instant: distinct instants are the ticks.
    ticks = np.unique(np.round(np.asarray(stamps), 6))
    steps = np.diff(ticks)
    assert np.median(steps) == pytest.approx(0.005, abs=1e-6)
    # The log spans the run's device time: warm-up, two 2 s windows and the move between.
    assert stamps[-1] - stamps[0] > 4.0


def test_a_log_without_window_takes_every_sample_at_the_position(logged_runs):
    path, _ = logged_runs[".blf"]
    session = read_can_log(path)
    # find stops the stream after its window: a few more samples arrived at each position.
    assert all(len(w.counter) >= 400 for w in session.windows)
    assert all(np.all(np.diff(w.counter) == 1) for w in session.windows)
    assert session.notes == ()
    assert any("RotateTo" in c for _, c in session.commands)


def test_a_log_with_lost_frames_reports_the_gap(logged_runs, tmp_path):
    path, _ = logged_runs[".log"]
    cut = tmp_path / "cut.log"
    dropped = aux = 0
    with can.LogReader(str(path)) as reader, FrameLog(cut) as out:
        for msg in reader:
            # Drop the SAMPLE_AUX frames of ten ticks in the first window: incomplete ticks.
            if msg.arbitration_id == 0x131:
                aux += 1
                if 100 < aux <= 110:
                    dropped += 1
                    continue
            out(msg)
    assert dropped == 10
    session = read_can_log(cut, window_s=2.0)
    assert any("missing" in n for n in session.notes), session.notes
    code, _, err = run_cli("solve", str(cut), "--latitude", "34", "--window", "2")
    assert code == 1
    assert "missing" in err and "window 1" in err


@pytest.mark.parametrize("suffix", FORMATS)
def test_a_log_cut_short_is_reported_and_not_solved(logged_runs, suffix, tmp_path):
    """A copy cut inside the last window (``head -c`` of any format, a BLF's container cut in
    two): the shortfall is named and solve refuses the heading (exit 1, as for a gap)."""
    path, _ = logged_runs[suffix]
    data = path.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    # 80 % of the file: inside the second (last) window's stream, mid-line or mid-container.
    cut.write_bytes(data[: len(data) * 8 // 10])
    if suffix == ".db":
        # SQLite keeps its pages in no time order: a cut database is unreadable as a whole.
        code, out, err = run_cli("solve", str(cut), "--latitude", "34")
        assert code == 2 and out == "" and f"{cut}: unreadable CAN log" in err
        return
    session = read_can_log(cut)
    assert any("cut short" in n for n in session.notes), session.notes
    code, out, err = run_cli("solve", str(cut), "--latitude", "34")
    assert code == 1 and out == ""
    assert "cut short" in err and str(cut) in err
    assert "window 2" in err or "breaks off" in err
    # The whole log still solves with no note.
    assert read_can_log(path).notes == ()


def test_python_can_player_replays_a_log_onto_a_bus(logged_runs, monkeypatch):
    """``python -m can.player`` (docs/recordings.md): the replayed frames rebuild the same samples."""
    import uuid

    import can.player

    from northfinder.driver.protocol.can import CanReceiver
    from northfinder.driver.protocol.messages import Sample

    path, _ = logged_runs[".asc"]
    channel = f"replay-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as host:
        argv = ["can.player", "-i", "virtual", "-c", channel, "--ignore-timestamps", str(path)]
        monkeypatch.setattr(sys, "argv", argv)
        can.player.main()
        receiver = CanReceiver(node_id=1)
        replayed = []
        while (msg := host.recv(0.5)) is not None:
            replayed += [
                m
                for m in receiver.feed(msg.arbitration_id, bytes(msg.data))
                if isinstance(m, Sample)
            ]
    logged = [s for w in read_can_log(path).windows for s in w.counter]
    assert len(replayed) >= len(logged) >= 800  # two 2 s windows at 200 Hz
    assert [s.counter for s in replayed][-len(logged[-10:]) :] == [int(c) for c in logged[-10:]]


@pytest.mark.parametrize("command", ["find", "record", "conformance", "sim"])
def test_an_interface_that_sends_off_the_machine_is_refused(command, tmp_path):
    """``-i udp_multicast`` would send every frame as IP multicast: refused before anything opens
    (exit 2), with the reason and the interfaces accepted."""
    argv = [command, "-i", "udp_multicast", "-c", "239.74.163.2"]
    if command == "record":
        argv.append(str(tmp_path / "r.npz"))
    code, out, err = run_cli(*argv)
    assert code == 2 and out == ""
    assert "'udp_multicast' is refused" in err and "IP multicast" in err
    assert "accepted: " in err and "virtual" in err and "socketcan" in err


@pytest.mark.parametrize(
    ("name", "content", "why"),
    [
        ("garbage.blf", bytes(range(256)) * 8, "Unexpected file format"),
        ("notes.db", b'VERSION ""\nBU_: NF\n', "not a database"),
        ("empty.db", b"", "no such table"),
    ],
)
def test_a_file_that_is_not_the_log_its_name_says_is_a_clear_error(tmp_path, name, content, why):
    """Garbage BLF, a DBC-like text named .db: one line naming the file and what is wrong, exit 2
    (never an internal error), for solve and calibrate alike."""
    path = tmp_path / name
    path.write_bytes(content)
    for argv in (["solve", str(path), "--latitude", "34"], ["calibrate", str(path)]):
        code, out, err = run_cli(*argv)
        assert code == 2 and out == "", err
        assert str(path) in err and why in err and "internal error" not in err


def test_an_mf4_log_without_asammdf_names_the_package(tmp_path, monkeypatch):
    path = tmp_path / "run.mf4"
    path.write_bytes(b"MDF     4.10    ")
    monkeypatch.setitem(sys.modules, "asammdf", None)
    code, _, err = run_cli("solve", str(path), "--latitude", "34")
    assert code == 2 and str(path) in err and "asammdf" in err and "internal error" not in err


@pytest.mark.parametrize("command", [["find", *FAST], ["study", "--runs", "5"], ["solve", "x.npz"]])
def test_a_plot_name_of_no_format_is_refused_before_the_run(command, tmp_path):
    pytest.importorskip("matplotlib")
    for bad, why in (
        (tmp_path / "p.xyz", ".xyz is no plot format"),
        (tmp_path / "p", "no file ending"),
    ):
        code, out, err = run_cli(*command, "--plot", str(bad))
        assert code == 2 and out == "" and why in err and ".png" in err, err
        assert not bad.exists()


def test_the_log_name_must_name_a_format(tmp_path):
    code, _, err = run_cli("find", *FAST, "--can-log", str(tmp_path / "run.xyz"))
    assert code == 2 and "--can-log" in err
    assert log_suffix("a/run.log.gz") == ".log"


def test_the_embedded_simulator_logs_what_it_sends_and_receives(tmp_path):
    from northfinder.embed import RELAXED_DEVICE_OPTIONS, SimulatedInstrument, Truth
    from northfinder.host.procedure import Plan, find_north

    log = tmp_path / "sim.asc"
    with SimulatedInstrument(
        "ideal", Truth(azimuth_deg=10.0), clock="virtual", warmup_s=0, log=log
    ) as sim:
        with sim.open_device(**RELAXED_DEVICE_OPTIONS) as dev:
            result, _ = find_north(dev, Plan((0.0, 180.0), 1.0), 34.0)
    assert result.azimuth_deg == pytest.approx(10.0, abs=1e-5)
    with can.LogReader(str(log)) as reader:
        frames = list(reader)
    tx = [m for m in frames if not m.is_rx]
    rx = [m for m in frames if m.is_rx]
    assert {m.arbitration_id for m in rx} == {0x041}  # the simulator receives commands only
    assert {0x051, 0x101, 0x111, 0x121, 0x131, 0x201, 0x211, 0x301} <= {
        m.arbitration_id for m in tx
    }
    session = read_can_log(log, window_s=1.0)
    assert [len(w.counter) for w in session.windows] == [200, 200]


@pytest.mark.subprocess
@pytest.mark.realtime
def test_sim_log_on_a_serial_pty_logs_the_can_frames_of_its_messages(tmp_path, validator):
    """``northfinder sim --pty --log``: the serial session logged as CAN frames, solved again."""
    log = tmp_path / "serial.blf"
    args = ["--pty", "--warmup", "0", "--speed", "20", "--seed", "4", "--azimuth", "123"]
    with sim_process(*args, "--log", str(log), wanted={"pty"}) as facts:
        found = run_json(
            "find", "--serial", facts["pty"], "--latitude", "34", "--window", "2",
            "--positions", "0,180", "--reply-timeout", "2", "--link-timeout", "3",
        )  # fmt: skip
    validator.validate(found)
    assert found["device"]["simulated"] is False  # a unit on a port: find cannot know
    solved = run_json("solve", str(log), "--latitude", "34", "--window", "2")
    assert solved["azimuth_deg"] == pytest.approx(found["azimuth_deg"], abs=1e-9)


def test_calibrate_reads_can_logs_through_its_reader_table(logged_runs):
    from northfinder.host.calibrate.readers import read_runs

    path, _ = logged_runs[".trc"]
    (run,) = read_runs([path])
    assert run.sample_rate_hz == 200.0
    assert len(run.windows) == 2
    assert run.meta["device"]["model"] == SIMULATOR_MODEL
    assert [w.commanded_deg for w in run.windows] == pytest.approx([0.0, 180.0])


# -- cantools on the DBC ----------------------------------------------------------------------
def test_cantools_decodes_a_candump_log_as_the_readme_says(logged_runs):
    path, _ = logged_runs[".log"]
    text = path.read_text()

    def decode(*options: str) -> list[str]:
        res = subprocess.run(
            [sys.executable, "-m", "cantools", "decode", *options, "-s", str(DBC)],
            input=text, capture_output=True, text=True, check=True,
        )  # fmt: skip
        return res.stdout.splitlines()

    strict = decode()
    assert len(strict) == len(text.splitlines())
    wrong = [line for line in strict if "Wrong data size" in line]
    # Strict decoding refuses exactly the COMMAND and REPLY frames: they are shorter than the
    # DBC's 8 bytes (protocol.md 4.1, 4.2: no padding).
    assert wrong and all(" 041#" in line or " 051#" in line for line in wrong)
    assert any("SAMPLE_X(Tick:" in line for line in strict)
    assert all(" 041#" not in line or "Wrong" in line or "#" in line.split()[2] for line in strict)
    loose = decode("--no-strict")
    assert not any("Wrong data size" in line for line in loose)
    assert any("COMMAND(Seq:" in line and "Opcode: ROTATE_TO" in line for line in loose)
    assert any("REPLY(Seq:" in line and "Result: OK" in line for line in loose)


def test_cantools_decode_message_agrees_with_the_codec(logged_runs):
    path, _ = logged_runs[".log"]
    db = cantools.database.load_file(str(DBC), strict=True)
    assert isinstance(db, cantools.database.can.Database)
    rotations = []
    with can.LogReader(str(path)) as reader:
        for msg in reader:
            data = bytes(msg.data)
            _, ours = decode_can(msg.arbitration_id, data)
            decoded: Any
            if len(data) == 8:
                decoded = db.decode_message(msg.arbitration_id, data)
            else:
                with pytest.raises(cantools.database.DecodeError, match="Wrong data size"):
                    db.decode_message(msg.arbitration_id, data)
                decoded = db.decode_message(msg.arbitration_id, data, allow_truncated=True)
            if isinstance(ours, RotateTo):
                assert decoded["RotateToAngle"] == pytest.approx(ours.angle * 1e-6, abs=1e-9)
                rotations.append(decoded["RotateToAngle"])
            if isinstance(ours, SampleX):
                assert decoded["GyroX"] == pytest.approx(ours.gyro * 1e-4, abs=1e-9)
    assert rotations == pytest.approx([0.0, 180.0])


# -- NMEA 0183 --------------------------------------------------------------------------------
def test_find_sends_hdt_and_the_sigma_sentence_pynmea2_parses(tmp_path, validator):
    target = tmp_path / "heading.nmea"
    found = run_json("find", *FAST, "--nmea", str(target), "--nmea-count", "3", "--nmea-rate", "50")
    validator.validate(found)
    lines = target.read_bytes().split(b"\r\n")
    assert lines[-1] == b"" and len(lines) == 7
    parsed = [pynmea2.parse(line.decode(), check=True) for line in lines[:-1]]
    hdt, nfdh = parsed[0], parsed[1]
    assert isinstance(hdt, pynmea2.HDT) and hdt.talker == "HE" and hdt.hdg_true == "T"
    assert float(hdt.heading) == pytest.approx(found["azimuth_deg"], abs=0.005)
    assert nfdh.manufacturer == "NFD"
    assert nfdh.heading == pytest.approx(found["azimuth_deg"], abs=5e-5)
    assert nfdh.sigma == pytest.approx(found["sigma_deg"], abs=5e-5)
    assert nfdh.status == "A"
    assert nfdh.positions == 2
    assert [str(p) for p in parsed[2:4]] == [str(hdt), str(nfdh)]


def test_nmea_to_stdout_leaves_stdout_to_the_sentences():
    code, out, err = run_cli("find", *FAST, "--nmea", "-", "--nmea-count", "2", "--nmea-rate", "50")
    assert code == 0
    lines = out.splitlines()
    assert len(lines) == 4 and all(line.startswith("$") for line in lines)
    assert all(pynmea2.parse(line, check=True) for line in lines)
    assert "azimuth" in err


def test_nmea_to_a_pseudo_terminal(tmp_path):
    master, slave = os.openpty()
    try:
        import tty

        tty.setraw(slave)
        path = os.ttyname(slave)
        code, _, err = run_cli("find", *FAST, "--nmea", path, "--nmea-count", "1")
        assert code == 0, err
        data = os.read(master, 4096)
    finally:
        os.close(master)
        os.close(slave)
    lines = data.decode().split("\r\n")
    assert pynmea2.parse(lines[0], check=True).sentence_type == "HDT"
    assert pynmea2.parse(lines[1], check=True).manufacturer == "NFD"


def test_a_heading_that_is_not_good_enough_is_sent_as_not_valid():
    good = HeadingFix(359.999, 0.05, 0.1, -0.2, 2)
    assert hdt_sentence(good) == "$HEHDT,0.00,T*" + f"{_xor('HEHDT,0.00,T'):02X}"
    bad = HeadingFix(42.0, 3.0, 0.0, 0.0, 2, max_sigma_deg=1.0)
    hdt, nfdh = pynmea2.parse(hdt_sentence(bad), check=True), pynmea2.parse(nfdh_sentence(bad))
    assert hdt.heading is None  # empty field: no heading to use
    assert nfdh.status == "V" and nfdh.data[1] == "" and nfdh.sigma == 3.0
    unknown = HeadingFix(42.0, None, 0.0, 0.0, 2)
    assert pynmea2.parse(nfdh_sentence(unknown)).status == "V"


def test_a_heading_the_consistency_check_rejected_is_never_sent_as_valid():
    """Windows that disagree beyond their noise: however small sigma, no heading in either
    sentence and status V; a passed check (or none, with two windows) leaves it valid."""
    rejected = HeadingFix(42.0, 0.01, 0.0, 0.0, 4, consistent=False)
    hdt, nfdh = (
        pynmea2.parse(hdt_sentence(rejected), check=True),
        pynmea2.parse(nfdh_sentence(rejected)),
    )
    assert hdt.heading is None
    assert nfdh.status == "V" and nfdh.data[1] == "" and nfdh.sigma == 0.01
    for consistent in (True, None):
        fix = HeadingFix(42.0, 0.01, 0.0, 0.0, 4, consistent=consistent)
        assert pynmea2.parse(hdt_sentence(fix)).heading == 42.0
        assert pynmea2.parse(nfdh_sentence(fix)).status == "A"
    nan = HeadingFix(float("nan"), 0.01, 0.0, 0.0, 4, consistent=True)
    assert pynmea2.parse(nfdh_sentence(nan)).status == "V"


def _xor(body: str) -> int:
    c = 0
    for ch in body:
        c ^= ord(ch)
    return c


# -- JSON results -----------------------------------------------------------------------------
def test_find_json_carries_envelope_identity_and_the_old_keys(validator):
    doc = run_json("find", *FAST)
    validator.validate(doc)
    assert doc["schema"] == "northfinder-result" and doc["schema_version"] == 1
    assert doc["command"] == "find" and doc["created_utc"].endswith("Z")
    assert doc["device"]["model"] == SIMULATOR_MODEL and doc["device"]["sensor"] == "paper-rlg"
    for key in ("azimuth_deg", "sigma_deg", "pitch_deg", "roll_deg"):  # read by scripts/hil.d
        assert isinstance(doc[key], float)
    assert doc["truth"]["azimuth_deg"] == 42.5
    assert doc["solver"] == doc["method"] == "two-position"


def test_the_schema_rejects_a_result_without_its_envelope(validator):
    doc = run_json("find", *FAST)
    for key in ("device", "schema_version", "created_utc"):
        broken = {k: v for k, v in doc.items() if k != key}
        assert not validator.is_valid(broken), key
    assert not validator.is_valid({**doc, "azimuth_deg": 360.0})
    assert not validator.is_valid({**doc, "created_utc": "yesterday"})


def test_recordings_carry_identity_and_time_and_solve_reports_them(tmp_path, validator):
    from northfinder.host.recording import Recording

    for suffix in (".npz", ".csv"):
        rec_path = tmp_path / f"run{suffix}"
        code, _, err = run_cli("record", str(rec_path), *FAST)
        assert code == 0, err
        meta = Recording.load(rec_path).meta
        assert meta["device"]["model"] == SIMULATOR_MODEL
        assert meta["created_utc"].endswith("Z")
        doc = run_json("solve", str(rec_path))
        validator.validate(doc)
        assert doc["device"] == meta["device"]


def test_study_json_validates_in_both_kinds(validator):
    mc = run_json("study", "--sensor", "paper-rlg", "--positions", "0,180", "--runs", "50")
    validator.validate(mc)
    assert mc["kind"] == "monte-carlo" and mc["device"]["simulated"] is True
    ps = run_json("study", "--sensor", "nav-fog", "--plan-budget", "200", "--runs", "0")
    validator.validate(ps)
    assert ps["kind"] == "plan-search" and ps["plans"]


@pytest.mark.realtime
def test_conformance_json_validates_with_the_units_identity(validator):
    from northfinder.embed import SimulatedInstrument

    with SimulatedInstrument("paper-rlg", speed=20, warmup_s=0) as sim:
        assert sim.channel is not None
        doc = run_json(
            "conformance", "-i", "virtual", "-c", sim.channel, "--time-scale", "20",
            "--only", "identify,state.ready",
        )  # fmt: skip
    validator.validate(doc)
    assert doc["counts"]["fail"] == 0 and doc["passed"] is True
    assert [c["name"] for c in doc["checks"]] == ["identify", "state.ready"]
    assert doc["device"]["model"] == SIMULATOR_MODEL


def test_the_schema_ships_with_the_package():
    from importlib import resources

    text = resources.files("northfinder.host").joinpath("schemas/result.schema.json").read_text()
    assert json.loads(text)["$defs"]["device"]["required"][0] == "model"


def test_the_simulators_model_name_is_the_one_results_recognise():
    from northfinder.firmware_sim.firmware import Firmware

    assert Firmware.MODEL == SIMULATOR_MODEL


# -- the figure -------------------------------------------------------------------------------
def test_the_figure_stays_readable_at_eight_positions(tmp_path):
    pytest.importorskip("matplotlib")
    import matplotlib.image

    png = tmp_path / "f.png"
    code, _, err = run_cli(
        "find", *FAST, "--positions", "0,45,90,135,180,225,270,315", "--denoise", "hampel",
        "--plot", str(png),
    )  # fmt: skip
    assert code == 0, err
    height, width, _ = matplotlib.image.imread(png).shape
    assert height <= 1000 and width >= 1000


# -- the command line -------------------------------------------------------------------------
def test_version_log_level_and_debug_after_the_subcommand(tmp_path):
    code, out, _ = run_cli("--version")
    assert code == 0 and out.startswith("northfinder ")
    missing = str(tmp_path / "none.npz")
    code, _, err = run_cli("solve", missing)
    assert code == 2 and "cannot read" in err  # a file named on the command line: usage
    with pytest.raises(Exception, match="cannot read"):
        run_cli("solve", missing, "--debug")  # the traceback, not the line
    code, _, err = run_cli("solve", missing, "--log-level", "loud")
    assert code == 2 and "--log-level" in err


def test_the_solver_option_has_one_name_and_the_old_one_still_works():
    code, out, _ = run_cli("find", *FAST, "--method", "least-squares", "--json")
    assert code == 0 and json.loads(out)["solver"] == "least-squares"
    for command in ("find", "solve", "study"):
        buf = io.StringIO()
        with redirect_stdout(buf):
            assert main([command, "--help"]) == 0
        assert "--solver" in buf.getvalue() and "--method" not in buf.getvalue(), command


def test_simctl_help_lists_every_operation_and_its_keys():
    from northfinder.firmware_sim.control import OPS

    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main(["simctl", "--help"]) == 0
    text = buf.getvalue()
    for name, op in OPS.items():
        assert f"  {name}:" in text
        for line in op.usage(name)[1:]:
            assert line.split("=")[0].split(" ")[0] in text


# -- the pytest plugin, as a user uses it -----------------------------------------------------
USER_TEST = """
import pytest
from northfinder.host.procedure import Plan, find_north


@pytest.mark.northfinder_sim(sensor="ideal", azimuth_deg=42.0)
def test_my_host_finds_north(northfinder_sim, northfinder_device):
    result, _ = find_north(northfinder_device, Plan((0.0, 180.0), 1.0), latitude_deg=34.0)
    assert abs(result.azimuth_deg - northfinder_sim.truth.azimuth_deg) < 1e-4


@pytest.mark.parametrize(
    "northfinder_sim", [{"link": "serial-pty"}, {"link": "slcan-pty"}], indirect=True
)
def test_a_pty_for_another_process(northfinder_sim):
    assert northfinder_sim.path.startswith("/dev/")
    assert northfinder_sim.control.call("status")["ok"]


def test_faults_through_the_control_channel(northfinder_sim, northfinder_device):
    northfinder_sim.control.call("drop", count=3)
    assert northfinder_device.status().state.name == "READY"
"""


@pytest.mark.subprocess
def test_a_users_own_test_runs_on_the_installed_plugin(tmp_path):
    (tmp_path / "test_user.py").write_text(textwrap.dedent(USER_TEST))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_user.py"],
        cwd=tmp_path, capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    assert "4 passed" in res.stdout


# -- a C host on the pseudo-terminal ----------------------------------------------------------
@pytest.mark.subprocess
@pytest.mark.realtime
def test_the_c_host_example_reaches_the_simulator_on_a_pty(tmp_path):
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler (gcc or cc) on this machine")
    exe = tmp_path / "nf_host"
    subprocess.run(
        [gcc, "-O2", "-Wall", "-Wextra", "-Werror", "-std=c11", "-D_DEFAULT_SOURCE", "-o", str(exe),
         str(ROOT / "examples" / "c_host" / "nf_host.c")],
        check=True, capture_output=True,
    )  # fmt: skip
    args = ["--pty", "--warmup", "0", "--sensor", "ideal", "--azimuth", "0", "--speed", "5"]
    with sim_process(*args, wanted={"pty"}) as facts:
        res = subprocess.run(
            [str(exe), facts["pty"], "400"], capture_output=True, text=True, timeout=120
        )
    assert res.returncode == 0, res.stderr
    ident, samples, mean = res.stdout.splitlines()
    assert ident == "identify model NF-SIM serial 1 firmware 0.1.0 protocol 1.1"
    assert samples.startswith("samples 400 ") and samples.endswith(" gaps 0")
    values = [float(v) for v in mean.split()[2:5]]
    # Ideal sensor, level, azimuth 0 at 34 deg N: x reads the horizontal Earth rate, y nothing,
    # z the vertical one (NOTES.md 2), to the wire's resolution.
    omega_dph = 7.292115e-5 * 180 / np.pi * 3600
    lat = np.radians(34.0)
    assert values == pytest.approx(
        [omega_dph * np.cos(lat), 0.0, omega_dph * np.sin(lat)], abs=2e-6
    )


def test_the_instrument_page_names_every_control_operation():
    from northfinder.firmware_sim.control import OPS

    text = (ROOT / "docs" / "instrument.md").read_text()
    missing = [name for name in OPS if f"`{name}`" not in text]
    assert not missing, f"docs/instrument.md does not name {missing}"


@pytest.mark.parametrize("plan", [["--window", "2"], ["--spin", "6"]], ids=["stop-and-go", "spin"])
def test_a_heading_that_rounds_up_to_360_is_printed_as_0(plan):
    # An ideal unit a hundredth of a millidegree west of north: the printed heading is 0.0000,
    # never 360.0000 (a compass and NMEA's HDT read [0, 360)).
    code, out, err = run_cli(
        "find", "--sim", "--sensor", "ideal", "--warmup", "0", "--seed", "1",
        "--azimuth", "359.99999", *plan,
    )  # fmt: skip
    assert code == 0, err
    first = out.splitlines()[0]
    assert first.startswith("azimuth 0.0000 deg"), first
    assert "truth   0.0000 deg" in out and "360.0" not in out
    code, out, err = run_cli("simulate", "--azimuth", "359.99999", "--window", "1", "--seed", "1")
    assert code == 0 and "truth azimuth 0.0000 deg" in out, err
    fix = HeadingFix(359.99996, 0.05, 0.0, 0.0, 2)
    assert nfdh_sentence(fix).startswith("$PNFDH,0.0000,0.0500,A,")
    assert hdt_sentence(fix).startswith("$HEHDT,0.00,T")
    for digits in (1, 2, 3, 4):
        unit = 10.0**-digits
        assert heading_text(360.0 - 0.4 * unit, digits) == "0." + "0" * digits
        assert heading_text(360.0 - 0.6 * unit, digits) == "359." + "9" * digits
        assert heading_text(360.0 - 1.6 * unit, digits) == "359." + "9" * (digits - 1) + "8"
    assert heading_text(-0.00001, 4) == "0.0000" and heading_text(720.5, 1) == "0.5"
