"""Between-position terms: what window means at several table positions say about the gyro bias.

A multi-position record (one run: power-on, then windows at several table angles with moves
between them) gives one mean per window for each horizontal gyro. Over one or more runs those
means are the Earth rate seen through the table, a bias, and random parts; this module estimates
the variance of each random part (a variance-component fit, by restricted maximum likelihood):

``white``
    Independent from window to window: white noise and anything faster than a window, 1 sigma
    of one window mean (of the reference window length; shorter windows scale as 1/sqrt(length)).
``turn_on``
    One value per run, the same in all its windows: the turn-on bias repeatability (needs two or
    more runs).
``move_walk``
    A lasting bias step at every move, 1 sigma per sqrt(deg) turned: window means after ``k``
    moves carry the sum of ``k`` steps. (With a drive that warms up, ``heat_tau_s`` > 0, a move's
    size is the heat it finds: all angles turned so far, each decayed with that time constant.)
``move_transient``
    A bias transient started by every move, 1 sigma per sqrt(deg) turned at the start of the move
    and decaying with a time constant ``tau_s`` that the caller states: each window carries the
    window mean of every earlier move's decay.

Slow noise that the Allan deviation already describes (bias instability B, rate random walk K)
may be given as a known part, so that it is not taken for a move term. The fixed part is either
the Earth rate of each run through the table angles plus one bias per axis (``per-run``: runs may
stand at different azimuths), or one mean per commanded position and axis shared by all runs
(``same-mount``: the runs repeat one plan on one mount; any effect that repeats at a position,
such as a position-dependent bias or a table wobble, is then removed rather than counted).

The log-likelihood is the restricted one (REML, Patterson and Thompson 1971), so the fixed part
costs its degrees of freedom; 95 % intervals are from the profile likelihood (a drop of 1.92).
With few runs a component's estimate often sits at zero: its interval then gives the upper limit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq, minimize
from threadpoolctl import threadpool_limits

from northfinder.host.errors import InputError

__all__ = [
    "COMPONENTS",
    "DESIGNS",
    "BetweenFit",
    "RunWindows",
    "SlowNoise",
    "fit_between_positions",
]

#: The random parts, in the order of :attr:`BetweenFit.sigma`.
COMPONENTS = ("white", "turn_on", "move_walk", "move_transient")
#: Fixed parts: each run's Earth rate and a common bias, or one mean per position shared by runs.
DESIGNS = ("per-run", "same-mount")
#: Drop of the log-likelihood at the ends of a 95 % profile interval: chi2(1, 0.95) / 2.
PROFILE_DROP = 0.5 * 3.841458820694124

#: Gauss-Markov approximation of flicker noise for the known slow-noise part: correlation times
#: 1 s to 10^4 s spaced by sqrt(10), each of variance ln(sqrt 10) / pi per B^2 (one-sided PSD
#: B^2 / (pi f) between a few seconds and a few hours).
_FLICKER_TAUS_S = 10.0 ** np.arange(0.0, 4.01, 0.5)
_FLICKER_VARIANCE = math.log(10.0**0.5) / math.pi


@dataclass(frozen=True)
class RunWindows:
    """The windows of one run (one power-on), in time order.

    Attributes
    ----------
    gyro_dph : (k, 2) float
        Mean of the x and y gyro over each window, deg/h.
    table_deg : (k,) float
        Table angle during each window (encoder), deg.
    commanded_deg : (k,) float
        Table angle ordered for each window, deg (groups positions for ``same-mount``).
    start_s, end_s : (k,) float
        Start and end of each window, s (any origin common to the run).
    move_deg : (k,) float
        Angle turned by the move before each window, deg; 0 where the table did not move.
    move_start_s : (k,) float
        When that move started, s (ignored where ``move_deg`` is 0).
    """

    gyro_dph: NDArray[np.float64]
    table_deg: NDArray[np.float64]
    commanded_deg: NDArray[np.float64]
    start_s: NDArray[np.float64]
    end_s: NDArray[np.float64]
    move_deg: NDArray[np.float64]
    move_start_s: NDArray[np.float64]

    def __post_init__(self) -> None:
        k = len(self.table_deg)
        g = np.asarray(self.gyro_dph, dtype=float)
        if g.shape != (k, 2) or k < 1:
            raise InputError(f"gyro_dph: expected shape ({k}, 2) for {k} windows, got {g.shape}")
        for name in ("commanded_deg", "start_s", "end_s", "move_deg", "move_start_s"):
            if np.shape(getattr(self, name)) != (k,):
                raise InputError(f"{name}: expected {k} values, one per window")
        if not np.all(np.isfinite(g)) or not np.all(np.isfinite(self.table_deg)):
            raise InputError("gyro_dph, table_deg: contain non-finite values")
        if np.any(np.asarray(self.end_s) <= np.asarray(self.start_s)):
            raise InputError("end_s: every window must end after it starts")

    @classmethod
    def regular(
        cls, gyro_dph: ArrayLike, positions_deg: Sequence[float], window_s: float, step_s: float
    ) -> RunWindows:
        """A run of a regular plan: windows of ``window_s`` every ``step_s`` seconds at the
        table angles ``positions_deg``, each move starting as the window before it ends."""
        pos = np.asarray(positions_deg, dtype=float)
        start = np.arange(pos.size, dtype=np.float64) * float(step_s)
        end: NDArray[np.float64] = start + float(window_s)
        move = np.concatenate([[0.0], (np.diff(pos) + 180.0) % 360.0 - 180.0])
        move_start = np.concatenate([[math.nan], end[:-1]])
        return cls(np.asarray(gyro_dph, dtype=float), pos, pos, start, end, move, move_start)

    @property
    def windows(self) -> int:
        return len(self.table_deg)

    @property
    def moves(self) -> int:
        return int(np.count_nonzero(self.move_deg))


@dataclass(frozen=True)
class SlowNoise:
    """Slow noise already known from the Allan deviation, added to the covariance as it is.

    Attributes
    ----------
    bias_instability_dph : float
        Flicker bias instability B (Allan floor 0.664 B), deg/h.
    rrw_dph_per_rts : float
        Rate random walk K, deg/h per sqrt(s).
    """

    bias_instability_dph: float = 0.0
    rrw_dph_per_rts: float = 0.0


@dataclass(frozen=True)
class BetweenFit:
    """Result of :func:`fit_between_positions`.

    Attributes
    ----------
    sigma : dict
        Estimate of each component of :data:`COMPONENTS` (units in the module doc: deg/h for
        ``white`` and ``turn_on``, deg/h/sqrt(deg) for the move terms); ``nan`` when the records
        cannot show it (``turn_on`` from one run, move terms without moves).
    interval : dict
        95 % profile-likelihood interval of each estimate, ``(low, high)``.
    window_s : float
        The reference window length of ``white``, s.
    tau_s : float
        Time constant assumed for ``move_transient``, s.
    heat_tau_s : float
        Time constant assumed for the drive's heat, s (0: none).
    design : str
        The fixed part used (:data:`DESIGNS`).
    runs, windows, moves : int
        What the fit saw (moves counted over runs).
    dof : int
        Residual degrees of freedom (window means less fixed parameters).
    log_likelihood : float
        Restricted log-likelihood at the estimate (up to a constant).
    bias_dph : (2,) float
        Common bias of the x and y gyro (``per-run`` design; ``nan`` for ``same-mount``), deg/h.
    """

    sigma: dict[str, float]
    interval: dict[str, tuple[float, float]]
    window_s: float
    tau_s: float
    heat_tau_s: float
    design: str
    runs: int
    windows: int
    moves: int
    dof: int
    log_likelihood: float
    bias_dph: NDArray[np.float64] = field(repr=False)

    def transient_in_window_dph(self, delay_s: float, length_s: float, move_deg: float) -> float:
        """1 sigma of the move transient in the mean of a window that starts ``delay_s`` after
        the start of a move of ``move_deg`` and lasts ``length_s``, deg/h."""
        w = float(_decay_mean(delay_s, delay_s + length_s, self.tau_s))
        return self.sigma["move_transient"] * math.sqrt(abs(move_deg)) * w


def _decay_mean(
    a: float | NDArray[np.float64], b: float | NDArray[np.float64], tau: float
) -> NDArray[np.float64]:
    """Mean of exp(-s / tau) over s in [a, b] (0 <= a < b)."""
    return np.asarray(tau / (b - a) * (np.exp(-a / tau) - np.exp(-b / tau)))


def _gm_window_cov(
    start: NDArray[np.float64], end: NDArray[np.float64], tau: float
) -> NDArray[np.float64]:
    """Covariance of the window means of a unit-variance first-order Gauss-Markov process."""

    # F(x) = tau^2 exp(-|x| / tau) + tau |x| has F'' = exp(-|x| / tau): the double integral of
    # the correlation over windows [a, b] and [c, d] is F(b - c) + F(a - d) - F(a - c) - F(b - d).
    def prim(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return tau * tau * np.exp(-np.abs(x) / tau) + tau * np.abs(x)

    a, b = start[:, None], end[:, None]
    c, d = start[None, :], end[None, :]
    total = prim(b - c) + prim(a - d) - prim(a - c) - prim(b - d)
    return np.asarray(total / ((b - a) * (d - c)))


def _slow_cov(run: RunWindows, slow: SlowNoise) -> NDArray[np.float64]:
    """Covariance of the window means of one run from the known slow noise, (k, k), (deg/h)^2."""
    s = np.asarray(run.start_s, dtype=float)
    e = np.asarray(run.end_s, dtype=float)
    s, e = s - s[0], e - s[0]
    cov = np.zeros((run.windows, run.windows))
    b = slow.bias_instability_dph
    if b:
        for tau in _FLICKER_TAUS_S:
            cov += _FLICKER_VARIANCE * b * b * _gm_window_cov(s, e, tau)
    k = slow.rrw_dph_per_rts
    if k:
        # A walk from the first window's start: E[W(s) W(u)] = K^2 min(s, u), averaged over both
        # windows (exact for windows that do not overlap, and for a window with itself). What it
        # did since power-on is one value per run, like the turn-on bias.
        mid = 0.5 * (s + e)
        m = np.minimum(mid[:, None], mid[None, :])
        np.fill_diagonal(m, s + (e - s) / 3.0)
        cov += k * k * m
    return cov


def _heat_sizes(start_s: NDArray[np.float64], angle_deg: NDArray[np.float64], heat_tau_s: float):
    """Size of each move's disturbance, deg: the angles turned so far, each decayed with the
    motor's heat time constant (the simulator's model of a drive that warms up)."""
    d = np.abs(angle_deg)
    if heat_tau_s <= 0.0:
        return d
    lag = start_s[:, None] - start_s[None, :]
    return (np.where(lag >= 0.0, np.exp(-np.maximum(lag, 0.0) / heat_tau_s), 0.0) * d).sum(1)


def _component_blocks(
    run: RunWindows, tau_s: float, window_s: float, heat_tau_s: float
) -> dict[str, NDArray[np.float64]]:
    """Covariance of one run's window means (one axis) per component at unit sigma, (k, k)."""
    start = np.asarray(run.start_s, dtype=float)
    end = np.asarray(run.end_s, dtype=float)
    moves = np.flatnonzero(run.move_deg)
    t0 = np.asarray(run.move_start_s, dtype=float)[moves]
    size = _heat_sizes(t0, np.asarray(run.move_deg, dtype=float)[moves], heat_tau_s)
    root = np.sqrt(size)[:, None]
    t0 = t0[:, None]
    after = start[None, :] >= t0  # (moves, k): the move came before the window
    step = after * root
    delay0 = np.maximum(start[None, :] - t0, 0.0)
    delay1 = np.maximum(end[None, :] - t0, delay0 + 1e-9)
    decay = np.where(after, _decay_mean(delay0, delay1, tau_s), 0.0) * root
    k = run.windows
    return {
        "white": np.diag(window_s / (end - start)),
        "turn_on": np.ones((k, k)),
        "move_walk": step.T @ step,
        "move_transient": decay.T @ decay,
    }


