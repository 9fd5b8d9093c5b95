"""Units and physical constants, defined once for the wire format, the simulator and the host.

Everything inside the packages is SI (rad, rad/s, m/s^2, s); datasheet units appear only at the
edges (sensor files, CLI options, printed results) and are converted with the factors below:
multiply a datasheet value by the factor to get SI, divide an SI value by it to get the datasheet
unit.

This module lives beside the codec because the wire format is the one package that the simulated
firmware, the driver and the host all may import (docs/architecture.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Earth rotation rate (WGS84), rad/s.
OMEGA_IE = 7.292115e-5
#: Standard gravity, m/s^2: defines the unit "g" (and micro-g) of accelerometer values.
G0 = 9.80665

#: One degree, rad.
DEG = math.pi / 180.0
#: One degree per hour, rad/s.
DPH = DEG / 3600.0
#: One degree per second, rad/s.
DPS = DEG
#: One degree per root hour (angle random walk), rad/sqrt(s).
DPSH = DEG / 60.0
#: One degree per hour per root hour (rate random walk), rad/s/sqrt(s).
DPH_PSH = DPH / 60.0
#: One micro-g, m/s^2.
UG = 1e-6 * G0


def normal_gravity(latitude_rad: ArrayLike) -> NDArray[np.float64] | float:
    """Normal gravity on the WGS84 ellipsoid (Somigliana's formula), m/s^2.

    Parameters
    ----------
    latitude_rad : array_like
        Geodetic latitude, rad.
    """
    s2 = np.sin(np.asarray(latitude_rad, dtype=float)) ** 2
    g = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / np.sqrt(1.0 - 6.69437999013e-3 * s2)
    return float(g) if np.ndim(g) == 0 else g


#: Latitude of a simulation or a study when none is given, deg (the source paper's site is near
#: 34 deg N). A real device's latitude is never assumed.
DEFAULT_LATITUDE_DEG = 34.0

#: Warm-up of a simulated instrument when none is given, s (the source paper's 2 min; protocol.md
#: 5 leaves a real device's to the device). Simulator, studies and command line read it here.
DEFAULT_WARMUP_S = 120.0

#: Latitudes closer to a pole than this are refused: the horizontal Earth rate vanishes there.
MAX_LATITUDE_DEG = 89.0


def finite_float(value: Any, error: Callable[[str], Exception], field: str) -> float:
    """``value`` as a finite float, else raise ``error`` (each package passes its own error
    class) with a message that starts with ``field``."""
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise error(f"{field}: must be a number, got {value!r}") from exc
    if not math.isfinite(x):
        raise error(f"{field}: must be a finite number, got {value!r}")
    return x


def check_latitude_deg(
    latitude_deg: Any, error: Callable[[str], Exception], field: str = "latitude_deg"
) -> float:
    """``latitude_deg`` as a float if north finding is defined there, else raise ``error``
    (each package passes its own error class) with a message that starts with ``field``.

    Raises
    ------
    error
        Not a number, not finite, outside [-90, 90] deg, or beyond +-:data:`MAX_LATITUDE_DEG`
        (the horizontal Earth rate Omega*cos(lat) vanishes towards a pole).
    """
    lat = finite_float(latitude_deg, error, field)
    if abs(lat) > 90.0:
        raise error(f"{field}: must lie in [-90, 90] deg, got {lat}")
    if abs(lat) > MAX_LATITUDE_DEG:
        raise error(
            f"{field}: {lat} deg is too close to a pole (limit +-{MAX_LATITUDE_DEG} deg): the "
            f"horizontal Earth rate Omega*cos(lat) = {OMEGA_IE * math.cos(math.radians(lat)):.3e} "
            "rad/s vanishes there, so north is undefined"
        )
    return lat


def readable_duration(seconds: float) -> str:
    """A length of time in the unit that reads best: s below 2 min, min below 2 h, else h
    (three significant digits); ``an unknown time`` when not finite."""
    if not math.isfinite(seconds):
        return "an unknown time"
    if seconds < 120.0:
        return f"{seconds:.3g} s"
    if seconds < 7200.0:
        return f"{seconds / 60.0:.3g} min"
    return f"{seconds / 3600.0:.3g} h"
