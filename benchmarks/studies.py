"""What the accuracy and planner benchmarks share: the site and warm-up of their studies, and
the presets they study."""

from __future__ import annotations

from collections.abc import Iterator

from northfinder.firmware_sim.sensors import SensorSpec, load_spec, preset_names
from northfinder.host.accuracy import ErrorModel
from northfinder.host.montecarlo import StudySettings
from northfinder.simwindows import error_model

LATITUDE = 34.0
WARMUP = 120.0
SETTINGS = StudySettings(latitude_deg=LATITUDE, warmup_s=WARMUP)


def noisy_presets() -> Iterator[tuple[str, SensorSpec, ErrorModel]]:
    """Every preset but ``ideal`` (no noise: any plan is exact), with its spec and error model."""
    for name in preset_names():
        if name != "ideal":
            spec = load_spec(name)
            yield name, spec, error_model(spec)
