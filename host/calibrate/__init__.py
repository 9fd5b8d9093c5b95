"""Calibration of a gyro north finder from its own recordings (``northfinder calibrate``).

- :mod:`~northfinder.host.calibrate.readers`: recordings of every format the project reads, one
  reader per file ending (a new format plugs in with ``register_reader``);
- :mod:`~northfinder.host.calibrate.between`: the between-position variance components (turn-on
  repeatability, bias steps and transients started by table moves) of window means;
- :mod:`~northfinder.host.calibrate.core`: Allan deviation and IEEE 952 fit per axis, the
  between-position terms, and the sensor TOML the simulator takes;
- :mod:`~northfinder.host.calibrate.plot`: the report's figure (needs the ``plot`` extra).
"""

from northfinder.host.calibrate.between import (
    COMPONENTS,
    DESIGNS,
    BetweenFit,
    RunWindows,
    SlowNoise,
    fit_between_positions,
)
from northfinder.host.calibrate.core import AXES, Calibration, IndexingFit, calibrate
from northfinder.host.calibrate.readers import (
    READERS,
    RecordedRun,
    good_stretches,
    read_runs,
    register_reader,
)

__all__ = [
    "AXES",
    "COMPONENTS",
    "DESIGNS",
    "READERS",
    "BetweenFit",
    "Calibration",
    "IndexingFit",
    "RecordedRun",
    "RunWindows",
    "SlowNoise",
    "calibrate",
    "fit_between_positions",
    "good_stretches",
    "read_runs",
    "register_reader",
]
