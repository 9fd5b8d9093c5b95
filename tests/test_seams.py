"""The seams a user trips on: every output checked before the work, NMEA to the network,
reproducible runs, a failed consistency check that says so, logs that forgive, link statistics,
progress, one JSON envelope, ``dump``, and a calibration that bounds what it cannot resolve.

Everything runs in-process against the embedded simulator in virtual time; network sockets are
on 127.0.0.1 only.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import select
import socket
import threading
from pathlib import Path
from typing import Any

import pynmea2
import pytest
from clirun import run_cli, run_json

#: A number printed as a negative zero (-0, -0.000), not -0.0001.
NEGATIVE_ZERO = re.compile(r"(?<![\w.])-0(\.0*)?(?![\d.])")
FAST = ["--sim", "--warmup", "0", "--window", "2", "--positions", "0,180"]


# -- 1. outputs checked before any work; NMEA to UDP and TCP ----------------------------------
@pytest.mark.parametrize(
    ("option", "value", "says"),
    [
        ("--nmea", "/dev/ttyNOSUCHPORT", "no such device"),
        ("--nmea", "udp://127.0.0.1", "udp://HOST:PORT"),
        ("--nmea", "tcp://127.0.0.1:99999", "tcp://HOST:PORT"),
        ("--nmea", "/no/such/folder/heading.nmea", "cannot open"),
        ("--record", "/dev/nosuchdevice.csv", "no such device"),
        ("--record", "/no/such/folder/run.csv", "does not exist"),
        ("--can-log", "/dev/nosuchdevice.log", "no such device"),
        ("--plot", "/no/such/folder/find.png", "does not exist"),
        ("--plot", "find.nosuchformat", "no plot format"),
    ],
)
def test_a_bad_output_stops_find_before_it_measures(option, value, says, monkeypatch):
    """Exit 2 with one line (argparse's usage before it for a malformed option), and the
    device is never opened (no measuring first)."""
    import northfinder.cli.measure as measure

    def never(*_: Any, **__: Any) -> Any:
        raise AssertionError("the device was opened")

    monkeypatch.setattr(measure, "open_device", never)
    code, out, err = run_cli("find", *FAST, option, value)
    assert code == 2, err
    assert out == "" and says in err.strip().splitlines()[-1], err
    assert not os.path.exists(value) or not value.startswith("/dev/")


def test_nmea_over_udp_reaches_a_listener_on_loopback():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(5.0)
        port = rx.getsockname()[1]
        found = run_json(
            "find", *FAST, "--seed", "3", "--nmea", f"udp://127.0.0.1:{port}",
            "--nmea-count", "2", "--nmea-rate", "100",
        )  # fmt: skip
        datagrams = [rx.recv(4096).decode("ascii") for _ in range(4)]
    assert all(d.endswith("\r\n") and d.count("$") == 1 for d in datagrams)  # one sentence each
    parsed = [pynmea2.parse(d.strip(), check=True) for d in datagrams]
    assert isinstance(parsed[0], pynmea2.HDT)
    assert float(parsed[0].heading) == pytest.approx(found["azimuth_deg"] % 360, abs=0.005)
    assert parsed[1].manufacturer == "NFD" and parsed[1].status == "A"
    assert [str(p) for p in parsed[2:]] == [str(p) for p in parsed[:2]]


def test_nmea_over_udp_with_nobody_listening_is_not_an_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    code, _, err = run_cli(
        "find", *FAST, "--nmea", f"udp://127.0.0.1:{port}", "--nmea-count", "3",
        "--nmea-rate", "100",
    )  # fmt: skip
    assert code == 0, err


def test_nmea_over_tcp_is_sent_to_the_server():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        server.settimeout(5.0)
        port = server.getsockname()[1]
        code, _, err = run_cli("find", *FAST, "--nmea", f"tcp://127.0.0.1:{port}")
        assert code == 0, err
        conn, _ = server.accept()  # the connection waited in the backlog
        with conn:
            conn.settimeout(5.0)
            data = b""
            while data.count(b"\r\n") < 2:
                chunk = conn.recv(4096)
                if not chunk:
                    break
                data += chunk
    lines = data.decode("ascii").split("\r\n")
    assert pynmea2.parse(lines[0], check=True).sentence_type == "HDT"
    assert pynmea2.parse(lines[1], check=True).manufacturer == "NFD"


def test_nmea_to_a_tcp_server_that_closes_prints_the_heading_then_exits_1(monkeypatch):
    """A listener on loopback that accepts and closes at once; the sentences are sent only
    once it has closed (so the order does not depend on the scheduler)."""
    from northfinder.host.nmea import NmeaOutput

    closed = threading.Event()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        server.settimeout(30.0)
        port = server.getsockname()[1]

        def accept_and_close() -> None:
            conn, _ = server.accept()
            conn.close()
            closed.set()

        thread = threading.Thread(target=accept_and_close, daemon=True)
        thread.start()
        send = NmeaOutput.send

        def send_after_the_close(self: NmeaOutput, *lines: str) -> None:
            assert closed.wait(30.0)
            send(self, *lines)

        monkeypatch.setattr(NmeaOutput, "send", send_after_the_close)
        for k, count in enumerate(("1", "3")):
            if k:  # a listener again for the next run
                closed.clear()
                thread = threading.Thread(target=accept_and_close, daemon=True)
                thread.start()
            code, out, err = run_cli(
                "find", *FAST, "--nmea", f"tcp://127.0.0.1:{port}", "--nmea-count", count,
                "--nmea-rate", "50",
            )  # fmt: skip
            assert code == 1, err  # docs/cli.md: a file (an output) that cannot be written
            assert "azimuth" in out  # the heading first
            assert err.strip().splitlines()[-1] == (
                f"northfinder find: error: --nmea tcp://127.0.0.1:{port}: cannot write (the "
                "server closed the connection)"
            )
            thread.join(30.0)


def test_tcp_nmea_with_no_server_stops_before_measuring():
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # closed again: nobody listens there
    code, out, err = run_cli("find", *FAST, "--nmea", f"tcp://127.0.0.1:{port}")
    assert code == 2 and "refused" in err.lower() and out == ""


def test_an_output_path_under_dev_is_never_created(tmp_path):
    for option in ("--record", "--can-log"):
        path = "/dev/northfinder-no-such-device" + (".csv" if option == "--record" else ".log")
        code, _, err = run_cli("find", *FAST, option, path)
        assert code == 2 and "no such device" in err
        assert not Path(path).exists()
    code, _, err = run_cli("record", "/dev/northfinder-no-such.npz", *FAST)
    assert code == 2 and not Path("/dev/northfinder-no-such.npz").exists()


# -- 2. the seed reported and taken back --------------------------------------------------------
def test_an_unseeded_find_reports_its_seed_and_the_seed_repeats_it_exactly():
    first = run_json("find", *FAST)
    seed = first["truth"]["seed"]
    assert isinstance(seed, int) and seed >= 0
    again = run_json("find", *FAST, "--seed", str(seed))
    for doc in (first, again):
        doc.pop("created_utc")
    assert again == first
    code, out, _ = run_cli("find", *FAST, "--seed", str(seed))
    assert code == 0 and f"seed {seed}" in out


def test_an_unseeded_recording_keeps_its_seed_and_the_seed_repeats_it(tmp_path):
    from northfinder.host.recording import Recording

    code, out, err = run_cli("record", str(tmp_path / "a.npz"), *FAST)
    assert code == 0, err
    seed = Recording.load(tmp_path / "a.npz").meta["truth"]["seed"]
    assert f"seed {seed}" in out
    code, _, err = run_cli("record", str(tmp_path / "b.npz"), *FAST, "--seed", str(seed))
    assert code == 0, err
    a, b = Recording.load(tmp_path / "a.npz"), Recording.load(tmp_path / "b.npz")
    for wa, wb in zip(a.windows, b.windows, strict=True):
        assert (wa.gyro_dph == wb.gyro_dph).all() and (wa.counter == wb.counter).all()
    assert a.meta["truth"] == b.meta["truth"]


def test_simulate_reports_its_seed_and_repeats_with_it():
    first = json.loads(run_cli("simulate", "--window", "1", "--json")[1])
    seed = first["seed"]
    again = json.loads(run_cli("simulate", "--window", "1", "--json", "--seed", str(seed))[1])
    first.pop("created_utc"), again.pop("created_utc")
    assert again == first


# -- 3. a failed consistency check: its own exit status, said as a shift, shown in the plot ----
def _stepped_recording(tmp_path: Path, step_dph: float = 2.0) -> Path:
    """A four-window recording whose last two windows carry a gyro x bias step."""
    import dataclasses

    from northfinder.host.recording import Recording

    path = tmp_path / "run.npz"
    code, _, err = run_cli(
        "record", str(path), "--sim", "--warmup", "0", "--window", "2", "--seed", "5",
        "--azimuth", "30",
    )  # fmt: skip
    assert code == 0, err
    rec = Recording.load(path)
    windows = list(rec.windows)
    for i in (2, 3):
        gyro = windows[i].gyro_dph.copy()
        gyro[:, 0] += step_dph
        windows[i] = dataclasses.replace(windows[i], gyro_dph=gyro)
    stepped = tmp_path / "stepped.npz"
    Recording(tuple(windows), rec.meta).save(stepped)
    return stepped


def test_a_heading_that_failed_its_check_exits_3_and_says_so_as_a_shift(tmp_path):
    from northfinder.cli.exits import EXIT_INCONSISTENT

    assert EXIT_INCONSISTENT == 3
    stepped = _stepped_recording(tmp_path)
    plot = tmp_path / "failed.png"
    code, out, err = run_cli("solve", str(stepped), "--plot", str(plot))
    assert code == 3, err
    assert "CONSISTENCY CHECK FAILED" in out and "fitting it shifts the azimuth by" in out
    assert "if so" not in out and not NEGATIVE_ZERO.search(out)
    assert plot.stat().st_size > 0
    doc = json.loads(run_cli("solve", str(stepped), "--json")[1])
    assert doc["consistent"] is False and doc["check"]["consistent"] is False
    # The same recording without the step passes and exits 0.
    code, out, _ = run_cli("solve", str(tmp_path / "run.npz"))
    assert code == 0 and "consistency check passed" in out


def test_the_plot_of_a_failed_check_says_so_in_its_title(tmp_path, monkeypatch):
    import matplotlib.figure

    titles: list[tuple[str, str]] = []
    real = matplotlib.figure.Figure.suptitle

    def spy(self: Any, t: str, **kw: Any) -> Any:
        titles.append((t, kw.get("color", "")))
        return real(self, t, **kw)

    monkeypatch.setattr(matplotlib.figure.Figure, "suptitle", spy)
    stepped = _stepped_recording(tmp_path)
    assert run_cli("solve", str(stepped), "--plot", str(tmp_path / "a.png"))[0] == 3
    assert run_cli("solve", str(tmp_path / "run.npz"), "--plot", str(tmp_path / "b.png"))[0] == 0
    (failed, colour), (passed, _) = titles
    assert failed.startswith("CONSISTENCY CHECK FAILED") and colour == "tab:red"
    assert "FAILED" not in passed
    assert not NEGATIVE_ZERO.search(failed + passed)


def test_no_negative_zero_in_nmea_or_the_notes():
    from northfinder.host.nmea import HeadingFix, nfdh_sentence

    fix = HeadingFix(42.0, 0.01, -0.0001, -0.0004, 4)
    body = nfdh_sentence(fix)
    assert ",0.000,0.000," in body and "-0.000" not in body
    assert pynmea2.parse(body, check=True).pitch == 0.0
    from northfinder.cli.output import dumps

    assert "-0.0" not in dumps({"notes": ["shift -0.0000 deg"], "x": -0.0})


# -- 4. solve: damaged lines skipped, complete windows of a cut log, a session picked ----------
def _logged_find(path: Path, seed: int, azimuth: str = "42.5") -> dict[str, Any]:
    return run_json(
        "find", "--sim", "--warmup", "0", "--window", "2", "--seed", str(seed),
        "--azimuth", azimuth, "--can-log", str(path),
    )  # fmt: skip


@pytest.fixture(scope="module")
def candump(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A candump log of a four-window find, and find's result."""
    path = tmp_path_factory.mktemp("solve") / "find.log"
    return path, _logged_find(path, 11)


def _sample_line(lines: list[str], fraction: float) -> int:
    """Index of the first SAMPLE_X frame (id 101) at or after this fraction of the log."""
    start = int(len(lines) * fraction)
    return next(i for i in range(start, len(lines)) if " 101#" in lines[i])


def test_solve_skips_a_damaged_line_with_a_warning_and_leaves_its_window_out(candump, tmp_path):
    path, found = candump
    lines = path.read_text().splitlines(keepends=True)
    bad = _sample_line(lines, 0.6)
    lines[bad] = "(17963.0) can0 1ZZ#GARBLED\n"
    damaged = tmp_path / "damaged.log"
    damaged.write_text("".join(lines))
    code, out, err = run_cli("solve", str(damaged), "--latitude", "34", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["source"]["skipped_lines"] == 1
    assert f"skipped 1 damaged line(s) of the log (first: line {bad + 1}" in err
    assert "warning" in err and "left out" in err
    assert len(doc["source"]["windows"]) == 3  # the window that lost a sample is left out
    assert abs(doc["azimuth_deg"] - found["azimuth_deg"]) < 4 * found["sigma_deg"]
    code, out, err = run_cli("solve", str(damaged), "--latitude", "34", "--strict")
    assert code == 1 and out == ""
    assert err.strip() == (
        f"northfinder solve: error: {damaged}:{bad + 1}: damaged line '(17963.0) can0 "
        "1ZZ#GARBLED' (ValueError: invalid literal for int() with base 16: '1ZZ'); --strict "
        "refuses a log with a damaged line (1 in all)"
    )
    # --on-gap report: the window that lost the sample is solved from the samples it holds
    code, out, err = run_cli("solve", str(damaged), "--latitude", "34", "--json", "--on-gap",
                             "report")  # fmt: skip
    assert code == 0, err
    doc = json.loads(out)
    assert len(doc["source"]["windows"]) == 4 and "left out" not in err
    assert [n for n in doc["notes"] if "1 of 400 sample ticks missing" in n]
    assert abs(doc["azimuth_deg"] - found["azimuth_deg"]) < 4 * found["sigma_deg"]


def test_solve_takes_the_complete_windows_of_a_cut_log(candump, tmp_path):
    path, _ = candump
    text = path.read_text()
    lines = text.splitlines(keepends=True)
    cut = tmp_path / "cut.log"
    cut.write_text("".join(lines[: _sample_line(lines, 0.9)]) + "(1796388094.28")  # mid-line
    code, out, err = run_cli("solve", str(cut), "--latitude", "34", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["source"]["windows"] == [1, 2, 3]
    assert "cut short" in err and "solving the complete windows 1, 2, 3" in err
    assert run_cli("solve", str(cut), "--latitude", "34", "--strict")[0] == 1


def test_solve_picks_a_session_and_windows_from_a_log_of_several(candump, tmp_path):
    path, first = candump
    second_log = tmp_path / "second.log"
    second = _logged_find(second_log, 12, azimuth="200")
    both = tmp_path / "both.log"
    both.write_text(path.read_text() + second_log.read_text())
    code, _, err = run_cli("solve", str(both), "--latitude", "34")
    assert code == 2 and "2 host sessions (1: 4 window(s), 2: 4 window(s))" in err
    assert "--session" in err
    for n, expected in ((1, first), (2, second)):
        doc = run_json("solve", str(both), "--latitude", "34", "--session", str(n))
        assert doc["azimuth_deg"] == pytest.approx(expected["azimuth_deg"], abs=1e-9)
        assert doc["source"]["session"] == n
    picked = run_json("solve", str(both), "--latitude", "34", "--session", "2", "--windows", "1,2")
    assert picked["source"]["windows"] == [1, 2] and len(picked["windows"]) == 2
    assert picked["positions"] == pytest.approx(second["positions"][:2], abs=1e-9)
    code, _, err = run_cli("solve", str(both), "--latitude", "34", "--session", "3")
    assert code == 2 and "no session 3" in err
    code, _, err = run_cli(
        "solve", str(both), "--session", "2", "--windows", "1,9", "--latitude", "34"
    )
    assert code == 2 and "no window 9" in err


# -- 5. -v link statistics, -vv traffic -----------------------------------------------------------
def _link_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("link: ")]
    assert len(lines) == 1, err
    return lines[0]


def test_v_prints_the_link_statistics_at_the_end():
    code, _, err = run_cli("find", *FAST, "--seed", "1", "-v")
    assert code == 0
    line = _link_line(err)
    m = re.search(r"(\d+) commands sent \((\d+) resent\), (\d+) replies \((\d+) refused", line)
    assert m is not None, line
    sent, resent, replies, refused = map(int, m.groups())
    assert sent == replies > 5 and resent == refused == 0
    assert "0 rejected, 0 foreign, 0 lost" in line and "samples" in line
    assert "the device counted 0 malformed, 0 dropped, 0 rejected" in line
    code, _, err = run_cli("find", *FAST, "--seed", "1")
    assert code == 0 and "link: " not in err  # only with -v


def test_the_link_summary_names_every_counter():
    from northfinder.driver.device_link import LinkStats

    stats = LinkStats(10, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0, commands_sent=20, replies_received=11)
    assert stats.summary().startswith(
        "20 commands sent (8 resent), 11 replies (0 refused, 7 stray)"
    )
    assert (
        "9 reply timeouts" in stats.summary() and "1 rejected, 2 foreign, 3 lost" in stats.summary()
    )


def test_vv_logs_every_command_and_reply_with_its_delay(caplog):
    import logging

    caplog.set_level(logging.DEBUG, logger="northfinder.driver")
    code, _, err = run_cli("find", *FAST, "--seed", "1", "-vv")
    assert code == 0
    sent = [r.getMessage() for r in caplog.records if r.getMessage().startswith("-> ")]
    replies = [r.getMessage() for r in caplog.records if r.getMessage().startswith("<- ")]
    assert sent and len(sent) == len(replies)
    assert any("RotateTo" in s for s in sent)
    assert all(re.search(r"<- [A-Z_]+ OK \(seq \d+\) after \d+\.\d ms$", r) for r in replies)
    n = int(re.search(r"(\d+) commands sent", _link_line(err)).group(1))  # type: ignore[union-attr]
    assert n == len(sent)


# -- 6. progress on every long command, plain where a bar cannot work -----------------------------
def _pty_with_width(columns: int, rows: int = 24) -> tuple[Any, int]:
    import fcntl
    import struct
    import termios

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    return os.fdopen(slave, "w"), master


def test_a_bar_needs_a_terminal_that_reports_its_width():
    from northfinder.cli.progress import progress_mode

    assert progress_mode(io.StringIO()) == "lines"
    assert progress_mode(io.StringIO(), enabled=False) == "off"
    # tqdm draws nothing on a terminal of no height (a pty whose size was never set: 0 x 0, or
    # 80 x 0 where only the width was): plain lines there.
    for columns, rows, mode in (
        (0, 24, "lines"),
        (80, 0, "lines"),
        (0, 0, "lines"),
        (80, 24, "bar"),
    ):
        stream, master = _pty_with_width(columns, rows)
        try:
            assert progress_mode(stream) == mode
        finally:
            stream.close()
            os.close(master)


@pytest.mark.parametrize(("columns", "rows"), [(0, 24), (80, 0)])
def test_progress_on_a_terminal_of_no_width_is_plain_lines(columns, rows):
    from northfinder.cli.progress import Progress

    stream, master = _pty_with_width(columns, rows)
    try:
        with Progress("study", unit="chunks", stream=stream) as bar:
            for done in range(1, 21):
                bar.count(done, 20)
        stream.flush()
        text = ""
        while "(100%)" not in text:  # a pty hands its bytes over in pieces
            ready, _, _ = select.select([master], [], [], 10.0)
            assert ready, text
            text += os.read(master, 65536).decode()
    finally:
        stream.close()
        os.close(master)
    lines = [line for line in text.replace("\r\n", "\n").split("\n") if line]
    assert lines[0] == "study: 1/20 chunks (5%)" and lines[-1] == "study: 20/20 chunks (100%)"
    assert len(lines) == 11 and "\r" not in "".join(lines)  # a line at each tenth, no redraws


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["study", "--runs", "300", "--window", "1"], "study: 1/1 chunks (100%)"),
        (["sweep", "--runs", "300", "--windows", "1,2"], "sweep: 2 studies of 300 runs"),
        (["find", *FAST, "--seed", "1"], "find: acquire position 2/2"),
    ],
)
def test_long_commands_show_progress_off_a_terminal(argv, expected):
    code, _, err = run_cli(*argv)
    assert code == 0, err
    assert expected in err.splitlines() or any(
        line.startswith(expected) for line in err.splitlines()
    ), err
    assert "\r" not in err  # no bar redraws in a log
    code, _, err = run_cli(*argv, "--json")
    assert code == 0 and expected.split(":")[0] + ": " not in err  # --json: quiet


