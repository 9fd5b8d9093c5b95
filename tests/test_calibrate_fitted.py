"""`calibrate` reduces each window as it is read (its stretches' Allan curves and slopes, its
means, a fingerprint) and drops its samples: the same calibration to the last digit as from the
windows held, memory one window's samples whatever the number of windows (tracemalloc, numpy's
buffers traced too), and a recording given twice still refused."""

from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path

import pytest
from clirun import run_cli
from seeded import saved, seeded_windows

from northfinder.host.calibrate import calibrate, read_runs
from northfinder.host.errors import RecordingError

RATE_HZ = 200.0


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A seeded simulated record of six windows with moves between them, as NPZ and BLF."""
    d = tmp_path_factory.mktemp("rec")
    npz, blf = d / "run.npz", d / "run.blf"
    code, _, err = run_cli("record", "--sim", "--seed", "3", "--warmup", "0", "--window", "20",
                           "--positions", "0,90,180,270,0,90", "--can-log", str(blf), str(npz))  # fmt: skip
    assert code == 0, err
    return {".npz": npz, ".blf": blf}


@pytest.mark.parametrize("suffix", [".npz", ".blf"])
def test_calibration_of_windows_reduced_as_read_is_that_of_the_windows_held(recorded, suffix):
    path = recorded[suffix]
    fitted = read_runs([path], fitted=True)
    assert fitted[0].windows == () and len(fitted[0].fits) == 6
    held = read_runs([path])
    assert len(held[0].windows) == 6
    assert calibrate(fitted).to_json_dict() == calibrate(held).to_json_dict()
    assert calibrate(fitted).report() == calibrate(held).report()


def test_a_recording_given_twice_is_refused_when_reduced_as_read(recorded):
    with pytest.raises(RecordingError, match="holds the same samples as"):
        read_runs([recorded[".npz"], recorded[".blf"]], fitted=True)


def _npz(path: Path, windows: int, n: int, seed: int) -> Path:
    return saved(path, seeded_windows(windows, n, seed, spacing=2, biased=False))


def test_another_power_on_is_not_taken_for_the_same(tmp_path):
    a, b = _npz(tmp_path / "a.npz", 3, 2000, 1), _npz(tmp_path / "b.npz", 3, 2000, 2)
    assert len(read_runs([a, b], fitted=True)) == 2


def test_four_times_the_windows_hold_one_window_at_a_time(tmp_path):
    n = 20_000
    few, many = _npz(tmp_path / "few.npz", 2, n, 3), _npz(tmp_path / "many.npz", 8, n, 3)

    def peak(path: Path) -> int:
        gc.collect()
        tracemalloc.start()
        try:
            read_runs([path], fitted=True)
            _, top = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        return top

    peak(few)
    growth = peak(many) - peak(few)
    one_window = 8 * (1 + 1 + 3 + 3 + 1 + 1) * n  # its arrays in float64/int64, bytes
    # Six windows more, held whole: 6 x one_window; reduced as read: their Allan curves and
    # fingerprints only.
    assert growth < one_window / 2, (growth, one_window)
