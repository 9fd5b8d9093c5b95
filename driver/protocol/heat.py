"""The heat the table's drive puts into the unit, defined once for the simulator and the host.

Moves
-----
Every move of ``d`` degrees (the commanded angle turned) starting at ``t0`` disturbs the sensors
by ``sqrt(q) * (walk * z_walk + transient * z_transient * exp(-(t - t0) / tau))`` (z standard
normal per move and channel): a lasting bias step and a transient. Its size ``q`` (deg) is the
heat the motor holds as the move starts (:func:`move_heat`): the angles of this and every earlier
move, each decayed with the heat time constant.

Spins
-----
A table that turns for minutes works its motor all that time. The spin follows the same model as
the move transient, with the spin taken as a train of short moves: every degree turned at the
steady rate disturbs like ``spin_heat`` degrees of a move, and the ramp up to the rate is one
move of its own angle (``rate^2 / (2 accel)``) as it starts. In the limit of short moves the
transient part is a first-order Gauss-Markov process of time constant ``tau`` driven by the
angle turned (innovation variance ``spin_heat * transient^2 * |rate|`` per second) and the
lasting part a random walk in the angle turned (``spin_heat * walk^2 * |rate|`` per second);
steady turning reaches a bias scatter of ``transient * sqrt(spin_heat * |rate| * tau / 2)``
(:func:`spin_heat_sigma`). Assumption: a steady spin's work per degree (friction only) is at most
a move's (which accelerates and brakes), so ``0 <= spin_heat <= 1``; 0 turns the term off, and
the heat time constant, which sizes discrete moves by their history, does not enter (the steady
turning's heat is in its rate). :func:`spin_heat_state` gives the process's state where the
steady spin starts, after the ramp.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["move_heat", "spin_heat_sigma", "spin_heat_state", "spin_heat_steps"]


def move_heat(
    start_s: ArrayLike, angle_deg: ArrayLike, heat_tau_s: float, last: int | None = None
) -> NDArray[np.float64]:
    """Size of each move's disturbance (deg): the heat the motor holds as it starts.

    Parameters
    ----------
    start_s, angle_deg : (M,) float
        Start time (s) and commanded angle turned (deg) of every move so far, in order.
    heat_tau_s : float
        Time constant of the motor's heat, s; 0 sizes each move by its own angle.
    last : int, optional
        Size only the last ``last`` moves (the earlier ones still heat the motor).

    Returns
    -------
    (M,) or (last,) float
        ``sum over moves j <= m of |d_j| exp(-(t_m - t_j) / heat_tau_s)``.
    """
    t = np.asarray(start_s, dtype=float)
    d = np.abs(np.asarray(angle_deg, dtype=float))
    rows = slice(None) if last is None else slice(d.size - last, None)
    if heat_tau_s <= 0.0 or d.size < 2:
        return d[rows]
    lag = t[rows, None] - t[None, :]
    return np.asarray(
        (np.where(lag >= 0.0, np.exp(-np.maximum(lag, 0.0) / heat_tau_s), 0.0) * d).sum(axis=1)
    )


def spin_heat_sigma(transient: float, tau_s: float, rate_dps: float, spin_heat: float) -> float:
    """Steady scatter of a spin's heat transient, in the units of ``transient`` times sqrt(deg):
    ``transient * sqrt(spin_heat * |rate| * tau / 2)``."""
    return transient * math.sqrt(max(spin_heat, 0.0) * abs(rate_dps) * tau_s / 2.0)


def spin_heat_state(
    rate_dps: float, accel_dps2: float, tau_s: float, spin_heat: float
) -> tuple[float, float]:
    """Variances per unit ``transient^2`` and ``walk^2`` (deg) of the spin's heat terms where the
    steady rate is reached: the ramp (a move of ``rate^2 / (2 accel)`` deg) decayed over the ramp
    time for the transient, the ramp's angle for the walk; scaled by ``spin_heat`` (0: none)."""
    if spin_heat <= 0.0 or rate_dps == 0.0:
        return 0.0, 0.0
    ramp_s = abs(rate_dps) / accel_dps2
    ramp_deg = 0.5 * abs(rate_dps) * ramp_s
    return spin_heat * ramp_deg * math.exp(-2.0 * ramp_s / tau_s), spin_heat * ramp_deg


def spin_heat_steps(
    rate_dps: float, tau_s: float, spin_heat: float, step_s: float
) -> tuple[float, float, float]:
    """One sample step of the spin's heat processes: the transient's decay ``phi`` and the
    innovation variances per step (per unit ``transient^2`` and ``walk^2``, deg) of the transient
    and of the walk; ``x_k = phi x_(k-1) + w_k``."""
    phi = math.exp(-step_s / tau_s) if tau_s > 0 else 0.0
    angle = max(spin_heat, 0.0) * abs(rate_dps) * step_s
    # The exact discretisation of the continuous process: the transient's innovation over a step
    # is the integral of the drive's increments decayed to the step's end.
    trans = angle * (1.0 - phi * phi) * tau_s / (2.0 * step_s) if tau_s > 0 else 0.0
    return phi, trans, angle
