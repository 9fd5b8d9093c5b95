"""Many simulated north-finding runs at once: the still windows of a plan for a whole array of runs.

:func:`simulate_windows` produces, for ``n_runs`` independent power-ons of the instrument, the
samples of every recording window of a plan (table positions, window length, settle time) as
arrays of shape ``(runs, positions, samples, 3)``. It follows the conventions of
:class:`northfinder.firmware_sim.imu.Instrument` and takes its error terms from the same
definitions (:mod:`northfinder.firmware_sim.error_terms`), but draws whole arrays of runs with
numpy instead of stepping one instrument, and it only generates the samples inside the windows:
the slow noise processes jump across the moves exactly. A run draws its turn-on errors from the
generator's streams as an instrument with the same seed does.

Timeline of one run (the same for every run)
--------------------------------------------
Power-on at t = 0 with the table already at ``positions_deg[0]``; ``warmup_s`` pass; window 0
records ``round(window_s * fs)`` samples; then, for every next position, the table moves the
shorter way with the trapezoidal profile of the spec's table limits, ``settle_s`` pass, and the
next window records. A position equal to the previous one needs neither move nor settle. Window
starts are whole samples: a move starts at the end of the previous window and the next window
starts at the first sample boundary at or after the end of move plus settle.

Error terms
-----------
Per run: constant and turn-on bias, scale-factor and misalignment draws, table indexing error per
move (a repeated position keeps the last stop's error), vibration phase, and per move the bias
step and transient it starts (from the end of the window before it). Per sample: white noise
(ARW, VRW), bias instability (Gauss-Markov components from 1 s to 10^4 s on a 0.1 s grid) and
random walks, warm-up transient, temperature sensitivity, rate ramp, Poisson impulses (half-sine,
random direction), vibration line, optional bias step, range clipping and quantisation. The quantiser
carries its remainder within a window; the remainder at a window start is drawn uniformly (what
the samples before it left over). The post-stop ring-down comes from the turntable model and enters
linearised (its amplitude at a window start is far below any other term).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.blas import daxpy

from northfinder.driver.protocol.motion import move_time_s, shortest_delta_deg, wobble_matrix
from northfinder.driver.protocol.units import DPH, normal_gravity
from northfinder.firmware_sim.earth import alpha_from_azimuth, earth_rate_n, mat_nb
from northfinder.firmware_sim.error_terms import (
    FLICKER_GRID_S,
    FLICKER_STD,
    FLICKER_TAUS_S,
    ErrorTerms,
    TurnOnDraws,
    check_sample_rate,
    draw_move,
    draw_turn_on,
    half_sine,
    move_bias,
    move_heat,
    quantise_carry,
    random_directions,
    slow_noise_jump,
    slow_noise_window,
    spin_heat_bias,
    vibration,
)
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import SensorSpec, TableSpec
from northfinder.firmware_sim.turntable import Turntable, encoder_reading_deg, spin_angles_deg

__all__ = [
    "ALL_CHANNELS",
    "BatchWindows",
    "SpinBatch",
    "plan_timeline",
    "simulate_spin",
    "simulate_windows",
]

#: Gyro and accelerometer error matrices of every run, each (runs, 3, 3).
_Matrices = tuple[NDArray[np.float64], NDArray[np.float64]]


@dataclass(frozen=True)
class BatchWindows:
    """The recording windows of many runs.

    Attributes
    ----------
    gyro_rps : (runs, positions, samples, 3) float64
        Gyro triad, mean rate over each sample interval, rad/s (a strided view; the samples of
        one channel are contiguous, so ``numpy.moveaxis(gyro_rps, 2, -1)`` is C-contiguous).
    accel_mps2 : (runs, positions, samples, 3) float64
        Accelerometer triad, specific force, m/s^2 (same layout).
    table_deg : (runs, positions) float64
        Encoder reading during each window, [0, 360) deg.
    commanded_deg : (positions,) float64
        Commanded table angle of each window, [0, 360) deg.
    azimuth_deg : (runs,) float64
        True azimuth of each run, deg clockwise from north.
    window_start_s : (positions,) float64
        Start of each window, seconds since power-on.
    sample_rate_hz : float
        Sample rate, Hz.
    plan_time_s : float
        From the start of the first window to the end of the last, s (moves and settling
        included, warm-up not).
    """

    gyro_rps: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    table_deg: NDArray[np.float64]
    commanded_deg: NDArray[np.float64]
    azimuth_deg: NDArray[np.float64]
    window_start_s: NDArray[np.float64]
    sample_rate_hz: float
    plan_time_s: float

    @property
    def n_runs(self) -> int:
        return int(self.gyro_rps.shape[0])


def _check_positive(name: str, value: float, *, allow_zero: bool = False) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        kind = "non-negative" if allow_zero else "positive"
        raise SimConfigError(f"{name}: must be a finite {kind} number, got {value!r}")
    return v


def plan_timeline(
    spec: SensorSpec,
    positions_deg: Sequence[float],
    window_s: float,
    settle_s: float | None = None,
    *,
    warmup_s: float = 0.0,
    sample_rate_hz: float = 200.0,
) -> tuple[NDArray[np.int64], int, NDArray[np.float64], NDArray[np.float64]]:
    """Sample layout of a plan (see the module docstring).

    Returns
    -------
    start : (positions,) int64
        Index of the first sample of each window (sample ``k`` ends at ``(k + 1) / fs``).
    n : int
        Samples per window.
    move_end_s : (positions,) float64
        When the move before each window ended, s (``-inf`` when there was none).
    delta_deg : (positions,) float64
        The commanded move before each window, deg (0 for the first window).
    """
    fs = check_sample_rate(sample_rate_hz)
    pos = np.asarray(positions_deg, dtype=float)
    if pos.ndim != 1 or pos.size < 1 or not np.all(np.isfinite(pos)):
        raise SimConfigError(f"positions_deg: expected finite table angles, got {positions_deg!r}")
    window_s = _check_positive("window_s", window_s)
    settle = spec.table.settle_s if settle_s is None else settle_s
    settle = _check_positive("settle_s", settle, allow_zero=True)
    warmup_s = _check_positive("warmup_s", warmup_s, allow_zero=True)
    n = round(window_s * fs)
    if n < 1:
        raise SimConfigError(f"window_s: {window_s} s holds no sample at {fs:g} Hz")
    starts = np.empty(pos.size, dtype=np.int64)
    move_end = np.full(pos.size, -math.inf)
    delta = np.zeros(pos.size)
    k = round(warmup_s * fs)
    for i in range(pos.size):
        if i:
            k += n
            d = shortest_delta_deg(pos[i - 1], pos[i])
            if d != 0.0:
                travel = move_time_s(d, spec.table.max_rate_dps, spec.table.max_accel_dps2)
                move_end[i] = k / fs + travel
                k += math.ceil(round((travel + settle) * fs, 6))
            delta[i] = d
        starts[i] = k
    return starts, n, move_end, delta


def _truth_arrays(truth: Truth | Sequence[Truth], n_runs: int) -> tuple[NDArray[np.float64], ...]:
    truths = [truth] * n_runs if isinstance(truth, Truth) else list(truth)
    if len(truths) != n_runs:
        raise SimConfigError(f"truths: expected one Truth per run ({n_runs}), got {len(truths)}")
    if not all(isinstance(t, Truth) for t in truths):
        raise SimConfigError("truths: expected northfinder.firmware_sim.imu.Truth values")
    return tuple(
        np.array([getattr(t, f) for t in truths], dtype=float)
        for f in ("azimuth_deg", "latitude_deg", "pitch_deg", "roll_deg")
    )


@dataclass(frozen=True, eq=False)
class _GridWindow:
    """Where one window's samples lie on the slow-noise grid.

    ``g0`` and ``g1`` are the first and last grid points the window needs (its coarse values
    run over ``g0..g1``); ``blocks`` cover the window's samples in pieces of at most
    :data:`_BLOCK`, each ``(s0, s1, j0, j1, weights)``: samples ``s0:s1`` are
    ``coarse[j0:j1] @ weights`` (linear interpolation between the grid points around each).
    """

    g0: int
    g1: int
    blocks: tuple[tuple[int, int, int, int, NDArray[np.float64]], ...]


@dataclass(frozen=True, eq=False)
class _Timeline:
    """Everything about a plan's samples that is the same for every run (cached per plan)."""

    starts: NDArray[np.int64]
    n: int
    move_end: NDArray[np.float64]
    delta: NDArray[np.float64]
    t: NDArray[np.float64]  # (P, n) sample end times, s
    drift: NDArray[np.float64] | None  # (6, P, n) warm-up, temperature and ramp terms, SI
    ringing: NDArray[np.bool_]  # (P,) window rings after a stop
    ring_dmu: NDArray[np.float64]  # (P, n) mean angle offset per sample, rad
    ring_rate: NDArray[np.float64]  # (P, n) mean table rate per sample, rad/s
    ring_offset_deg: NDArray[np.float64]  # (P,) mean angle offset of each window, deg
    grid: tuple[_GridWindow, ...]


