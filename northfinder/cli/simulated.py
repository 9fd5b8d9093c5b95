"""Defaults of a simulated run: its seed, latitude, truth and sensor."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any


def run_seed(args: argparse.Namespace) -> int:
    """The seed of a simulated run: ``--seed``, or a fresh one drawn now (and kept in ``args``)
    when none was given, so that every run can state its seed and be run again with it."""
    if getattr(args, "seed", None) is None:
        import secrets

        args.seed = secrets.randbelow(2**32)  # short to type; any seed up to MAX_SEED is taken
    seed: int = args.seed
    return seed


def sim_latitude(args: argparse.Namespace) -> float:
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG  # numpy: not for --help

    return DEFAULT_LATITUDE_DEG if args.latitude is None else args.latitude


def sim_truth(args: argparse.Namespace, rng: Any) -> Any:
    """The simulated truth of :func:`add_truth_arguments` (azimuth drawn from ``rng`` when not
    given); SimConfigError names a field the simulated base cannot take."""
    from northfinder.firmware_sim.imu import Truth

    azimuth = float(rng.uniform(0.0, 360.0)) if args.azimuth is None else args.azimuth
    return Truth(azimuth, sim_latitude(args), args.pitch or 0.0, args.roll or 0.0)


def latitude_source(args: argparse.Namespace, simulated: bool) -> str:
    """Where the latitude of a run comes from, as the result states it."""
    if args.latitude is not None:
        return "--latitude"
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG

    return f"the simulated truth (default, {DEFAULT_LATITUDE_DEG:g} deg)" if simulated else ""


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