def test_calibrate_shows_its_steps(tmp_path):
    rec = tmp_path / "run.npz"
    assert run_cli("record", str(rec), *FAST, "--seed", "1")[0] == 0
    code, _, err = run_cli("calibrate", str(rec))
    assert code == 0, err
    assert "calibrate: reading 1 recording(s)" in err and "calibrate: done" in err


# -- 7. one versioned envelope on every --json ----------------------------------------------------
@pytest.fixture(scope="module")
def validator() -> Any:
    import jsonschema

    from northfinder.host.results import schema

    s = schema()
    jsonschema.Draft202012Validator.check_schema(s)
    return jsonschema.Draft202012Validator(s)


def test_every_json_output_has_the_envelope_and_meets_the_schema(tmp_path, validator):
    from northfinder.host.results import SCHEMA, SCHEMA_VERSION

    rec = tmp_path / "run.npz"
    assert run_cli("record", str(rec), *FAST, "--seed", "1")[0] == 0
    datasheet = tmp_path / "datasheet.toml"
    datasheet.write_text("[gyro]\narw_dpsh = 0.003\n")
    commands = {
        "find": ["find", *FAST, "--seed", "1"],
        "solve": ["solve", str(rec)],
        "study": ["study", "--runs", "100", "--window", "1"],
        "sweep": ["sweep", "--runs", "100", "--windows", "1"],
        "simulate": ["simulate", "--window", "1", "--seed", "1"],
        "calibrate": ["calibrate", str(rec)],
        "conformance": ["conformance", "--sim", "--only", "identify"],
        "accept": [
            "accept",
            "--datasheet",
            str(datasheet),
            "--sim",
            "--seed",
            "1",
            "--static-s",
            "20",
            "-o",
            str(tmp_path / "acc"),
        ],
    }
    for command, argv in commands.items():
        code, out, err = run_cli(*argv, "--json")
        assert code == 0, (command, err)
        doc = json.loads(out)
        assert (doc["schema"], doc["schema_version"], doc["command"]) == (
            SCHEMA, SCHEMA_VERSION, command,
        )  # fmt: skip
        validator.validate(doc)