#: Samples per product of the slow terms: a block touches about ``_BLOCK / (fs * grid) + 2``
#: grid points, so the product costs that many multiply-adds per sample instead of the window's.
_BLOCK = 200


def _grid_windows(pos: NDArray[np.float64]) -> tuple[_GridWindow, ...]:
    out = []
    for p in range(pos.shape[0]):
        g0 = math.floor(pos[p, 0])
        g1 = math.floor(pos[p, -1]) + 1
        size = g1 - g0 + 1
        x = pos[p] - g0
        j = np.minimum(np.floor(x).astype(np.int64), size - 2)
        f = x - j
        blocks = []
        for s0 in range(0, x.size, _BLOCK):
            s1 = min(x.size, s0 + _BLOCK)
            j0, j1 = int(j[s0]), int(j[s1 - 1]) + 2
            w = np.zeros((j1 - j0, s1 - s0))
            cols = np.arange(s1 - s0)
            w[j[s0:s1] - j0, cols] = 1.0 - f[s0:s1]
            w[j[s0:s1] - j0 + 1, cols] = f[s0:s1]
            w.flags.writeable = False
            blocks.append((s0, s1, j0, j1, w))
        out.append(_GridWindow(g0, g1, tuple(blocks)))
    return tuple(out)


@functools.lru_cache(maxsize=8)
def _error_terms(spec: SensorSpec) -> ErrorTerms:
    return ErrorTerms.from_spec(spec)


@functools.lru_cache(maxsize=8)
def _timeline(
    spec: SensorSpec,
    positions_deg: tuple[float, ...],
    window_s: float,
    settle_s: float | None,
    warmup_s: float,
    fs: float,
) -> _Timeline:
    starts, n, move_end, delta = plan_timeline(
        spec, positions_deg, window_s, settle_s, warmup_s=warmup_s, sample_rate_hz=fs
    )
    terms = ErrorTerms.from_spec(spec)
    # Sample times: sample k covers ((k)/fs, (k+1)/fs].
    k = starts[:, None] + np.arange(n)[None, :]
    t = (k + 1) / fs  # (P, n)
    det = terms.drift(t, spec.thermal)
    drift = np.ascontiguousarray(np.moveaxis(det, -1, 0)) if det.any() else None
    ringing, dmu, rate, offset = _ring_down(spec.table, move_end, delta, starts, n, fs)
    grid = _grid_windows((t - 0.5 / fs) / FLICKER_GRID_S)
    for a in (starts, move_end, delta, t, drift, ringing, dmu, rate, offset):
        if a is not None:
            a.flags.writeable = False
    return _Timeline(starts, n, move_end, delta, t, drift, ringing, dmu, rate, offset, grid)


