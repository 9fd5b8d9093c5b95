"""The table's motion profile, defined once for the simulated firmware, the driver and the host.

A move is rest to rest with a trapezoidal rate profile: constant acceleration up to the rate
limit, constant rate, constant deceleration (triangular when the distance is too short to reach
the rate). The driver's move deadlines (protocol.md section 6) and the host's plan times are built on
:func:`move_time_s`.
"""

from __future__ import annotations

import math


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