# -- 8. consistent defaults and wording ------------------------------------------------------------
def test_study_sweep_and_simulate_plan_by_default_as_find_does():
    from northfinder.host.plan import DEFAULT_POSITIONS_DEG

    assert DEFAULT_POSITIONS_DEG == (0.0, 180.0, 180.0, 0.0)
    find = run_json("find", "--sim", "--warmup", "0", "--window", "1", "--seed", "1")
    assert [w["commanded_deg"] for w in find["windows"]] == list(DEFAULT_POSITIONS_DEG)
    study = run_json("study", "--runs", "100", "--window", "1")
    assert study["plan"]["positions_deg"] == list(DEFAULT_POSITIONS_DEG)
    sweep = run_json("sweep", "--runs", "100", "--windows", "1")
    assert sweep["studies"][0]["plan"]["positions_deg"] == list(DEFAULT_POSITIONS_DEG)
    simulate = run_json("simulate", "--window", "1", "--seed", "1")
    assert len(simulate["windows"]) == 4


def test_the_text_says_solver_as_the_option_does():
    code, out, _ = run_cli("find", *FAST, "--seed", "1", "--solver", "least-squares")
    assert code == 0 and "solver least-squares" in out and "method " not in out


@pytest.mark.parametrize("command", ["find", "study", "solve", "sim", "dump"])
def test_version_after_the_command(command):
    from northfinder.host.results import package_version

    code, out, _ = run_cli(command, "--version")
    assert code == 0 and out.strip() == f"northfinder {package_version()}"


