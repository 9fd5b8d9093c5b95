"""``cli``: bad input over every subcommand, each case its own process (a section of
``bench_robustness.py``)."""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from robustness.control import SIM, simulator

#: Options that make ``--sim`` runs short (no warm-up, 1 s windows, fast).
QUICK = ["--sim", "--warmup", "0", "--window", "1", "--speed", "500", "--seed", "1"]


@dataclass(frozen=True)
class CliCase:
    """One bad-input case: the arguments, the exit status it must give and a word the error line
    must contain (the argument or field it names), case-insensitive."""

    command: str
    argv: tuple[str, ...]
    exit: int
    names: str


def _files(tmp: str) -> dict[str, str]:
    """Bad input files for the sweep: sensor TOMLs and mutated recordings, by name."""
    out: dict[str, str] = {}
    for name, body in {
        "rate-tiny.toml": "[table]\nmax_rate_dps = 1e-300\n",
        "rate-huge.toml": "[table]\nmax_rate_dps = 1e300\n",
        "impulses.toml": "[disturbance]\nimpulse_rate_hz = 1e9\n[gyro]\nimpulse_dph = 10\n",
        "arw-huge.toml": "[gyro]\narw_dpsh = 1e300\n",
        "not-toml.toml": "this is = = not toml\n",
        "unknown-field.toml": "[gyro]\nwarp_factor = 9\n",
        "string-value.toml": '[gyro]\narw_dpsh = "small"\n',
        "section-value.toml": "gyro = 3\n",
        "nan.toml": "[gyro]\narw_dpsh = nan\n",
        "negative.toml": "[table]\nsettle_s = -1\n",
        "vec.toml": "[gyro]\nbias_dph = [1, 2]\n",
        "empty.csv": "",
    }.items():
        _write(out, tmp, name, body)
    good, good4 = _good_recordings(out, tmp)
    head, rows = _csv_files(out, tmp, good)
    _npz_files(out, tmp, good4)
    _log_files(out, tmp, head, rows)
    return out


def _write(out: dict[str, str], tmp: str, name: str, text: str) -> str:
    """Write ``text`` to the file ``name`` in ``tmp`` and keep its path in ``out``."""
    path = os.path.join(tmp, name)
    with open(path, "w") as f:
        f.write(text)
    out[name] = path
    return path


def _good_recordings(out: dict[str, str], tmp: str) -> tuple[str, str]:
    """Two good recordings of simulated finds: a two-position CSV and a four-position NPZ."""
    from northfinder.cli import main as cli

    good = os.path.join(tmp, "good.csv")
    good4 = os.path.join(tmp, "good4.npz")
    with contextlib.redirect_stdout(io.StringIO()):
        cli(["record", good, *QUICK, "--window", "2", "--positions", "0,180"])
        cli(["record", good4, *QUICK, "--window", "2", "--positions", "0,180,180,0"])
    out["good.csv"], out["good4.npz"] = good, good4
    return good, good4


def _csv_files(out: dict[str, str], tmp: str, good: str) -> tuple[str, list[str]]:
    """Recordings with a broken header (metadata): the good CSV's header and its rows."""
    text = open(good).read()
    head, _, body = text.partition("window,")
    body = "window," + body

    def meta(key: str, value: str | None, name: str) -> None:
        lines = [ln for ln in head.splitlines() if not ln.startswith(f"# {key} =")]
        if value is not None:
            lines.append(f"# {key} = {value}")
        _write(out, tmp, name, "\n".join(lines) + "\n" + body)

    meta("sample_rate_hz", "0", "rate-0.csv")
    meta("sample_rate_hz", '"fast"', "rate-string.csv")
    meta("sample_rate_hz", "-200", "rate-negative.csv")
    meta("sample_rate_hz", "1e300", "rate-huge.csv")
    meta("sample_rate_hz", None, "rate-missing.csv")
    meta("truth", "[1, 2]", "truth-list.csv")
    meta("truth", '{"azimuth_deg": "north"}', "truth-string.csv")
    meta("truth", '{"pitch_deg": 0}', "truth-partial.csv")
    meta("truth", '{"azimuth_deg": 1e400}', "truth-inf.csv")
    meta("latitude_deg", None, "latitude-missing.csv")
    meta("latitude_deg", "95", "latitude-95.csv")
    meta("latitude_deg", '"34N"', "latitude-string.csv")
    meta("plan", "7", "plan-number.csv")
    meta("format", '"other"', "format-other.csv")
    meta("version", "99", "version-99.csv")
    _write(out, tmp, "meta-not-json.csv", head + "# broken = {\n" + body)
    _write(out, tmp, "no-header.csv", head)
    _write(out, tmp, "header-only.csv", head + body.splitlines()[0] + "\n")
    rows = body.splitlines()
    _csv_row_files(out, tmp, head, rows)
    return head, rows


