"""What a north-finding run measures and how its windows are reduced: the one plan type.

A :class:`Plan` is used alike by the procedure on a device (:mod:`northfinder.host.procedure`),
the accuracy study (:mod:`northfinder.host.montecarlo`) and the planner
(:mod:`northfinder.host.plan_search`): table positions, one recording window of ``window_s`` at each,
the settle time after every move, the denoising method applied to every window and the solver.

Settle time
-----------
``settle_s`` is the time from the end of a move (the end of the table's motion profile) to the
start of the next window; None means the table's own settle time (:attr:`TableModel.settle_s`,
on a device its ``SETTLE_TIME_MS``, after which it reports READY). A device cannot record before
its own settle time has passed, so on a device the procedure waits for READY and then whatever
remains of ``settle_s``; a study simulates exactly ``settle_s`` (a what-if for a table that
settles faster).

Plan time
---------
Moves go the shorter way with the table's trapezoidal profile
(:func:`northfinder.driver.protocol.motion.move_time_s`); a position equal to the previous one
needs neither move nor settling. The **plan time** runs from the start of the first window to the
end of the last: windows, moves and settling, not the warm-up before the first window.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.motion import TableLimits, shortest_delta_deg
from northfinder.host.denoise import METHODS
from northfinder.host.errors import GeometryError, HostConfigError, InputError, check_choice
from northfinder.host.kernels import MIN_MU_SEPARATION_DEG
from northfinder.host.spin import MIN_SWEEP_DEG

__all__ = [
    "DEFAULT_POSITIONS_DEG",
    "HEADING_SOLVERS",
    "PAPER_SWEEP",
    "PLANS",
    "SOLVERS",
    "Plan",
    "SpinPlan",
    "TableModel",
    "moves_deg",
    "plan_time_s",
    "resolve_solver",
    "settle_time_s",
    "spin_ramp_s",
    "spin_start_deg",
    "window_starts_s",
]

#: Heading solvers a plan may name.
#: The commands' default plan (find, record, study, sweep, simulate): each position twice, in the
#: symmetric order 0, 180, 180, 0. Opposite positions give the most heading per second (notes 4);
#: the symmetric order cancels a linear drift; and the two redundant windows let the solver test
#: the windows against their noise, so a bias step or drift between windows is flagged instead of
#: giving a silently wrong heading (a two-position plan cannot check itself). docs/find.md, "The
#: plan", says more.
DEFAULT_POSITIONS_DEG: tuple[float, ...] = (0.0, 180.0, 180.0, 0.0)

SOLVERS: Mapping[str, str] = {
    "auto": "two-position for 2 positions, least-squares for more",
    "two-position": "paper eq. 14 (eq. 15 when level is assumed); exactly 2 positions",
    "least-squares": "multi-position least squares, gyro biases estimated",
    "pairwise": "every position against the first by eq. 14 (the paper's Table 2; studies only)",
}
#: The solvers of :data:`SOLVERS` that give one heading (``pairwise`` gives one per pair).
HEADING_SOLVERS = ("auto", "two-position", "least-squares")


def resolve_solver(name: str, positions: int, field: str = "method") -> str:
    """The solver of :data:`SOLVERS` that ``name`` stands for with ``positions`` windows
    (``auto``: two-position for two, least-squares for more).

    Raises
    ------
    HostConfigError
        An unknown name, or ``two-position`` with other than two positions.
    """
    check_choice(name, SOLVERS, field)
    if name == "auto":
        return "two-position" if positions == 2 else "least-squares"
    if name == "two-position" and positions != 2:
        raise HostConfigError(f"{field} two-position needs exactly two positions, got {positions}")
    return name


@dataclass(frozen=True)
class TableModel(TableLimits):
    """What plans need to know about the turntable: its motion limits and settle time
    (:class:`~northfinder.driver.protocol.motion.TableLimits`, whose defaults are the
    simulated table's), and how well it stops.

    Attributes
    ----------
    max_rate_dps, max_accel_dps2 : float
        Speed and acceleration limits, deg/s and deg/s^2.
    settle_s : float
        The table's own settle time after a move, s (the plans' default).
    indexing_error_deg : float
        Stop-position error per move, 1 sigma, deg.
    encoder_resolution_deg : float
        Encoder resolution, deg (0: exact).
    heat_tau_s : float
        Time constant of the heat the drive holds, s: it sizes the bias disturbance of a move
        (0: each move by its own angle).
    spin_heat : float
        While spinning: the fraction of a move's bias disturbance per degree that steady turning
        carries (:mod:`northfinder.driver.protocol.heat`; 0: none).
    rate_ripple, rate_ripple_phase_deg : float
        While spinning: once-per-turn rate ripple (fraction of the rate) and the table angle of
        its fastest point, deg.
    wobble_urad, wobble_phase_deg : float
        Tilt of the table top against its axis, urad, and the table-frame direction it tilts
        towards, deg.
    encoder_error_deg, encoder_error_harmonic, encoder_error_phase_deg : float
        Periodic encoder error: it reads ``mu + e sin(n mu + phase)``.
    """

    indexing_error_deg: float = 0.0
    encoder_resolution_deg: float = 0.0
    heat_tau_s: float = 0.0
    spin_heat: float = 0.0
    rate_ripple: float = 0.0
    rate_ripple_phase_deg: float = 0.0
    wobble_urad: float = 0.0
    wobble_phase_deg: float = 0.0
    encoder_error_deg: float = 0.0
    encoder_error_harmonic: float = 1.0
    encoder_error_phase_deg: float = 0.0


@dataclass(frozen=True)
class Plan:
    """Table positions with one window each, the settle time, and how the windows are reduced.

    Attributes
    ----------
    positions_deg : tuple of float
        Commanded table angle of each window, deg (any angles; at least two of them
        :data:`~northfinder.host.kernels.MIN_MU_SEPARATION_DEG` apart mod 360).
    window_s : float
        Recording time per window, s.
    settle_s : float or None
        Time from the end of each move to the next window, s; None: the table's own (see the
        module docstring).
    denoise : str
        A method of :data:`northfinder.host.denoise.METHODS`, applied to every window before its
        mean.
    method : str
        A solver of :data:`SOLVERS`.
    denoise_options : tuple of (str, value) pairs
        Options of the denoising method, e.g. ``(("window", 5),)`` for ``moving-average``.

    Raises
    ------
    GeometryError
        Fewer than two positions, or none far enough apart to separate the Earth rate.
    HostConfigError
        A bad number, an unknown method, or ``two-position`` with other than two positions.
    """

    positions_deg: tuple[float, ...] = (0.0, 180.0)
    window_s: float = 10.0
    settle_s: float | None = None
    denoise: str = "none"
    method: str = "auto"
    denoise_options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        pos = tuple(float(p) for p in self.positions_deg)
        if len(pos) < 2:
            raise GeometryError(
                f"positions {list(pos)}: need at least two table angles "
                f"(a plan needs at least 2 positions, got {len(pos)})"
            )
        if not all(math.isfinite(p) for p in pos):
            raise InputError(f"positions_deg: must be finite, got {pos}")
        spread = np.abs(np.sin(np.radians(np.subtract.outer(pos, pos)) / 2.0)).max()
        if spread < math.sin(math.radians(MIN_MU_SEPARATION_DEG) / 2.0):
            raise GeometryError(
                f"positions {list(pos)} deg lie within {MIN_MU_SEPARATION_DEG} deg of each other: "
                f"at least two must be {MIN_MU_SEPARATION_DEG:g} deg apart (mod 360) for the gyro "
                "biases to separate from the Earth rate"
            )
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise InputError(f"window_s: must be a positive number of seconds, got {self.window_s}")
        if self.settle_s is not None and not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise InputError(f"settle_s: must be >= 0 s, got {self.settle_s}")
        check_choice(self.denoise, METHODS, "denoise", "method")
        resolve_solver(self.method, len(pos))
        pairs = tuple(self.denoise_options)
        if not all(
            isinstance(kv, tuple | list) and len(kv) == 2 and isinstance(kv[0], str) for kv in pairs
        ):
            raise HostConfigError(
                f"denoise_options: expected (name, value) pairs, got {self.denoise_options!r}"
            )
        object.__setattr__(self, "positions_deg", pos)
        object.__setattr__(self, "denoise_options", tuple((k, v) for k, v in pairs))

    @property
    def solver(self) -> str:
        """The solver ``method`` stands for (``auto`` resolved by the number of positions)."""
        return resolve_solver(self.method, len(self.positions_deg))

    def label(self) -> str:
        """The positions as ``0,90,180``."""
        return ",".join(f"{p:g}" for p in self.positions_deg)

    def pairs(self) -> tuple[tuple[int, int], ...]:
        """Index pairs (first, k) of the ``pairwise`` solver."""
        return tuple((0, k) for k in range(1, len(self.positions_deg)))

    def pair_mu_deg(self) -> tuple[float, ...]:
        """Table angle of each pair, deg."""
        a0 = self.positions_deg[0]
        return tuple(a - a0 for a in self.positions_deg[1:])


@dataclass(frozen=True)
class SpinPlan:
    """A spin (rotation modulation): the table turns at a constant rate and the heading is the
    phase of the Earth rate's sinusoid (:mod:`northfinder.host.spin`).

    The table starts at rest at angle 0, accelerates to ``rate_dps`` at its acceleration limit,
    records ``spin_s`` seconds at the steady rate and brakes: the plan time counts both ramps
    (:func:`plan_time_s`), as ``find --spin RATE --spin-time SECONDS`` runs it.

    Attributes
    ----------
    rate_dps : float
        Table rate, deg/s (either sign; within the table's limit).
    spin_s : float
        Seconds at the steady rate (whole turns, ``360 / |rate|`` s each, are best).
    drift : bool
        The solver also fits a linear drift of each gyro and accelerometer.

    Raises
    ------
    GeometryError
        The table would turn less than :data:`~northfinder.host.spin.MIN_SWEEP_DEG`.
    InputError
        A rate or time that is not a finite positive number.
    """

    rate_dps: float = 6.0
    spin_s: float = 60.0
    drift: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_dps) and self.rate_dps != 0.0):
            raise InputError(f"rate_dps: must be a finite non-zero rate, got {self.rate_dps!r}")
        if not (math.isfinite(self.spin_s) and self.spin_s > 0):
            raise InputError(f"spin_s: must be a positive number of seconds, got {self.spin_s!r}")
        if abs(self.rate_dps) * self.spin_s < MIN_SWEEP_DEG:
            raise GeometryError(
                f"a spin of {self.spin_s:g} s at {self.rate_dps:g} deg/s: the table must turn "
                f"at least {MIN_SWEEP_DEG:g} deg"
            )
        object.__setattr__(self, "rate_dps", float(self.rate_dps))
        object.__setattr__(self, "spin_s", float(self.spin_s))
        object.__setattr__(self, "drift", bool(self.drift))

    @property
    def turns(self) -> float:
        return abs(self.rate_dps) * self.spin_s / 360.0

    def label(self) -> str:
        """``spin +6 deg/s x 60 s`` (and ``, drift fitted``)."""
        return f"spin {self.rate_dps:+g} deg/s x {self.spin_s:g} s" + (
            ", drift fitted" if self.drift else ""
        )


def spin_ramp_s(plan: SpinPlan, table: TableModel) -> float:
    """Time to reach the spin's rate from rest (and to brake from it), s.

    Raises
    ------
    HostConfigError
        The rate is beyond the table's limit.
    """
    if abs(plan.rate_dps) > table.max_rate_dps * (1 + 1e-12):
        raise HostConfigError(
            f"spin rate {plan.rate_dps:g} deg/s: beyond the table's rate limit "
            f"{table.max_rate_dps:g} deg/s"
        )
    return abs(plan.rate_dps) / table.max_accel_dps2


def spin_start_deg(plan: SpinPlan, table: TableModel) -> float:
    """Table angle at the start of the steady spin, deg (from rest at 0 at the acceleration
    limit)."""
    return 0.5 * plan.rate_dps * spin_ramp_s(plan, table)


#: The source paper's prototype procedure: eight positions 30 deg apart, 10 s each, every position
#: after the first solved against the first (seven azimuths, mu = 30 ... 210 deg).
PAPER_SWEEP = Plan(tuple(float(a) for a in range(0, 240, 30)), 10.0, method="pairwise")

#: Plans by name.
PLANS: Mapping[str, Plan] = {"paper-30deg-sweep": PAPER_SWEEP}


def settle_time_s(plan: Plan, table: TableModel) -> float:
    """Time from the end of each move to the next window, s (the plan's, else the table's)."""
    return table.settle_s if plan.settle_s is None else plan.settle_s


def moves_deg(plan: Plan) -> list[float]:
    """Signed shortest move before each window after the first, deg (0 where none)."""
    pos = plan.positions_deg
    return [shortest_delta_deg(a, b) for a, b in itertools.pairwise(pos)]


def window_starts_s(plan: Plan, table: TableModel) -> NDArray[np.float64]:
    """Start of each window relative to the start of the first, s."""
    settle = settle_time_s(plan, table)
    starts = [0.0]
    for d in moves_deg(plan):
        move = table.move_time_s(d)
        starts.append(starts[-1] + plan.window_s + (move + settle if d != 0.0 else 0.0))
    return np.array(starts)


def plan_time_s(plan: Plan | SpinPlan, table: TableModel) -> float:
    """Windows, moves and settling from the first window's start to the last one's end, s; for
    a spin, the ramp to the rate, the steady spin and the brake."""
    if isinstance(plan, SpinPlan):
        return plan.spin_s + 2.0 * spin_ramp_s(plan, table)
    return float(window_starts_s(plan, table)[-1] + plan.window_s)
