"""Earth model and the direction cosine matrices of the north finder.

All functions take radians and broadcast over array-likes; see the package docstring for frames.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.units import (
    MAX_LATITUDE_DEG,
    OMEGA_IE,
    check_latitude_deg,
    normal_gravity,
)
from northfinder.firmware_sim.errors import SimConfigError

__all__ = [
    "MAX_LATITUDE_DEG",
    "OMEGA_IE",
    "alpha_from_azimuth",
    "azimuth_from_alpha",
    "body_rates",
    "check_latitude",
    "earth_rate_n",
    "gravity",
    "mat_nb",
    "mat_table",
]

#: Normal gravity (Somigliana, WGS84) of latitude in rad, m/s^2; the units module defines it.
gravity = normal_gravity


def check_latitude(latitude_deg: float, field: str = "latitude_deg") -> float:
    """Return ``latitude_deg`` as float if north finding is defined there, else raise.

    Raises
    ------
    SimConfigError
        Not a finite number, outside [-90, 90], or within ``90 - MAX_LATITUDE_DEG`` degrees of a
        pole (:func:`~northfinder.driver.protocol.units.check_latitude_deg`).
    """
    return check_latitude_deg(latitude_deg, SimConfigError, field)


def earth_rate_n(latitude: ArrayLike) -> NDArray[np.float64]:
    """Earth rate in the North-West-Up frame, rad/s, shape ``(..., 3)``."""
    lat = np.asarray(latitude, dtype=float)
    return OMEGA_IE * np.stack([np.cos(lat), np.zeros_like(lat), np.sin(lat)], axis=-1)


def mat_nb(alpha: ArrayLike, theta: ArrayLike, gamma: ArrayLike) -> NDArray[np.float64]:
    """C_n^b for azimuth rotation ``alpha``, pitch ``theta``, roll ``gamma`` (z-y-x), shape ``(..., 3, 3)``."""
    a, t, r = (np.asarray(v, dtype=float) for v in (alpha, theta, gamma))
    ca, sa, ct, st, cr, sr = np.cos(a), np.sin(a), np.cos(t), np.sin(t), np.cos(r), np.sin(r)
    return np.stack(
        [
            np.stack([ca * ct, sa * ct, -st], axis=-1),
            np.stack([ca * st * sr - sa * cr, sa * st * sr + ca * cr, ct * sr], axis=-1),
            np.stack([ca * st * cr + sa * sr, sa * st * cr - ca * sr, ct * cr], axis=-1),
        ],
        axis=-2,
    )


def mat_table(mu: ArrayLike) -> NDArray[np.float64]:
    """C_m^m1 for a table angle ``mu`` about body z (right-handed about up), shape ``(..., 3, 3)``."""
    m = np.asarray(mu, dtype=float)
    c, s = np.cos(m), np.sin(m)
    z, o = np.zeros_like(m), np.ones_like(m)
    return np.stack(
        [np.stack([c, s, z], -1), np.stack([-s, c, z], -1), np.stack([z, z, o], -1)], axis=-2
    )


def alpha_from_azimuth(azimuth_deg: ArrayLike) -> NDArray[np.float64]:
    """The model's ``alpha`` (rad, counter-clockwise) for a public azimuth (deg, clockwise from north)."""
    return -np.radians(np.asarray(azimuth_deg, dtype=float))


def azimuth_from_alpha(alpha: ArrayLike) -> NDArray[np.float64]:
    """Public azimuth in [0, 360) deg, clockwise from north, for the model's ``alpha`` (rad)."""
    return np.mod(-np.degrees(np.asarray(alpha, dtype=float)), 360.0)


def body_rates(
    azimuth_deg: float, pitch_deg: float, roll_deg: float, latitude_deg: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Noise-free Earth rate (rad/s) and specific force (m/s^2) in the body frame at table angle 0."""
    lat = math.radians(latitude_deg)
    c_nb = mat_nb(alpha_from_azimuth(azimuth_deg), math.radians(pitch_deg), math.radians(roll_deg))
    omega_ib_b = c_nb @ earth_rate_n(lat)
    f_b = c_nb @ np.array([0.0, 0.0, normal_gravity(lat)])
    return omega_ib_b, f_b