def _slow_grid(
    rng: np.random.Generator,
    grid: Sequence[_GridWindow],
    n_runs: int,
    flicker_b: NDArray[np.float64],
    walk_k: NDArray[np.float64],
) -> list[NDArray[np.float64]]:
    """Flicker plus random walk at the grid points of every window: per window (nc, runs, m).

    ``flicker_b`` and ``walk_k`` are those of the nc channels that have slow noise.
    """
    nc = flicker_b.size
    with_walk = bool(walk_k.any())
    k = FLICKER_TAUS_S.size
    # Flicker components and walk at grid point ``last``; the walk has run since t = 0.
    last = grid[0].g0
    state = rng.standard_normal((k, n_runs, nc))
    walk = np.zeros((n_runs, nc))
    if with_walk:
        walk = math.sqrt(FLICKER_GRID_S * last) * rng.standard_normal((n_runs, nc))
    prev = np.empty((0, n_runs, nc))  # coarse values of the previous window, (m, runs, nc)
    out = []
    for win in grid:
        # Jump exactly from the last grid point of the previous window to this window's.
        first = max(win.g0, last)
        if first > last:
            state, walk = slow_noise_jump(rng, state, walk, first - last, with_walk=with_walk)
        flick = state.sum(axis=0)[None]
        walks = walk[None]
        if win.g1 > first:
            more, more_walks, state, walk = slow_noise_window(
                rng, state, walk, win.g1 - first, with_walk=with_walk
            )
            flick = np.concatenate([flick, more])
            walks = np.concatenate([walks, more_walks])
        last = win.g1
        coarse = flick * (flicker_b * FLICKER_STD)  # (m, runs, nc)
        if with_walk:
            coarse += walks * walk_k
        if first > win.g0:  # this window begins one grid step before the previous one ended
            coarse = np.concatenate([prev[-2:-1], coarse])
        prev = coarse
        out.append(np.ascontiguousarray(np.moveaxis(coarse, (0, 2), (2, 0))))
    return out


#: Every channel: gyro x, y, z, accelerometer x, y, z.
ALL_CHANNELS: tuple[int, ...] = (0, 1, 2, 3, 4, 5)


def _check_channels(channels: Sequence[int] | None) -> tuple[int, ...]:
    if channels is None:
        return ALL_CHANNELS
    try:
        chans = tuple(sorted({operator.index(c) for c in channels}))
    except TypeError:
        raise SimConfigError(f"channels: expected channel numbers 0..5, got {channels!r}") from None
    if not chans or chans[0] < 0 or chans[-1] > 5:
        raise SimConfigError(f"channels: expected channel numbers 0..5, got {channels!r}")
    return chans


def _table_angles(
    tab: TableSpec,
    pos_deg: NDArray[np.float64],
    delta: NDArray[np.float64],
    table_rng: np.random.Generator,
    n_runs: int,
) -> NDArray[np.float64]:
    """True continuous table angle of every window (R, P), deg: the commanded angle as reached
    the shorter way, plus the last stop's indexing error."""
    pc = delta.size
    idx_err = np.zeros((n_runs, pc))
    moved = delta != 0.0
    if tab.indexing_error_deg and moved.any():
        idx_err[:, moved] = table_rng.normal(0.0, tab.indexing_error_deg, (n_runs, moved.sum()))
        # A repeated position needs no move: the table keeps the error of its last stop.
        last_stop = np.maximum.accumulate(np.where(moved, np.arange(pc), 0))
        idx_err = idx_err[:, last_stop]
    angle = pos_deg[0] + np.cumsum(delta)
    return angle[None, :] + idx_err  # (R, P)


def _window_signal(
    tab: TableSpec,
    terms: ErrorTerms,
    truths: tuple[NDArray[np.float64], ...],
    true_angle: NDArray[np.float64],
    draws: TurnOnDraws,
) -> tuple[NDArray[np.float64], _Matrices | None]:
    """The noise-free signal of every window (R, P, 6): the Earth rate and gravity through the
    table (its angle ``true_angle`` and tilt) and the sensor error matrices; with the matrices."""
    az, lat, pitch, roll = truths
    c_nb = mat_nb(alpha_from_azimuth(az), np.radians(pitch), np.radians(roll))  # (R, 3, 3)
    lat_r = np.radians(lat)
    omega_b = np.einsum("rij,rj->ri", c_nb, earth_rate_n(lat_r))
    grav = np.asarray(normal_gravity(lat_r), dtype=float).reshape(-1)
    f_b = c_nb[:, :, 2] * grav[:, None]
    mu = np.radians(true_angle)
    cm, sm = np.cos(mu), np.sin(mu)

    def _rotate(v: NDArray[np.float64]) -> NDArray[np.float64]:
        x = cm * v[:, 0, None] + sm * v[:, 1, None]
        y = -sm * v[:, 0, None] + cm * v[:, 1, None]
        return np.stack([x, y, np.broadcast_to(v[:, 2, None], x.shape)], axis=-1)  # (R, P, 3)

    true = np.concatenate([_rotate(omega_b), _rotate(f_b)], axis=-1)  # (R, P, 6)
    wob = wobble_matrix(tab.wobble_urad, tab.wobble_phase_deg)
    if wob is not None:  # the table top's tilt, as the instrument's
        true = np.concatenate([true[..., :3] @ wob.T, true[..., 3:] @ wob.T], axis=-1)
    mats = terms.matrices(draws) if terms.has_matrix else None
    if mats is not None:
        # Instrument: out = true @ M.T, i.e. out_i = sum_j M_ij true_j.
        true = np.concatenate(
            [
                np.einsum("rij,rpj->rpi", mats[0], true[..., :3]),
                np.einsum("rij,rpj->rpi", mats[1], true[..., 3:]),
            ],
            axis=-1,
        )
    return true, mats