def _design(runs: Sequence[RunWindows], design: str) -> list[NDArray[np.float64]]:
    """Fixed-effect columns of each run's means, each (k, 2 axes, p), over all runs' parameters."""
    out = []
    if design == "per-run":
        n = len(runs)
        for r, run in enumerate(runs):
            mu = np.radians(np.asarray(run.table_deg, dtype=float))
            c, s = np.cos(mu), np.sin(mu)
            x = np.zeros((run.windows, 2, 2 * n + 2))
            # The x gyro reads c h_x + s h_y + b_x, the y gyro -s h_x + c h_y + b_y (C_m^m1 h).
            x[:, 0, 2 * r], x[:, 0, 2 * r + 1], x[:, 0, 2 * n] = c, s, 1.0
            x[:, 1, 2 * r], x[:, 1, 2 * r + 1], x[:, 1, 2 * n + 1] = -s, c, 1.0
            out.append(x)
        return out
    keys = sorted({round(float(c) % 360.0, 6) for run in runs for c in run.commanded_deg})
    index = {key: i for i, key in enumerate(keys)}
    for run in runs:
        x = np.zeros((run.windows, 2, 2 * len(keys)))
        for k, c in enumerate(run.commanded_deg):
            j = index[round(float(c) % 360.0, 6)]
            x[k, 0, 2 * j] = x[k, 1, 2 * j + 1] = 1.0
        out.append(x)
    return out