def test_latitude_is_among_the_options_a_device_needs():
    code, text, _ = run_cli("find", "--help")
    assert code == 0
    own = next(part for part in text.split("\n\n") if part.startswith("options:"))
    assert "--latitude" in own and "required with a device" in " ".join(own.split())
    truth = text[text.index("simulated truth:") :].split("\n\n")[0]
    assert "--latitude" not in truth
    # Still refused when a real device is given without it (never assumed).
    code, _, err = run_cli("find", "--serial", "loop://")
    assert code == 2 and "--latitude" in err


# -- 9. dump: a CAN log or a live bus decoded with the DBC ----------------------------------------
DUMP_LINE = re.compile(
    r"^\((\d+\.\d{6})\) (\S+) ([0-9A-F]{3})#([0-9A-F]*) ([RT]) :: (\w+)(?: node \d+)?\((.*)\)$"
)


def test_dump_decodes_every_frame_of_a_log_with_the_dbc(candump):
    import can

    from northfinder.driver.protocol.can import decode_can
    from northfinder.driver.protocol.messages import SampleX

    path, _ = candump
    code, out, err = run_cli("dump", str(path))
    assert code == 0, err
    lines = out.splitlines()
    with can.LogReader(str(path)) as reader:
        frames = list(reader)
    assert len(lines) == len(frames)
    names = set()
    for line, msg in zip(lines, frames, strict=True):
        m = DUMP_LINE.match(line)
        assert m is not None, line
        assert int(m.group(3), 16) == msg.arbitration_id and bytes.fromhex(m.group(4)) == msg.data
        assert m.group(5) == ("R" if msg.is_rx else "T")  # the direction the log holds
        names.add(m.group(6))
        if m.group(6) == "SAMPLE_X":
            ours = decode_can(msg.arbitration_id, bytes(msg.data)).message
            assert isinstance(ours, SampleX)
            gyro = float(re.search(r"GyroX: (\S+) deg/h", line).group(1))  # type: ignore[union-attr]
            assert gyro == pytest.approx(ours.gyro * 1e-4, rel=1e-5, abs=1e-9)
    assert names == {"COMMAND", "REPLY", "SAMPLE_X", "SAMPLE_Y", "SAMPLE_Z", "SAMPLE_AUX",
                     "STATUS", "STATUS_COUNTERS", "IDENTIFY"}  # fmt: skip


