"""Monte Carlo accuracy of a plan: many seeded runs drawn at once, solved, and compared.

The engine draws N seeded runs in chunks (whole arrays of runs), solves every run
(:func:`northfinder.host.batch_solve.chunk_errors`) and reports the azimuth bias and RMSE beside the
white-noise bound of the same plan (notes, section 4), their ratio, the error predicted from the
datasheet figures (:func:`northfinder.host.accuracy.predict`) and the plan time. A ratio below 1
beyond its statistical spread would be a bug.

Where the samples come from is injected: a :class:`WindowGenerator` turns a :class:`RunRequest`
(truths, plan, sample rate, warm-up) and a seeded generator into a :class:`WindowBatch`. The
application layer wires in the simulated instrument (``northfinder.simwindows``); the
host library never imports it. A generator is a module-level, picklable callable (a frozen
dataclass instance, say), so that studies can run in other processes.

Chunks and seeds
----------------
The runs of a study are cut into chunks of a fixed number of runs (:func:`chunk_runs`: a
function of the plan and the sample rate only, so that a chunk's arrays fit in a processor's
cache), and chunk ``k`` draws from its own generator, seeded with child ``k`` of
``numpy.random.SeedSequence(seed)`` (``SeedSequence(seed).spawn(...)[k]``). A chunk is
therefore the same wherever and whenever it runs: results for a seed are identical whether
the chunks run one after the other, on a pool of local threads (:func:`local_executor`) or on
a cluster (any :class:`concurrent.futures.Executor`, such as a Dask client's, see
:mod:`northfinder.host.distributed`), and the whole chunks of a shorter study are the first
chunks of a longer one. They depend on the generator, the plan, the settings and
:data:`CHUNK_SAMPLES`.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol, TypeVar, cast

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import ThreadpoolController

from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG, DEFAULT_WARMUP_S
from northfinder.host.accuracy import (
    ANGLE_SOURCES,
    TILT_SOURCES,
    ErrorModel,
    bound_deg,
    predict_solutions,
    spin_bound_deg,
)
from northfinder.host.batch_solve import (
    Summary,
    azimuth_errors,
    chunk_errors,
    summarize,
    summarize_columns,
)
from northfinder.host.errors import HostConfigError, check_choice
from northfinder.host.plan import Plan, SpinPlan, spin_start_deg
from northfinder.host.spin import solve_spin_batch

__all__ = [
    "CHUNK_SAMPLES",
    "ChunkTask",
    "RunRequest",
    "SpinRuns",
    "Study",
    "StudySettings",
    "WindowBatch",
    "WindowGenerator",
    "chunk_runs",
    "chunk_tasks",
    "local_executor",
    "monte_carlo",
    "monte_carlo_many",
    "prediction_options",
    "rmse_interval_deg",
    "run_chunk",
    "study_rows",
    "verify_plan",
]

#: Samples of one channel (runs x positions x samples) in one chunk, at most (a chunk holds at
#: least one run): about 2 MiB per channel. Part of the definition of a study's random draws.
CHUNK_SAMPLES = 2**18
#: Most sample values (samples x 6 channels) of one run: a study never holds more than about
#: 300 MB of samples (with the generator's temporaries), whatever the plan asks.
MAX_RUN_VALUES = 24_000_000


class _Runs(Protocol):
    """The samples of many runs, as a window generator returns them (a leading ``runs`` axis,
    then ``positions`` for a plan's windows, then ``samples``)."""

    @property
    def gyro_rps(self) -> NDArray[np.float64]:
        """(runs, [positions,] samples, 3): gyro triad, mean rate over each sample, rad/s."""
        ...

    @property
    def accel_mps2(self) -> NDArray[np.float64]:
        """(runs, [positions,] samples, 3): specific force, m/s^2."""
        ...

    @property
    def azimuth_deg(self) -> NDArray[np.float64]:
        """(runs,): true azimuth of each run, deg."""
        ...


class WindowBatch(_Runs, Protocol):
    """The recording windows of many runs, as a window generator returns them."""

    @property
    def table_deg(self) -> NDArray[np.float64]:
        """(runs, positions): encoder reading during each window, deg."""
        ...

    @property
    def commanded_deg(self) -> NDArray[np.float64]:
        """(positions,): commanded table angle of each window, deg."""
        ...


@dataclass(frozen=True, eq=False)
class RunRequest:
    """The runs a window generator is asked for.

    Attributes
    ----------
    plan : Plan or SpinPlan
        Positions, window and settle time (its ``denoise`` and ``method`` are the engine's); or
        a spin (the generator returns :class:`SpinRuns`: the table starts at rest at 0 when the
        warm-up ends and accelerates to the rate at its limit).
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
    channels : tuple of int
        The channels the engine uses (0, 1, 2: gyro x, y, z; 3, 4, 5: accelerometer x, y, z);
        a generator may leave the others out (NaN).
    """

    plan: Plan | SpinPlan
    azimuth_deg: NDArray[np.float64]
    latitude_deg: float
    pitch_deg: float
    roll_deg: float
    sample_rate_hz: float
    warmup_s: float
    bias_step_dph: float
    channels: tuple[int, ...] = field(default=(0, 1, 2, 3, 4, 5))

    @property
    def n_runs(self) -> int:
        return int(self.azimuth_deg.size)


class SpinRuns(_Runs, Protocol):
    """The samples of many runs of a spin, as a window generator returns them for a
    :class:`~northfinder.host.plan.SpinPlan`."""

    @property
    def read0_rad(self) -> NDArray[np.float64]:
        """(runs, samples): encoder angle at the start of each sample, continuous, rad."""
        ...

    @property
    def read1_rad(self) -> NDArray[np.float64]:
        """(runs, samples): encoder angle at the end of each sample, continuous, rad."""
        ...

    @property
    def time_s(self) -> NDArray[np.float64]:
        """(samples,): end of each sample from the start of the steady spin, s."""
        ...


class WindowGenerator(Protocol):
    """Draws the windows of a request with the given generator (module-level and picklable)."""

    def __call__(self, request: RunRequest, rng: np.random.Generator) -> WindowBatch | SpinRuns: ...


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

    latitude_deg: float = DEFAULT_LATITUDE_DEG
    azimuth_deg: float | None = None
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    warmup_s: float = DEFAULT_WARMUP_S
    sample_rate_hz: float = 200.0
    denoise_accel: bool = False
    tilt: str = "accel"
    angles: str = "encoder"
    bias_step_dph: float = 0.0

    def __post_init__(self) -> None:
        check_choice(self.tilt, TILT_SOURCES, "tilt")
        check_choice(self.angles, ANGLE_SOURCES, "angles")


def _run_samples(plan: Plan | SpinPlan, settings: StudySettings) -> tuple[int, int]:
    """Windows and samples per window of one run (a spin: one window)."""
    if isinstance(plan, SpinPlan):
        return 1, max(1, round(plan.spin_s * settings.sample_rate_hz))
    return len(plan.positions_deg), max(1, round(plan.window_s * settings.sample_rate_hz))


def chunk_runs(plan: Plan | SpinPlan, settings: StudySettings) -> int:
    """Runs per chunk: :data:`CHUNK_SAMPLES` over the samples of one run's windows (at least 1)."""
    p, n = _run_samples(plan, settings)
    return max(1, CHUNK_SAMPLES // (p * n))


@dataclass(frozen=True)
class ChunkTask:
    """One chunk of a study: everything a worker needs to draw and solve it (picklable).

    Attributes
    ----------
    generator : WindowGenerator
    plan : Plan
    settings : StudySettings
    seed : int
        The study's seed.
    index : int
        The chunk's number: it draws from child ``index`` of ``SeedSequence(seed)``.
    runs : int
        Runs in this chunk.
    """

    generator: WindowGenerator
    plan: Plan | SpinPlan
    settings: StudySettings
    seed: int
    index: int
    runs: int


def chunk_tasks(
    generator: WindowGenerator,
    plan: Plan | SpinPlan,
    settings: StudySettings,
    runs: int,
    seed: int,
) -> list[ChunkTask]:
    """The chunks of a study of ``runs`` runs, in order (see the module doc)."""
    if isinstance(runs, bool) or int(runs) != runs or runs < 2:
        raise HostConfigError(f"runs: need at least 2 runs for statistics, got {runs}")
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise HostConfigError(f"seed: must be a non-negative integer, got {seed!r}")
    # Samples per window, for the memory budget only (the generator decides the exact count).
    p, n = _run_samples(plan, settings)
    if isinstance(plan, SpinPlan) and settings.angles != "encoder":
        raise HostConfigError(
            "angles: a spin solves with the encoder angle of every sample (angles encoder)"
        )
    if p * n * 6 > MAX_RUN_VALUES:
        raise HostConfigError(
            f"a run of {p} windows of {n} samples ({p * n * 6:.3g} values: positions x window x "
            f"rate x 6 channels) exceeds the {MAX_RUN_VALUES:.3g} a study holds at once; "
            "shorten the windows or lower the rate"
        )
    size = chunk_runs(plan, settings)
    return [
        ChunkTask(generator, plan, settings, int(seed), k, min(size, runs - start))
        for k, start in enumerate(range(0, int(runs), size))
    ]


@functools.cache
def _blas() -> ThreadpoolController:
    return ThreadpoolController()  # looks up the loaded BLAS libraries once


def _one_blas_thread() -> Any:
    """A context in which BLAS runs on the calling thread alone (results then do not depend on
    how many threads BLAS would use: large products split their sums differently)."""
    return _blas().limit(limits=1, user_api="blas")


def _channels(settings: StudySettings) -> tuple[int, ...]:
    """The channels the solvers read: gyro x and y, and accelerometer x and y unless level."""
    return (0, 1) if settings.tilt == "level" else (0, 1, 3, 4)


def run_chunk(task: ChunkTask) -> NDArray[np.float64]:
    """Azimuth errors of one chunk, deg: shape (runs,), or (runs, P - 1) pairwise."""
    plan, settings = task.plan, task.settings
    seq = np.random.SeedSequence(task.seed, spawn_key=(task.index,))
    rng = np.random.default_rng(seq)
    if settings.azimuth_deg is None:
        az = rng.uniform(0.0, 360.0, task.runs)
    else:
        az = np.full(task.runs, settings.azimuth_deg)
    request = RunRequest(
        plan,
        az,
        settings.latitude_deg,
        settings.pitch_deg,
        settings.roll_deg,
        settings.sample_rate_hz,
        settings.warmup_s,
        settings.bias_step_dph,
        _channels(settings),
    )
    # The products inside are small: BLAS threads would only contend with the other workers.
    with _one_blas_thread():
        if isinstance(plan, SpinPlan):
            runs = cast(SpinRuns, task.generator(request, rng))
            az = solve_spin_batch(
                runs.gyro_rps,
                None if settings.tilt == "level" else runs.accel_mps2,
                runs.read0_rad,
                runs.read1_rad,
                latitude_deg=settings.latitude_deg,
                time_s=runs.time_s,
                drift=plan.drift,
            )
            return azimuth_errors(az, runs.azimuth_deg)
        batch = cast(WindowBatch, task.generator(request, rng))
        angles = batch.table_deg if settings.angles == "encoder" else batch.commanded_deg
        return chunk_errors(
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


def monte_carlo(
    generator: WindowGenerator,
    plan: Plan | SpinPlan,
    settings: StudySettings,
    runs: int,
    seed: int,
    *,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> NDArray[np.float64]:
    """Azimuth errors of ``runs`` seeded runs, deg: shape (runs,), or (runs, P - 1) pairwise.

    The runs are drawn and solved chunk by chunk (see the module doc): one after the other in
    this thread, or on ``executor``; the result is the same. A run without a solution (tilt
    beyond the solvers' limit) has a NaN error.

    Parameters
    ----------
    generator : WindowGenerator
        Where the samples come from (picklable, to run in other processes).
    plan : Plan
        Positions, window, settle, denoising and solver.
    settings : StudySettings
    runs : int
        Number of runs (at least 2).
    seed : int
        The study's seed (non-negative).
    executor : concurrent.futures.Executor, optional
        Where the chunks run: :func:`local_executor`, a Dask client's executor, any other.
    progress : callable, optional
        Called with (chunks done, chunks in all) as each chunk's result comes in.
    """
    return monte_carlo_many(
        [(generator, plan, settings, runs, seed)], executor=executor, progress=progress
    )[0]


#: One study of :func:`monte_carlo_many`: generator, plan, settings, runs, seed.
Study = tuple[WindowGenerator, Plan | SpinPlan, StudySettings, int, int]


def monte_carlo_many(
    studies: Sequence[Study],
    *,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[NDArray[np.float64]]:
    """:func:`monte_carlo` of several studies, their chunks all handed out at once.

    A sweep keeps every worker busy to its end this way; each study's errors are those
    :func:`monte_carlo` gives it alone. ``progress`` is called with (chunks done, chunks in
    all) as results come in.
    """
    tasks = [chunk_tasks(*study) for study in studies]
    flat = [t for ts in tasks for t in ts]
    # Small products inside: BLAS threads would only contend with the study's own workers (and
    # make results depend on them).
    done: list[NDArray[np.float64]] = []
    with _one_blas_thread():
        results = map(run_chunk, flat) if executor is None else executor.map(run_chunk, flat)
        for result in results:
            done.append(result)
            if progress is not None:
                progress(len(done), len(flat))
    out, k = [], 0
    for ts in tasks:
        out.append(np.concatenate(done[k : k + len(ts)]))
        k += len(ts)
    return out


@contextmanager
def local_executor(workers: int | None = None) -> Iterator[Executor]:
    """A pool of ``workers`` threads in this process (default: one per core).

    Threads suffice: numpy draws its random numbers and does its array arithmetic without
    holding the interpreter lock, so chunks run on all cores, with no worker start-up and
    nothing to copy between processes.
    """
    count = (os.cpu_count() or 1) if workers is None else workers
    if isinstance(count, bool) or int(count) != count or count < 1:
        raise HostConfigError(f"workers: must be a positive integer, got {workers!r}")
    pool = ThreadPoolExecutor(int(count), thread_name_prefix="northfinder-study")
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _spin_row(
    model: ErrorModel, plan: SpinPlan, settings: StudySettings, errors: NDArray[np.float64]
) -> dict[str, Any]:
    s = summarize(errors)
    b = spin_bound_deg(
        plan.spin_s, plan.rate_dps, model.arw_dpsh, settings.latitude_deg,
        sample_rate_hz=settings.sample_rate_hz, start_deg=spin_start_deg(plan, model.table),
        drift=plan.drift,
    )  # fmt: skip
    pred = predict_solutions(model, plan, **prediction_options(settings))[0]
    return {
        "rate_dps": plan.rate_dps,
        "spin_s": plan.spin_s,
        "drift": plan.drift,
        **asdict(s),
        "bound_deg": b,
        "ratio": s.rmse_deg / b if b > 0 else math.inf,
        "predicted_deg": pred.sigma_deg,
        "predicted_parts_deg": pred.parts_deg,
    }


def rmse_interval_deg(rmse_deg: float, runs: int, level: float = 0.95) -> tuple[float, float]:
    """Confidence interval of an RMSE over ``runs`` independent zero-mean normal errors, deg:
    ``runs RMSE^2 / sigma^2`` is chi-square with ``runs`` degrees of freedom."""
    from scipy.stats import chi2  # imported when first needed

    return (
        rmse_deg * math.sqrt(runs / chi2.ppf(0.5 + level / 2, runs)),
        rmse_deg * math.sqrt(runs / chi2.ppf(0.5 - level / 2, runs)),
    )


def study_rows(
    model: ErrorModel, plan: Plan | SpinPlan, settings: StudySettings, errors: NDArray[np.float64]
) -> list[dict[str, Any]]:
    """One result row per solution (one, or one per pair with ``pairwise``).

    Each row holds the :class:`~northfinder.host.batch_solve.Summary` fields (``rejected`` counts the
    runs without a solution), ``bound_deg``, ``ratio`` (RMSE over bound), ``predicted_deg`` and
    its parts; pairwise rows also ``mu_deg``. A spin's row holds ``rate_dps``, ``spin_s`` and
    ``drift`` instead of the positions, and its bound is
    :func:`~northfinder.host.accuracy.spin_bound_deg` (gyro white noise, the fit's own design).
    """
    if isinstance(plan, SpinPlan):
        return [_spin_row(model, plan, settings, errors)]
    pos = plan.positions_deg
    pairwise = errors.ndim == 2
    if pairwise:
        subplans = [replace(plan, positions_deg=(pos[0], pos[k])) for k in range(1, len(pos))]
        stats: list[Summary] = summarize_columns(errors)
    else:
        subplans, stats = [plan], [summarize(errors)]
    preds = predict_solutions(model, plan, **prediction_options(settings))
    rows = []
    for sub, s, pred in zip(subplans, stats, preds, strict=True):
        b = bound_deg(sub.positions_deg, plan.window_s, model.arw_dpsh, settings.latitude_deg)
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


def prediction_options(settings: StudySettings) -> dict[str, Any]:
    """The keyword arguments of :func:`~northfinder.host.accuracy.predict` that describe the
    runs of a study with these settings (latitude, warm-up, tilt, angles, rate, truth, step)."""
    return {
        "latitude_deg": settings.latitude_deg,
        "warmup_s": settings.warmup_s,
        "tilt": settings.tilt,
        "angles": settings.angles,
        "sample_rate_hz": settings.sample_rate_hz,
        "pitch_deg": settings.pitch_deg,
        "roll_deg": settings.roll_deg,
        "azimuth_deg": settings.azimuth_deg,
        "bias_step_dph": settings.bias_step_dph,
    }


_P = TypeVar("_P", Plan, SpinPlan)


def _lengthened(plan: _P, factor: float) -> _P:
    """The plan with its windows (a spin: its steady time) ``factor`` times as long."""
    p: Any = plan
    if isinstance(plan, SpinPlan):
        return cast(_P, replace(p, spin_s=plan.spin_s * factor))
    return cast(_P, replace(p, window_s=p.window_s * factor))


def verify_plan(
    generator: WindowGenerator,
    model: ErrorModel,
    plan: _P,
    settings: StudySettings,
    runs: int,
    seed: int,
    target_deg: float | None = None,
    max_rounds: int = 4,
    *,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[_P, dict[str, Any]]:
    """Monte Carlo of a plan; with a target, lengthen the window (a spin's time) until the
    simulated RMSE meets it.

    Each round scales the window by ``1.05 (RMSE / target)^2`` (white noise falls as the square
    root of the dwell), at most ``max_rounds`` rounds. The row gains ``meets_target``.
    """
    row: dict[str, Any] = {}
    for _ in range(max_rounds):
        errors = monte_carlo(
            generator, plan, settings, runs, seed, executor=executor, progress=progress
        )
        row = study_rows(model, plan, settings, errors)[0]
        if target_deg is None or row["rmse_deg"] <= target_deg:
            row["meets_target"] = True
            return plan, row
        grow = 1.05 * (row["rmse_deg"] / target_deg) ** 2
        plan = _lengthened(plan, grow)
    row["meets_target"] = False
    return plan, row
