"""The turntable: trapezoidal moves about body z, settling, encoder and indexing error, and
turning at a constant rate (:meth:`Turntable.spin`) with a once-per-turn rate ripple.

The table angle is continuous (not wrapped) in the model; the encoder reports it modulo 360 deg,
quantised to its resolution. A move stops at the commanded angle plus an indexing error drawn
afresh for every move (the drive positions on its encoder, so one stop's error does not carry into
the next); the encoder sees where the table really is. An order to go where the table was last
sent is no move: the table stays, with the error of its last stop. Every move is logged
(:attr:`Turntable.moves`) for the bias disturbances that moves start in the sensors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.motion import (
    encoder_angle_deg,
    move_phases_s,
    shortest_delta_deg,
    spin_angle_deg,
)
from northfinder.firmware_sim.errors import SimError
from northfinder.firmware_sim.sensors import TableSpec


def spin_angles_deg(
    table: TableSpec, rate_dps: float, start_deg: ArrayLike, dt_s: ArrayLike
) -> NDArray[np.float64]:
    """True continuous table angle of a steady spin, deg, with the table's once-per-turn ripple
    (:func:`~northfinder.driver.protocol.motion.spin_angle_deg`); arguments broadcast."""
    return spin_angle_deg(rate_dps, start_deg, dt_s, table.rate_ripple, table.rate_ripple_phase_deg)


def encoder_reading_deg(table: TableSpec, angle_deg: ArrayLike) -> NDArray[np.float64]:
    """What the table's encoder reads for true continuous angles, not taken modulo a turn
    (:func:`~northfinder.driver.protocol.motion.encoder_angle_deg`)."""
    return encoder_angle_deg(
        angle_deg,
        table.encoder_error_deg,
        table.encoder_error_harmonic,
        table.encoder_error_phase_deg,
        table.encoder_resolution_deg,
    )


class TableBusyError(SimError):
    """A move was ordered while the table was still moving."""


@dataclass(frozen=True)
class _Segment:
    """Constant acceleration from ``t0``: angle = a0 + v0 dt + acc dt^2 / 2 (deg, deg/s, deg/s^2).

    A steady spin (``acc`` 0) may carry a once-per-turn ripple: the rate is
    ``v0 (1 + ripple cos(mu_n - ripple_phase))`` with ``mu_n = a0 + v0 dt`` the nominal angle.
    """

    t0: float
    a0: float
    v0: float
    acc: float
    ripple: float = 0.0
    ripple_phase_deg: float = 0.0

    def at(self, dt: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        angle, rate = self.a0 + self.v0 * dt + 0.5 * self.acc * dt * dt, self.v0 + self.acc * dt
        if self.ripple and self.v0:
            angle = (
                angle
                - (self.a0 + self.v0 * dt)
                + spin_angle_deg(self.v0, self.a0, dt, self.ripple, self.ripple_phase_deg)
            )
            x = np.radians(self.a0 + self.v0 * dt - self.ripple_phase_deg)
            rate = rate + self.ripple * abs(self.v0) * np.cos(x)
        return angle, rate


class Turntable:
    """A rate- and acceleration-limited table that moves on command.

    Parameters
    ----------
    spec : TableSpec
        Limits, settle time, encoder resolution, indexing error, post-stop oscillation.
    rng : numpy.random.Generator
        Source of the indexing errors.
    angle_deg : float
        Initial angle.
    """

    def __init__(self, spec: TableSpec, rng: np.random.Generator, angle_deg: float = 0.0) -> None:
        self.spec = spec
        self._rng = rng
        self._segments: list[_Segment] = [_Segment(-math.inf, float(angle_deg), 0.0, 0.0)]
        self._motion_start = -math.inf  # start of the latest profile
        self._motion_end = -math.inf  # end of the commanded profile
        self._target = float(angle_deg)  # commanded angle (continuous)
        self._overshoot = 0.0
        self._stalled = False
        self._moves: list[tuple[float, float]] = []
        self._steady = (math.inf, math.inf)  # the present spin's steady interval [start, end)
        self._ramps: list[tuple[float, float]] = []  # spins' ramps: (start s, angle deg)
        self._spins: list[tuple[float, float, float]] = []  # steady spins: (start s, end s, deg/s)

    def generators(self) -> tuple[np.random.Generator, ...]:
        """The random generators the table draws from (for a snapshot of its state)."""
        return (self._rng,)

    # -- commands -----------------------------------------------------------------------------
    def move_by(self, t: float, delta_deg: float, max_rate_dps: float | None = None) -> float:
        """Start a move by ``delta_deg`` from where the table is at time ``t``; return the time
        the profile ends. It stops at that angle plus a fresh indexing error.

        Raises
        ------
        TableBusyError
            The previous profile has not ended at ``t``.
        """
        return self._start(t, delta_deg, delta_deg, max_rate_dps)

    def move_to(self, t: float, target_deg: float, max_rate_dps: float | None = None) -> float:
        """Move to an absolute angle (modulo 360) by the shorter way; return the profile end time.

        The move is measured from where the table really is (as a drive positioning on its
        encoder does), so it stops at ``target_deg`` plus a fresh indexing error. When
        ``target_deg`` is where the table was last sent and it is at rest, nothing moves.
        """
        if self.is_moving(t):
            raise TableBusyError(f"table still moving at t={t:.3f} s")
        commanded = shortest_delta_deg(self._target, target_deg)
        if commanded == 0.0:
            return t
        actual = float(self.state(t)[0])
        return self._start(t, shortest_delta_deg(actual, target_deg), commanded, max_rate_dps)

    def _start(
        self, t: float, delta_deg: float, commanded_deg: float, max_rate_dps: float | None
    ) -> float:
        """Move by ``delta_deg`` from the present angle; ``commanded_deg`` is the move as ordered
        (the angle from the last commanded position), which sizes the sensor disturbance."""
        if self.is_moving(t):
            raise TableBusyError(f"table still moving at t={t:.3f} s")
        start, _ = self.state(t)
        v = (
            self.spec.max_rate_dps
            if max_rate_dps is None
            else min(max_rate_dps, self.spec.max_rate_dps)
        )
        a = self.spec.max_accel_dps2
        err = (
            self._rng.normal(0.0, self.spec.indexing_error_deg)
            if self.spec.indexing_error_deg
            else 0.0
        )
        self._target = float(start) + delta_deg
        self._motion_start = t
        d = self._target + err - float(start)
        s = math.copysign(1.0, d)
        dist = abs(d)
        if self._stalled or dist == 0.0:
            self._segments = [_Segment(-math.inf, float(start), 0.0, 0.0)]
            self._motion_end = t
            self._overshoot = 0.0  # no move, no ring-down
            return t
        self._moves.append((float(t), float(commanded_deg)))
        ta, tc = move_phases_s(dist, v, a)
        vp = a * ta
        a1 = float(start) + s * 0.5 * a * ta * ta
        a2 = a1 + s * vp * tc
        self._segments = [
            _Segment(-math.inf, float(start), 0.0, 0.0),
            _Segment(t, float(start), 0.0, s * a),
            _Segment(t + ta, a1, s * vp, 0.0),
            _Segment(t + ta + tc, a2, s * vp, -s * a),
            _Segment(t + 2 * ta + tc, float(start) + d, 0.0, 0.0),
        ]
        self._motion_end = t + 2 * ta + tc
        self._overshoot = s * self.spec.overshoot_deg
        return self._motion_end

    def spin(self, t: float, rate_dps: float) -> float:
        """Start turning from rest at time ``t`` towards ``rate_dps`` at the acceleration limit and
        hold that rate (with the specified ripple) until :meth:`stop`; return when the rate is
        reached (the start of the steady spin).

        Raises
        ------
        TableBusyError
            The table is moving at ``t``.
        """
        if self.is_moving(t):
            raise TableBusyError(f"table still moving at t={t:.3f} s")
        start = float(self.state(t)[0])
        self._motion_start = t
        if self._stalled or rate_dps == 0.0:
            self._segments = [_Segment(-math.inf, start, 0.0, 0.0)]
            self._motion_end = t
            return t
        # A spin logs no move (the move log, which sizes the moves by the motor's heat, stays as
        # it is): its ramp and its steady turning go to logs of their own, which the drive's
        # heat while turning reads (spec.spin_heat, northfinder.driver.protocol.heat).
        a = self.spec.max_accel_dps2
        ta = abs(rate_dps) / a
        self._ramps.append((float(t), 0.5 * abs(rate_dps) * ta))
        self._spins.append((t + ta, math.inf, float(rate_dps)))
        a1 = start + 0.5 * rate_dps * ta
        self._segments = [
            _Segment(-math.inf, start, 0.0, 0.0),
            _Segment(t, start, 0.0, math.copysign(a, rate_dps)),
            _Segment(
                t + ta, a1, rate_dps, 0.0, self.spec.rate_ripple, self.spec.rate_ripple_phase_deg
            ),
        ]
        self._motion_end = math.inf
        self._overshoot = 0.0
        self._steady = (t + ta, math.inf)
        return t + ta

    def is_steady(self, t: ArrayLike) -> NDArray[np.bool_]:
        """Whether the table turns at the steady rate of a spin at times ``t`` (s)."""
        tt = np.asarray(t, dtype=float)
        return (tt >= self._steady[0]) & (tt < self._steady[1])

    @property
    def steady_start_s(self) -> float:
        """When the present (or last) spin reached its rate, s (inf: none)."""
        return self._steady[0]

    @property
    def steady_end_s(self) -> float:
        """When the present (or last) spin's steady rate ended (STOP), s (inf: still turning)."""
        return self._steady[1]

    def stop(self, t: float) -> float:
        """Decelerate at the acceleration limit from time ``t``; return when the table is at rest."""
        if self._steady[0] <= t < self._steady[1]:
            self._steady = (self._steady[0], t)
        elif t < self._steady[0] < math.inf:
            self._steady = (math.inf, math.inf)  # stopped while still accelerating
        braking = bool(self._spins) and self._spins[-1][0] <= t < self._spins[-1][1]
        if self._spins and self._spins[-1][1] > t:
            t0, _, r = self._spins[-1]
            self._spins[-1] = (t0, max(t, t0), r)  # ends here (empty: stopped on the ramp)
        angle, rate = (float(x) for x in self.state(t))
        if rate == 0.0:
            self._motion_end = min(self._motion_end, t)
            self._segments = [_Segment(-math.inf, angle, 0.0, 0.0)]
            self._target = angle
            return t
        a = self.spec.max_accel_dps2
        tb = abs(rate) / a
        acc = -math.copysign(a, rate)
        if braking:
            self._ramps.append((float(t), 0.5 * abs(rate) * tb))  # a spin's braking ramp
        end_angle = angle + rate * tb + 0.5 * acc * tb * tb
        keep = [s for s in self._segments if s.t0 <= t]
        self._segments = [
            *keep,
            _Segment(t, angle, rate, acc),
            _Segment(t + tb, end_angle, 0.0, 0.0),
        ]
        self._motion_end = t + tb
        self._target = end_angle
        self._overshoot = 0.0
        return self._motion_end

    def stall(self, t: float, stalled: bool = True) -> None:
        """Simulate a jammed table: it stops where it is and does not move until released.

        Moves ordered while jammed end at once, short of their target: the firmware sees the
        encoder disagree with the command.
        """
        if stalled:
            ramps = len(self._ramps)
            self.stop(t)
            del self._ramps[ramps:]  # a jammed table does not brake: no braking ramp
            # A jammed table stops at once, not on a deceleration ramp.
            angle = float(self.state(t)[0])
            self._segments = [_Segment(-math.inf, angle, 0.0, 0.0)]
            # A move in progress ends now; a table at rest stays at rest since it came to rest
            # (a jam at rest shows nothing until the next move).
            self._motion_end = min(self._motion_end, t)
        self._stalled = stalled

    # -- queries ------------------------------------------------------------------------------
    @property
    def target_deg(self) -> float:
        """The commanded angle modulo 360 (the table ends near it, off by the indexing error)."""
        return self._target % 360.0

    @property
    def moves(self) -> list[tuple[float, float]]:
        """Every move started so far: (start time s, commanded angle turned deg), in order."""
        return self._moves

    @property
    def ramps(self) -> list[tuple[float, float]]:
        """The ramps of every spin so far, up to the rate and braking: (start time s, angle
        turned deg), in order (not in :attr:`moves`)."""
        return self._ramps

    @property
    def spins(self) -> list[tuple[float, float, float]]:
        """The steady turning of every spin so far: (start s, end s, rate deg/s), in order; the
        end is inf while the table spins, the start where a spin stopped on its ramp."""
        return self._spins

    @property
    def stalled(self) -> bool:
        return self._stalled

    @property
    def motion_start_s(self) -> float:
        return self._motion_start

    @property
    def motion_end_s(self) -> float:
        return self._motion_end

    def is_moving(self, t: float) -> bool:
        """True while the commanded profile runs (settling oscillation not included)."""
        return t < self._motion_end

    def is_settled(self, t: float) -> bool:
        return t >= self._motion_end + self.spec.settle_s

    def state(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """True (continuous) angle in deg and rate in deg/s at times ``t`` (s), same shape as ``t``."""
        tt = np.asarray(t, dtype=float)
        starts = np.array([s.t0 for s in self._segments])
        idx = np.searchsorted(starts, tt, side="right") - 1
        if (
            idx.size
            and idx.min() == idx.max()
            and not math.isfinite(self._segments[int(idx.flat[0])].t0)
        ):
            angle, rate = np.full_like(tt, self._segments[int(idx.flat[0])].a0), np.zeros_like(tt)
            segs: list[int] = []
        else:
            angle, rate = np.empty_like(tt), np.empty_like(tt)
            segs = [int(i) for i in np.unique(idx)]
        for i in segs:
            seg = self._segments[int(i)]
            sel = idx == i
            dt = tt[sel] - seg.t0 if math.isfinite(seg.t0) else np.zeros(np.count_nonzero(sel))
            angle[sel], rate[sel] = seg.at(dt)
        if self._overshoot and math.isfinite(self._motion_end):
            # Damped ring-down after the stop; tau = settle/8 leaves 0.03 % at the end of settling.
            x = tt - self._motion_end
            tau = max(self.spec.settle_s / 8.0, 1e-3)
            on = (x > 0) & (x < 40.0 * tau)  # exp(-40) is far below any encoder resolution
            if np.any(on):
                w = 2 * math.pi * self.spec.overshoot_hz
                env = self._overshoot * np.exp(-x[on] / tau)
                angle[on] += env * np.sin(w * x[on])
                rate[on] += env * (w * np.cos(w * x[on]) - np.sin(w * x[on]) / tau)
        return angle, rate

    def encoder(self, angle_deg: ArrayLike) -> NDArray[np.float64]:
        """What the encoder reports for true angles: with its periodic error, modulo 360,
        quantised to its resolution."""
        return np.mod(encoder_reading_deg(self.spec, angle_deg), 360.0)