def test_dump_filters_by_id_time_and_session(candump, tmp_path):
    path, _ = candump
    code, out, _ = run_cli("dump", str(path), "--id", "COMMAND,51")
    assert code == 0
    kinds = {line.split(" :: ")[1].split("(")[0] for line in out.splitlines()}
    assert kinds == {"COMMAND", "REPLY"}
    assert "Opcode: ROTATE_TO" in out
    out = run_cli("dump", str(path), "--time-from", "1", "--time-to", "2")[1]
    times = [float(DUMP_LINE.match(line).group(1)) for line in out.splitlines()]  # type: ignore[union-attr]
    first = float(DUMP_LINE.match(run_cli("dump", str(path), "--count", "1")[1].strip()).group(1))  # type: ignore[union-attr]
    assert times and all(1.0 <= t - first <= 2.0 for t in times)
    second_log = tmp_path / "second.log"
    _logged_find(second_log, 13)
    both = tmp_path / "both.log"
    both.write_text(path.read_text() + second_log.read_text())
    n_first = len(path.read_text().splitlines())
    n_second = len(second_log.read_text().splitlines())
    assert len(run_cli("dump", str(both), "--session", "1")[1].splitlines()) == n_first
    assert len(run_cli("dump", str(both), "--session", "2")[1].splitlines()) == n_second
    assert run_cli("dump", str(both), "--session", "3")[1] == ""


