"""The simulated instrument wired into the host library's accuracy studies (application layer).

The host library's study engine (:mod:`northfinder.host.montecarlo`) and planner
(:mod:`northfinder.host.plan_search`) know nothing of the simulator. This module gives them:

- :class:`SimulatedWindows`, the window generator that draws whole arrays of runs with
  :func:`northfinder.firmware_sim.batch.simulate_windows`;
- :func:`error_model`, the planner's :class:`~northfinder.host.accuracy.ErrorModel` of a
  :class:`~northfinder.firmware_sim.sensors.SensorSpec` (its deterministic drift is
  :class:`SpecDrift`).

Both are module-level frozen dataclasses holding a frozen spec, so they pickle (a study can run
in worker processes).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from northfinder.driver.protocol.units import DEFAULT_WARMUP_S
from northfinder.firmware_sim.batch import BatchWindows, SpinBatch, simulate_spin, simulate_windows
from northfinder.firmware_sim.error_terms import ACCEL, GYRO, ErrorTerms
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import SensorSpec
from northfinder.host.accuracy import ErrorModel
from northfinder.host.montecarlo import RunRequest
from northfinder.host.plan import SpinPlan, TableModel, spin_ramp_s, spin_start_deg

__all__ = [
    "MAX_RATE_HZ",
    "MAX_WINDOW_S",
    "SimulatedWindows",
    "SpecDrift",
    "error_model",
    "simulator_identity",
    "table_model",
    "write_recordings",
]

#: Longest window, s, and highest sample rate, Hz, of the windows simulated in this process
#: (``simulate``, the studies): a window holds at most 3.6 million samples (about 200 MB with
#: its temporaries).
MAX_WINDOW_S = 3600.0
MAX_RATE_HZ = 1000.0


def simulator_identity(sensor: str | None = None) -> dict[str, Any]:
    """The simulated instrument's identity as results state it (``simulated`` true; the serial
    number is null: a study draws runs of the sensor model, not of one unit)."""
    from northfinder.driver.protocol.constants import PROTOCOL_VERSION_MAJOR, PROTOCOL_VERSION_MINOR
    from northfinder.firmware_sim.firmware import Firmware

    out: dict[str, Any] = {
        "model": Firmware.MODEL,
        "serial_number": None,
        "hardware_revision": None,
        "firmware_version": ".".join(map(str, Firmware.FIRMWARE_VERSION)),
        "protocol_version": f"{PROTOCOL_VERSION_MAJOR}.{PROTOCOL_VERSION_MINOR}",
        "simulated": True,
    }
    if sensor is not None:
        out["sensor"] = sensor
    return out


@dataclass(frozen=True)
class SimulatedWindows:
    """Window generator of the study engine: the batch generator of the simulated instrument."""

    spec: SensorSpec

    def __call__(self, request: RunRequest, rng: np.random.Generator) -> BatchWindows | SpinBatch:
        plan = request.plan
        truths = [
            Truth(float(a), request.latitude_deg, request.pitch_deg, request.roll_deg)
            for a in request.azimuth_deg
        ]
        if isinstance(plan, SpinPlan):
            # The table at rest at 0 when the warm-up ends, then up to the rate at its limit.
            table = table_model(self.spec)
            return simulate_spin(
                self.spec,
                truths,
                plan.rate_dps,
                plan.spin_s,
                n_runs=request.n_runs,
                rng=rng,
                sample_rate_hz=request.sample_rate_hz,
                start_deg=spin_start_deg(plan, table),
                start_s=request.warmup_s + spin_ramp_s(plan, table),
                bias_step_dph=request.bias_step_dph,
            )
        return simulate_windows(
            self.spec,
            truths,
            plan.positions_deg,
            plan.window_s,
            plan.settle_s,
            n_runs=request.n_runs,
            rng=rng,
            sample_rate_hz=request.sample_rate_hz,
            warmup_s=request.warmup_s,
            bias_step_dph=request.bias_step_dph,
            channels=request.channels,
        )


@dataclass(frozen=True)
class SpecDrift:
    """Deterministic x/y bias of a sensor spec's gyros (or accelerometers) against time since
    power-on, rad/s (m/s^2).

    The warm-up transient, the temperature sensitivity times the temperature rise over ambient
    (self-heating and ramp), and the rate ramp.
    """

    spec: SensorSpec
    triad: str = "gyro"

    def __call__(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        # The simulator's own definition of its deterministic terms (firmware_sim.error_terms).
        drift = ErrorTerms.from_spec(self.spec).drift(np.asarray(t, dtype=float), self.spec.thermal)
        out: NDArray[np.float64] = drift[..., GYRO if self.triad == "gyro" else ACCEL][..., :2]
        return out


def table_model(spec: SensorSpec) -> TableModel:
    """The planner's view of a sensor spec's turntable (every field of its ``table`` section but
    the post-stop ring-down, which is over before a window starts)."""
    t = spec.table
    return TableModel(**{f.name: getattr(t, f.name) for f in fields(TableModel)})


def error_model(spec: SensorSpec) -> ErrorModel:
    """The planner's view of a sensor spec: every error term of its x and y gyros and
    accelerometers, its disturbances and its table."""
    g, a, d = spec.gyro, spec.accel, spec.disturbance
    thermal = spec.thermal.warmup_rise_c or spec.thermal.ramp_c_per_h
    gyro_drift = (
        any(g.warmup_bias_dph[:2])
        or any(g.rate_ramp_dph_per_h[:2])
        or (thermal and any(g.temp_coeff_dph_per_c[:2]))
    )
    accel_drift = (
        any(a.warmup_bias_ug[:2])
        or any(a.ramp_ug_per_h[:2])
        or (thermal and any(a.temp_coeff_ug_per_c[:2]))
    )
    return ErrorModel(
        arw_dpsh=g.arw_dpsh,
        bias_instability_dph=g.bias_instability_dph,
        rrw_dphpsh=g.rrw_dphpsh,
        misalignment_urad=g.misalignment_urad,
        scale_factor_ppm=g.scale_factor_ppm,
        vrw_ug_rthz=a.vrw_ug_rthz,
        table=table_model(spec),
        drift_rps=SpecDrift(spec) if gyro_drift else None,
        lsb_dph=g.lsb_dph,
        move_walk_dph_per_rtdeg=g.move_walk_dph_per_rtdeg,
        move_transient_dph_per_rtdeg=g.move_transient_dph_per_rtdeg,
        move_transient_tau_s=g.move_transient_tau_s,
        vibration_dph=g.vibration_dph,
        impulse_dph=g.impulse_dph,
        accel_bias_instability_ug=a.bias_instability_ug,
        accel_random_walk_ug_rts=a.random_walk_ug_rts,
        accel_scale_factor_ppm=a.scale_factor_ppm,
        accel_misalignment_urad=a.misalignment_urad,
        accel_lsb_ug=a.lsb_ug,
        accel_move_walk_ug_per_rtdeg=a.move_walk_ug_per_rtdeg,
        accel_move_transient_ug_per_rtdeg=a.move_transient_ug_per_rtdeg,
        accel_move_transient_tau_s=a.move_transient_tau_s,
        accel_vibration_ug=a.vibration_ug,
        accel_impulse_ug=a.impulse_ug,
        vibration_hz=d.vibration_hz,
        impulse_rate_hz=d.impulse_rate_hz,
        impulse_duration_s=d.impulse_duration_s,
        accel_drift_mps2=SpecDrift(spec, "accel") if accel_drift else None,
    )


def write_recordings(
    spec: SensorSpec,
    truth: Truth,
    positions_deg: Sequence[float],
    window_s: float,
    runs: int,
    seed: int,
    folder: str | Path,
    *,
    sample_rate_hz: float = 20.0,
    warmup_s: float = DEFAULT_WARMUP_S,
) -> list[str]:
    """Simulated power-ons written as recordings, one file per run (``folder/run{seed}-{r}.npz``,
    as ``northfinder record`` writes them), for calibration; returns their paths.

    The runs are drawn at once by :func:`~northfinder.firmware_sim.batch.simulate_windows` with
    ``numpy.random.default_rng(seed)``; ``folder`` must exist.
    """
    from northfinder.host.recording import Recording

    batch = simulate_windows(
        spec, truth, list(positions_deg), window_s, n_runs=runs, rng=np.random.default_rng(seed),
        sample_rate_hz=sample_rate_hz, warmup_s=warmup_s,
    )  # fmt: skip
    paths = []
    for r in range(runs):
        path = Path(folder) / f"run{seed}-{r}.npz"
        Recording.from_batch(batch, r, truth.latitude_deg).save(path)
        paths.append(str(path))
    return paths