def _csv_row_files(out: dict[str, str], tmp: str, head: str, rows: list[str]) -> None:
    """Recordings with a broken row, or rows that make no find."""

    def cell(column: int, value: str, name: str, row: int = 5) -> None:
        mutated = list(rows)
        parts = mutated[row].split(",")
        parts[column] = value
        mutated[row] = ",".join(parts)
        _write(out, tmp, name, head + "\n".join(mutated) + "\n")

    cell(2, "nan", "counter-nan.csv")
    cell(2, "1.5", "counter-fraction.csv")
    cell(2, "1e30", "counter-huge.csv")
    cell(12, "300", "validity-300.csv")
    cell(12, "-1", "validity-negative.csv")
    cell(12, "2.5", "validity-fraction.csv")
    cell(0, "-1", "window-negative.csv")
    cell(0, "0.5", "window-fraction.csv")
    cell(1, "nan", "commanded-nan.csv")
    cell(4, "nan", "gyro-nan.csv")
    cell(4, "1e300", "gyro-huge.csv")
    cell(4, "abc", "gyro-text.csv")
    cell(10, "1e300", "table-huge.csv")
    _write(out, tmp, "short-row.csv", head + "\n".join([*rows[:6], rows[6][:20], *rows[7:]]) + "\n")
    one = [r for r in rows[1:] if r.startswith("0,")]
    _write(out, tmp, "one-window.csv", head + rows[0] + "\n" + "\n".join(one) + "\n")
    close = [r.replace(",180.000000,", ",0.500000,", 1) for r in rows[1:]]
    _write(out, tmp, "positions-close.csv", head + rows[0] + "\n" + "\n".join(close) + "\n")
    flagged = [",".join([*r.split(",")[:12], "0"]) for r in rows[1:]]
    _write(out, tmp, "validity-clear.csv", head + rows[0] + "\n" + "\n".join(flagged) + "\n")


def _npz_files(out: dict[str, str], tmp: str, good4: str) -> None:
    """NPZ recordings of broken metadata, shapes and types."""
    import numpy as np

    with np.load(good4) as data:
        arrays = {k: data[k] for k in data.files}
    for name, meta_json in {
        "meta-list.npz": "[1, 2, 3]",
        "meta-string.npz": '"hello"',
        "meta-broken.npz": "{",
    }.items():
        np.savez(os.path.join(tmp, name), **{**arrays, "meta_json": np.array(meta_json)})
        out[name] = os.path.join(tmp, name)
    np.savez(
        os.path.join(tmp, "gyro-shape.npz"), **{**arrays, "gyro_dph": arrays["gyro_dph"][:, :2]}
    )
    out["gyro-shape.npz"] = os.path.join(tmp, "gyro-shape.npz")
    np.savez(os.path.join(tmp, "counter-float.npz"),
             **{**arrays, "counter": arrays["counter"].astype(float) + 0.5})  # fmt: skip
    out["counter-float.npz"] = os.path.join(tmp, "counter-float.npz")
    np.savez(
        os.path.join(tmp, "no-meta.npz"), **{k: v for k, v in arrays.items() if k != "meta_json"}
    )
    out["no-meta.npz"] = os.path.join(tmp, "no-meta.npz")
    _write(out, tmp, "garbage.npz", "PK\x03\x04 not really a zip")
    _write(out, tmp, "pickle.npz", "x")  # numpy could only unpickle it
    np.savez(os.path.join(tmp, "half.npz"),
             **{**arrays, "gyro_dph": arrays["gyro_dph"].astype(np.float16)})  # fmt: skip
    out["half.npz"] = os.path.join(tmp, "half.npz")


def _log_files(out: dict[str, str], tmp: str, head: str, rows: list[str]) -> None:
    """Sensor TOMLs of out-of-range fields, CAN logs of junk, a rotated log with a gap."""
    from northfinder.cli import main as cli

    for name, body in {
        "ambient-1e9.toml": "[thermal]\nambient_c = 1e9\n",
        "misalignment-1e9.toml": "[gyro]\nmisalignment_urad = 1e9\n",
        "indexing-45.toml": "[table]\nindexing_error_deg = 45\n",
    }.items():
        _write(out, tmp, name, body)
    _write(out, tmp, "short.blf", "LOGG")  # a BLF too short for its header
    # CAN logs of binary junk, a FIFO and a folder named as logs, a DBC that is none.
    junk = bytes((i * 7919 + 13) % 256 for i in range(100_000))
    for name in ("junk.trc", "junk.asc", "junk.log", "junk.dbc"):
        with open(os.path.join(tmp, name), "wb") as fh:
            fh.write(junk)
        out[name] = os.path.join(tmp, name)
    out["fifo.log"] = os.path.join(tmp, "fifo.log")
    os.mkfifo(out["fifo.log"])
    out["folder.log"] = os.path.join(tmp, "folder.log")
    os.mkdir(out["folder.log"])
    # A CSV of more windows than a recording holds (two samples each, under a megabyte).
    many = [rows[0]] + [
        f"{w},0.000000,{2 * w + i},{(2 * w + i) / 200:.6f},1,1,1,0,0,9.8,0,20,3"
        for w in range(1100) for i in range(2)
    ]  # fmt: skip
    _write(out, tmp, "windows-1100.csv", head + "\n".join(many) + "\n")
    # A rotated CAN log of a four-window find, and the same without one of its middle parts.
    rotated = os.path.join(tmp, "rot", "run.log")
    os.makedirs(os.path.dirname(rotated))
    with contextlib.redirect_stdout(io.StringIO()):
        cli(["find", *QUICK, "--window", "2", "--can-log", rotated, "--can-log-rotate", "64K"])
    from northfinder.driver.framelog import log_parts

    parts = [str(x) for x in log_parts(rotated)] + [rotated]
    out["rotated"] = " ".join(parts)
    out["rotated-gap"] = " ".join(parts[:1] + parts[2:])