def test_dump_skips_a_damaged_line_with_a_warning(candump, tmp_path):
    path, _ = candump
    lines = path.read_text().splitlines(keepends=True)
    lines[100] = "garbage\n"
    damaged = tmp_path / "damaged.log"
    damaged.write_text("".join(lines))
    code, out, err = run_cli("dump", str(damaged))
    assert code == 0 and len(out.splitlines()) == len(lines) - 1
    assert "skipped 1 damaged line(s) (first: line 101" in err
    code, out, err = run_cli("dump", str(damaged), "--strict")
    assert code == 2 and "breaks off after frame 100" in err and len(out.splitlines()) == 100


def test_dump_reads_a_live_bus():
    import threading

    import can

    from northfinder.driver.protocol.can import encode_can
    from northfinder.driver.protocol.messages import RotateTo

    channel = f"nf-dump-{os.getpid()}"
    stop = threading.Event()

    def send() -> None:
        with can.Bus(interface="virtual", channel=channel) as bus:
            frame = encode_can(RotateTo(7, 90_000_000))[0]
            while not stop.wait(0.01):
                bus.send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                                     is_extended_id=False))  # fmt: skip

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    try:
        code, out, err = run_cli("dump", "-i", "virtual", "-c", channel, "--count", "3",
                                 "--duration", "30")  # fmt: skip
    finally:
        stop.set()
        sender.join()
    assert code == 0, err
    lines = out.splitlines()
    assert len(lines) == 3 and all("COMMAND(Seq: 7, Opcode: ROTATE_TO" in line for line in lines)


