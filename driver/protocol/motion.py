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

from northfinder.driver.protocol.constants import ConfigKey

__all__ = ["TableLimits", "move_time_s", "shortest_delta_deg"]


def move_time_s(distance_deg: float, max_rate_dps: float, max_accel_dps2: float) -> float:
    """Duration of a rest-to-rest move over ``|distance_deg|``, s.

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
    if d == 0.0:
        return 0.0
    if d <= v * v / a:
        return 2.0 * math.sqrt(d / a)
    return v / a + d / v


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

    max_rate_dps: float
    max_accel_dps2: float
    settle_s: float

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