def _add_slow_terms(
    data: NDArray[np.float64],
    chans: tuple[int, ...],
    tl: _Timeline,
    terms: ErrorTerms,
    true: NDArray[np.float64],
    base: NDArray[np.float64],
    mats: _Matrices | None,
    slow: np.random.Generator,
) -> None:
    """Write into ``data`` (6, R, P, n) the terms that are slow in time, one low-rank product per
    channel and window: turn-on signal and bias ``base`` (per run), drift of time (per sample),
    the post-stop ring-down (linearised in the angle: per run times per sample) and slow noise
    on its coarse grid."""
    _, n_runs, pc, n = data.shape
    ring_deriv, ring_rate = _ring_coefficients(true, mats, tl.ringing)
    slow_chans = [ch for ch in chans if terms.flicker_b[ch] + terms.walk_k[ch]]
    coarse = (
        _slow_grid(slow, tl.grid, n_runs, terms.flicker_b[slow_chans], terms.walk_k[slow_chans])
        if slow_chans
        else []
    )
    ones = np.ones(max(n, n_runs))
    for ch in chans:
        for p in range(pc):
            cols, rows = [base[:, p, ch]], [ones[:n]]
            if tl.ringing[p]:
                cols.append(ring_deriv[:, p, ch])
                rows.append(tl.ring_dmu[p])
                if ring_rate is not None and ch < 3:
                    cols.append(ring_rate[:, ch])
                    rows.append(tl.ring_rate[p])
            if tl.drift is not None and tl.drift[ch, p].any():
                cols.append(ones[:n_runs])
                rows.append(tl.drift[ch, p])
            a, b = np.stack(cols, axis=1), np.stack(rows)  # (R, k), (k, n)
            dst = data[ch, :, p]  # (R, n)
            if ch in slow_chans:
                c = coarse[p][slow_chans.index(ch)]  # (R, m)
                for s0, s1, j0, j1, w in tl.grid[p].blocks:
                    np.matmul(
                        np.concatenate([a, c[:, j0:j1]], axis=1),
                        np.concatenate([b[:, s0:s1], w]),
                        out=dst[:, s0:s1],
                    )
            else:
                np.matmul(a, b, out=dst)


def _add_white_noise(
    data: NDArray[np.float64],
    chans: tuple[int, ...],
    terms: ErrorTerms,
    fs: float,
    white: np.random.Generator,
) -> None:
    """Add white noise (ARW, VRW) to ``data`` (6, R, P, n), channel by channel."""
    _, n_runs, pc, n = data.shape
    white_sigma = terms.white_sigma(fs)
    scratch = np.empty((n_runs, pc, n))
    for ch in chans:
        if white_sigma[ch]:
            white.standard_normal(out=scratch)
            # y += a x in one pass over memory.
            daxpy(scratch.reshape(-1), data[ch].reshape(-1), a=white_sigma[ch])


def _add_move_terms(
    data: NDArray[np.float64],
    chans: tuple[int, ...],
    tl: _Timeline,
    terms: ErrorTerms,
    fs: float,
    moves_rng: np.random.Generator,
) -> None:
    """Add to ``data`` (6, R, P, n) the bias steps and transients that moves start."""
    moved = tl.delta != 0.0
    if not (terms.has_move_terms and moved.any()):
        return
    n_runs, pc, n, starts = data.shape[1], data.shape[2], tl.n, tl.starts
    # Each move starts at the end of the window before it (plan_timeline).
    move_start = (starts[moved.nonzero()[0] - 1] + n) / fs
    z = draw_move(moves_rng, (n_runs, int(moved.sum())))
    size = move_heat(move_start, tl.delta[moved], terms.move_heat_tau_s)
    done = np.cumsum(moved)  # moves made before each window
    for p in range(pc):
        if done[p]:
            m = done[p]
            bias = move_bias(terms, tl.t[p], move_start[:m], size[:m], z[:, :m])  # (R, n, 6)
            for ch in chans:
                data[ch, :, p] += bias[..., ch]