def test_dump_refuses_what_it_cannot_do(tmp_path):
    assert run_cli("dump")[0] == 2
    code, _, err = run_cli("dump", str(tmp_path / "missing.log"))
    assert code == 2 and "no such file" in err
    code, _, err = run_cli("dump", str(tmp_path / "x.log"), "--id", "NOPE")
    assert code == 2 and "SAMPLE_X" in err


# -- 10. calibrate: an unresolved term at its bound, or refused, with the record it needs -------
@pytest.fixture(scope="module")
def short_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cal") / "short.npz"
    code, _, err = run_cli(
        "record", str(path), "--sim", "--warmup", "0", "--window", "20", "--seed", "4",
        "--sensor", "paper-rlg", "--positions", "0,180",
    )  # fmt: skip
    assert code == 0, err
    return path


def _toml(text: str) -> dict[str, Any]:
    import tomllib

    return tomllib.loads(text[text.index("# calibrated from") :])


def test_an_unresolved_term_is_written_at_its_bound_not_as_zero(short_recording):
    from northfinder.host.calibrate import calibrate, read_runs

    code, out, err = run_cli("calibrate", str(short_recording))
    assert code == 0, err
    cal = calibrate(read_runs([short_recording]))
    assert not cal.triad_fits["gyro"].resolved["bias_instability"]
    _, _, bound = cal.field_value(0, "bias_instability")
    written = _toml(out)["gyro"]["bias_instability_dph"]
    assert written == pytest.approx(bound, rel=1e-12) and written > 0
    assert "written at the bound" in out and "stretches of about" in out
    code, out, _ = run_cli("calibrate", str(short_recording), "--unresolved", "zero")
    assert code == 0 and _toml(out)["gyro"]["bias_instability_dph"] == 0.0
    # The simulator takes the conservative file.
    code, out, _ = run_cli("calibrate", str(short_recording), "--json")
    assert json.loads(out)["sensor"]["gyro"]["bias_instability_dph"] == pytest.approx(bound)


