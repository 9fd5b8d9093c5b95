"""Bad input of every kind gets one clear line and a stated exit status: sensor figures out of
their range, a serial link whose bytes never parse (a baud rate mismatch), half-precision
recordings, recordings too large to hold, and argparse's own errors."""

from __future__ import annotations

import math
import warnings

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