def _add_disturbances(
    data: NDArray[np.float64],
    chans: tuple[int, ...],
    t: NDArray[np.float64],
    fs: float,
    spec: SensorSpec,
    terms: ErrorTerms,
    vib_phase: NDArray[np.float64],
    impulses: np.random.Generator,
    bias_step_dph: float,
) -> None:
    """Add to ``data`` (6, R, P, n) the impulses, the vibration line and the optional bias step
    (sample end times ``t``, (P, n))."""
    n_runs, d = data.shape[1], spec.disturbance
    if d.impulse_rate_hz > 0 and terms.impulse_amp.any():
        _add_impulses(
            data,
            chans,
            impulses,
            t,
            fs,
            d.impulse_rate_hz,
            d.impulse_duration_s,
            terms.impulse_amp,
        )
    if d.vibration_hz > 0 and terms.vibration_amp.any():
        for ch in map(int, np.flatnonzero(terms.vibration_amp)):
            if ch in chans:
                data[ch] += vibration(
                    t[None],
                    d.vibration_hz,
                    terms.vibration_amp[ch],
                    vib_phase[:, ch, None, None],
                )
    if bias_step_dph:
        t_step = impulses.uniform(t[0, 0] - 1.0 / fs, t[-1, -1], n_runs)
        v = impulses.standard_normal((n_runs, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        # The step applies from the first sample whose interval starts after it.
        on = (t[None] - 1.0 / fs) >= t_step[:, None, None]  # (R, P, n)
        for ch in chans:
            if ch < 3:
                data[ch] += (bias_step_dph * DPH * v[:, ch])[:, None, None] * on


def _range_and_quantise(
    data: NDArray[np.float64],
    chans: tuple[int, ...],
    terms: ErrorTerms,
    turn_on: np.random.Generator,
) -> None:
    """Clip ``data`` (6, R, P, n) to the sensors' range and quantise it, in place."""
    _, n_runs, pc, _ = data.shape
    for ch in chans:
        chan, limit = data[ch], terms.range[ch]
        if chan.max() > limit or chan.min() < -limit:
            np.clip(chan, -limit, limit, out=chan)
    lsb = terms.lsb
    if lsb.any():
        # What the samples before each window left over.
        remainder = turn_on.uniform(-0.5, 0.5, (n_runs, pc, 6))
        for ch in map(int, np.flatnonzero(lsb)):
            if ch in chans:
                counts, _ = quantise_carry(data[ch] / lsb[ch], remainder[:, :, ch])
                data[ch] = counts * lsb[ch]


def simulate_windows(
    spec: SensorSpec,
    truth: Truth | Sequence[Truth],
    positions_deg: Sequence[float],
    window_s: float,
    settle_s: float | None = None,
    *,
    n_runs: int,
    rng: np.random.Generator,
    sample_rate_hz: float = 200.0,
    warmup_s: float = 0.0,
    bias_step_dph: float = 0.0,
    channels: Sequence[int] | None = None,
) -> BatchWindows:
    """Samples of every window of a plan for ``n_runs`` independent runs.

    Parameters
    ----------
    spec : SensorSpec
        Sensors, environment, table.
    truth : Truth or sequence of Truth
        One truth for every run, or one per run (azimuth, latitude, pitch, roll may all differ).
    positions_deg : sequence of float
        Commanded table angle of each window, deg.
    window_s : float
        Recording time per window, s.
    settle_s : float, optional
        Wait after each move, s (default: the spec's ``table.settle_s``).
    n_runs : int
        Number of independent runs (power-ons).
    rng : numpy.random.Generator
        Seeded generator.
    sample_rate_hz : float
        Output rate, Hz.
    warmup_s : float
        Time from power-on to the first window, s.
    bias_step_dph : float
        Size of one permanent gyro bias step per run, deg/h, at a uniformly random time within
        the recorded span, in a random direction (as :meth:`Instrument.inject_bias_step`).
    channels : sequence of int, optional
        The channels to generate (0, 1, 2: gyro x, y, z; 3, 4, 5: accelerometer x, y, z);
        default all. The others are NaN, so that nothing can use them unnoticed. Which channels
        are generated changes the random draws (not their law).

    Returns
    -------
    BatchWindows

    Raises
    ------
    SimConfigError
        Bad plan, run count, rate, truths or channels.
    """
    if isinstance(n_runs, bool) or int(n_runs) != n_runs or int(n_runs) < 1:
        raise SimConfigError(f"n_runs: must be a positive integer, got {n_runs!r}")
    n_runs = int(n_runs)
    chans = _check_channels(channels)
    fs = check_sample_rate(sample_rate_hz)
    pos_deg = np.asarray(positions_deg, dtype=float)
    if pos_deg.ndim != 1 or pos_deg.size < 1 or not np.all(np.isfinite(pos_deg)):
        raise SimConfigError(f"positions_deg: expected finite table angles, got {positions_deg!r}")
    window_s = _check_positive("window_s", window_s)
    warmup_s = _check_positive("warmup_s", warmup_s, allow_zero=True)
    if settle_s is not None:
        settle_s = _check_positive("settle_s", settle_s, allow_zero=True)
    tl = _timeline(spec, tuple(pos_deg.tolist()), window_s, settle_s, warmup_s, fs)
    starts, n = tl.starts, tl.n
    bias_step_dph = _check_positive("bias_step_dph", bias_step_dph, allow_zero=True)
    terms = _error_terms(spec)
    truths = _truth_arrays(truth, n_runs)
    turn_on, white, slow, impulses, table_rng, moves_rng = rng.spawn(6)

    true_angle = _table_angles(spec.table, pos_deg, tl.delta, table_rng, n_runs)  # (R, P)
    draws = draw_turn_on(turn_on, (n_runs,))
    true, mats = _window_signal(spec.table, terms, truths, true_angle, draws)
    base = true + terms.turn_on(draws.z_bias)[:, None, :]  # (R, P, 6)
    # Channel-major memory: every (runs, positions, samples) block of one channel is contiguous.
    data = np.empty((6, n_runs, starts.size, n))
    for ch in set(ALL_CHANNELS) - set(chans):
        data[ch] = np.nan
    _add_slow_terms(data, chans, tl, terms, true, base, mats, slow)
    _add_white_noise(data, chans, terms, fs, white)
    _add_move_terms(data, chans, tl, terms, fs, moves_rng)
    _add_disturbances(data, chans, tl.t, fs, spec, terms, draws.vib_phase, impulses, bias_step_dph)
    _range_and_quantise(data, chans, terms, turn_on)

    # The encoder's periodic error and resolution (the table's own reading).
    enc = encoder_reading_deg(spec.table, true_angle + tl.ring_offset_deg[None, :])
    view = np.moveaxis(data, 0, -1)  # (R, P, n, 6), channel-minor view of channel-major memory
    plan_time = (starts[-1] + n - starts[0]) / fs
    return BatchWindows(
        gyro_rps=view[..., :3],
        accel_mps2=view[..., 3:],
        table_deg=np.mod(enc, 360.0),
        commanded_deg=np.mod(pos_deg, 360.0),
        azimuth_deg=np.mod(truths[0], 360.0),
        window_start_s=starts / fs,
        sample_rate_hz=fs,
        plan_time_s=float(plan_time),
    )


def _ring_down(
    tab: TableSpec,
    move_end: NDArray[np.float64],
    delta: NDArray[np.float64],
    starts: NDArray[np.int64],
    n: int,
    fs: float,
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The damped oscillation after each stop, the same for every run.

    Returns, per window, whether it rings, the mean angle offset (rad) and the mean table rate
    (rad/s) over each sample, and the mean angle offset of the window (deg: what the encoder
    sees on average).
    """
    pc = len(starts)
    ringing = np.zeros(pc, dtype=bool)
    dmu, rate, mean_offset = np.zeros((pc, n)), np.zeros((pc, n)), np.zeros(pc)
    if not tab.overshoot_deg:
        return ringing, dmu, rate, mean_offset
    # The turntable's own model of the stop (indexing error aside: it is added per run).
    quiet = dataclasses.replace(tab, indexing_error_deg=0.0)
    last = None  # (move start s, move, angle before the move)
    angle = 0.0
    for p in range(pc):
        if math.isfinite(move_end[p]):
            last = ((starts[p - 1] + n) / fs, delta[p], angle)
        angle += delta[p]
        if last is None:
            continue
        table = Turntable(quiet, np.random.default_rng(0), last[2])
        table.move_by(last[0], last[1])
        edges = (starts[p] + np.arange(n + 1)) / fs
        osc = table.state(edges)[0] - (last[2] + last[1])  # deg, at the sample edges
        if np.abs(osc).max() < 1e-15:
            continue
        ringing[p] = True
        mean_offset[p] = osc[1:].mean()
        rate[p] = np.radians(np.diff(osc) * fs)
        dmu[p] = np.radians(0.5 * (osc[:-1] + osc[1:]))
    return ringing, dmu, rate, mean_offset


def _ring_coefficients(
    true: NDArray[np.float64], mats: _Matrices | None, ringing: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Per run: what a unit angle offset adds to each channel (R, P, 6), and what a unit table
    rate adds to the gyros (R, 3; None without error matrices: gyro z alone, by 1)."""
    deriv = np.zeros(true.shape)
    if not ringing.any():
        return deriv, None
    mg, ma = (None, None) if mats is None else mats
    # d/dmu of (c vx + s vy, -s vx + c vy) is (y, -x) of the rotated vector.
    for sl, m in ((slice(0, 3), mg), (slice(3, 6), ma)):
        rot = true[:, :, sl]
        if m is not None:
            rot = np.einsum("rij,rpj->rpi", np.linalg.inv(m), rot)
        d = np.stack([rot[..., 1], -rot[..., 0], np.zeros(rot.shape[:2])], axis=-1)
        if m is not None:
            d = np.einsum("rij,rpj->rpi", m, d)
        deriv[:, :, sl] = d
    gz = np.array([0.0, 0.0, 1.0])
    rate = None if mg is None else mg @ gz
    if rate is None:
        rate = np.broadcast_to(gz, (true.shape[0], 3))
    return deriv, rate


def _add_impulses(
    data: NDArray[np.float64],
    chans: tuple[int, ...],
    rng: np.random.Generator,
    t: NDArray[np.float64],
    fs: float,
    rate_hz: float,
    duration_s: float,
    amp: NDArray[np.float64],
) -> None:
    """Poisson half-sine impulses over each window (events that overlap it), random directions."""
    _, n_runs, pc, n = data.shape
    for p in range(pc):
        t0, t1 = t[p, 0] - 1.0 / fs, t[p, -1]
        span = t1 - t0 + duration_s
        counts = rng.poisson(rate_hz * span, n_runs)
        total = int(counts.sum())
        if total == 0:
            continue
        run = np.repeat(np.arange(n_runs), counts)
        start = t0 - duration_s + rng.uniform(0.0, span, total)
        v = random_directions(rng, total)
        # Samples whose end time lies inside (start, start + duration).
        first = np.floor((start - t[p, 0]) * fs).astype(np.int64) + 1
        m = math.ceil(duration_s * fs) + 1
        idx = first[:, None] + np.arange(m)[None, :]
        valid = (idx >= 0) & (idx < n)
        idx_c = np.clip(idx, 0, n - 1)
        x = (t[p, idx_c] - start[:, None]) / duration_s
        shape = np.where(valid, half_sine(x), 0.0)  # (E, m)
        contrib = shape[:, :, None] * (amp * v)[:, None, :]  # (E, m, 6)
        for j in np.flatnonzero(amp):
            if j in chans:
                np.add.at(data[j, :, p, :], (run[:, None], idx_c), contrib[:, :, j])


@dataclass(frozen=True)
class SpinBatch:
    """Angle-tagged samples of many runs of a steady spin.

    Attributes
    ----------
    gyro_rps, accel_mps2 : (runs, samples, 3) float64
        Sample means, sensor frame, rad/s and m/s^2.
    mu0_rad, mu1_rad : (runs, samples) float64
        Continuous true table angle at the start and end of each sample, rad.
    time_s : (samples,) float64
        End of each sample from the start of the steady spin, s.
    azimuth_deg : (runs,) float64
        True azimuth of each run.
    encoder_rad : (runs, samples + 1) float64 or None
        What the encoder reads at the sample edges (its periodic error and resolution), continuous
        (not taken modulo a turn), rad; None when it reads the true angle.
    """

    gyro_rps: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    mu0_rad: NDArray[np.float64]
    mu1_rad: NDArray[np.float64]
    time_s: NDArray[np.float64]
    azimuth_deg: NDArray[np.float64]
    encoder_rad: NDArray[np.float64] | None = None

    @property
    def read0_rad(self) -> NDArray[np.float64]:
        """Encoder angle at the start of each sample (what a solver is given), (runs, samples)."""
        return self.mu0_rad if self.encoder_rad is None else self.encoder_rad[:, :-1]

    @property
    def read1_rad(self) -> NDArray[np.float64]:
        """Encoder angle at the end of each sample, (runs, samples)."""
        return self.mu1_rad if self.encoder_rad is None else self.encoder_rad[:, 1:]


def _spin_ideal_samples(
    tab: TableSpec,
    az: NDArray[np.float64],
    lat: NDArray[np.float64],
    pitch: NDArray[np.float64],
    roll: NDArray[np.float64],
    rate_dps: float,
    start: NDArray[np.float64],
    n: int,
    fs: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Error-free samples of spins (R, n, 6): the Earth rate and gravity through the table (sample
    means over the angle swept), the table rate on its axis, the wobble; with the sample times
    (n,), the true edge angles in deg and rad (R, n+1)."""
    n_runs = az.shape[0]
    c_nb = mat_nb(alpha_from_azimuth(az), np.radians(pitch), np.radians(roll))
    lat_r = np.radians(lat)
    omega_b = np.einsum("rij,rj->ri", c_nb, earth_rate_n(lat_r))
    grav = np.asarray(normal_gravity(lat_r), dtype=float).reshape(-1)
    f_b = c_nb[:, :, 2] * grav[:, None]
    t = np.arange(1, n + 1) / fs
    edge_deg = spin_angles_deg(tab, rate_dps, start[:, None], np.arange(n + 1)[None, :] / fs)
    edges = np.radians(edge_deg)  # (R, n+1)
    d = edges[:, 1:] - edges[:, :-1]
    c = (np.sin(edges[:, 1:]) - np.sin(edges[:, :-1])) / d
    s = -(np.cos(edges[:, 1:]) - np.cos(edges[:, :-1])) / d
    out = np.empty((n_runs, n, 6))
    for k, v in ((0, omega_b), (3, f_b)):
        out[..., k] = c * v[:, 0, None] + s * v[:, 1, None]
        out[..., k + 1] = -s * v[:, 0, None] + c * v[:, 1, None]
        out[..., k + 2] = v[:, 2, None]
    out[..., 2] += d * fs  # the table rate (mean over each sample)
    wob = wobble_matrix(tab.wobble_urad, tab.wobble_phase_deg)
    if wob is not None:
        out[..., :3] = out[..., :3] @ wob.T
        out[..., 3:] = out[..., 3:] @ wob.T
    return out, t, edge_deg, edges


def _spin_time_terms(
    out: NDArray[np.float64],
    terms: ErrorTerms,
    spec: SensorSpec,
    t_on: NDArray[np.float64],
    fs: float,
    slow: np.random.Generator,
    impulses: np.random.Generator,
    vib_phase: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Add the terms of time since power-on to a spin's samples ``out`` (R, n, 6): drifts,
    flicker and random walks, impulses, vibration; return the samples (a new array when
    impulses or vibration are on)."""
    n_runs = out.shape[0]
    dist = spec.disturbance
    det = terms.drift(t_on, spec.thermal)
    if det.any():
        out += det[None]
    slow_chans = [ch for ch in range(6) if terms.flicker_b[ch] + terms.walk_k[ch]]
    if slow_chans:
        pos = ((t_on - 0.5 / fs) / FLICKER_GRID_S)[None, :]
        grid = _grid_windows(pos)
        coarse = _slow_grid(
            slow, grid, n_runs, terms.flicker_b[slow_chans], terms.walk_k[slow_chans]
        )[0]  # (nc, R, m)
        # Linear between the grid points (as the windows' interpolation matrices).
        x = pos[0] - grid[0].g0
        j = np.minimum(np.floor(x).astype(np.int64), grid[0].g1 - grid[0].g0 - 1)
        f = x - j
        for i, ch in enumerate(slow_chans):
            out[..., ch] += coarse[i][:, j] * (1.0 - f) + coarse[i][:, j + 1] * f
    if (dist.impulse_rate_hz > 0 and terms.impulse_amp.any()) or (
        dist.vibration_hz > 0 and terms.vibration_amp.any()
    ):
        data = np.ascontiguousarray(np.moveaxis(out, -1, 0))[:, :, None, :]  # (6, R, 1, n)
        if dist.impulse_rate_hz > 0 and terms.impulse_amp.any():
            _add_impulses(data, ALL_CHANNELS, impulses, t_on[None, :], fs,
                          dist.impulse_rate_hz, dist.impulse_duration_s, terms.impulse_amp)  # fmt: skip
        if dist.vibration_hz > 0 and terms.vibration_amp.any():
            phase = vib_phase
            for ch in map(int, np.flatnonzero(terms.vibration_amp)):
                data[ch, :, 0] += vibration(
                    t_on[None, :], dist.vibration_hz, terms.vibration_amp[ch], phase[:, ch, None]
                )
        out = np.moveaxis(data[:, :, 0, :], 0, -1)
    return out


def simulate_spin(
    spec: SensorSpec,
    truth: Truth | Sequence[Truth],
    rate_dps: float,
    duration_s: float,
    *,
    n_runs: int,
    rng: np.random.Generator,
    sample_rate_hz: float = 200.0,
    start_deg: float | None = None,
    start_s: float = 0.0,
    bias_step_dph: float = 0.0,
) -> SpinBatch:
    """Samples of ``n_runs`` independent steady spins at once (the spin Monte Carlo's generator).

    The model is the instrument's (:class:`~northfinder.firmware_sim.imu.Instrument`): the
    error-free samples of :func:`_spin_ideal_samples`, the error matrices, the constant and
    turn-on biases, white noise, the terms of time since power-on (:func:`_spin_time_terms`), an
    optional bias step, range and quantisation, the encoder's periodic error and resolution
    (:attr:`SpinBatch.encoder_rad`), and the drive's heat (the table's ``spin_heat``,
    :func:`~northfinder.firmware_sim.error_terms.spin_heat_bias`). The steady spin follows no
    stop, so neither discrete moves nor the ring-down enter.

    Parameters
    ----------
    spec : SensorSpec
    truth : Truth or sequence of Truth
        One truth for every run, or one per run.
    rate_dps : float
        Table rate, deg/s (non-zero).
    duration_s : float
        Length of the steady spin, s.
    n_runs : int
    rng : numpy.random.Generator
    sample_rate_hz : float
    start_deg : float, optional
        Table angle at the start of the steady spin; default a uniformly random angle per run.
    start_s : float
        Time from power-on to the start of the steady spin, s (for the terms of time since
        power-on: warm-up, temperature, ramps, random walks).
    bias_step_dph : float
        One gyro bias step of this size per run at a uniformly random time within the spin, in a
        random direction, deg/h.

    Raises
    ------
    SimConfigError
        Bad arguments.
    """
    if isinstance(n_runs, bool) or int(n_runs) != n_runs or int(n_runs) < 1:
        raise SimConfigError(f"n_runs: must be a positive integer, got {n_runs!r}")
    n_runs = int(n_runs)
    fs = check_sample_rate(sample_rate_hz)
    duration_s = _check_positive("duration_s", duration_s)
    start_s = _check_positive("start_s", start_s, allow_zero=True)
    bias_step_dph = _check_positive("bias_step_dph", bias_step_dph, allow_zero=True)
    if not (math.isfinite(rate_dps) and rate_dps != 0.0):
        raise SimConfigError(f"rate_dps: must be a finite non-zero rate, got {rate_dps!r}")
    terms = _error_terms(spec)
    tab = spec.table
    n = round(duration_s * fs)
    if n < 1:
        raise SimConfigError(f"duration_s: {duration_s} s holds no sample at {fs:g} Hz")
    az, lat, pitch, roll = _truth_arrays(truth, n_runs)
    turn_on, white, table_rng = rng.spawn(3)
    # Streams of the slower terms, after the first three (so that runs without them keep
    # their draws).
    slow, impulses, quantiser = rng.spawn(3)
    start = (
        table_rng.uniform(0.0, 360.0, n_runs)
        if start_deg is None
        else np.full(n_runs, float(start_deg))
    )
    out, t, edge_deg, edges = _spin_ideal_samples(tab, az, lat, pitch, roll, rate_dps, start, n, fs)
    draws = draw_turn_on(turn_on, (n_runs,))
    if terms.has_matrix:
        mg, ma = terms.matrices(draws)
        out[..., :3] = np.einsum("rij,rnj->rni", mg, out[..., :3])
        out[..., 3:] = np.einsum("rij,rnj->rni", ma, out[..., 3:])
    out += terms.turn_on(draws.z_bias)[:, None, :]
    sigma = terms.white_sigma(fs)
    if sigma.any():
        noise = white.standard_normal((n_runs, n, 6))
        noise *= sigma
        out += noise
        del noise
    # -- terms of time since power-on ---------------------------------------------------------
    t_on = start_s + t  # (n,)
    out = _spin_time_terms(out, terms, spec, t_on, fs, slow, impulses, draws.vib_phase)
    if bias_step_dph:
        t_step = impulses.uniform(t_on[0] - 1.0 / fs, t_on[-1], n_runs)
        v = impulses.standard_normal((n_runs, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        on = (t_on[None, :] - 1.0 / fs) >= t_step[:, None]  # (R, n)
        out[..., :3] += (bias_step_dph * DPH * v)[:, None, :] * on[..., None]
    heat = spin_heat_bias(
        terms, rate_dps, tab.max_accel_dps2, tab.spin_heat, n, fs, rng.spawn(1)[0], n_runs
    )
    if heat is not None:
        out += heat
    limit = terms.range
    if np.any(out > limit) or np.any(out < -limit):
        np.clip(out, -limit, limit, out=out)
    if terms.lsb.any():
        remainder = quantiser.uniform(-0.5, 0.5, (n_runs, 6))
        for ch in map(int, np.flatnonzero(terms.lsb)):
            counts, _ = quantise_carry(out[..., ch] / terms.lsb[ch], remainder[:, ch])
            out[..., ch] = counts * terms.lsb[ch]
    encoder = None
    if tab.encoder_error_deg or tab.encoder_resolution_deg > 0:
        encoder = np.radians(encoder_reading_deg(tab, edge_deg))
    return SpinBatch(
        gyro_rps=out[..., :3],
        accel_mps2=out[..., 3:],
        mu0_rad=edges[:, :-1],
        mu1_rad=edges[:, 1:],
        time_s=t,
        azimuth_deg=az,
        encoder_rad=encoder,
    )