_Group = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


class _Reml:
    """Negative restricted log-likelihood of the window means as a function of the component
    sigmas. Runs are independent and so are the two axes, which share one (k, k) covariance per
    run: every product is done per run, batched over runs with the same number of windows."""

    def __init__(
        self,
        y: list[NDArray[np.float64]],
        x: list[NDArray[np.float64]],
        known: list[NDArray[np.float64]],
        g: list[list[NDArray[np.float64]]],
    ) -> None:
        # The likelihood does not change when the fixed part is reparametrised: use an
        # orthonormal basis of its columns, which also drops columns the data cannot separate.
        flat = np.concatenate([xi.reshape(-1, xi.shape[-1]) for xi in x])
        u, sv, _ = np.linalg.svd(flat, full_matrices=False)
        self.rank = int(np.sum(sv > 1e-10 * sv[0]))
        basis = u[:, : self.rank]
        offsets = np.cumsum([0] + [2 * len(yi) for yi in y])
        by_len: dict[int, list[int]] = {}
        for i, yi in enumerate(y):
            by_len.setdefault(len(yi), []).append(i)
        self.groups: list[_Group] = []
        for k, members in sorted(by_len.items()):
            ys = np.stack([y[i] for i in members])  # (m, k, 2)
            xs = np.stack(
                [basis[offsets[i] : offsets[i + 1]].reshape(k, 2, self.rank) for i in members]
            )  # (m, k, 2, p)
            ks = np.stack([known[i] for i in members])  # (m, k, k)
            gs = np.stack([np.stack([gc[i] for i in members]) for gc in g])  # (c, m, k, k)
            if np.array_equal(ks, ks[:1].repeat(len(members), 0)) and np.array_equal(
                gs, gs[:, :1].repeat(len(members), 1)
            ):
                # Runs of one plan share their covariance: keep it once.
                ks, gs = ks[:1], gs[:, :1]
            self.groups.append((ys, xs, ks, gs))
        self.n = int(offsets[-1])

    def __call__(self, sig: NDArray[np.float64]) -> float:
        return self.value_and_grad(sig, grad=False)[0]

    def value_and_grad(
        self, sig: NDArray[np.float64], grad: bool = True
    ) -> tuple[float, NDArray[np.float64]]:
        """The negative restricted log-likelihood and its gradient in the sigmas.

        With P = V^-1 - V^-1 X (X^T V^-1 X)^-1 X^T V^-1 and r = P y, d/d sigma_i of
        (log|V| + log|X^T V^-1 X| + y^T P y) / 2 is sigma_i (tr(P G_i) - r^T G_i r).
        """
        sig = np.asarray(sig, dtype=float)
        sq = np.square(sig)
        p = self.rank
        logdet = 0.0
        xvx = np.zeros((p, p))
        xvy = np.zeros(p)
        yvy = 0.0
        cache = []
        bad = (1e30, np.zeros(sig.size))
        for ys, xs, ks, gs in self.groups:
            m, k = ys.shape[0], ys.shape[1]
            v = ks + np.tensordot(sq, gs, axes=1)  # (1 or m, k, k)
            v = v + (1e-12 * np.trace(v, axis1=1, axis2=2) / k + 1e-10)[:, None, None] * np.eye(k)
            try:
                c = np.linalg.cholesky(v)
            except np.linalg.LinAlgError:
                return bad
            # log det V = 2 sum log diag(L) per covariance; the two axes share each, and one
            # shared covariance serves every run of its group.
            shared = len(c) == 1
            logdet += (
                4.0 * float(np.sum(np.log(np.diagonal(c, axis1=1, axis2=2)))) * (m if shared else 1)
            )
            w = np.linalg.solve(c, np.broadcast_to(np.eye(k), c.shape))
            vinv = np.swapaxes(w, 1, 2) @ w  # (1 or m, k, k)
            vy = vinv @ ys  # (m, k, 2)
            vx = (vinv @ xs.reshape(m, k, -1)).reshape(xs.shape)  # (m, k, 2, p)
            yvy += float(np.sum(ys * vy))
            xf = xs.reshape(-1, p)
            xvy += xf.T @ vy.reshape(-1)
            xvx += xf.T @ vx.reshape(-1, p)
            cache.append((vinv, vy, vx, shared))
        try:
            cx = np.linalg.cholesky(xvx)
        except np.linalg.LinAlgError:
            return bad
        proj = np.linalg.solve(cx, xvy)
        value = 0.5 * (logdet + 2.0 * float(np.sum(np.log(np.diag(cx)))) + yvy - float(proj @ proj))
        if not math.isfinite(value):
            return bad
        out = np.zeros(sig.size)
        if not grad:
            return value, out
        xvx_inv = np.linalg.inv(xvx)
        beta = xvx_inv @ xvy
        for (ys, _xs, _ks, gs), (vinv, vy, vx, shared) in zip(self.groups, cache, strict=True):
            m, k = ys.shape[0], ys.shape[1]
            r = vy - vx @ beta  # V^-1 (y - X beta), (m, k, 2)
            for i in range(sig.size):
                g = gs[i]  # (1 or m, k, k)
                gr = g @ r
                gvx = (g @ vx.reshape(m, k, -1)).reshape(vx.shape)
                trace = 2.0 * float(np.sum(vinv * g)) * (m if shared else 1)
                zgz = vx.reshape(-1, p).T @ gvx.reshape(-1, p)
                out[i] += trace - float(np.sum(xvx_inv * zgz)) - float(np.sum(r * gr))
        return value, sig * out


