"""Bad input of every kind gets one clear line and a stated exit status: sensor figures out of
their range, a serial link whose bytes never parse (a baud rate mismatch), half-precision
recordings, recordings too large to hold, and argparse's own errors."""

from __future__ import annotations

import math
import re
import warnings
from typing import Any

import pytest
from clirun import run_cli

from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.sensors import field_ranges, load_spec, preset_names


# -- sensor figures have documented ranges ----------------------------------------------------
def test_every_preset_is_within_the_ranges():
    for name in preset_names():
        load_spec(name)  # raises on a figure out of its range


def test_every_figure_has_a_finite_range_that_holds_its_default():
    import dataclasses

    from northfinder.firmware_sim.sensors import SensorSpec

    spec = SensorSpec()
    ranges = field_ranges()
    assert len(ranges) == sum(
        len(dataclasses.fields(getattr(spec, section)))
        for section in ("gyro", "accel", "thermal", "disturbance", "table")
    )
    for dotted, (lo, hi, doc) in ranges.items():
        section, name = dotted.split(".")
        default = getattr(getattr(spec, section), name)
        values = default if isinstance(default, tuple) else (default,)
        assert math.isfinite(lo) and math.isfinite(hi) and lo < hi, dotted
        assert all(lo <= v <= hi for v in values), dotted
        assert "," in doc, dotted  # the meaning ends with its unit


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ("[thermal]\nambient_c = 1e9\n", "thermal.ambient_c = 1e+09 is outside its range -100 to 150"),
        ("[gyro]\nmisalignment_urad = 1e9\n", "gyro.misalignment_urad = 1e+09 is outside its range 0 to 100000"),
        ("[accel]\nbias_ug = [0, 0, -2e6]\n", "accel.bias_ug[2] = -2e+06 is outside its range -1e+06 to 1e+06"),
        ("[table]\nindexing_error_deg = 45\n", "table.indexing_error_deg = 45 is outside its range 0 to 10"),
        ("[gyro]\narw_dpsh = 1000\n", "gyro.arw_dpsh = 1000 is outside its range 0 to 100"),
    ],
)  # fmt: skip
def test_a_figure_out_of_its_range_is_refused_naming_key_value_and_range(tmp_path, body, says):
    path = tmp_path / "unit.toml"
    path.write_text(body)
    with pytest.raises(SimConfigError, match=None) as info:
        load_spec(path)
    assert says in str(info.value)
    code, out, err = run_cli("simulate", "--sensor", str(path))
    assert code == 2 and out == "" and says in err
    assert len(err.splitlines()) == 1


def test_the_docs_state_every_range():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "instrument.md").read_text()
    for dotted, (lo, hi, _) in field_ranges().items():
        assert f"| `{dotted}` | {lo:g} to {hi:g} |" in page, dotted


# -- a serial link whose bytes never parse -----------------------------------------------------
class _GarbageServer:
    """A TCP server on 127.0.0.1 that sends random bytes to whoever connects (what a host reads
    from a unit at another baud rate), as pyserial's ``socket://`` URL reaches it."""

    def __init__(self) -> None:
        import socket
        import threading

        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        import random

        rng = random.Random(7)
        self.sock.settimeout(0.2)
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            with conn:
                while not self.stop.is_set():
                    try:
                        conn.sendall(rng.randbytes(256))
                    except OSError:
                        break
                    self.stop.wait(0.005)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.sock.close()


@pytest.fixture
def garbage() -> Any:
    server = _GarbageServer()
    yield f"socket://127.0.0.1:{server.port}"
    server.close()


def test_bytes_that_never_parse_are_reported_as_a_wrong_baud_rate(garbage):
    import serial

    from northfinder.driver.device import Device
    from northfinder.driver.errors import DriverTimeout, LinkLost
    from northfinder.driver.transport import SerialTransport

    port = serial.serial_for_url(garbage, timeout=0.05)
    transport = SerialTransport(port)
    with pytest.raises((DriverTimeout, LinkLost)) as info:
        Device(transport, reply_timeout=0.2, retries=1)
    text = str(info.value)
    assert "bytes arrive but no frame parses" in text and "wrong baud rate or protocol?" in text
    assert "silent" not in text
    assert transport.counters()["bytes_unparsed"] >= 256
    port.close()