def cli_cases(
    f: dict[str, str], control: str, silent: str, tmp: str, garbage: str | None = None
) -> list[CliCase]:
    """Every bad-input case of the sweep. ``control``: a live simulator's control address;
    ``silent``: a TCP address that accepts connections and never answers; ``garbage``: one that
    sends random bytes (a serial line at another baud rate, through pyserial's socket://)."""
    c: list[CliCase] = []

    def add(command: str, argv: list[str], exit: int, names: str) -> None:
        c.append(CliCase(command, (command, *argv), exit, names))

    missing_dir = os.path.join(tmp, "no", "such", "dir")
    _find_and_record_cases(add, f, tmp, missing_dir)
    _solve_and_dump_cases(add, f, tmp, missing_dir, garbage)
    _study_cases(add, f, tmp, missing_dir)
    _simulate_and_sim_cases(add, f, tmp, missing_dir)
    _simctl_cases(add, tmp, control, silent)
    _conformance_and_calibrate_cases(add, f, tmp, missing_dir)
    return c


def _device_rows(tmp: str) -> list[tuple[list[str], int, str]]:
    """The device options of ``find`` and ``record``: (argv, exit status, names)."""
    return [
        ([], 2, "choose exactly one device"),
        (["--sim", "--serial", "/dev/null"], 2, "choose exactly one device"),
        (["--serial", "/dev/null"], 2, "--latitude"),
        (["-i", "virtual", "-c", "nf-sweep"], 2, "--latitude"),
        (["--serial", os.path.join(tmp, "no-port")], 2, "--latitude"),
        (["--serial", os.path.join(tmp, "no-port"), "--latitude", "34"], 1, "no-port"),
        (["--serial", "/dev/null", "--latitude", "34"], 1, "/dev/null"),
        (["-i", "virtual", "-c", "nf-sweep", "--latitude", "34"], 1, "reply"),
        (["-i", "no-such-interface", "-c", "x", "--latitude", "34"], 2, "interface"),
        (
            ["--serial", "/dev/null", "--latitude", "34", "--reply-timeout", "0.05"],
            2,
            "--reply-timeout",
        ),
        (
            ["--serial", "/dev/null", "--latitude", "34", "--reply-timeout", "1e300"],
            2,
            "--reply-timeout",
        ),
        (
            ["--serial", "/dev/null", "--latitude", "34", "--link-timeout", "1e300"],
            2,
            "--link-timeout",
        ),
        (
            ["--serial", "/dev/null", "--latitude", "34", "--link-timeout", "0"],
            2,
            "--link-timeout",
        ),
        (["--serial", "/dev/null", "--latitude", "34", "--speed", "5"], 2, "--speed"),
        (["--serial", "/dev/null", "--latitude", "34", "--sensor", "mems"], 2, "--sensor"),
        (["--serial", "/dev/null", "--latitude", "91"], 2, "latitude"),
        (["--serial", "/dev/null", "--latitude", "nan"], 2, "--latitude"),
    ]


