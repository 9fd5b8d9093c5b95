"""The instrument's physics: Earth rate and gravity through the turntable into two sensor triads.

:class:`Instrument` produces samples at a fixed rate (200 Hz by default), either as whole blocks
(:meth:`Instrument.generate`) or step by step (:meth:`Instrument.advance`); both give identical
output for the same seed because every random process draws from its own stream in time order.

Each sample is the increment over its interval expressed as a mean rate (rad/s) or mean specific
force (m/s^2), as pulse-counting outputs deliver; quantisation carries its remainder to the next
sample, so window sums are exact to one least significant bit. The error terms are those of
:mod:`northfinder.firmware_sim.error_terms`, shared with the batch generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.motion import wobble_matrix
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.firmware_sim.earth import body_rates, check_latitude
from northfinder.firmware_sim.error_terms import (
    FLICKER_GRID_S,
    FLICKER_STD,
    FLICKER_TAUS_S,
    ErrorTerms,
    channels_si,
    check_sample_rate,
    draw_move,
    draw_turn_on,
    half_sine,
    move_bias,
    move_heat,
    quantise_carry,
    random_directions,
    slow_noise_steps,
    spin_heat_decay,
    spin_heat_innovations,
    temperature_c,
    vibration,
)
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.firmware_sim.turntable import Turntable

__all__ = ["MAX_BASE_TILT_DEG", "Instrument", "SampleBlock", "Truth", "body_rates"]

#: Largest pitch or roll the simulated base can stand at, deg.
MAX_BASE_TILT_DEG = 45.0


@dataclass(frozen=True)
class Truth:
    """Where the instrument really stands: azimuth clockwise from north, latitude, pitch, roll (deg)."""

    azimuth_deg: float = 0.0
    latitude_deg: float = DEFAULT_LATITUDE_DEG
    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise SimConfigError(f"truth {f.name}: must be a finite number, got {v!r}")
        check_latitude(self.latitude_deg, "truth latitude_deg")
        for name in ("pitch_deg", "roll_deg"):
            if abs(getattr(self, name)) > MAX_BASE_TILT_DEG:
                raise SimConfigError(
                    f"truth {name}: {getattr(self, name)} deg exceeds the +-{MAX_BASE_TILT_DEG} deg the "
                    "simulated base can stand at"
                )


@dataclass(frozen=True)
class SampleBlock:
    """Consecutive samples. Sample ``counter[i]`` covers ``(time_s[i] - 1/fs, time_s[i]]``.

    Attributes
    ----------
    counter : (n,) int64
        Sample number since power-on, starting at 0.
    time_s : (n,) float
        End of each sample interval, seconds since power-on.
    gyro_rps : (n, 3) float
        Gyro triad, mean rate over the interval, rad/s, sensor frame m1.
    accel_mps2 : (n, 3) float
        Accelerometer triad, mean specific force, m/s^2.
    table_deg : (n,) float
        Encoder reading at the end of the interval, [0, 360) deg.
    table_rate_dps : (n,) float
        True mean table rate over the interval, deg/s.
    temperature_c : (n,) float
        Sensor temperature, degC.
    gyro_saturated, accel_saturated : (n,) bool
        Any axis of the triad hit its range.
    """

    counter: NDArray[np.int64]
    time_s: NDArray[np.float64]
    gyro_rps: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    table_deg: NDArray[np.float64]
    table_rate_dps: NDArray[np.float64]
    temperature_c: NDArray[np.float64]
    gyro_saturated: NDArray[np.bool_]
    accel_saturated: NDArray[np.bool_]

    def __len__(self) -> int:
        return len(self.counter)

    @staticmethod
    def concat(blocks: list[SampleBlock]) -> SampleBlock:
        """Join blocks in order."""
        return SampleBlock(
            *(np.concatenate([getattr(b, f.name) for b in blocks]) for f in fields(SampleBlock))
        )


def _times(v: NDArray[np.float64], m: NDArray[np.float64]) -> NDArray[np.float64]:
    """``v @ m`` summed in a fixed order, so that a row's result does not depend on how many rows
    are computed together (a matrix product's blocking does): output computed in chunks of any
    length, or again after a rewind, is then the same to the last bit."""
    out = np.zeros((v.shape[0], m.shape[1]))
    for i in range(m.shape[0]):
        for j in np.flatnonzero(m[i]):
            out[:, j] += v[:, i] * m[i, j]
    return out


class _SlowNoise:
    """Flicker noise and random walks on the coarse grid of
    :mod:`~northfinder.firmware_sim.error_terms`, interpolated to the sample times."""

    def __init__(self, rng: np.random.Generator, nch: int) -> None:
        self.rng = rng
        self._state = rng.standard_normal((len(FLICKER_TAUS_S), nch))
        self._walk = np.zeros(nch)
        self._k0 = 0
        self._flicker = self._state.sum(axis=0)[None, :]
        self._walks = self._walk[None, :].copy()

    def _extend(self, k_last: int) -> None:
        m = k_last - (self._k0 + len(self._flicker) - 1)
        if m <= 0:
            return
        w = self.rng.standard_normal((m, len(FLICKER_TAUS_S) + 1, self._walk.size))
        flicker, walks, self._state, self._walk = slow_noise_steps(w, self._state, self._walk)
        self._flicker = np.concatenate([self._flicker, flicker])
        self._walks = np.concatenate([self._walks, walks])

    def values(
        self, t: NDArray[np.float64], flicker_b: NDArray[np.float64], walk_k: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Slow noise at increasing times ``t`` (s), shape ``(len(t), nch)``, SI units."""
        pos = t / FLICKER_GRID_S
        self._extend(math.floor(pos[-1]) + 1)
        drop = math.floor(pos[0]) - self._k0
        if drop > 0:
            self._flicker, self._walks = self._flicker[drop:], self._walks[drop:]
            self._k0 += drop
        coarse = self._flicker * (flicker_b * FLICKER_STD) + self._walks * walk_k
        grid = np.arange(len(coarse)) + self._k0
        out = np.empty((len(t), coarse.shape[1]))
        for j in np.flatnonzero(flicker_b + walk_k):
            out[:, j] = np.interp(pos, grid, coarse[:, j])
        for j in np.flatnonzero(flicker_b + walk_k == 0):
            out[:, j] = 0.0
        return out


class Instrument:
    """Turntable, gyro triad and accelerometer triad of one simulated north finder.

    Parameters
    ----------
    spec : SensorSpec
        Sensor, environment and table specification (datasheet units).
    truth : Truth
        Azimuth, latitude, pitch and roll of the base.
    rng : numpy.random.Generator
        Seeded generator; the instrument spawns independent streams from it.
    sample_rate_hz : float
        Output rate, 200 Hz by default.
    table_angle_deg : float
        Table angle at power-on.
    """

    def __init__(
        self,
        spec: SensorSpec,
        truth: Truth,
        rng: np.random.Generator,
        *,
        sample_rate_hz: float = 200.0,
        table_angle_deg: float = 0.0,
    ) -> None:
        self.sample_rate_hz = check_sample_rate(sample_rate_hz)
        turn_on, white, slow, impulses, table, moves = rng.spawn(6)
        self._draws = draw_turn_on(turn_on)
        self._move_rng = moves
        self._moves_seen = 0  # moves of the table registered so far
        self._move_start = np.empty(0)  # moves whose transient still matters: start s,
        self._move_size = np.empty(0)  # commanded angle deg,
        self._move_z = np.empty((0, 2, 6))  # z-scores
        self._move_steps = np.zeros(6)  # sum of sqrt(|size|) z_walk of the moves dropped from those
        # The drive's heat while spinning (table.spin_heat) draws from a stream of its own, so
        # that instruments which never spin with it keep every draw.
        self._heat_rng = moves.spawn(1)[0]
        self._ramps_seen = 0  # spins' ramps registered so far (as moves)
        self._heat = np.zeros((2, 6))  # the steady turning's walk and transient at the last sample
        self._white = white
        self._slow = _SlowNoise(slow, 6)
        self._imp_rng = impulses
        self._imp_next = math.inf
        self._events: list[tuple[float, float, NDArray[np.float64]]] = []
        # Bursts not yet drawn: (first start, interval, next index, count, duration, amplitude).
        self._bursts: list[tuple[float, float, int, int, float, NDArray[np.float64]]] = []
        self._k = 0
        self._clock = 0.0
        self._remainder = np.zeros(6)
        self._extra_bias = np.zeros(6)
        self._vibration: tuple[float, NDArray[np.float64]] | None = None
        self.vibration_on = True
        self.table = Turntable(spec.table, table, table_angle_deg)
        self.truth = truth
        self.set_spec(spec)

    # -- configuration ------------------------------------------------------------------------
    def set_spec(self, spec: SensorSpec) -> None:
        """Change the specification while running; drawn turn-on errors keep their z-scores."""
        self.spec = spec
        terms = self._terms = ErrorTerms.from_spec(spec)
        self._bias = terms.turn_on(self._draws.z_bias)
        self._white_sigma = terms.white_sigma(self.sample_rate_hz)
        mg, ma = terms.matrices(self._draws)
        self._m_t = np.zeros((6, 6))
        self._m_t[:3, :3], self._m_t[3:, 3:] = mg.T, ma.T
        self._identity = not terms.has_matrix
        d = spec.disturbance
        if d.impulse_rate_hz > 0 and not math.isfinite(self._imp_next):
            self._imp_next = self.time_s + self._imp_rng.exponential(1.0 / d.impulse_rate_hz)
        elif d.impulse_rate_hz == 0:
            self._imp_next = math.inf
        vib_amp = terms.vibration_amp
        self._vibration = (
            (d.vibration_hz, vib_amp) if d.vibration_hz > 0 and vib_amp.any() else None
        )
        self.table.spec = spec.table
        self._wobble = wobble_matrix(spec.table.wobble_urad, spec.table.wobble_phase_deg)

    def generators(self) -> tuple[np.random.Generator, ...]:
        """Every random generator the instrument draws from, the table's included.

        A snapshot of the instrument (the firmware's rewind) shares these and records their
        states instead of copying them: a generator's state is a small dict, its copy a pickle.
        """
        return (self._white, self._slow.rng, self._imp_rng, self._move_rng, self._heat_rng,
                *self.table.generators())  # fmt: skip

    @property
    def terms(self) -> ErrorTerms:
        """The error terms of the current specification (frozen)."""
        return self._terms

    def set_truth(self, truth: Truth) -> None:
        """Move the base; applies from the next sample on."""
        self.truth = truth

    # -- fault and disturbance injection ------------------------------------------------------
    def inject_bias_step(
        self,
        gyro_dph: tuple[float, float, float] = (0.0, 0.0, 0.0),
        accel_ug: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        """Add a permanent bias step from the next sample on."""
        self._extra_bias += channels_si(gyro_dph, accel_ug)

    def inject_impulses(
        self,
        count: int,
        *,
        interval_s: float = 0.5,
        gyro_dph: float = 50.0,
        accel_ug: float = 5000.0,
        duration_s: float | None = None,
    ) -> None:
        """Queue a burst of ``count`` half-sine impulses, one every ``interval_s``, from now.

        Each impulse is drawn when it falls due, so a burst costs the same memory and time to
        queue whatever its count.
        """
        dur = self.spec.disturbance.impulse_duration_s if duration_s is None else duration_s
        amp = channels_si(gyro_dph, accel_ug)
        if int(count) > 0:
            self._bursts.append((self.time_s, float(interval_s), 0, int(count), dur, amp))

    def set_vibration(
        self, on: bool, *, hz: float = 35.0, gyro_dph: float = 5.0, accel_ug: float = 2000.0
    ) -> None:
        """Switch vibration on or off; with no vibration in the spec, ``on`` uses the given line."""
        self.vibration_on = bool(on)
        if on and self._vibration is None:
            self._vibration = (hz, channels_si(gyro_dph, accel_ug))

    def _direction(self) -> NDArray[np.float64]:
        return random_directions(self._imp_rng, 1)[0]

    # -- sampling ------------------------------------------------------------------------------
    @property
    def samples_emitted(self) -> int:
        return self._k

    @property
    def clock_s(self) -> float:
        """Simulated time reached by :meth:`advance`, s (at or after the last sample's time)."""
        return max(self._clock, self.time_s)

    @property
    def time_s(self) -> float:
        """Time of the last emitted sample, seconds since power-on."""
        return self._k / self.sample_rate_hz

    def temperature(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Sensor temperature at times ``t``, degC."""
        return temperature_c(self.spec.thermal, t)

    def advance(self, dt: float) -> SampleBlock:
        """Advance the clock by ``dt`` seconds and return the samples that fell due."""
        if not (math.isfinite(dt) and dt >= 0):
            raise SimConfigError(f"dt: must be a finite non-negative number of seconds, got {dt!r}")
        self._clock = max(self._clock, self.time_s) + dt
        due = math.floor(self._clock * self.sample_rate_hz + 1e-6) - self._k
        return self.generate(max(due, 0))

    def generate(self, n: int) -> SampleBlock:
        """The next ``n`` samples as one block."""
        fs = self.sample_rate_hz
        k = self._k + np.arange(n, dtype=np.int64)
        edges = (self._k + np.arange(n + 1)) / fs
        t = edges[1:]
        angle, _ = self.table.state(edges)
        table_rate = np.diff(angle) * fs
        omega_b, f_b = body_rates(
            self.truth.azimuth_deg,
            self.truth.pitch_deg,
            self.truth.roll_deg,
            self.truth.latitude_deg,
        )
        out = np.empty((n, 6))
        if n and np.ptp(angle) == 0.0:
            # The table is still: every sample sees the same true vector, so apply the error
            # matrix to that one vector instead of to every sample.
            mu0 = math.radians(angle[0])
            c0, s0 = math.cos(mu0), math.sin(mu0)
            true = np.array(
                [
                    c0 * omega_b[0] + s0 * omega_b[1],
                    -s0 * omega_b[0] + c0 * omega_b[1],
                    omega_b[2],
                    c0 * f_b[0] + s0 * f_b[1],
                    -s0 * f_b[0] + c0 * f_b[1],
                    f_b[2],
                ]
            )
            if self._wobble is not None:
                true = (true.reshape(2, 3) @ self._wobble.T).reshape(6)
            if not self._identity:
                true = _times(true[None, :], self._m_t)[0]
            out[:] = true + self._bias + self._extra_bias
        else:
            mu = np.radians(angle)
            cm, sm = np.cos(mu), np.sin(mu)
            # Means of cos and sin over each interval, exact for a constant rate within it (the
            # trapezoid where the table hardly moves): a turning table's samples keep the phase
            # of the angle at mid-interval.
            dmu = np.diff(mu)
            turning = np.abs(dmu) > 1e-6
            safe = np.where(turning, dmu, 1.0)
            c = np.where(turning, (sm[1:] - sm[:-1]) / safe, 0.5 * (cm[:-1] + cm[1:]))
            s = np.where(turning, -(cm[1:] - cm[:-1]) / safe, 0.5 * (sm[:-1] + sm[1:]))
            out[:, 0] = c * omega_b[0] + s * omega_b[1]
            out[:, 1] = -s * omega_b[0] + c * omega_b[1]
            out[:, 2] = omega_b[2] + np.radians(table_rate)
            out[:, 3] = c * f_b[0] + s * f_b[1]
            out[:, 4] = -s * f_b[0] + c * f_b[1]
            out[:, 5] = f_b[2]
            if self._wobble is not None:
                out[:, :3] = out[:, :3] @ self._wobble.T
                out[:, 3:] = out[:, 3:] @ self._wobble.T
            if not self._identity:
                out = _times(out, self._m_t)
            out += self._bias + self._extra_bias
        terms = self._terms
        if terms.warmup_bias.any():
            out += terms.warmup(t)
        temperature = self.temperature(t)
        if terms.temp_coeff.any():
            out += terms.thermal(temperature, self.spec.thermal)
        if terms.ramp.any():
            out += terms.ramp_bias(t)
        if n:
            self._add_moves(out, t)
        if n and self._white_sigma.any():
            noise = self._white.standard_normal((n, 6))
            noise *= self._white_sigma
            out += noise
        if n and (terms.flicker_b.any() or terms.walk_k.any()):
            out += self._slow.values(t - 0.5 / fs, terms.flicker_b, terms.walk_k)
        if n:
            self._add_impulses(out, t)
        if n and self._vibration is not None and self.vibration_on:
            hz, amp = self._vibration
            out += vibration(t[:, None], hz, amp, self._draws.vib_phase)
        limit = terms.range
        sat = np.zeros((n, 6), dtype=bool)
        if n and (np.any(out.max(axis=0) > limit) or np.any(out.min(axis=0) < -limit)):
            np.greater(np.abs(out), limit, out=sat)
            np.clip(out, -limit, limit, out=out)
        self._quantise(out)
        self._k += n
        self._clock = max(self._clock, self.time_s)
        return SampleBlock(
            counter=k,
            time_s=t,
            gyro_rps=out[:, :3],
            accel_mps2=out[:, 3:],
            table_deg=self.table.encoder(angle[1:]),
            table_rate_dps=table_rate,
            temperature_c=temperature,
            gyro_saturated=np.any(sat[:, :3], axis=1),
            accel_saturated=np.any(sat[:, 3:], axis=1),
        )

    def _add_moves(self, out: NDArray[np.float64], t: NDArray[np.float64]) -> None:
        """Register the table's new moves (drawing their z-scores in order) and add their bias."""
        terms = self._terms
        moves = self.table.moves
        new = len(moves) - self._moves_seen
        if new:
            # Sized as they start, from every move so far (the motor's heat).
            start, angle = np.array(moves).T
            size = move_heat(start, angle, terms.move_heat_tau_s, last=new)
            self._moves_seen = len(moves)
            self._move_start = np.append(self._move_start, start[-new:])
            self._move_size = np.append(self._move_size, size)
            self._move_z = np.concatenate([self._move_z, draw_move(self._move_rng, (new,))])
        self._register_ramps()
        if not terms.has_move_terms:
            return
        # A transient 60 time constants old is below 1e-26 of its size: keep only its step.
        old = t[0] - self._move_start > 60.0 * terms.move_tau_s.max()
        if old.any():
            self._move_steps += (np.sqrt(np.abs(self._move_size[old]))[:, None]
                                 * self._move_z[old, 0]).sum(axis=0)  # fmt: skip
            keep = ~old
            self._move_start = self._move_start[keep]
            self._move_size = self._move_size[keep]
            self._move_z = self._move_z[keep]
        out += self._move_steps * terms.move_walk
        if self._move_start.size:
            out += move_bias(terms, t, self._move_start, self._move_size, self._move_z)
        self._add_spin_heat(out, t)

    def _register_ramps(self) -> None:
        """Register the ramps of spins (up to the rate and braking) as moves of the drive's heat:
        each one move of ``spin_heat`` times its angle (:mod:`northfinder.driver.protocol.heat`)."""
        ramps = self.table.ramps
        new = len(ramps) - self._ramps_seen
        spin_heat = self.spec.table.spin_heat
        if not new or spin_heat <= 0.0 or not self._terms.has_move_terms:
            self._ramps_seen = len(ramps)  # no heat: the ramps start nothing, now or later
            return
        start, angle = np.array(ramps[-new:]).T
        self._ramps_seen = len(ramps)
        self._move_start = np.append(self._move_start, start)
        self._move_size = np.append(self._move_size, spin_heat * angle)
        self._move_z = np.concatenate([self._move_z, draw_move(self._heat_rng, (new,))])

    def _add_spin_heat(self, out: NDArray[np.float64], t: NDArray[np.float64]) -> None:
        """Add the drive's heat while the table turns steadily: per channel a Gauss-Markov
        transient and a random walk in the angle turned, drawn sample by sample in time order
        (:func:`~northfinder.firmware_sim.error_terms.spin_heat_innovations`)."""
        terms = self._terms
        steps = spin_heat_innovations(
            terms, self.spec.table.spin_heat, self.table.spins, t, self.sample_rate_hz
        )
        walk, trans = self._heat
        if steps is None:
            if not (walk.any() or trans.any()):
                return
            u = np.zeros((t.size, 2, 6))
            phi = spin_heat_decay(terms, self.sample_rate_hz)
        else:
            phi, std = steps
            on = std.any(axis=(1, 2))
            u = np.zeros_like(std)
            u[on] = self._heat_rng.standard_normal((int(on.sum()), 2, 6)) * std[on]
        from scipy.signal import lfilter  # imported when first needed: it takes a second

        # The walk summed from its last value, as sample-by-sample steps would sum it.
        walks = np.cumsum(np.concatenate([walk[None, :], u[:, 0, :]]), axis=0)[1:]
        transients = np.empty((t.size, 6))
        for ch in range(6):
            if trans[ch] or u[:, 1, ch].any():
                transients[:, ch] = lfilter(
                    [1.0], [1.0, -phi[ch]], u[:, 1, ch], zi=[phi[ch] * trans[ch]]
                )[0]
            else:
                transients[:, ch] = 0.0
        # A transient 60 time constants old is below 1e-26 of its size: drop it.
        spins = self.table.spins
        if steps is None and spins and t[-1] - spins[-1][1] > 60.0 * terms.move_tau_s.max():
            transients[-1] = 0.0
        self._heat = np.stack([walks[-1], transients[-1]])
        out += walks + transients

    def _add_impulses(self, out: NDArray[np.float64], t: NDArray[np.float64]) -> None:
        rate = self.spec.disturbance.impulse_rate_hz
        while self._imp_next <= t[-1]:
            amp = self._terms.impulse_amp * self._direction()
            self._events.append((self._imp_next, self.spec.disturbance.impulse_duration_s, amp))
            self._imp_next += self._imp_rng.exponential(1.0 / rate) if rate > 0 else math.inf
        bursts = []
        for first, interval, i, count, dur, amp in self._bursts:
            while i < count and first + i * interval <= t[-1]:
                self._events.append((first + i * interval, dur, amp * self._direction()))
                i += 1
            if i < count:
                bursts.append((first, interval, i, count, dur, amp))
        self._bursts = bursts
        t0, t1 = t[0] - 1.0 / self.sample_rate_hz, t[-1]
        keep = []
        for start, dur, amp in self._events:
            if start + dur <= t0:
                continue
            keep.append((start, dur, amp))
            if start >= t1:
                continue
            x = (t - start) / dur
            on = (x > 0) & (x < 1)
            out[on] += half_sine(x[on])[:, None] * amp
        self._events = keep

    def _quantise(self, out: NDArray[np.float64]) -> None:
        lsb = self._terms.lsb
        ch = np.flatnonzero(lsb)
        if ch.size:
            counts, self._remainder[ch] = quantise_carry(
                out[:, ch] / lsb[ch], self._remainder[ch], axis=0
            )
            out[:, ch] = counts * lsb[ch]