# Thousands of likelihoods of small matrices: BLAS threads only contend for them.
@threadpool_limits.wrap(limits=1, user_api="blas")
def fit_between_positions(
    runs: Sequence[RunWindows],
    *,
    tau_s: float = 10.0,
    design: str = "per-run",
    slow: SlowNoise | None = None,
    window_s: float | None = None,
    fixed: Mapping[str, float] | None = None,
    heat_tau_s: float = 0.0,
    intervals: Sequence[str] | None = None,
) -> BetweenFit:
    """Variance components of the x and y gyro window means over runs (see the module doc).

    Parameters
    ----------
    runs : sequence of RunWindows
        One entry per run (power-on).
    tau_s : float
        Time constant of the move transient, s. The window means of a plan with fixed timing
        cannot tell it apart from the transient's size; state it.
    design : {"per-run", "same-mount"}
        The fixed part (module doc).
    slow : SlowNoise, optional
        Known bias instability and rate random walk (from the Allan deviation).
    window_s : float, optional
        Reference window length of ``white``, s (default: the median window length).
    fixed : mapping, optional
        Components held at a given value (names of :data:`COMPONENTS`, their units) rather than
        estimated, e.g. a turn-on repeatability known from elsewhere.
    heat_tau_s : float
        Time constant of the drive's heat, s: a move's disturbance then has the variance of all
        angles turned so far, each decayed with it (0: of its own angle alone).
    intervals : sequence of str, optional
        Components whose profile interval to compute (default all; each costs a few hundred
        refits). Those left out get ``(nan, nan)``.

    Returns
    -------
    BetweenFit

    Raises
    ------
    InputError
        No runs, an unknown design, a bad time constant, or fewer window means than the fixed
        part has parameters.
    """
    runs = list(runs)
    if not runs:
        raise InputError("runs: need at least one run of windows")
    if design not in DESIGNS:
        raise InputError(f"design: unknown {design!r}; choose from {', '.join(DESIGNS)}")
    if not (math.isfinite(tau_s) and tau_s > 0):
        raise InputError(f"tau_s: must be a positive number of seconds, got {tau_s!r}")
    lengths = np.concatenate([np.asarray(r.end_s) - np.asarray(r.start_s) for r in runs])
    ref = float(np.median(lengths)) if window_s is None else float(window_s)
    x = _design(runs, design)
    y = [np.asarray(r.gyro_dph, dtype=float) for r in runs]
    slow = slow or SlowNoise()
    if not (math.isfinite(heat_tau_s) and heat_tau_s >= 0):
        raise InputError(f"heat_tau_s: must be a finite number of seconds >= 0, got {heat_tau_s!r}")
    blocks = [_component_blocks(r, tau_s, ref, heat_tau_s) for r in runs]
    known = [_slow_cov(r, slow) for r in runs]
    n_moves = sum(r.moves for r in runs)
    names = _shown_components(len(runs), n_moves)
    fixed = _checked_fixed(fixed)
    nll, scale, unit = _scaled_likelihood(x, y, known, blocks, names)
    dof = nll.n - nll.rank
    if dof < 2:
        raise InputError(
            f"{nll.n} window means (x and y) against {nll.rank} fixed parameters: need more "
            "windows or runs"
        )

    held = {i: fixed[name] * unit[i] / scale for i, name in enumerate(names) if name in fixed}
    # Starts: every component alike, and each one alone carrying the residual variance.
    starts = [np.full(len(names), v) for v in (0.2, 0.6)]
    starts += [np.where(np.arange(len(names)) == i, 1.0, 0.05) for i in range(len(names))]
    f_min, est = min((_minimise(nll, len(names), held, x0) for x0 in starts), key=lambda r: r[0])

    def profile(i: int, v: float) -> float:
        return _minimise(nll, len(names), {**held, i: v}, est)[0] - f_min - PROFILE_DROP

    sigma, interval = _sigmas_and_intervals(
        names, est, held, fixed, scale, unit, intervals, profile
    )
    bias = np.full(2, math.nan)
    if design == "per-run":
        bias = _gls_bias(runs, x, known, blocks, names, est * scale / unit)
    return BetweenFit(
        sigma=sigma,
        interval=interval,
        window_s=ref,
        tau_s=float(tau_s),
        heat_tau_s=float(heat_tau_s),
        design=design,
        runs=len(runs),
        windows=sum(r.windows for r in runs),
        moves=n_moves,
        dof=int(dof),
        log_likelihood=-f_min - dof * math.log(scale),
        bias_dph=bias,
    )


