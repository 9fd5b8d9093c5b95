"""The sensor error terms, defined once for every generator of sensor data.

The step-by-step instrument (:class:`northfinder.firmware_sim.imu.Instrument`) and the batch
generator (:func:`northfinder.firmware_sim.batch.simulate_windows`) draw their samples from the
definitions here, so that both describe the same sensor: the conversion of a :class:`SensorSpec`
from datasheet units to SI (:class:`ErrorTerms`), the sample rates the model honours, the turn-on
draws and error matrices, the temperature model, the warm-up transient, the flicker-noise model
(a sum of Gauss-Markov processes) with its random walks, impulses, the vibration line and
quantisation with carry, the rate ramp, and the bias disturbances that table moves start. Host
code that predicts accuracy from a spec (the study's error model) uses the same conversion and
flicker constants.

Channel layout
--------------
Every per-channel array has six entries on its last axis: gyro x, y, z (rad/s), then
accelerometer x, y, z (m/s^2); :data:`GYRO` and :data:`ACCEL` slice them.

Flicker noise
-------------
Bias instability ``B`` is flicker noise with one-sided PSD ``B^2 / (pi f)`` (IEEE Std 952's
``(B^2 / 2 pi) / f``, two-sided), whose Allan deviation has its floor ``B sqrt(2 ln 2 / pi) =
0.664 B``. It is built on a grid of :data:`FLICKER_GRID_S` from first-order Gauss-Markov
components with correlation times :data:`FLICKER_TAUS_S` (1 s to 10^4 s, spaced by sqrt(10)):
``n`` components of variance ``c`` spaced by a ratio ``r`` sum to the PSD ``c / (f ln r)``, so
``c = B^2 ln r / pi`` (:data:`FLICKER_VARIANCE` is ``c / B^2``) gives ``B^2 / (pi f)`` between a
few seconds and a few thousand seconds. Components are kept at unit variance and scaled on
output, so noise levels can change while running without a jump in the random sequence. Random
walks (gyro rate random walk, accelerometer bias random walk) are integrated on the same grid.

Moves
-----
Every table move of ``d`` degrees (the commanded angle turned) starting at ``t0`` draws two
standard normal vectors ``z_walk`` and ``z_transient`` (:func:`draw_move`) and adds, from ``t0``
on, ``sqrt(q) * (move_walk * z_walk + move_transient * z_transient * exp(-(t - t0) / tau))``:
a lasting bias step (a random walk in the angle turned) and a transient that decays with the
time constant ``tau`` (the mechanical and thermal disturbance of the sensor by the drive). The
size ``q`` (deg) is the heat the motor holds when the move starts (:func:`move_heat`): the angles
of this and every earlier move, each decayed with the table's ``heat_tau_s``; with that at 0,
``q = |d|``, so that two half moves disturb as much as one whole move. A position the table
already holds needs no move and adds nothing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from northfinder.driver.protocol.heat import move_heat, spin_heat_state, spin_heat_steps
from northfinder.driver.protocol.units import DPH, DPH_PSH, DPS, DPSH, G0, UG
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.sensors import SensorSpec, ThermalSpec

__all__ = [
    "ACCEL",
    "FLICKER_GAIN",
    "FLICKER_GRID_S",
    "FLICKER_PHI",
    "FLICKER_STD",
    "FLICKER_TAUS_S",
    "FLICKER_VARIANCE",
    "GYRO",
    "MAX_SAMPLE_RATE_HZ",
    "MIN_SAMPLE_RATE_HZ",
    "Channels",
    "ErrorTerms",
    "Triads",
    "TurnOnDraws",
    "channels_si",
    "check_sample_rate",
    "draw_move",
    "draw_turn_on",
    "half_sine",
    "move_bias",
    "move_heat",
    "quantise_carry",
    "random_directions",
    "slow_noise_jump",
    "slow_noise_steps",
    "slow_noise_window",
    "spin_heat_bias",
    "spin_heat_decay",
    "spin_heat_innovations",
    "temperature_c",
    "triad_matrices",
    "vibration",
]

#: Sample rates the model honours, Hz. Below 10 Hz the slow-noise grid (0.1 s) would alias.
MIN_SAMPLE_RATE_HZ = 10.0
MAX_SAMPLE_RATE_HZ = 2000.0

#: The gyro and accelerometer channels of a six-channel array (last axis).
GYRO = slice(0, 3)
ACCEL = slice(3, 6)
#: A value per channel, shape (..., 6): gyro x, y, z then accelerometer x, y, z, SI.
Channels = NDArray[np.float64]
#: A value per triad, shape (2,): gyro, then accelerometer.
Triads = NDArray[np.float64]

#: Step of the grid on which flicker noise and random walks are generated, s.
FLICKER_GRID_S = 0.1
#: Correlation times of the Gauss-Markov components of flicker noise, s (1 to 10^4, ratio sqrt 10).
FLICKER_TAUS_S: NDArray[np.float64] = 10.0 ** np.arange(0.0, 4.01, 0.5)
#: Variance of each component per B^2 (B = bias instability in SI): ln(sqrt 10) / pi.
FLICKER_VARIANCE = math.log(10.0**0.5) / math.pi
#: Standard deviation of each component per B: sqrt(FLICKER_VARIANCE).
FLICKER_STD = math.sqrt(FLICKER_VARIANCE)
#: Per-grid-step decay of each component, exp(-FLICKER_GRID_S / tau).
FLICKER_PHI: NDArray[np.float64] = np.exp(-FLICKER_GRID_S / FLICKER_TAUS_S)
#: Per-grid-step innovation gain of each unit-variance component, sqrt(1 - phi^2).
FLICKER_GAIN: NDArray[np.float64] = np.sqrt(1.0 - FLICKER_PHI**2)


def check_sample_rate(sample_rate_hz: float) -> float:
    """Return ``sample_rate_hz`` as float if the model honours it.

    Raises
    ------
    SimConfigError
        Not finite, or outside [:data:`MIN_SAMPLE_RATE_HZ`, :data:`MAX_SAMPLE_RATE_HZ`].
    """
    fs = float(sample_rate_hz)
    if not (math.isfinite(fs) and MIN_SAMPLE_RATE_HZ <= fs <= MAX_SAMPLE_RATE_HZ):
        raise SimConfigError(
            f"sample_rate_hz: {sample_rate_hz!r} Hz cannot be honoured; the model runs from "
            f"{MIN_SAMPLE_RATE_HZ:g} to {MAX_SAMPLE_RATE_HZ:g} Hz"
        )
    return fs


def channels_si(gyro_dph: ArrayLike, accel_ug: ArrayLike) -> NDArray[np.float64]:
    """Six SI channel values from a gyro value in deg/h and an accelerometer value in ug.

    Each argument is a scalar (the same on the three axes) or three values (x, y, z).
    Returns shape ``(6,)``: rad/s, then m/s^2.
    """
    g = np.broadcast_to(np.asarray(gyro_dph, dtype=float) * DPH, (3,))
    a = np.broadcast_to(np.asarray(accel_ug, dtype=float) * UG, (3,))
    return np.concatenate([g, a])


@dataclass(frozen=True)
class ErrorTerms:
    """The error terms of a :class:`SensorSpec` in SI, one entry per channel (see module doc).

    Build with :meth:`from_spec`. Gyro entries are in rad/s (noise densities in rad/s/sqrt(Hz),
    walks in rad/s/sqrt(s)), accelerometer entries in m/s^2 (m/s^2/sqrt(Hz), m/s^2/sqrt(s)).

    Attributes
    ----------
    bias : (6,) float
        Constant bias.
    turn_on_bias : (6,) float
        Turn-on to turn-on bias repeatability, 1 sigma.
    white_density : (6,) float
        White noise density (ARW, VRW); per sample it is ``white_density * sqrt(fs)``.
    flicker_b : (6,) float
        Flicker bias instability ``B`` (Allan floor 0.664 B).
    walk_k : (6,) float
        Random-walk coefficient (gyro rate random walk, accelerometer bias random walk).
    scale_factor, misalignment : (2,) float
        Scale-factor error (fraction) and misalignment (rad) of the gyro and the accelerometer
        triad, 1 sigma.
    lsb : (6,) float
        Output quantum; 0 = none.
    range : (6,) float
        Measurement range (the output clips at +-range).
    warmup_bias, warmup_tau_s : (6,) float
        Amplitude of the warm-up transient at power-on and its time constant, s.
    temp_coeff : (6,) float
        Bias change per degC of sensor temperature.
    impulse_amp, vibration_amp : (6,) float
        Peak of one impulse (shock), amplitude of the vibration line.
    ramp : (6,) float
        Linear bias trend from power-on, per second (rate ramp).
    move_walk, move_transient : (6,) float
        Lasting bias step and initial transient amplitude of a move, 1 sigma per sqrt(deg) turned.
    move_tau_s : (6,) float
        Time constant of the move transient, s.
    move_heat_tau_s : float
        Time constant of the motor's heat that sizes the move terms, s (0: each move alone).
    """

    bias: Channels
    turn_on_bias: Channels
    white_density: Channels
    flicker_b: Channels
    walk_k: Channels
    scale_factor: Triads
    misalignment: Triads
    lsb: Channels
    range: Channels
    warmup_bias: Channels
    warmup_tau_s: Channels
    temp_coeff: Channels
    impulse_amp: Channels
    vibration_amp: Channels
    ramp: Channels
    move_walk: Channels
    move_transient: Channels
    move_tau_s: Channels
    move_heat_tau_s: float

    @classmethod
    def from_spec(cls, spec: SensorSpec) -> ErrorTerms:
        """Convert the datasheet values of ``spec`` to SI."""
        g, a = spec.gyro, spec.accel
        return cls(
            bias=channels_si(g.bias_dph, a.bias_ug),
            turn_on_bias=channels_si(g.turn_on_bias_dph, a.turn_on_bias_ug),
            white_density=np.repeat([g.arw_dpsh * DPSH, a.vrw_ug_rthz * UG], 3),
            flicker_b=channels_si(g.bias_instability_dph, a.bias_instability_ug),
            walk_k=np.repeat([g.rrw_dphpsh * DPH_PSH, a.random_walk_ug_rts * UG], 3),
            scale_factor=np.array([g.scale_factor_ppm, a.scale_factor_ppm]) * 1e-6,
            misalignment=np.array([g.misalignment_urad, a.misalignment_urad]) * 1e-6,
            lsb=channels_si(g.lsb_dph, a.lsb_ug),
            range=np.repeat([g.range_dps * DPS, a.range_g * G0], 3),
            warmup_bias=channels_si(g.warmup_bias_dph, a.warmup_bias_ug),
            warmup_tau_s=np.repeat([g.warmup_tau_s, a.warmup_tau_s], 3),
            temp_coeff=channels_si(g.temp_coeff_dph_per_c, a.temp_coeff_ug_per_c),
            impulse_amp=channels_si(g.impulse_dph, a.impulse_ug),
            vibration_amp=channels_si(g.vibration_dph, a.vibration_ug),
            ramp=channels_si(g.rate_ramp_dph_per_h, a.ramp_ug_per_h) / 3600.0,
            move_walk=channels_si(g.move_walk_dph_per_rtdeg, a.move_walk_ug_per_rtdeg),
            move_transient=channels_si(
                g.move_transient_dph_per_rtdeg, a.move_transient_ug_per_rtdeg
            ),
            move_tau_s=np.repeat([g.move_transient_tau_s, a.move_transient_tau_s], 3),
            move_heat_tau_s=spec.table.heat_tau_s,
        )

    def white_sigma(self, sample_rate_hz: float) -> NDArray[np.float64]:
        """Standard deviation of the white noise of one sample at ``sample_rate_hz``, (6,)."""
        return self.white_density * math.sqrt(sample_rate_hz)

    @property
    def has_matrix(self) -> bool:
        """True when scale-factor or misalignment errors make the error matrices non-identity."""
        return bool(self.scale_factor.any() or self.misalignment.any())

    def turn_on(self, z_bias: NDArray[np.float64]) -> NDArray[np.float64]:
        """Bias of one power-on from its z-scores ``z_bias`` (..., 6)."""
        return self.bias + self.turn_on_bias * z_bias

    def matrices(self, draws: TurnOnDraws) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Gyro and accelerometer error matrices M of one power-on, each (..., 3, 3).

        A triad reads ``M @ true``: diagonal ``1 + scale factor``, off-diagonals misalignment.
        """
        sf, mis = self.scale_factor, self.misalignment
        return (
            triad_matrices(sf[0] * draws.z_sf[..., GYRO], mis[0] * draws.z_mis[..., 0, :]),
            triad_matrices(sf[1] * draws.z_sf[..., ACCEL], mis[1] * draws.z_mis[..., 1, :]),
        )

    def warmup(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Warm-up transient at times ``t`` (s since power-on), shape ``t.shape + (6,)``."""
        out = np.zeros((*np.shape(t), 6))
        for sl in (GYRO, ACCEL):
            if self.warmup_bias[sl].any():
                out[..., sl] = (
                    np.exp(-t / self.warmup_tau_s[sl][0])[..., None] * self.warmup_bias[sl]
                )
        return out

    def thermal(
        self, temperature: NDArray[np.float64], thermal: ThermalSpec
    ) -> NDArray[np.float64]:
        """Bias from the sensor temperature (degC) above ambient, shape ``temperature.shape + (6,)``."""
        return (temperature - thermal.ambient_c)[..., None] * self.temp_coeff

    def ramp_bias(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Rate ramp at times ``t`` (s since power-on), shape ``t.shape + (6,)``."""
        return np.asarray(t, dtype=float)[..., None] * self.ramp

    def drift(self, t: NDArray[np.float64], thermal: ThermalSpec) -> NDArray[np.float64]:
        """Deterministic bias of time since power-on: warm-up, temperature and rate ramp,
        ``t.shape + (6,)``; each term is computed only when the spec has it (zeros if none)."""
        out = np.zeros((*np.shape(t), 6))
        if self.warmup_bias.any():
            out += self.warmup(t)
        if self.temp_coeff.any():
            out += self.thermal(temperature_c(thermal, t), thermal)
        if self.ramp.any():
            out += self.ramp_bias(t)
        return out

    @property
    def has_move_terms(self) -> bool:
        """True when table moves disturb the bias."""
        return bool(self.move_walk.any() or self.move_transient.any())


def temperature_c(thermal: ThermalSpec, t: ArrayLike) -> NDArray[np.float64]:
    """Sensor temperature at times ``t`` (s since power-on), degC.

    ``T(t) = ambient + rise (1 - exp(-t / tau)) + ramp t``.
    """
    tt = np.asarray(t, dtype=float)
    return (
        thermal.ambient_c
        + thermal.warmup_rise_c * (1.0 - np.exp(-tt / thermal.warmup_tau_s))
        + thermal.ramp_c_per_h * tt / 3600.0
    )


@dataclass(frozen=True)
class TurnOnDraws:
    """The z-scores a power-on draws once (leading axes: runs, if any).

    Attributes
    ----------
    z_bias, z_sf : (..., 6) float
        Turn-on bias and scale-factor z-scores.
    z_mis : (..., 2, 6) float
        Misalignment z-scores of the gyro (row 0) and the accelerometer triad (row 1), in the
        row-major order of the off-diagonal entries.
    vib_phase : (..., 6) float
        Phase of the vibration line on each channel, rad.
    """

    z_bias: NDArray[np.float64]
    z_sf: NDArray[np.float64]
    z_mis: NDArray[np.float64]
    vib_phase: NDArray[np.float64]


def draw_turn_on(rng: np.random.Generator, shape: tuple[int, ...] = ()) -> TurnOnDraws:
    """Draw the turn-on z-scores for ``shape`` power-ons (``()`` for one), in a fixed order."""
    return TurnOnDraws(
        z_bias=rng.standard_normal((*shape, 6)),
        z_sf=rng.standard_normal((*shape, 6)),
        z_mis=rng.standard_normal((*shape, 2, 6)),
        vib_phase=rng.uniform(0.0, 2 * math.pi, (*shape, 6)),
    )


def draw_move(rng: np.random.Generator, shape: tuple[int, ...] = ()) -> NDArray[np.float64]:
    """Draw the z-scores of ``shape`` moves, ``(*shape, 2, 6)``: the lasting step (row 0) and the
    transient (row 1) of every channel, move after move in C order."""
    return rng.standard_normal((*shape, 2, 6))


def move_bias(
    terms: ErrorTerms,
    t: NDArray[np.float64],
    start_s: NDArray[np.float64],
    size_deg: NDArray[np.float64],
    z: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The bias that earlier table moves add at times ``t`` (see the module doc), SI.

    Parameters
    ----------
    terms : ErrorTerms
        The move terms (``move_walk``, ``move_transient``, ``move_tau_s``).
    t : (n,) float
        Sample times, s since power-on.
    start_s, size_deg : (M,) float
        Start time (s) and size ``q`` (deg, :func:`move_heat`) of each move.
    z : (..., M, 2, 6) float
        The z-scores of the moves (:func:`draw_move`); leading axes: runs, if any.

    Returns
    -------
    (..., n, 6) float
        A move adds nothing to samples at or before its start.
    """
    tt = np.asarray(t, dtype=float)
    out = np.zeros((*z.shape[:-3], tt.size, 6))
    root = np.sqrt(np.abs(np.asarray(size_deg, dtype=float)))
    for m, t0 in enumerate(np.asarray(start_s, dtype=float)):
        on = tt > t0
        if not on.any():
            continue
        zm = z[..., m, :, :] * root[m]  # (..., 2, 6)
        step = zm[..., 0, :] * terms.move_walk  # (..., 6)
        amp = zm[..., 1, :] * terms.move_transient
        decay = np.exp(-np.maximum(tt[:, None] - t0, 0.0) / terms.move_tau_s)  # (n, 6)
        out += on[:, None] * (step[..., None, :] + amp[..., None, :] * decay)
    return out


def spin_heat_bias(
    terms: ErrorTerms,
    rate_dps: float,
    accel_dps2: float,
    spin_heat: float,
    n: int,
    fs: float,
    rng: np.random.Generator,
    n_runs: int,
) -> NDArray[np.float64] | None:
    """The bias the drive's heat adds over ``n`` samples of a steady spin from its start, SI,
    ``(n_runs, n, 6)`` (the module :mod:`northfinder.driver.protocol.heat`): on every channel
    with move terms, a Gauss-Markov transient and a random walk in the angle turned, each from
    the state the ramp left. None when ``spin_heat`` is 0 or no channel has move terms."""
    chans = [ch for ch in range(6) if terms.move_transient[ch] or terms.move_walk[ch]]
    if spin_heat <= 0.0 or not chans:
        return None
    from scipy.signal import lfilter  # imported when first needed: it takes a second

    out = np.zeros((n_runs, n, 6))
    for ch in chans:
        tau = float(terms.move_tau_s[ch])
        v0_t, v0_w = spin_heat_state(rate_dps, accel_dps2, tau, spin_heat)
        phi, q_t, q_w = spin_heat_steps(rate_dps, tau, spin_heat, 1.0 / fs)
        for amp, v0, a, q in ((terms.move_transient[ch], v0_t, phi, q_t),
                              (terms.move_walk[ch], v0_w, 1.0, q_w)):  # fmt: skip
            if not amp:
                continue
            z = rng.standard_normal((n_runs, n + 1))
            z[:, 0] *= math.sqrt(v0)
            z[:, 1:] *= math.sqrt(q)
            out[..., ch] += amp * lfilter([1.0], [1.0, -a], z, axis=-1)[:, 1:]
    return out


def spin_heat_innovations(
    terms: ErrorTerms,
    spin_heat: float,
    spins: list[tuple[float, float, float]],
    t: NDArray[np.float64],
    fs: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The steady turning's part of the drive's heat over samples at times ``t`` (the instrument's
    step-by-step form of :func:`spin_heat_bias`; the ramps are moves of their own).

    Parameters
    ----------
    terms : ErrorTerms
    spin_heat : float
        The table's ``spin_heat``.
    spins : list of (start s, end s, rate deg/s)
        Intervals of steady turning (:attr:`~northfinder.firmware_sim.turntable.Turntable.spins`).
    t : (n,) float
        Sample times, s; sample ``k`` covers ``(t_k - 1/fs, t_k]``.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    phi : (6,) float
        The transient's decay over one sample (1 on a channel without a time constant).
    std : (n, 2, 6) float
        Standard deviations (SI) of each sample's innovation of the walk (row 0) and of the
        transient (row 1), decayed to the sample's end; zero where the table does not turn
        steadily. None when nothing turns steadily within ``t`` or ``spin_heat`` is 0.
    """
    step = 1.0 / fs
    lo = t - step
    spins = [sp for sp in spins if sp[0] < t[-1] and sp[1] > lo[0] and sp[1] > sp[0]]
    if spin_heat <= 0.0 or not spins or not terms.has_move_terms:
        return None
    phi = spin_heat_decay(terms, fs)
    tau = np.where(terms.move_tau_s > 0, terms.move_tau_s, np.inf)
    chans = np.flatnonzero(terms.move_transient + terms.move_walk)
    var = np.zeros((t.size, 2, 6))
    for start, end, rate in spins:
        a, b = np.maximum(lo, start), np.minimum(t, end)
        full = (a == lo) & (b == t)
        for ch in chans:
            _, q_t, q_w = _heat_step(rate, float(tau[ch]), spin_heat, step, 0.0)
            var[full, 0, ch] += q_w
            var[full, 1, ch] += q_t
            # Samples partly in the steady turning (where it starts and ends): their part,
            # decayed to the sample's end.
            for k in np.flatnonzero((b > a) & ~full):
                _, q_t, q_w = _heat_step(rate, float(tau[ch]), spin_heat, float(b[k] - a[k]),
                                         float(t[k] - b[k]))  # fmt: skip
                var[k, 0, ch] += q_w
                var[k, 1, ch] += q_t
    std = np.sqrt(var)
    std[:, 0, :] *= terms.move_walk
    std[:, 1, :] *= terms.move_transient
    return phi, std


def spin_heat_decay(terms: ErrorTerms, fs: float) -> NDArray[np.float64]:
    """The decay of the spin heat's transient over one sample of ``fs`` Hz, (6,)."""
    return np.exp(-1.0 / (fs * np.where(terms.move_tau_s > 0, terms.move_tau_s, np.inf)))


def _heat_step(
    rate_dps: float, tau_s: float, spin_heat: float, step_s: float, after_s: float
) -> tuple[float, float, float]:
    """:func:`spin_heat_steps` over ``step_s`` of turning, the transient's innovation decayed
    over ``after_s`` more; no transient without a time constant."""
    if not math.isfinite(tau_s):
        return 1.0, 0.0, max(spin_heat, 0.0) * abs(rate_dps) * step_s
    phi, q_t, q_w = spin_heat_steps(rate_dps, tau_s, spin_heat, step_s)
    return phi, q_t * math.exp(-2.0 * after_s / tau_s), q_w


def triad_matrices(sf: NDArray[np.float64], mis: NDArray[np.float64]) -> NDArray[np.float64]:
    """Error matrices (..., 3, 3): diagonal ``1 + sf`` (..., 3), off-diagonals ``mis`` (..., 6)
    in row-major order."""
    m = np.zeros((*sf.shape[:-1], 3, 3))
    m[..., ~np.eye(3, dtype=bool)] = mis
    m[..., np.arange(3), np.arange(3)] = 1.0 + sf
    return m


#: Runs of at most this many grid steps are filtered by the recursion itself, longer ones by lfilter
#: (scipy, whose import takes a second): the instrument's look-ahead chunks, up to 6.4 s, stay short.
_SHORT_RUN = 64


def slow_noise_steps(
    w: NDArray[np.float64], state: NDArray[np.float64], walk: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Advance the flicker components and the random walk by ``m`` grid steps.

    Parameters
    ----------
    w : (m, K + 1, ...) float
        Unit normal innovations: one per flicker component (K = len(FLICKER_TAUS_S)), then the walk.
    state : (K, ...) float
        Unit-variance flicker components at the grid point before the first step.
    walk : (...) float
        Unit random walk (in sqrt(s)) at that grid point.

    Returns
    -------
    flicker : (m, ...) float
        Sum of the components at each new grid point (scale by ``B * FLICKER_STD``).
    walks : (m, ...) float
        The walk at each new grid point (scale by the walk coefficient).
    state, walk
        The components and the walk at the last new grid point.
    """
    m = w.shape[0]
    acc = np.zeros((m, *w.shape[2:]))
    new_state = np.empty_like(state)
    if m <= _SHORT_RUN:
        # A few steps (the instrument's look-ahead): the recursion itself, all components at
        # once; the same operations in the same order as lfilter's, so the same numbers.
        shape = (-1,) + (1,) * (state.ndim - 1)
        phi, gain = FLICKER_PHI.reshape(shape), FLICKER_GAIN.reshape(shape)
        s = state
        comps = np.empty((m, *state.shape))
        for j in range(m):
            s = gain * w[j, :-1] + phi * s
            comps[j] = s
        for i in range(len(FLICKER_PHI)):
            acc += comps[:, i]
            new_state[i] = comps[-1, i]
    else:
        from scipy.signal import lfilter  # imported when first needed: it takes a second

        for i, phi in enumerate(FLICKER_PHI):
            comp, _ = lfilter(
                [FLICKER_GAIN[i]], [1.0, -phi], w[:, i], axis=0, zi=(phi * state[i])[None]
            )
            acc += comp
            new_state[i] = comp[-1]
    walks = walk + np.cumsum(math.sqrt(FLICKER_GRID_S) * w[:, -1], axis=0)
    return acc, walks, new_state, walks[-1]


def slow_noise_jump(
    rng: np.random.Generator,
    state: NDArray[np.float64],
    walk: NDArray[np.float64],
    steps: int,
    *,
    with_walk: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The flicker components and the walk ``steps`` grid steps later, drawn exactly in one go.

    ``with_walk=False`` leaves the walk as it is and draws nothing for it (for channels
    without a random walk, whose walk is multiplied by zero).
    """
    a = FLICKER_PHI.reshape((-1,) + (1,) * (state.ndim - 1)) ** steps
    state = a * state + np.sqrt(1.0 - a * a) * rng.standard_normal(state.shape)
    if with_walk:
        walk = walk + math.sqrt(FLICKER_GRID_S * steps) * rng.standard_normal(walk.shape)
    return state, walk


#: Grid steps drawn jointly at most (the factor is (steps + K) squared).
_JOINT_STEPS = 256


@functools.lru_cache(maxsize=32)
def _flicker_window_factor(m: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Factor of the joint law of the flicker noise over ``m`` grid steps (see
    :func:`slow_noise_window`): ``(mean, factor)``.

    ``mean`` (m + K, K): the noise-free part of the vector (sum at steps 1..m, then every
    component at step m) from the components at step 0. ``factor`` (m - 1 + K, m + K): rows of
    ``z @ factor`` are the zero-mean part when ``z`` is unit normal of length m - 1 + K (the sum
    at step m is the sum of the components there, so it takes no draw of its own).
    """
    phi = FLICKER_PHI
    g = np.arange(1, m + 1, dtype=float)
    # Component i after g steps from x0: phi^g x0 + nu_g, Cov(nu_g, nu_h) = phi^|g-h| (1 - phi^2min).
    pg = phi[None, :] ** g[:, None]  # (m, K)
    lag = np.abs(g[:, None] - g[None, :])
    low = np.minimum(g[:, None], g[None, :])
    cov_ss = np.zeros((m, m))
    for p in phi:
        cov_ss += p**lag * (1.0 - p ** (2.0 * low))
    cov_se = phi[None, :] ** (m - g)[:, None] * (1.0 - phi[None, :] ** (2.0 * g[:, None]))
    cov_ee = np.diag(1.0 - phi ** (2.0 * m))
    # Drawn: the sums at steps 1..m-1 and the K components at step m.
    keep = np.r_[np.arange(m - 1), m + np.arange(phi.size)]
    full = np.block([[cov_ss, cov_se], [cov_se.T, cov_ee]])
    vals, vecs = np.linalg.eigh(full[np.ix_(keep, keep)])
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))  # (D, D): cov = root @ root.T
    factor = np.zeros((keep.size, m + phi.size))
    factor[:, keep] = root.T
    factor[:, m - 1] = factor[:, m:].sum(axis=1)  # the sum at step m
    mean = np.vstack([pg, np.diag(phi**m)])
    return mean, factor


def slow_noise_window(
    rng: np.random.Generator,
    state: NDArray[np.float64],
    walk: NDArray[np.float64],
    m: int,
    *,
    with_walk: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """What :func:`slow_noise_steps` gives for ``m`` grid steps, drawn jointly in one go.

    The flicker components are Gaussian and linear in their innovations, so the sums at the
    ``m`` new grid points and the components at the last one have a joint normal law given the
    state at the start; this draws that law exactly from ``m - 1 + K`` unit normals per channel
    (per piece of at most 256 steps) instead of ``m K`` innovations (the law is the same; the
    draws differ). The walk takes ``m``
    innovations as before, none with ``with_walk=False`` (its values then stay at ``walk``).

    Parameters
    ----------
    rng : numpy.random.Generator
    state : (K, ...) float
        Unit-variance flicker components at the grid point before the first step.
    walk : (...) float
        Unit random walk (in sqrt(s)) at that grid point.
    m : int
        Grid steps, at least 1.

    Returns
    -------
    flicker, walks : (m, ...) float
    state, walk
        As :func:`slow_noise_steps`.
    """
    k = FLICKER_PHI.size
    shape = state.shape[1:]
    x0 = state.reshape(k, -1)  # (K, N)
    pieces = []
    # Pieces of at most _JOINT_STEPS steps, each from the state the one before left (the
    # process is Markov in its components): the factors stay small whatever the window.
    for first in range(0, m, _JOINT_STEPS):
        size = min(_JOINT_STEPS, m - first)
        mean, factor = _flicker_window_factor(size)
        z = rng.standard_normal((x0.shape[1], factor.shape[0]))  # (N, D)
        vec = (z @ factor).T + mean @ x0  # (size + K, N)
        pieces.append(vec[:size])
        x0 = vec[size:]
    flicker = (pieces[0] if len(pieces) == 1 else np.concatenate(pieces)).reshape((m, *shape))
    new_state = x0.reshape(state.shape)
    if with_walk:
        steps = rng.standard_normal((m, *shape))
        walks = walk + np.cumsum(math.sqrt(FLICKER_GRID_S) * steps, axis=0)
    else:
        walks = np.broadcast_to(walk, (m, *shape))
    return flicker, walks, new_state, walks[-1]


def random_directions(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    """``n`` random directions for impulses, (n, 6): a unit vector for each triad."""
    v = rng.standard_normal((n, 6))
    for sl in (GYRO, ACCEL):
        norm = np.linalg.norm(v[:, sl], axis=1, keepdims=True)
        v[:, sl] /= np.where(norm > 0, norm, 1.0)
    return v


def half_sine(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Shape of one impulse at phase ``x`` = (t - start) / duration: sin(pi x) on (0, 1), else 0."""
    return np.where((x > 0) & (x < 1), np.sin(math.pi * x), 0.0)


def vibration(
    t: NDArray[np.float64],
    hz: float,
    amp: NDArray[np.float64] | float,
    phase: NDArray[np.float64] | float,
) -> NDArray[np.float64]:
    """The vibration line ``amp sin(2 pi hz t + phase)`` (arguments broadcast), SI."""
    return amp * np.sin(2 * math.pi * hz * t + phase)


def quantise_carry(
    values: NDArray[np.float64], remainder: ArrayLike, axis: int = -1
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Round runs of values (in counts) to whole counts along ``axis``, carrying the remainder.

    Parameters
    ----------
    values : array
        Values in counts; each run lies along ``axis``.
    remainder : array
        What earlier runs left over (|r| <= 1/2), ``values`` without ``axis``.

    Returns
    -------
    counts : array
        Whole counts, like ``values``; their sum over any run differs from the exact sum by at
        most one count.
    remainder : array
        What this run leaves over, for the next.
    """
    rem = np.asarray(remainder, dtype=float)
    if values.shape[axis] == 0:
        return values.copy(), rem
    # The whole counts of each value pass through exactly; only the fractions (|f| <= 1/2) are
    # summed, so the running sum stays small and its rounding error (what makes a sum taken from
    # another starting point round differently) is about 1e-16 of a count, not of the total.
    whole = np.round(values)
    cum = np.expand_dims(rem, axis) + np.cumsum(values - whole, axis=axis)
    q = np.round(cum)
    last = np.take(cum, -1, axis=axis) - np.take(q, -1, axis=axis)
    return whole + np.diff(q, axis=axis, prepend=0.0), last
