"""Files read are bounded and regular: a FIFO, /dev/zero, an empty or BOM-marked sensor file get
one clear line (exit 2), never a hang, a MemoryError or a silent ideal sensor."""

from __future__ import annotations

import os
import threading

import pytest

from northfinder.cli import main
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.recording import Recording, RecordingError


def test_an_empty_sensor_file_is_refused(tmp_path):
    empty = tmp_path / "empty.toml"
    empty.write_text("# nothing\n")
    with pytest.raises(SimConfigError, match="specifies nothing"):
        load_spec(empty)


def test_a_byte_order_mark_is_read_as_utf8(tmp_path):
    spec = load_spec("paper-rlg")
    text = tmp_path / "x.toml"
    text.write_bytes(b"\xef\xbb\xbf" + b'name = "bom"\n[gyro]\narw_dpsh = 0.002\n')
    assert load_spec(text).gyro.arw_dpsh == pytest.approx(0.002)
    assert spec is not None


def test_dev_zero_and_a_fifo_are_refused_at_once(tmp_path, capsys):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    for path in ("/dev/zero", str(fifo)):
        with pytest.raises(SimConfigError, match="not a regular file"):
            load_spec(path)
    assert main(["find", "--sim", "--sensor", "/dev/zero"]) == 2
    assert "not a regular file" in capsys.readouterr().err
    rec_fifo = tmp_path / "rec.csv"
    os.mkfifo(rec_fifo)
    done = threading.Event()

    def load() -> None:
        with pytest.raises(RecordingError, match="not a regular file"):
            Recording.load(rec_fifo)
        done.set()

    t = threading.Thread(target=load, daemon=True)
    t.start()
    t.join(10)
    assert done.is_set()


def test_a_sensor_file_beyond_the_size_limit_is_refused(tmp_path):
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * (2 << 20) + b"\n")
    with pytest.raises(SimConfigError, match="larger than 1 MiB"):
        load_spec(big)
