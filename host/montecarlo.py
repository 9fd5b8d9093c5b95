"""Monte Carlo accuracy of a plan: many seeded runs drawn at once, solved, and compared.

The engine draws N seeded runs in chunks (whole arrays of runs), solves every run
(:func:`northfinder.host.study.chunk_errors`) and reports the azimuth bias and RMSE beside the
white-noise bound of the same plan (notes, section 4), their ratio, the error predicted from the
datasheet figures (:func:`northfinder.host.accuracy.predict`) and the plan time. A ratio below 1
beyond its statistical spread would be a bug.

Where the samples come from is injected: a :class:`WindowGenerator` turns a :class:`RunRequest`
(truths, plan, sample rate, warm-up) and a seeded generator into a :class:`WindowBatch`. The
application layer wires in the simulated instrument (``northfinder.host.cli.simulated``); the
host library never imports it. A generator is a module-level, picklable callable (a frozen
dataclass instance, say), so that studies can run in other processes.

Results for a seed depend only on the generator, the plan, the settings and the chunk size
(through the order of the random draws).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from northfinder.host.accuracy import ANGLE_SOURCES, TILT_SOURCES, ErrorModel, bound_deg, predict
from northfinder.host.errors import HostConfigError, check_choice
from northfinder.host.plan import Plan
from northfinder.host.study import Summary, chunk_errors, summarize, summarize_columns

__all__ = [
    "CHUNK_VALUES",
    "RunRequest",
    "StudySettings",
    "WindowBatch",
    "WindowGenerator",
    "monte_carlo",
    "study_rows",
    "verify_plan",
]

#: Samples (runs x positions x samples x 6 channels) generated at once.
CHUNK_VALUES = 24_000_000
#: Most sample values (samples x 6 channels) of one run: a study never holds more than about
#: 300 MB of samples (with the generator's temporaries), whatever the plan asks.
MAX_RUN_VALUES = 24_000_000


class WindowBatch(Protocol):
    """The recording windows of many runs, as a window generator returns them."""

    @property
    def gyro_rps(self) -> NDArray[np.float64]:
        """(runs, positions, samples, 3): gyro triad, mean rate over each sample, rad/s."""
        ...

    @property
    def accel_mps2(self) -> NDArray[np.float64]:
        """(runs, positions, samples, 3): specific force, m/s^2."""
        ...

    @property
    def table_deg(self) -> NDArray[np.float64]:
        """(runs, positions): encoder reading during each window, deg."""
        ...

    @property
    def commanded_deg(self) -> NDArray[np.float64]:
        """(positions,): commanded table angle of each window, deg."""
        ...

    @property
    def azimuth_deg(self) -> NDArray[np.float64]:
        """(runs,): true azimuth of each run, deg."""
        ...


@dataclass(frozen=True, eq=False)
class RunRequest:
    """The runs a window generator is asked for.

    Attributes
    ----------
    plan : Plan
        Positions, window and settle time (its ``denoise`` and ``method`` are the engine's).
    azimuth_deg : ndarray, shape (runs,)
        True azimuth of each run, deg clockwise from north.
    latitude_deg, pitch_deg, roll_deg : float
        The site and the instrument's tilt, deg (the same for every run).
    sample_rate_hz : float
        Sample rate, Hz.
    warmup_s : float
        Time from power-on to the first window, s.
    bias_step_dph : float
        One gyro bias step of this size per run at a random time, deg/h (0: none).
    """

    plan: Plan
    azimuth_deg: NDArray[np.float64]
    latitude_deg: float
    pitch_deg: float
    roll_deg: float
    sample_rate_hz: float
    warmup_s: float
    bias_step_dph: float

    @property
    def n_runs(self) -> int:
        return int(self.azimuth_deg.size)


class WindowGenerator(Protocol):
    """Draws the windows of a request with the given generator (module-level and picklable)."""

    def __call__(self, request: RunRequest, rng: np.random.Generator) -> WindowBatch: ...


@dataclass(frozen=True)
class StudySettings:
    """Everything a Monte Carlo study needs besides the sensor and the plan.

    Attributes
    ----------
    latitude_deg : float
    azimuth_deg : float or None
        True azimuth of every run, deg; None draws it uniformly per run.
    pitch_deg, roll_deg : float
        Tilt of the instrument, deg.
    warmup_s : float
        Power-on to the first window, s (simulated, not counted in the plan time).
    sample_rate_hz : float
    denoise_accel : bool
        Denoise the accelerometer windows too (with the plan's method).
    tilt : str
        A key of :data:`northfinder.host.accuracy.TILT_SOURCES`.
    angles : str
        A key of :data:`northfinder.host.accuracy.ANGLE_SOURCES`.
    bias_step_dph : float
        One gyro bias step per run, deg/h.
    """

    latitude_deg: float = 34.0
    azimuth_deg: float | None = None
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    warmup_s: float = 120.0
    sample_rate_hz: float = 200.0
    denoise_accel: bool = False
    tilt: str = "accel"
    angles: str = "encoder"
    bias_step_dph: float = 0.0

    def __post_init__(self) -> None:
        check_choice(self.tilt, TILT_SOURCES, "tilt")
        check_choice(self.angles, ANGLE_SOURCES, "angles")


def monte_carlo(
    generator: WindowGenerator,
    plan: Plan,
    settings: StudySettings,
    runs: int,
    seed: int,
    *,
    chunk_values: int = CHUNK_VALUES,
) -> NDArray[np.float64]:
    """Azimuth errors of ``runs`` seeded runs, deg: shape (runs,), or (runs, P - 1) pairwise.

    Runs are drawn in chunks so that at most about ``chunk_values`` samples exist at once; the
    result depends on the chunk size only through the order of the random draws. A run without
    a solution (tilt beyond the solvers' limit) has a NaN error.

    Parameters
    ----------
    generator : WindowGenerator
        Where the samples come from.
    plan : Plan
        Positions, window, settle, denoising and solver.
    settings : StudySettings
    runs : int
        Number of runs (at least 2).
    seed : int
        Seed of the one generator all draws come from.
    chunk_values : int
        Samples per chunk, at most about.
    """
    if runs < 2:
        raise HostConfigError(f"runs: need at least 2 runs for statistics, got {runs}")
    rng = np.random.default_rng(seed)
    p = len(plan.positions_deg)
    # Samples per window, for the memory budget only (the generator decides the exact count).
    n = round(plan.window_s * settings.sample_rate_hz)
    if p * n * 6 > MAX_RUN_VALUES:
        raise HostConfigError(
            f"a run of {p} windows of {n} samples ({p * n * 6:.3g} values: positions x window x "
            f"rate x 6 channels) exceeds the {MAX_RUN_VALUES:.3g} a study holds at once; "
            "shorten the windows or lower the rate"
        )
    chunk = max(1, min(runs, chunk_values // max(1, p * n * 6)))
    out = []
    done = 0
    while done < runs:
        m = min(chunk, runs - done)
        if settings.azimuth_deg is None:
            az = rng.uniform(0.0, 360.0, m)
        else:
            az = np.full(m, settings.azimuth_deg)
        request = RunRequest(
            plan,
            az,
            settings.latitude_deg,
            settings.pitch_deg,
            settings.roll_deg,
            settings.sample_rate_hz,
            settings.warmup_s,
            settings.bias_step_dph,
        )
        batch = generator(request, rng)
        angles = batch.table_deg if settings.angles == "encoder" else batch.commanded_deg
        out.append(
            chunk_errors(
                batch.gyro_rps,
                None if settings.tilt == "level" else batch.accel_mps2,
                angles,
                batch.azimuth_deg,
                settings.latitude_deg,
                solver=plan.method,
                denoise_method=plan.denoise,
                denoise_options=dict(plan.denoise_options),
                denoise_accel=settings.denoise_accel,
            )
        )
        done += m
        del batch
    return np.concatenate(out)


def study_rows(
    model: ErrorModel, plan: Plan, settings: StudySettings, errors: NDArray[np.float64]
) -> list[dict[str, Any]]:
    """One result row per solution (one, or one per pair with ``pairwise``).

    Each row holds the :class:`~northfinder.host.study.Summary` fields (``rejected`` counts the
    runs without a solution), ``bound_deg``, ``ratio`` (RMSE over bound), ``predicted_deg`` and
    its parts; pairwise rows also ``mu_deg``.
    """
    pos = plan.positions_deg
    pairwise = errors.ndim == 2
    if pairwise:
        subplans = [replace(plan, positions_deg=(pos[0], pos[k])) for k in range(1, len(pos))]
        stats: list[Summary] = summarize_columns(errors)
    else:
        subplans, stats = [plan], [summarize(errors)]
    rows = []
    for sub, s in zip(subplans, stats, strict=True):
        b = bound_deg(sub.positions_deg, plan.window_s, model.arw_dpsh, settings.latitude_deg)
        pred = predict(
            model,
            sub,
            settings.latitude_deg,
            warmup_s=settings.warmup_s,
            tilt=settings.tilt,
            angles=settings.angles,
        )
        row: dict[str, Any] = {
            "positions_deg": list(sub.positions_deg),
            **asdict(s),
            "bound_deg": b,
            "ratio": s.rmse_deg / b if b > 0 else math.inf,
            "predicted_deg": pred.sigma_deg,
            "predicted_parts_deg": pred.parts_deg,
        }
        if pairwise:
            row["mu_deg"] = sub.positions_deg[1] - sub.positions_deg[0]
        rows.append(row)
    return rows


def verify_plan(
    generator: WindowGenerator,
    model: ErrorModel,
    plan: Plan,
    settings: StudySettings,
    runs: int,
    seed: int,
    target_deg: float | None = None,
    max_rounds: int = 4,
) -> tuple[Plan, dict[str, Any]]:
    """Monte Carlo of a plan; with a target, lengthen the window until the simulated RMSE meets it.

    Each round scales the window by ``1.05 (RMSE / target)^2`` (white noise falls as the square
    root of the dwell), at most ``max_rounds`` rounds. The row gains ``meets_target``.
    """
    row: dict[str, Any] = {}
    for _ in range(max_rounds):
        errors = monte_carlo(generator, plan, settings, runs, seed)
        row = study_rows(model, plan, settings, errors)[0]
        if target_deg is None or row["rmse_deg"] <= target_deg:
            row["meets_target"] = True
            return plan, row
        grow = 1.05 * (row["rmse_deg"] / target_deg) ** 2
        plan = replace(plan, window_s=plan.window_s * grow)
    row["meets_target"] = False
    return plan, row
