"""The simulated instrument of a command's options: its configuration, seed and sensor."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from northfinder.config import SimConfig


def run_seed(args: argparse.Namespace) -> int:
    """The seed of a simulated run: ``--seed``, or a fresh one drawn now (and kept in ``args``)
    when none was given, so that every run can state its seed and be run again with it."""
    if getattr(args, "seed", None) is None:
        import secrets

        args.seed = secrets.randbelow(2**32)  # short to type; any seed up to MAX_SEED is taken
    seed: int = args.seed
    return seed


def simulated(args: argparse.Namespace) -> tuple[SimConfig, float]:
    """The simulated instrument of the sensor and truth options
    (:class:`~northfinder.config.SimConfig`) and its truth's latitude, deg (``--latitude``, or
    the simulation's default)."""
    from northfinder.cli.measure import sim_config  # numpy: not for --help
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG

    return sim_config(args), DEFAULT_LATITUDE_DEG if args.latitude is None else args.latitude


def load_sensor(name_or_path: str, overrides: Mapping[str, Any] | None = None) -> Any:
    """A sensor preset or TOML file, with ``SECTION.FIELD`` overrides, that the simulated
    device can run (table limits it reports, impulses it can compute: ``check_device_spec``).

    Raises
    ------
    SimConfigError
        Naming the field, its value and the bound (exit status 2).
    """
    from northfinder.firmware_sim.firmware import check_device_spec
    from northfinder.firmware_sim.sensors import load_spec

    spec = load_spec(name_or_path)
    if overrides:
        spec = spec.with_values(dict(overrides))
    return check_device_spec(spec)