def test_calibrate_refuses_on_request_and_says_what_record_resolves_it(short_recording, tmp_path):
    out_toml = tmp_path / "cal.toml"
    code, _, err = run_cli(
        "calibrate", str(short_recording), "--unresolved", "refuse", "-o", str(out_toml)
    )
    assert code == 1 and not out_toml.exists()
    assert "do not resolve gyro.bias_instability_dph" in err and "stretches of about" in err


def test_the_record_that_resolves_a_bias_instability_is_the_closed_form(short_recording):
    """paper-rlg (ARW 0.0015 deg/sqrt(h)), B = 0.005 deg/h: the white noise's Allan deviation
    60 N / sqrt(tau) meets the floor 0.664 B at tau = (60 N / 0.664 B)^2 = 751 s; thirty times
    that is 6.1 h, so the 2 h recipe cannot resolve it."""
    from northfinder.host.calibrate import calibrate, read_runs

    cal = calibrate(read_runs([short_recording]))
    arw = cal.triad_fits["gyro"].coefficients["arw"] / 60.0  # deg/sqrt(h)
    assert arw == pytest.approx(0.0015, rel=0.1)  # the preset's, within the fit's scatter
    expected = 30 * (60 * arw) ** 2 / (2 * math.log(2) / math.pi * 0.005**2)
    assert cal.resolving_record_s(0.005) == pytest.approx(expected, rel=1e-12)
    assert 5.0 * 3600 < cal.resolving_record_s(0.005) < 7.5 * 3600  # far beyond 2 h
