"""The table's motion profile, defined once for the simulated firmware, the driver and the host.

A move is rest to rest with a trapezoidal rate profile: constant acceleration up to the rate
limit, constant rate, constant deceleration (triangular when the distance is too short to reach
the rate). The driver's move deadlines (protocol.md section 6) and the host's plan times are built on
:func:`move_time_s`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.constants import ConfigKey

__all__ = [
    "DEFAULT_MAX_ACCEL_DPS2",
    "DEFAULT_MAX_RATE_DPS",
    "DEFAULT_SETTLE_S",
    "TableLimits",
    "encoder_angle_deg",
    "move_phases_s",
    "move_time_s",
    "shortest_delta_deg",
    "spin_angle_deg",
    "wobble_matrix",
]

#: The table's limits when none are configured: the simulated table's and the plans' defaults.
DEFAULT_MAX_RATE_DPS = 10.0
DEFAULT_MAX_ACCEL_DPS2 = 20.0
DEFAULT_SETTLE_S = 2.0


def move_phases_s(
    distance_deg: float, max_rate_dps: float, max_accel_dps2: float
) -> tuple[float, float]:
    """The phases of a rest-to-rest move over ``|distance_deg|``: the time of the acceleration
    (and of the deceleration, as long) and the time at the rate limit, s (0 for a triangular
    profile). The move takes ``2 * accel_s + cruise_s``; :func:`move_time_s` says how long.

    Parameters
    ----------
    distance_deg : float
        Signed or unsigned distance, deg; only its magnitude counts.
    max_rate_dps : float
        Rate limit, deg/s (> 0).
    max_accel_dps2 : float
        Acceleration limit, deg/s^2 (> 0).
    """
    d, v, a = abs(distance_deg), max_rate_dps, max_accel_dps2
    if d <= v * v / a:
        return math.sqrt(d / a), 0.0
    return v / a, (d - v * v / a) / v


def move_time_s(distance_deg: float, max_rate_dps: float, max_accel_dps2: float) -> float:
    """Duration of a rest-to-rest move over ``|distance_deg|``, s: the profile of
    :func:`move_phases_s` (the parameters are its)."""
    accel_s, cruise_s = move_phases_s(distance_deg, max_rate_dps, max_accel_dps2)
    return 2.0 * accel_s + cruise_s


def shortest_delta_deg(from_deg: float, to_deg: float) -> float:
    """Signed shortest turn from ``from_deg`` to ``to_deg``, in [-180, 180) deg."""
    return (to_deg - from_deg + 180.0) % 360.0 - 180.0


@dataclass(frozen=True, slots=True)
class TableLimits:
    """The table's motion configuration in physical units (protocol.md 4.4).

    Attributes
    ----------
    max_rate_dps : float
        Rate limit, deg/s.
    max_accel_dps2 : float
        Acceleration limit, deg/s^2.
    settle_s : float
        Time from the end of the motion to READY, s.
    """

    max_rate_dps: float = DEFAULT_MAX_RATE_DPS
    max_accel_dps2: float = DEFAULT_MAX_ACCEL_DPS2
    settle_s: float = DEFAULT_SETTLE_S

    @classmethod
    def from_config(cls, config: Mapping[ConfigKey, int]) -> TableLimits:
        """The limits from configuration values in wire units (1e-3 deg/s, 1e-3 deg/s^2, ms)."""
        return cls(
            config[ConfigKey.TABLE_MAX_RATE_MDPS] / 1000.0,
            config[ConfigKey.TABLE_MAX_ACCEL_MDPS2] / 1000.0,
            config[ConfigKey.SETTLE_TIME_MS] / 1000.0,
        )

    def move_time_s(self, distance_deg: float) -> float:
        """Duration of the motion over ``|distance_deg|``, s (see :func:`move_time_s`)."""
        return move_time_s(distance_deg, self.max_rate_dps, self.max_accel_dps2)

    def ready_after_s(self, distance_deg: float) -> float:
        """Time from the start of a move over ``|distance_deg|`` to READY: motion and settling, s."""
        return self.move_time_s(distance_deg) + self.settle_s


# ----------------------------------------------------------------------------------------------
# A turning table's imperfections (the simulated table and the host's prediction share them)
# ----------------------------------------------------------------------------------------------


def spin_angle_deg(
    rate_dps: float,
    start_deg: ArrayLike,
    dt_s: ArrayLike,
    ripple: float = 0.0,
    ripple_phase_deg: float = 0.0,
) -> NDArray[np.float64]:
    """Continuous table angle of a steady spin ``dt_s`` after it started at ``start_deg``, deg.

    With a once-per-turn rate ripple ``k`` the rate is ``v (1 + k cos(mu_n - phase))`` with
    ``mu_n = start + v dt`` the nominal angle, so the angle is
    ``mu_n + k |v| (sin(mu_n - phase) - sin(start - phase)) / v`` (v in rad/s in the last
    denominator). Arguments broadcast.
    """
    a0 = np.asarray(start_deg, dtype=float)
    angle = a0 + rate_dps * np.asarray(dt_s, dtype=float)
    if ripple and rate_dps:
        x = np.radians(angle - ripple_phase_deg)
        x0 = np.radians(a0 - ripple_phase_deg)
        angle = angle + ripple * abs(rate_dps) * (np.sin(x) - np.sin(x0)) / math.radians(rate_dps)
    return np.asarray(angle, dtype=float)


def encoder_angle_deg(
    angle_deg: ArrayLike,
    error_deg: float = 0.0,
    harmonic: float = 1.0,
    phase_deg: float = 0.0,
    resolution_deg: float = 0.0,
) -> NDArray[np.float64]:
    """What an encoder reads for true continuous table angles, deg, not taken modulo a turn:
    ``mu + e sin(n mu + phase)`` (its periodic error, e.g. eccentricity for n = 1), rounded to its
    resolution (0: exact)."""
    a = np.asarray(angle_deg, dtype=float)
    if error_deg:
        a = a + error_deg * np.sin(np.radians(harmonic * a + phase_deg))
    if resolution_deg > 0:
        a = np.round(a / resolution_deg) * resolution_deg
    return np.asarray(a, dtype=float)


def wobble_matrix(wobble_urad: float, phase_deg: float) -> NDArray[np.float64] | None:
    """Sensor frame from table frame for a table top tilted by ``wobble_urad`` towards the
    table-frame direction ``phase_deg`` (a small rotation about the horizontal axis at right
    angles to it), (3, 3), or None when there is no wobble: a vector ``v`` of the table frame
    has the sensor-frame coordinates ``matrix @ v``."""
    if not wobble_urad:
        return None
    w = wobble_urad * 1e-6
    p = math.radians(phase_deg)
    # The top's normal leans towards (cos p, sin p): a rotation by w about (-sin p, cos p, 0).
    k = np.array([-math.sin(p), math.cos(p), 0.0])
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rot = np.eye(3) + math.sin(w) * kx + (1.0 - math.cos(w)) * kx @ kx
    out: NDArray[np.float64] = rot.T  # coordinates in the tilted frame
    return out