def _plan_rows(f: dict[str, str], tmp: str) -> list[tuple[list[str], int, str]]:
    """The plan and simulation options of ``find`` and ``record`` (with ``--sim``)."""
    return [
        ([*QUICK, "--positions", "0,1"], 2, "positions"),
        ([*QUICK, "--positions", ","], 2, "--positions"),
        ([*QUICK, "--positions", "0,nan"], 2, "--positions"),
        ([*QUICK, "--positions", "0,1e400"], 2, "--positions"),
        ([*QUICK, "--positions", ",".join(["0", "180"] * 200)], 2, "positions"),
        ([*QUICK, "--window", "0"], 2, "--window"),
        ([*QUICK, "--window", "0.01"], 2, "window"),
        ([*QUICK, "--window", "1e7"], 2, "window"),
        ([*QUICK, "--window", "abc"], 2, "--window"),
        ([*QUICK, "--settle", "-1"], 2, "settle"),
        ([*QUICK, "--settle", "1e9"], 2, "settle"),
        ([*QUICK, "--speed", "0"], 2, "--speed"),
        ([*QUICK, "--speed", "1e300"], 2, "speed"),
        ([*QUICK, "--warmup", "-1"], 2, "--warmup"),
        ([*QUICK, "--warmup", "1e300"], 2, "warmup"),
        ([*QUICK, "--timeout", "0"], 2, "--timeout"),
        ([*QUICK, "--timeout", "1e300"], 2, "timeout"),
        ([*QUICK, "--latitude", "91"], 2, "latitude"),
        ([*QUICK, "--latitude", "89.99"], 2, "latitude"),
        ([*QUICK, "--pitch", "40"], 2, "pitch"),  # beyond the solvers' tilt limit
        ([*QUICK, "--azimuth", "inf"], 2, "--azimuth"),
        ([*QUICK, "--seed", "-1"], 2, "--seed"),
        ([*QUICK, "--seed", "1.5"], 2, "--seed"),
        ([*QUICK, "--node-id", "0"], 2, "--node-id"),
        ([*QUICK, "--baud", "0"], 2, "--baud"),
        ([*QUICK, "--sensor", "no-such-preset"], 2, "no-such-preset"),
        ([*QUICK, "--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        ([*QUICK, "--sensor", f["rate-huge.toml"]], 2, "max_rate_dps"),
        ([*QUICK, "--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        ([*QUICK, "--sensor", f["arw-huge.toml"]], 2, "arw_dpsh"),
        ([*QUICK, "--sensor", f["not-toml.toml"]], 2, "not-toml"),
        ([*QUICK, "--sensor", f["unknown-field.toml"]], 2, "warp_factor"),
        ([*QUICK, "--sensor", f["string-value.toml"]], 2, "arw_dpsh"),
        ([*QUICK, "--sensor", f["section-value.toml"]], 2, "gyro"),
        ([*QUICK, "--sensor", f["nan.toml"]], 2, "arw_dpsh"),
        ([*QUICK, "--sensor", f["negative.toml"]], 2, "settle_s"),
        ([*QUICK, "--sensor", f["vec.toml"]], 2, "bias_dph"),
        ([*QUICK, "--sensor", tmp], 2, "sensor"),
        ([*QUICK, "--denoise", "magic"], 2, "--denoise"),
        ([*QUICK, "--method", "pairwise"], 2, "--method"),
        ([*QUICK, "--method", "two-position", "--positions", "0,90,180"], 2, "two-position"),
        ([*QUICK, "--reply-timeout", "0.05"], 2, "--reply-timeout"),
        ([*QUICK, "--reply-timeout", "1e300"], 2, "--reply-timeout"),
        ([*QUICK, "--link-timeout", "1e300"], 2, "--link-timeout"),
        ([*QUICK, "--no-such-option"], 2, "unrecognized"),
    ]


def _find_and_record_cases(
    add: Callable[[str, list[str], int, str], None], f: dict[str, str], tmp: str, missing_dir: str
) -> None:
    # find and record share the device and plan options: every case is run for both.
    for cmd, lead in (("find", []), ("record", [os.path.join(tmp, "out.npz")])):
        for argv, exit, names in _device_rows(tmp) + _plan_rows(f, tmp):
            add(cmd, [*lead, *argv], exit, names)
    add("find", [*QUICK, "--record", os.path.join(tmp, "x.txt")], 2, "--record")
    add("find", [*QUICK, "--record", os.path.join(missing_dir, "x.csv")], 2, "--record")
    add("record", [os.path.join(tmp, "x.txt"), *QUICK], 2, "x.txt")
    add("record", [os.path.join(missing_dir, "x.npz"), *QUICK], 2, "x.npz")
    add("record", [tmp + "/", *QUICK], 2, "file")
    add("record", [], 2, "file")


def _solve_and_dump_cases(
    add: Callable[[str, list[str], int, str], None],
    f: dict[str, str],
    tmp: str,
    missing_dir: str,
    garbage: str | None,
) -> None:
    # solve: every broken recording
    bad_recordings = {
        "rate-0.csv": "sample_rate_hz", "rate-string.csv": "sample_rate_hz",
        "rate-negative.csv": "sample_rate_hz", "rate-huge.csv": "sample_rate_hz",
        "rate-missing.csv": "sample_rate_hz", "truth-list.csv": "truth",
        "truth-string.csv": "truth", "truth-partial.csv": "truth", "truth-inf.csv": "truth",
        "latitude-missing.csv": "--latitude", "latitude-95.csv": "latitude",
        "latitude-string.csv": "latitude", "plan-number.csv": "plan",
        "format-other.csv": "format", "version-99.csv": "version",
        "meta-not-json.csv": "line", "no-header.csv": "header", "header-only.csv": "samples",
        "empty.csv": "empty.csv", "counter-nan.csv": "counter", "counter-fraction.csv": "counter",
        "counter-huge.csv": "counter", "validity-300.csv": "validity",
        "validity-negative.csv": "validity", "validity-fraction.csv": "validity",
        "window-negative.csv": "window", "window-fraction.csv": "window",
        "commanded-nan.csv": "commanded_deg", "gyro-nan.csv": "gyro",
        "gyro-huge.csv": "gyro", "gyro-text.csv": "gyro_x_dph", "table-huge.csv": "table_deg",
        "short-row.csv": "line", "one-window.csv": "two positions",
        "positions-close.csv": "positions", "meta-list.npz": "meta_json",
        "meta-string.npz": "meta_json", "meta-broken.npz": "meta_json",
        "gyro-shape.npz": "gyro_dph", "counter-float.npz": "counter", "no-meta.npz": "meta_json",
        "garbage.npz": "garbage.npz",
    }  # fmt: skip
    for name, names in bad_recordings.items():
        add("solve", [f[name]], 2, names)
    add("solve", [f["validity-clear.csv"]], 1, "unusable")
    add("solve", [os.path.join(tmp, "absent.csv")], 2, "absent.csv")
    add("solve", [os.path.join(tmp, "run.txt")], 2, "run.txt")
    add("solve", [tmp + "/x.csv"], 2, "x.csv")
    add("solve", [f["good.csv"], "--latitude", "95"], 2, "latitude")
    add("solve", [f["good.csv"], "--latitude", "inf"], 2, "--latitude")
    add("solve", [f["good4.npz"], "--method", "two-position"], 2, "two-position")
    add("solve", [f["good.csv"], "--denoise", "magic"], 2, "--denoise")
    add("solve", [f["good.csv"], "--plot", os.path.join(missing_dir, "p.png")], 2, "--plot")
    add("solve", [], 2, "file")
    # recordings and logs the reader must bound or refuse (issue 25 item 7)
    add("solve", [f["half.npz"]], 2, "float16")
    add("solve", [f["pickle.npz"]], 2, "pickle.npz")
    add("solve", [f["windows-1100.csv"]], 2, "windows")
    add("solve", [f["short.blf"]], 2, "short.blf")
    add("solve", [*f["rotated-gap"].split(), "--latitude", "34", "--strict"], 1, "missing")
    add("dump", [f["short.blf"]], 2, "short.blf")
    add("dump", [*f["rotated-gap"].split(), "--strict"], 2, "missing")
    add("dump", [os.path.join(tmp, "no-such-*.log")], 2, "no file matches")
    for name in ("junk.trc", "junk.asc", "junk.log"):
        add("dump", [f[name]], 2, name)
    add("dump", [f["fifo.log"]], 2, "FIFO")
    add("dump", [f["folder.log"]], 2, "folder")
    add("dump", [f["rotated"].split()[0], "--dbc", f["junk.dbc"]], 2, "junk.dbc")
    for name, field in (("ambient-1e9.toml", "ambient_c"), ("misalignment-1e9.toml",
                        "misalignment_urad"), ("indexing-45.toml", "indexing_error_deg")):  # fmt: skip
        add("simulate", ["--sensor", f[name]], 2, field)
        add("find", [*QUICK, "--sensor", f[name]], 2, field)
    # log rotation refused before any work
    for argv, names in [
        (["--can-log-rotate", "1M"], "--can-log-rotate"),
        (["--can-log", os.path.join(tmp, "r.db"), "--can-log-rotate", "1h"], "rotates"),
        (["--can-log", os.path.join(tmp, "r.log"), "--can-log-rotate", "10m"], "--can-log-rotate"),
        (["--can-log", os.path.join(tmp, "r.log"), "--can-log-rotate", "12B"], "4K"),
    ]:
        add("find", [*QUICK, *argv], 2, names)
    add("sim", ["--pty", "--log-rotate", "1h"], 2, "--log-rotate")
    if garbage is not None:  # a serial link whose bytes never parse: another baud rate
        add("find", ["--serial", f"socket://{garbage}", "--latitude", "34"], 1, "wrong baud rate")


def _study_cases(
    add: Callable[[str, list[str], int, str], None], f: dict[str, str], tmp: str, missing_dir: str
) -> None:
    # study
    for argv, exit, names in [
        (["--set", "gyro.arw_dpsh=1e300"], 2, "arw_dpsh"),
        (["--set", "gyro.arw_dpsh=abc"], 2, "arw_dpsh"),
        (["--set", "gyro.arw_dpsh=-1"], 2, "arw_dpsh"),
        (["--set", "gyro.warp=1"], 2, "warp"),
        (["--set", "nothing=1"], 2, "nothing"),
        (["--set", "=1"], 2, "--set"),
        (["--set", "table.max_rate_dps=1e-300"], 2, "max_rate_dps"),
        (["--set", "disturbance.impulse_rate_hz=1e9"], 2, "impulse_rate_hz"),
        (["--denoise", "moving-average", "--denoise-option", "window=abc"], 2, "window"),
        (["--denoise", "moving-average", "--denoise-option", "window=0"], 2, "window"),
        (["--denoise", "moving-average", "--denoise-option", "window=1e9"], 2, "window"),
        (
            [
                "--denoise",
                "moving-average",
                "--denoise-option",
                "window=5",
                "--denoise-option",
                "nope=1",
            ],
            2,
            "nope",
        ),
        (["--denoise", "wavelet-2p", "--denoise-option", "level=99"], 2, "level"),
        (["--denoise-option", "window=5"], 2, "window"),
        (["--runs", "0"], 2, "--runs"),
        (["--runs", "-5"], 2, "--runs"),
        (["--runs", "100000000000"], 2, "--runs"),
        (["--runs", "1e3"], 2, "--runs"),
        (["--window", "1e7"], 2, "window"),
        (["--window", "0"], 2, "--window"),
        (["--rate", "1e9"], 2, "rate"),
        (["--rate", "0"], 2, "--rate"),
        (["--warmup", "1e300"], 2, "warmup"),
        (["--settle", "1e300"], 2, "settle"),
        (["--positions", "0,1"], 2, "positions"),
        (["--positions", ",".join(["0", "180"] * 200)], 2, "positions"),
        (["--latitude", "90"], 2, "latitude"),
        (["--pitch", "40"], 2, "pitch"),
        (["--seed", "-1"], 2, "--seed"),
        (["--bias-step", "1e300"], 2, "--bias-step"),
        (["--plan-budget", "1e300"], 2, "--plan-budget"),
        (["--plan-budget", "0.001"], 1, "no plan"),  # the search ran and found none
        (["--plan-target", "1e-9", "--runs", "0"], 1, "no plan"),
        (["--top", "0"], 2, "--top"),
        (["--top", "100000000"], 2, "--top"),
        (["--sweep", "0,-1", "--plot", os.path.join(tmp, "s.png")], 2, "--sweep"),
        (["--plot", os.path.join(missing_dir, "s.png")], 2, "--plot"),
        (["--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        (["--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        (["--plan", "no-such-plan"], 2, "--plan"),
        (["--solver", "pairwise", "--positions", "0,180"], 0, ""),
    ]:
        add("study", [*argv, "--runs", "20"] if "--runs" not in argv else argv, exit, names)


def _simulate_and_sim_cases(
    add: Callable[[str, list[str], int, str], None], f: dict[str, str], tmp: str, missing_dir: str
) -> None:
    # simulate
    for argv, exit, names in [
        (["--window", "1e7"], 2, "window"),
        (["--window", "-1"], 2, "--window"),
        (["--rate", "1e9"], 2, "rate"),
        (["--rate", "0"], 2, "--rate"),
        (["--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        (["--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        (["--sensor", f["rate-huge.toml"]], 2, "max_rate_dps"),
        (["--sensor", f["arw-huge.toml"]], 2, "arw_dpsh"),
        (["--positions", ",".join(["0", "180"] * 200)], 2, "positions"),
        (["--positions", "0,nan"], 2, "--positions"),
        (["--latitude", "95"], 2, "latitude"),
        (["--pitch", "60"], 2, "pitch"),
        (["--seed", "-1"], 2, "--seed"),
        (["--azimuth", "1e400"], 2, "--azimuth"),
    ]:
        add("simulate", argv, exit, names)

    # sim
    for argv, exit, names in [
        ([], 2, "choose exactly one link"),
        (["--pty", "--slcan-pty"], 2, "choose exactly one link"),
        (["--pty", "--baud", "0"], 2, "--baud"),
        (["--pty", "--baud", "-9600"], 2, "--baud"),
        (["--pty", "--speed", "0"], 2, "--speed"),
        (["--pty", "--speed", "1e300"], 2, "speed"),
        (["--pty", "--duration", "1e300"], 2, "duration"),
        (["--pty", "--duration", "0"], 2, "--duration"),
        (["--pty", "--warmup", "-5"], 2, "--warmup"),
        (["--pty", "--warmup", "1e300"], 2, "warmup"),
        (["--pty", "--latitude", "95"], 2, "latitude"),
        (["--pty", "--pitch", "60"], 2, "pitch"),
        (["--pty", "--seed", "-1"], 2, "--seed"),
        (["--pty", "--node-id", "16"], 2, "--node-id"),
        (["--pty", "--sensor", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        (["--pty", "--sensor", f["impulses.toml"]], 2, "impulse_rate_hz"),
        (["--pty", "--sensor", "nope"], 2, "nope"),
        (["--pty", "--control", "8.8.8.8:7700"], 2, "loopback"),
        (["--pty", "--control", "127.0.0.1:99999"], 2, "port"),
        (["--pty", "--control", "nonsense"], 2, "control"),
        (["--pty", "--control", f"unix:{f['good.csv']}"], 2, "not a socket"),
        (["--pty", "--control", "unix:" + os.path.join(missing_dir, "s")], 2, "cannot listen"),
        (["--serial", os.path.join(tmp, "no-port")], 1, "no-port"),
        (["-i", "no-such-interface", "-c", "x"], 2, "interface"),
    ]:
        add("sim", argv, exit, names)


def _simctl_cases(
    add: Callable[[str, list[str], int, str], None], tmp: str, control: str, silent: str
) -> None:
    # simctl, against a live simulator and a listener that never answers
    for argv, exit, names in [
        ([], 2, "address"),
        ([control], 2, "op"),
        ([control, "warp"], 2, "warp"),
        ([control, "drop", "count"], 2, "count"),
        ([control, "drop", "count=abc"], 2, "count"),
        ([control, "drop", "count=-1"], 2, "count"),
        ([control, "drop", "count=1e30"], 2, "count"),
        ([control, "drop", "speed=3"], 2, "speed"),
        ([control, "bias_step", "gyro_dph=[NaN,0,0]"], 2, "gyro_dph"),
        ([control, "vibration", "hz=NaN"], 2, "hz"),
        ([control, "impulses", "count=1000000"], 2, "count"),
        ([control, "impulses", "gyro_dph=NaN"], 2, "gyro_dph"),
        ([control, "set_sensor", 'values={"gyro.arw_dpsh": -1}'], 2, "arw_dpsh"),
        ([control, "set_sensor", 'values={"table.max_rate_dps": 1e300}'], 2, "max_rate_dps"),
        ([control, "set_truth", "latitude_deg=95"], 2, "latitude_deg"),
        ([control, "speed", "value=0"], 2, "value"),
        (["nonsense", "status"], 2, "nonsense"),
        (["8.8.8.8:7700", "status"], 2, "loopback"),
        (["127.0.0.1:1", "status"], 1, "127.0.0.1:1"),
        (["unix:" + os.path.join(tmp, "absent.sock"), "status"], 1, "absent.sock"),
        ([silent, "status"], 1, "no reply"),
    ]:
        add("simctl", argv, exit, names)


def _conformance_and_calibrate_cases(
    add: Callable[[str, list[str], int, str], None], f: dict[str, str], tmp: str, missing_dir: str
) -> None:
    # conformance
    for argv, exit, names in [
        ([], 2, "choose exactly one link"),
        (["--serial", os.path.join(tmp, "no-port")], 1, "no-port"),
        (["--serial", "/dev/null", "--only", "no.such.check"], 2, "no.such.check"),
        (["--serial", "/dev/null", "--time-scale", "0"], 2, "--time-scale"),
        (["--serial", "/dev/null", "--time-scale", "1e300"], 2, "time-scale"),
        (["--serial", "/dev/null", "--stream-seconds", "1e9"], 2, "stream-seconds"),
        (["--serial", "/dev/null", "--angles", "0,nan"], 2, "--angles"),
        (["--serial", "/dev/null", "--reply-limit-ms", "0"], 2, "--reply-limit-ms"),
        (["--serial", "/dev/null", "--ready-timeout", "1e300"], 2, "ready-timeout"),
        (["--serial", "/dev/null", "--junit", os.path.join(missing_dir, "j.xml")], 2, "--junit"),
        (["-i", "no-such-interface", "-c", "x"], 2, "interface"),
        (["-i", "virtual", "-c", "x", "--node-id", "99"], 2, "--node-id"),
    ]:
        add("conformance", argv, exit, names)

    # calibrate
    for argv, exit, names in [
        ([], 2, "recording"),
        ([os.path.join(tmp, "absent.npz")], 2, "absent.npz"),
        ([f["counter-nan.csv"]], 2, "counter"),
        ([f["meta-list.npz"]], 2, "meta_json"),
        ([f["rate-0.csv"]], 2, "sample_rate_hz"),
        ([f["good.csv"], "--move-tau", "0"], 2, "--move-tau"),
        ([f["good.csv"], "--heat-tau", "nan"], 2, "--heat-tau"),
        ([f["good.csv"], "--heat-tau", "-1"], 2, "--heat-tau"),
        ([f["good.csv"], "--base", "no-such-preset"], 2, "no-such-preset"),
        ([f["good.csv"], "--base", f["rate-tiny.toml"]], 2, "max_rate_dps"),
        ([f["good.csv"], "-o", os.path.join(missing_dir, "x.toml")], 2, "--output"),
        ([f["good.csv"], "--report", os.path.join(missing_dir, "r.txt")], 2, "--report"),
        ([f["good.csv"], "--between", "nowhere"], 2, "--between"),
        ([f["validity-clear.csv"]], 1, "good samples"),  # a valid file whose data are unusable
    ]:
        add("calibrate", argv, exit, names)


@contextlib.contextmanager
def _listener(on_connect: Callable[[socket.socket, threading.Event], None]) -> Iterator[str]:
    """A loopback TCP address; each connection is handed to ``on_connect`` (with the event set
    when the listener closes) on a thread of its own."""
    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []
    stop = threading.Event()

    def accept() -> None:
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            held.append(conn)
            threading.Thread(target=on_connect, args=(conn, stop), daemon=True).start()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(2)
        for conn in held:
            conn.close()
        server.close()


def silent_listener() -> contextlib.AbstractContextManager[str]:
    """A loopback TCP address that accepts connections and never answers (for simctl)."""
    return _listener(lambda conn, stop: None)


def garbage_listener() -> contextlib.AbstractContextManager[str]:
    """A loopback TCP address that sends random bytes to whoever connects: what a host reads
    from a serial unit at another baud rate."""
    import random

    rng = random.Random(1)

    def feed(conn: socket.socket, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                conn.sendall(rng.randbytes(256))
            except OSError:
                return
            stop.wait(0.005)

    return _listener(feed)


def run_case(case: CliCase, timeout_s: float) -> dict[str, Any]:
    """Run one case as its own process; what came back."""
    t0 = time.monotonic()
    try:
        res = subprocess.run(
            [*SIM, *case.argv], capture_output=True, text=True, timeout=timeout_s,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
    except subprocess.TimeoutExpired:
        return {"case": case, "hang": True, "exit": None, "line": "", "seconds": timeout_s}
    err = [line for line in res.stderr.splitlines() if line.strip()]
    # The one line: argparse's "error:" line or ours; log lines of `sim` (a time first) and
    # progress lines (`find: warm-up`) come before it. Anything else is a second line.
    lines = [
        line for line in err
        if "error" in line
        or not (line[:1].isdigit() or line.startswith(f"{case.command}: ") or "warning:" in line)
    ]  # fmt: skip
    return {
        "case": case,
        "hang": False,
        "exit": res.returncode,
        "traceback": "Traceback" in res.stderr,
        "internal": "internal error" in res.stderr,
        "lines": len(lines),
        "line": lines[-1] if lines else (err[-1] if err else ""),
        "seconds": time.monotonic() - t0,
    }


def cli_sweep(args: argparse.Namespace) -> dict[str, Any]:
    """Bad input over every subcommand, each case its own process."""
    from concurrent.futures import ThreadPoolExecutor

    with tempfile.TemporaryDirectory(dir="/tmp") as tmp, silent_listener() as silent, \
            garbage_listener() as garbage, \
            simulator("--control", "127.0.0.1:0") as (_, facts):  # fmt: skip
        files = _files(tmp)
        cases = cli_cases(files, facts["control"], silent, tmp, garbage)
        if args.only_cli:
            cases = [c for c in cases if args.only_cli in " ".join(c.argv)]
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            results = list(pool.map(lambda c: run_case(c, args.case_timeout), cases))
    by_command: dict[str, dict[str, int]] = {}
    problems: list[str] = []
    for r in results:
        case: CliCase = r["case"]
        row = by_command.setdefault(
            case.command,
            {"cases": 0, "clean": 0, "tracebacks": 0, "internal": 0, "hangs": 0, "wrong_exit": 0,
             "unnamed": 0},
        )  # fmt: skip
        row["cases"] += 1
        line = r["line"]
        if r["hang"]:
            row["hangs"] += 1
            problems.append(f"HANG    {' '.join(case.argv)[:150]}")
            continue
        bad = []
        if r["traceback"]:
            row["tracebacks"] += 1
            bad.append("traceback")
        if r["internal"]:
            row["internal"] += 1
            bad.append("internal error")
        if r["exit"] != case.exit:
            row["wrong_exit"] += 1
            bad.append(f"exit {r['exit']} (want {case.exit})")
        if case.exit and (r["lines"] != 1 or case.names.lower() not in line.lower()):
            row["unnamed"] += 1
            bad.append(f"line does not name {case.names!r}")
        if bad:
            problems.append(
                f"{', '.join(bad)}: {' '.join(case.argv)[:120]}\n        -> {line[:200]}"
            )
        else:
            row["clean"] += 1
    print("bad-input sweep (each case its own `northfinder` process, "
          f"{args.case_timeout:g} s limit per case)")  # fmt: skip
    print(f"{'command':<12} {'cases':>6} {'clean':>6} {'tracebacks':>11} {'internal':>9} "
          f"{'hangs':>6} {'wrong exit':>11} {'unnamed':>8}")  # fmt: skip
    total = {k: 0 for k in ("cases", "clean", "tracebacks", "internal", "hangs", "wrong_exit",
                            "unnamed")}  # fmt: skip
    for command, row in by_command.items():
        print(f"{command:<12} {row['cases']:>6} {row['clean']:>6} {row['tracebacks']:>11} "
              f"{row['internal']:>9} {row['hangs']:>6} {row['wrong_exit']:>11} {row['unnamed']:>8}")  # fmt: skip
        for k in total:
            total[k] += row[k]
    print(f"{'all':<12} {total['cases']:>6} {total['clean']:>6} {total['tracebacks']:>11} "
          f"{total['internal']:>9} {total['hangs']:>6} {total['wrong_exit']:>11} {total['unnamed']:>8}")  # fmt: skip
    slowest = max(results, key=lambda r: r["seconds"]) if results else None
    if slowest is not None:
        print(f"slowest case {slowest['seconds']:.1f} s: {' '.join(slowest['case'].argv)[:100]}")
    for p in problems:
        print(f"  {p}")
    return {"by_command": by_command, "total": total, "problems": problems}
