"""The command line's answers to interrupts, devices that cannot be opened and bad numbers:
one line, the stated exit status (docs/cli.md, "Exit status"), never a traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from northfinder.cli import main
from northfinder.cli.exits import EXIT_INTERRUPTED, EXIT_RUNTIME, EXIT_USAGE
from northfinder.cli.output import dumps, plain_numbers

# A plan long enough that the run is still going when the signal comes, even on a fast machine.
LONG_SIM = ["--sim", "--window", "3600", "--warmup", "80000", "--timeout", "86400", "--seed", "1"]


def _restore_sigint() -> None:
    # A child of a non-interactive shell may inherit SIGINT ignored; a user's Ctrl-C is not.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(argv: list[str], after_s: float) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-c", "import sys; from northfinder.cli import main; "
           "sys.exit(main())", *argv]  # fmt: skip
    p = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=_restore_sigint, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    time.sleep(after_s)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    return subprocess.CompletedProcess(cmd, p.returncode, out, err)


@pytest.mark.realtime(alone=False)
@pytest.mark.parametrize(
    "argv",
    [
        ["find", *LONG_SIM],
        ["record", *LONG_SIM, "{tmp}/run.csv"],
        ["study", "--runs", "1000000", "--seed", "1"],
    ],
    ids=["find", "record", "study"],
)
def test_ctrl_c_exits_130_with_one_line(argv, tmp_path):
    # 3 s: past the interpreter's start (a signal there is Python's own), in the run or in the
    # loading of the command's module, both of which must say "interrupted".
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    done = _interrupt(argv, 3.0)
    assert done.returncode == EXIT_INTERRUPTED, done.stderr
    assert "Traceback" not in done.stderr
    assert ": interrupted" in done.stderr.strip().splitlines()[-1]
    assert "error" not in done.stderr


def test_a_can_bus_that_cannot_be_opened_is_a_runtime_failure(capsys):
    # socketcan on a channel that does not exist: the device cannot be opened now (exit 1),
    # as a serial port that cannot be opened.
    status = main(["find", "-i", "socketcan", "-c", "nosuch-can9", "--latitude", "34"])
    assert status == EXIT_RUNTIME
    assert "cannot open the CAN bus" in capsys.readouterr().err
    status = main(["find", "--serial", "/nonexistent/port", "--latitude", "34"])
    assert status == EXIT_RUNTIME


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["--azimuth", "1e20"], ["--azimuth", "-360 to 360"]),
        (["--azimuth", "nan"], ["--azimuth"]),
        (["--positions", "1e300"], ["--positions", "-720 to 720"]),
        (["--positions", "0,,180"], ["--positions", "empty"]),
        (["--positions", "0,inf"], ["--positions"]),
        (["--positions", ","], ["--positions"]),
        (["--pitch", "80"], ["--pitch", "tilt limit"]),
        (["--roll", "-inf"], ["--roll"]),
    ],
)
def test_bad_numbers_are_usage_errors_naming_the_option(argv, names, capsys):
    status = main(["find", "--sim", *argv])
    err = capsys.readouterr().err
    assert status == EXIT_USAGE
    assert "Traceback" not in err
    for name in names:
        assert name in err


def test_solver_and_method_must_agree(capsys):
    status = main(["find", "--sim", "--solver", "least-squares", "--method", "two-position"])
    err = capsys.readouterr().err
    assert status == EXIT_USAGE
    assert "--solver least-squares and --method two-position disagree" in err


def test_solver_and_method_that_agree_are_taken(capsys):
    status = main(
        ["find", "--sim", "--seed", "1", "--warmup", "1", "--window", "1",
         "--solver", "least-squares", "--method", "least-squares"]
    )  # fmt: skip
    assert status == 0
    assert "solver least-squares" in capsys.readouterr().out


@pytest.mark.parametrize("path", ["{tmp}", "{tmp}/missing/run.asc"])
def test_a_can_log_that_cannot_be_written_is_refused_before_the_run(path, tmp_path, capsys):
    status = main(["find", "--sim", "--can-log", path.replace("{tmp}", str(tmp_path))])
    err = capsys.readouterr().err
    assert status == EXIT_USAGE
    assert "--can-log" in err


@pytest.mark.parametrize(
    ("text", "plain"),
    [
        ("pitch -0.0000 deg, roll -0.0001 deg", "pitch 0.0000 deg, roll -0.0001 deg"),
        ("error -0.000e+00 deg", "error 0.000e+00 deg"),
        ("(-0)", "(0)"),
        ("+- 0.2094", "+- 0.2094"),
        ("-0.5 and 10-0.0", "-0.5 and 10-0.0"),
    ],
)
def test_no_negative_zero_is_printed(text, plain):
    assert plain_numbers(text) == plain


def test_no_negative_zero_in_json():
    assert dumps({"a": -0.0, "b": [-0.0, (-0.0, 2.5)]}, indent=None) == (
        '{"a": 0.0, "b": [0.0, [0.0, 2.5]]}'
    )


@pytest.mark.parametrize("json_flag", [[], ["--json"]], ids=["text", "json"])
def test_a_plan_search_that_finds_no_plan_fails(json_flag, capsys):
    status = main(["study", "--plan-budget", "0.001", "--runs", "0", *json_flag])
    captured = capsys.readouterr()
    assert status == EXIT_RUNTIME
    assert "no plan reaches plan time <= 0.001 s" in captured.err


def test_a_failed_check_names_a_given_latitude_as_a_possible_cause(tmp_path, capsys):
    rec = str(tmp_path / "run.npz")
    argv = ["record", rec, "--sim", "--seed", "2", "--warmup", "1", "--window", "60"]
    assert main([*argv, "--pitch", "3", "--roll", "2"]) == 0
    capsys.readouterr()
    assert main(["solve", rec]) == 0
    assert "wrong latitude" not in capsys.readouterr().out
    assert main(["solve", rec, "--latitude", "60"]) == 3  # a heading that failed its check
    out = capsys.readouterr().out
    assert "CONSISTENCY CHECK FAILED" in out
    assert "wrong latitude: 60 deg (from --latitude)" in out