def test_find_on_a_garbled_serial_link_says_so_in_one_line(garbage):
    code, out, err = run_cli("find", "--serial", garbage, "--latitude", "34")
    assert code == 1 and out == ""
    assert "wrong baud rate or protocol?" in err and len(err.splitlines()) == 1, err


# -- recordings: half precision, pickles, too many windows or samples -------------------------
RATE = 200


def _window(k: int, angle: float, n: int = 40) -> Any:
    import numpy as np

    from northfinder.host.recording import RecordedWindow

    counter = np.arange(n) + k * 10_000
    return RecordedWindow(
        angle, counter, (counter + 1) / RATE, np.full((n, 3), 10.0),
        np.tile([0.0, 0.0, 9.8], (n, 1)), np.full(n, angle), np.full(n, 20.0),
        np.full(n, 3, dtype=np.uint8),
    )  # fmt: skip


def _saved(tmp_path: Any, windows: int, suffix: str = ".npz", n: int = 40) -> Any:
    from northfinder.host.recording import Recording

    path = tmp_path / f"rec{suffix}"
    meta = {"latitude_deg": 34.0, "sample_rate_hz": RATE}
    Recording(tuple(_window(k, 180.0 * (k % 2), n) for k in range(windows)), meta).save(path)
    return path


@pytest.mark.parametrize("array", ["gyro_dph", "counter", "time_s"])
def test_a_half_precision_recording_is_refused_in_one_line_without_a_numpy_warning(tmp_path, array):
    import numpy as np

    path = _saved(tmp_path, 2)
    arrays = dict(np.load(path))
    arrays[array] = arrays[array].astype(np.float16)
    np.savez(path, **arrays)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any numpy warning fails the test
        code, out, err = run_cli("solve", str(path))
    assert code == 2 and out == ""
    assert f"array {array!r} is float16 (half precision" in err and len(err.splitlines()) == 1


def test_a_file_numpy_could_only_unpickle_is_refused_without_numpy_s_advice(tmp_path):
    path = tmp_path / "junk.npz"
    path.write_bytes(b"x")
    code, _, err = run_cli("solve", str(path))
    assert code == 2 and "never loaded" in err and "allow_pickle" not in err


def test_a_csv_of_more_windows_than_a_recording_holds_is_refused_as_it_is_read(
    tmp_path, monkeypatch
):
    import northfinder.host.recording as recording

    path = _saved(tmp_path, 40, ".csv", n=4)
    monkeypatch.setattr(recording, "MAX_WINDOWS", 32)
    code, out, err = run_cli("solve", str(path))
    assert code == 2 and out == ""
    assert "more than 32 windows; a recording holds at most that many" in err
    # the line of the 33rd window's first sample: refused while reading, not after
    assert re.search(r"line (\d+):", err) and len(err.splitlines()) == 1


def test_a_recording_of_more_samples_than_the_cap_is_refused_in_either_format(
    tmp_path, monkeypatch
):
    import northfinder.host.recording as recording

    monkeypatch.setattr(recording, "MAX_SAMPLES", 100)
    for suffix in (".csv", ".npz"):
        path = _saved(tmp_path, 4, suffix, n=40)
        code, _, err = run_cli("solve", str(path))
        assert code == 2 and "a recording holds at most" in err and "100" in err, err


def test_the_csv_reader_never_holds_the_text(tmp_path):
    """A CSV is parsed row by row into blocks of numbers: the memory it takes is that of the
    samples as numbers (13 floats a row, twice while the blocks are joined), not the text and
    Python's lists of it (about 0.5 kB a row)."""
    import tracemalloc

    from northfinder.host.recording import Recording

    path = _saved(tmp_path, 4, ".csv", n=12_500)
    size = path.stat().st_size
    tracemalloc.start()
    rec = Recording.load(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert sum(len(w.counter) for w in rec.windows) == 50_000
    numbers = 50_000 * 13 * 8
    assert peak < 2.3 * numbers and peak < 3.5 * size, (peak, numbers, size)