def _checked_fixed(fixed: Mapping[str, float] | None) -> dict[str, float]:
    """The components held at a value, checked: known names, finite sigmas >= 0."""
    fixed = dict(fixed or {})
    for name, value in fixed.items():
        if name not in COMPONENTS:
            raise InputError(f"fixed: unknown component {name!r}; components are {COMPONENTS}")
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"fixed {name}: must be a finite sigma >= 0, got {value!r}")
    return fixed


def _shown_components(n_runs: int, n_moves: int) -> list[str]:
    """The components the records can show."""
    # What the records can show: the turn-on value needs a second run, the move terms moves.
    usable = {
        "white": True,
        "turn_on": n_runs >= 2,
        "move_walk": n_moves > 0,
        "move_transient": n_moves > 0,
    }
    return [c for c in COMPONENTS if usable[c]]


def _scaled_likelihood(
    x: list[NDArray[np.float64]],
    y: list[NDArray[np.float64]],
    known: list[NDArray[np.float64]],
    blocks: list[dict[str, NDArray[np.float64]]],
    names: list[str],
) -> tuple[_Reml, float, NDArray[np.float64]]:
    """The restricted likelihood of the window means in units of their residual spread: the
    likelihood, that spread (deg/h) and each component's unit."""
    # Work in units of the residual spread so that the optimiser's tolerances suit any data.
    flat_x = np.concatenate([xi.reshape(-1, xi.shape[-1]) for xi in x])
    flat_y = np.concatenate([yi.ravel() for yi in y])
    resid = flat_y - flat_x @ np.linalg.lstsq(flat_x, flat_y, rcond=None)[0]
    scale = float(np.sqrt(np.mean(resid**2))) or 1.0
    # Each component's unit: its mean variance over the windows it reaches, so that every
    # sigma the optimiser sees is of the size of the residuals (a transient that decays in a few
    # seconds may need a large start to show in a window).
    unit = np.array(
        [
            math.sqrt(np.mean([d for b in blocks for d in np.diag(b[c]) if d > 0]) or 1.0)
            for c in names
        ]
    )
    nll = _Reml(
        [yi / scale for yi in y],
        x,
        [kn / scale**2 for kn in known],
        [[b[c] / (u * u) for b in blocks] for c, u in zip(names, unit, strict=True)],
    )
    return nll, scale, unit


def _minimise(
    nll: _Reml, n_names: int, fixed: dict[int, float], x0: NDArray[np.float64]
) -> tuple[float, NDArray[np.float64]]:
    free = [i for i in range(n_names) if i not in fixed]
    s = np.array(x0, dtype=float)
    for i, val in fixed.items():
        s[i] = val
    if not free:
        return nll(s), s

    def f(v: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        s[free] = v
        value, grad = nll.value_and_grad(s)
        return value, grad[free]

    res = minimize(f, s[free], jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * len(free))
    out = s.copy()
    out[free] = res.x
    return float(res.fun), out


def _sigmas_and_intervals(
    names: list[str],
    est: NDArray[np.float64],
    held: dict[int, float],
    fixed: dict[str, float],
    scale: float,
    unit: NDArray[np.float64],
    intervals: Sequence[str] | None,
    profile: Callable[[int, float], float],
) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
    """Each component's sigma and profile interval (nan where the records cannot show it, the
    held value where it was fixed)."""
    sigma: dict[str, float] = {c: math.nan for c in COMPONENTS}
    interval: dict[str, tuple[float, float]] = {c: (math.nan, math.nan) for c in COMPONENTS}
    for i, name in enumerate(names):
        v = float(est[i])
        if i in held:
            sigma[name] = fixed[name]
            interval[name] = (fixed[name], fixed[name])
            continue
        sigma[name] = v * scale / unit[i]
        if intervals is not None and name not in intervals:
            continue
        lo = 0.0
        if v > 0.0 and profile(i, 0.0) > 0.0:
            lo = brentq(lambda s, i=i: profile(i, s), 0.0, v, xtol=1e-3 * v)
        hi = max(2.0 * v, 0.05)
        while profile(i, hi) < 0.0 and hi < 1e3:
            hi *= 2.0
        up = math.inf
        if profile(i, hi) >= 0.0:
            up = brentq(lambda s, i=i: profile(i, s), v, hi, xtol=1e-3 * hi)
        interval[name] = (lo * scale / unit[i], up * scale / unit[i])
    return sigma, interval


def _gls_bias(
    runs: Sequence[RunWindows],
    x: list[NDArray[np.float64]],
    known: list[NDArray[np.float64]],
    blocks: list[dict[str, NDArray[np.float64]]],
    names: list[str],
    sig: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Generalised least squares of the fixed part at the estimate: the common x and y bias."""
    p = x[0].shape[-1]
    xvx = np.zeros((p, p))
    xvy = np.zeros(p)
    for run, xi, kn, b in zip(runs, x, known, blocks, strict=True):
        v = kn + sum(s * s * b[c] for s, c in zip(sig, names, strict=True))
        v = v + 1e-12 * (np.trace(v) / len(v) + 1e-300) * np.eye(len(v))
        vx = np.linalg.solve(v, xi.reshape(len(v), -1)).reshape(xi.shape)
        vy = np.linalg.solve(v, np.asarray(run.gyro_dph, dtype=float))
        xvx += np.einsum("kap,kaq->pq", xi, vx)
        xvy += np.einsum("kap,ka->p", xi, vy)
    beta = np.linalg.lstsq(xvx, xvy, rcond=None)[0]
    return np.asarray(beta[-2:])
