"""From recordings to sensor terms: Allan fits per axis, between-position terms, the sensor TOML.

:func:`calibrate` takes recorded runs (:mod:`~northfinder.host.calibrate.readers`) and

1. cuts every window into stretches of consecutive good samples, computes the overlapping Allan
   deviation of each stretch per axis and pools them (:func:`northfinder.host.allan.pool_curves`);
2. fits the IEEE 952 terms per axis (:func:`northfinder.host.allan.fit_ieee952`): gyros in
   deg/h, accelerometers in ug; the sign of a rate ramp comes from the slope within the windows;
3. when runs hold several windows with table moves between them, fits the between-position
   terms of the x and y gyro (:func:`~northfinder.host.calibrate.between.fit_between_positions`:
   turn-on repeatability over runs, a lasting bias step and a transient per move), with the bias
   instability and rate random walk of step 2 as the known slow noise, and reads the table's
   indexing error from the encoder against the commanded angle after each move.

:meth:`Calibration.sensor_dict` gives the fields in the layout of a sensor TOML file (the
simulator's ``--sensor FILE``), with the datasheet units the simulator uses; terms the records do
not resolve are 0 there, and :meth:`Calibration.to_toml` says beside each what bounds it.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from northfinder.driver.protocol.motion import shortest_delta_deg
from northfinder.driver.protocol.units import readable_duration as _duration
from northfinder.host.allan import TERMS, AllanCurve, NoiseFit, fit_ieee952, pool_curves
from northfinder.host.calibrate.between import (
    BetweenFit,
    RunWindows,
    SlowNoise,
    fit_between_positions,
)
from northfinder.host.calibrate.readers import (
    AXES,
    MIN_PIECE_SAMPLES,
    RecordedRun,
    WindowFit,
)
from northfinder.host.errors import HostConfigError, InputError, QualityError

__all__ = ["AXES", "Calibration", "IndexingFit", "calibrate"]


#: Sensor TOML field of each IEEE 952 term (gyro, accelerometer) and the factor from the fitted
#: coefficient to it (Q, N, B, K, R in deg/h or ug with seconds; quantisation needs the rate).
_FIELDS = {
    "arw": (("arw_dpsh", 1.0 / 60.0), ("vrw_ug_rthz", 1.0)),
    "bias_instability": (("bias_instability_dph", 1.0), ("bias_instability_ug", 1.0)),
    "rrw": (("rrw_dphpsh", 60.0), ("random_walk_ug_rts", 1.0)),
    "rate_ramp": (("rate_ramp_dph_per_h", 3600.0), ("ramp_ug_per_h", 3600.0)),
    "quantisation": (("lsb_dph", math.sqrt(12.0)), ("lsb_ug", math.sqrt(12.0))),
}
_UNITS = {
    "arw_dpsh": "deg/sqrt(h)",
    "bias_instability_dph": "deg/h",
    "rrw_dphpsh": "deg/h/sqrt(h)",
    "rate_ramp_dph_per_h": "deg/h per h",
    "lsb_dph": "deg/h",
    "vrw_ug_rthz": "ug/sqrt(Hz)",
    "bias_instability_ug": "ug",
    "random_walk_ug_rts": "ug/sqrt(s)",
    "ramp_ug_per_h": "ug per h",
    "lsb_ug": "ug",
}


@dataclass(frozen=True)
class IndexingFit:
    """Stop errors of the table: encoder mean minus commanded angle after each move.

    Attributes
    ----------
    sigma_deg : float
        Root mean square stop error, deg.
    interval_deg : tuple of float
        Its 95 % interval (chi-squared with one degree of freedom per stop).
    stops : int
        Stops seen.
    """

    sigma_deg: float
    interval_deg: tuple[float, float]
    stops: int


@dataclass(frozen=True)
class Calibration:
    """What :func:`calibrate` found.

    Attributes
    ----------
    curves : dict
        Pooled Allan curve per channel of :data:`AXES` (deg/h or ug).
    fits : dict
        IEEE 952 fit per channel.
    triad_fits : dict
        IEEE 952 fit of the three axes of ``"gyro"`` and of ``"accel"`` pooled: the sensor file
        has one value per triad, and three axes give it three times the data.
    ramp_sign : dict
        Sign of the slope within the windows per channel (+1 or -1).
    between : BetweenFit or None
        Between-position terms of the x and y gyro, when the runs have moves.
    indexing : IndexingFit or None
        Table stop errors, when the runs have moves and encoder angles.
    sample_rate_hz : float
    runs, windows, pieces : int
        Runs, windows and stretches of good samples used.
    hours : float
        Good samples used, in hours.
    notes : list of str
        What could not be estimated and why.
    """

    curves: dict[str, AllanCurve]
    fits: dict[str, NoiseFit]
    triad_fits: dict[str, NoiseFit]
    ramp_sign: dict[str, float]
    between: BetweenFit | None
    indexing: IndexingFit | None
    sample_rate_hz: float
    runs: int
    windows: int
    pieces: int
    hours: float
    notes: list[str] = field(default_factory=list)
    #: How the sensor file writes a term the records do not resolve: ``bound`` its 95 % upper
    #: bound (a simulated unit at least as noisy as the records allow: never optimistic), or
    #: ``zero`` (the term left out: optimistic).
    unresolved: str = "bound"

    def field_value(self, triad: int, term: str) -> tuple[float, bool, float]:
        """(value in datasheet units, resolved, upper limit if not) of a term of a triad.

        ``triad`` 0 is the gyro, 1 the accelerometer; from the fit of its three axes pooled. The
        ramp keeps one value per axis (see :meth:`sensor_dict`). An unresolved term's value is
        its upper limit, or 0 when :attr:`unresolved` is ``zero`` or the limit is not finite.
        """
        factor = _FIELDS[term][triad][1]
        if term == "quantisation":
            factor *= self.sample_rate_hz
        fit = self.triad_fits[("gyro", "accel")[triad]]
        if fit.resolved[term]:
            return fit.coefficients[term] * factor, True, math.nan
        upper = fit.upper[term] * factor
        return self._unresolved_value(upper), False, upper

    def _unresolved_value(self, upper: float) -> float:
        return upper if self.unresolved == "bound" and math.isfinite(upper) else 0.0

    def unresolved_terms(self) -> list[tuple[str, str, float]]:
        """(section, field, upper limit in its units) of every term of the sensor file the
        records do not resolve (quantisation, which white noise hides in most records, left
        out)."""
        out = []
        for triad, section in enumerate(("gyro", "accel")):
            for term in ("arw", "bias_instability", "rrw", "rate_ramp"):
                _, resolved, upper = self.field_value(triad, term)
                if not resolved:
                    out.append((section, _FIELDS[term][triad][0], upper))
        return out

    def sensor_dict(self, name: str = "calibrated", description: str = "") -> dict[str, Any]:
        """The fitted terms in the layout of a sensor TOML file (simulator units).

        Only fields the calibration speaks to are present; unresolved terms are their upper
        bound (:attr:`unresolved`).
        """
        out: dict[str, Any] = {
            "name": name,
            "description": description or self.summary(),
            "gyro": {},
            "accel": {},
        }
        for triad, section in enumerate(("gyro", "accel")):
            for term, fields in _FIELDS.items():
                key = fields[triad][0]
                if term == "rate_ramp":
                    _, factor = fields[triad]
                    axes = AXES[3 * triad : 3 * triad + 3]
                    out[section][key] = [
                        self.ramp_sign[a] * self.fits[a].coefficients[term] * factor
                        if self.fits[a].resolved[term]
                        else self.ramp_sign[a]
                        * self._unresolved_value(self.fits[a].upper[term] * factor)
                        for a in axes
                    ]
                else:
                    out[section][key] = self.field_value(triad, term)[0]
        b = self.between
        if b is not None:
            g = out["gyro"]
            for comp, key in (
                ("turn_on", "turn_on_bias_dph"),
                ("move_walk", "move_walk_dph_per_rtdeg"),
                ("move_transient", "move_transient_dph_per_rtdeg"),
            ):
                if math.isfinite(b.sigma[comp]):
                    g[key] = b.sigma[comp]
            g["move_transient_tau_s"] = b.tau_s
            out["table"] = {"heat_tau_s": b.heat_tau_s}
        if self.indexing is not None:
            out.setdefault("table", {})["indexing_error_deg"] = self.indexing.sigma_deg
        return out

    def summary(self) -> str:
        return (
            f"calibrated from {self.runs} recording(s), {self.windows} window(s), "
            f"{self.hours:.2f} h of good samples at {self.sample_rate_hz:g} Hz"
        )

    def to_toml(self, name: str = "calibrated", base: dict[str, Any] | None = None) -> str:
        """A sensor TOML file (loads with the simulator's ``--sensor FILE``), with comments that
        give each value's uncertainty or, for a term the records do not resolve, its bound.

        ``base``: a whole sensor in the TOML layout (sections of fields) whose other fields are
        written after the fitted ones, so that the file describes a complete instrument.
        """
        data = self.sensor_dict(name)
        lines = [
            f"# {self.summary()} by `northfinder calibrate`.",
            (
                "# Terms the records do not resolve are written at the 95 % bound they allow "
                "(never optimistic); the comment says so."
                if self.unresolved == "bound"
                else "# Terms the records do not resolve are 0, with the bound they allow in a comment."
            ),
        ]
        if base is not None:
            lines.append(f"# Fields not fitted are those of {base.get('name', 'the base')!r}.")
        lines += [
            f"name = {json.dumps(data['name'])}",
            f"description = {json.dumps(data['description'])}",
        ]
        for triad, section in enumerate(("gyro", "accel")):
            lines += ["", f"[{section}]"]
            for term, fields in _FIELDS.items():
                key = fields[triad][0]
                value = data[section][key]
                note = self._note(triad, term)
                lines.append(f"{key} = {_toml_value(value)}{note}")
            if section == "gyro" and self.between is not None:
                b = self.between
                for comp, key in (
                    ("turn_on", "turn_on_bias_dph"),
                    ("move_walk", "move_walk_dph_per_rtdeg"),
                    ("move_transient", "move_transient_dph_per_rtdeg"),
                ):
                    if key in data["gyro"]:
                        lo, hi = b.interval[comp]
                        lines.append(
                            f"{key} = {_toml_value(data['gyro'][key])}  # 95 %: {lo:.3g} to "
                            f"{hi:.3g}"
                        )
                lines.append(
                    f"move_transient_tau_s = {_toml_value(b.tau_s)}  # assumed, not fitted"
                )
            lines += _base_rest(base, section, data[section])
        if "table" in data or (base is not None and "table" in base):
            lines += ["", "[table]"]
            for key, value in data.get("table", {}).items():
                note = "  # assumed, not fitted" if key == "heat_tau_s" else ""
                if key == "indexing_error_deg" and self.indexing is not None:
                    lo, hi = self.indexing.interval_deg
                    note = f"  # {self.indexing.stops} stops; 95 %: {lo:.3g} to {hi:.3g}"
                lines.append(f"{key} = {_toml_value(value)}{note}")
            lines += _base_rest(base, "table", data.get("table", {}))
        for section in ("thermal", "disturbance"):
            if base is not None and section in base:
                lines += ["", f"[{section}]", *_base_rest(base, section, {})]
        return "\n".join(lines) + "\n"

    def report(self) -> str:
        """What was fitted, per axis and between positions, and what the records cannot show."""
        lines = [f"northfinder calibrate: {self.summary()} ({self.pieces} stretches)", ""]
        lines.append(
            "IEEE 952 fit of the overlapping Allan deviation per axis (1 sigma from the fit; "
            "'<=' a term the records do not resolve, with its 95 % bound)"
        )
        head = f"{'axis':<8}" + "".join(f"{_HEAD[t]:>24}" for t in TERMS) + f"{'chi2/dof':>10}"
        lines.append(head)
        for ch, axis in enumerate(AXES):
            triad = 0 if ch < 3 else 1
            cells = []
            for term in TERMS:
                fit = self.fits[axis]
                factor = _FIELDS[term][triad][1]
                if term == "quantisation":
                    factor *= self.sample_rate_hz
                if fit.resolved[term]:
                    v = fit.coefficients[term] * factor
                    if term == "rate_ramp":
                        v *= self.ramp_sign[axis]
                    cells.append(f"{v:.4g} +-{fit.sigma[term] * factor:.2g}")
                else:
                    cells.append(f"<= {fit.upper[term] * factor:.3g}")
            lines.append(
                f"{axis:<8}" + "".join(f"{c:>24}" for c in cells) + f"{fit.chi2_per_dof:>10.2f}"
            )
        for triad, name in enumerate(("gyro", "accel")):
            fit = self.triad_fits[name]
            cells = []
            for term in TERMS:
                value, resolved, upper = self.field_value(triad, term)
                factor = _FIELDS[term][triad][1] * (
                    self.sample_rate_hz if term == "quantisation" else 1.0
                )
                cells.append(
                    f"{value:.4g} +-{fit.sigma[term] * factor:.2g}"
                    if resolved
                    else f"<= {upper:.3g}"
                )
            lines.append(
                f"{name + ' 3':<8}"
                + "".join(f"{c:>24}" for c in cells)
                + f"{fit.chi2_per_dof:>10.2f}"
            )
        lines.append(
            "rows 'gyro 3', 'accel 3': the three axes pooled, as written to the sensor file"
        )
        lines.append(
            "units: gyro deg/sqrt(h), deg/h, deg/h/sqrt(h), deg/h per h, deg/h (LSB); "
            "accelerometer ug/sqrt(Hz), ug, ug/sqrt(s), ug per h, ug (LSB)"
        )
        taus = self.curves[AXES[0]].taus_s
        lines.append(f"cluster times {taus[0]:.3g} s to {taus[-1]:.3g} s")
        b = self.between
        if b is not None:
            lines += [
                "",
                f"Between positions (x and y gyro; {b.runs} run(s), {b.windows} windows, "
                f"{b.moves} moves; design {b.design}; transient tau {b.tau_s:g} s and drive heat "
                f"{b.heat_tau_s:g} s assumed; 95 % profile intervals):",
            ]
            units = {
                "white": f"deg/h per {b.window_s:g} s window",
                "turn_on": "deg/h",
                "move_walk": "deg/h/sqrt(deg)",
                "move_transient": "deg/h/sqrt(deg) at the start of a move",
            }
            for comp, unit in units.items():
                v = b.sigma[comp]
                if math.isfinite(v):
                    lo, hi = b.interval[comp]
                    lines.append(f"  {comp:<15} {v:.4g} {unit} ({lo:.3g} to {hi:.3g})")
                else:
                    lines.append(f"  {comp:<15} not estimated")
            arw = b.sigma["white"] * math.sqrt(b.window_s) / 60.0
            lines.append(
                f"  white as ARW {arw:.3g} deg/sqrt(h) (the Allan fit: "
                f"{self.field_value(0, 'arw')[0]:.3g}); more means slow noise or disturbance"
            )
        if self.indexing is not None:
            lo, hi = self.indexing.interval_deg
            lines.append(
                f"Table stop error {self.indexing.sigma_deg:.3g} deg rms over "
                f"{self.indexing.stops} stops (95 %: {lo:.3g} to {hi:.3g})"
            )
        needs = self.needs()
        if needs or self.notes:
            lines.append("")
        lines += [f"note: {n}" for n in needs + self.notes]
        return "\n".join(lines)

    def to_json_dict(self, name: str = "calibrated") -> dict[str, Any]:
        """Everything fitted, as plain JSON-ready values (``None`` for what is undefined)."""

        def clean(d: dict[str, float]) -> dict[str, float | None]:
            return {k: (float(v) if math.isfinite(v) else None) for k, v in d.items()}

        def fit_dict(fit: NoiseFit) -> dict[str, Any]:
            return {
                "coefficients": clean(fit.coefficients),
                "sigma": clean(fit.sigma),
                "resolved": fit.resolved,
                "upper": clean(fit.upper),
                "chi2_per_dof": fit.chi2_per_dof,
            }

        out: dict[str, Any] = {
            "sensor": self.sensor_dict(name),
            "axes": {axis: fit_dict(fit) for axis, fit in self.fits.items()},
            "triads": {triad: fit_dict(fit) for triad, fit in self.triad_fits.items()},
        }
        b = self.between
        if b is not None:
            out["between"] = {
                "sigma": clean(b.sigma),
                "interval": {
                    k: [float(x) if math.isfinite(x) else None for x in v]
                    for k, v in b.interval.items()
                },
                "design": b.design,
                "tau_s": b.tau_s,
                "heat_tau_s": b.heat_tau_s,
                "runs": b.runs,
                "windows": b.windows,
                "moves": b.moves,
            }
        if self.indexing is not None:
            out["indexing"] = {
                "sigma_deg": self.indexing.sigma_deg,
                "interval_deg": list(self.indexing.interval_deg),
                "stops": self.indexing.stops,
            }
        out["notes"] = self.needs() + self.notes
        return out

    def resolving_record_s(self, bias_instability_dph: float) -> float:
        """The length of record, s, that resolves a gyro bias instability of this size, given
        the gyros' fitted ARW: the white noise's Allan deviation falls to the flat floor
        ``0.664 B`` at ``tau = N^2 / (0.441 B^2)``; the curve must reach about three times that,
        and the longest cluster is about a ninth of a record (30 times in all)."""
        n = self.triad_fits["gyro"].coefficients["arw"]  # deg/h sqrt(s)
        if not (bias_instability_dph > 0 and math.isfinite(n)):
            return math.nan
        return 30.0 * n * n / (_FLOOR * bias_instability_dph**2)

    def bias_instability_need(self) -> str:
        """What it takes to resolve the gyros' bias instability (a note of an unresolved one)."""
        _, _, upper = self.field_value(0, "bias_instability")
        at_bound = self.resolving_record_s(upper)
        n = self.triad_fits["gyro"].coefficients["arw"]
        per = 30.0 * n * n / _FLOOR / 3600.0
        return (
            f"bias instability: not resolved (<= {upper:.3g} deg/h, written at that bound unless "
            f"--unresolved zero); one that large would show in still stretches of about "
            f"{_duration(at_bound)} each; one of B deg/h needs stretches of about {per:.3g} / B^2 h "
            "(30 N^2 / (0.441 B^2), N the fitted ARW)"
        )

    def needs(self) -> list[str]:
        """What the records are too short to show: for an unresolved rate random walk or rate
        ramp of the gyros, the smallest value the longest cluster time would show, and the
        record length a given value needs."""
        out: list[str] = []
        fit = self.triad_fits["gyro"]
        tau = float(self.curves[AXES[0]].taus_s[-1])
        if not fit.resolved["bias_instability"]:
            out.append(self.bias_instability_need())
            if not (fit.resolved["rrw"] or fit.resolved["rate_ramp"]):
                out.append(
                    f"the gyros' bias instability is not resolved (longest cluster {tau:.3g} s): "
                    "the slow terms need longer still stretches"
                )
            return out
        floor = math.sqrt(_FLOOR) * fit.coefficients["bias_instability"]
        if not fit.resolved["rrw"]:
            k_min = floor * math.sqrt(3.0 / tau) * 60.0
            out.append(
                f"rrw: not resolved; the longest cluster ({tau:.3g} s) shows a rate random walk "
                f"only above about {k_min:.2g} deg/h/sqrt(h); one of K deg/h/sqrt(h) passes "
                f"the bias-instability floor at tau = 3 (0.664 B 60 / K)^2 = "
                f"{3.0 * (floor * 60.0) ** 2:.3g} / K^2 s; records about 30 times that long "
                "(longest clusters a ninth of the record, where it supplies most of the variance) "
                "resolve it"
            )
        if not fit.resolved["rate_ramp"]:
            r_min = floor * math.sqrt(2.0) / tau * 3600.0
            out.append(
                f"rate ramp: not resolved; the longest cluster shows a ramp only above about "
                f"{r_min:.2g} deg/h per h"
            )
        return out

    def _note(self, triad: int, term: str) -> str:
        _, resolved, upper = self.field_value(triad, term)
        axes = AXES[3 * triad : 3 * triad + 3]
        if term == "rate_ramp":
            if not any(self.fits[a].resolved[term] for a in axes):
                return f"  # not resolved: |ramp| <= {upper:.3g}{self._written()}"
            return "  # per axis, sign from the slope within the windows"
        if resolved:
            factor = _FIELDS[term][triad][1]
            if term == "quantisation":
                factor *= self.sample_rate_hz
            sd = self.triad_fits[("gyro", "accel")[triad]].sigma[term] * factor
            return f"  # +-{sd:.2g} (1 sigma, fit of the three axes)"
        return f"  # not resolved: <= {upper:.3g}{self._written()}"

    def _written(self) -> str:
        return ", written at the bound" if self.unresolved == "bound" else ""


#: How a sensor file may write a term the records do not resolve (:class:`Calibration`).
UNRESOLVED = ("bound", "zero")

_HEAD = {
    "quantisation": "quantisation",
    "arw": "ARW / VRW",
    "bias_instability": "bias instability",
    "rrw": "RRW / bias walk",
    "rate_ramp": "rate ramp",
}
_FLOOR = 2.0 * math.log(2.0) / math.pi


def _base_rest(base: dict[str, Any] | None, section: str, done: dict[str, Any]) -> list[str]:
    """The base's fields of ``section`` not already written."""
    if base is None or not isinstance(base.get(section), dict):
        return []
    return [
        f"{key} = {_toml_value(value)}" for key, value in base[section].items() if key not in done
    ]


def _toml_value(value: Any) -> str:
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(float(value))


def calibrate(
    runs: Sequence[RecordedRun],
    *,
    tau_s: float = 10.0,
    heat_tau_s: float = 0.0,
    design: str = "per-run",
    terms: Sequence[str] = TERMS,
    unresolved: str = "bound",
) -> Calibration:
    """Fit the sensor terms of recorded runs (see the module doc).

    Parameters
    ----------
    runs : sequence of RecordedRun
        One per recording (power-on).
    tau_s, heat_tau_s, design
        Assumptions of the between-position fit
        (:func:`~northfinder.host.calibrate.between.fit_between_positions`).
    terms : sequence of str
        IEEE 952 terms to fit (default all five).
    unresolved : {"bound", "zero"}
        How the sensor file writes a term the records do not resolve (:class:`Calibration`).

    Raises
    ------
    InputError
        No runs, runs at different sample rates, too little good data for an Allan curve, or
        an ``unresolved`` of neither kind.
    """
    if unresolved not in UNRESOLVED:
        raise InputError(f"unresolved={unresolved!r}: choose one of {', '.join(UNRESOLVED)}")
    runs = list(runs)
    if not runs:
        raise InputError("runs: give at least one recorded run")
    rates = {r.sample_rate_hz for r in runs}
    if len(rates) != 1:
        raise InputError(
            f"recordings at different sample rates ({', '.join(f'{r:g}' for r in sorted(rates))} "
            "Hz) cannot be pooled; calibrate them separately"
        )
    fs = rates.pop()
    # Each window reduced to its stretches' Allan curves and slopes and its means (runs read
    # ``fitted`` come so; the samples are not needed again).
    per_run = [run.window_fits() for run in runs]
    pieces = [
        (i, j, k)
        for i, fits in enumerate(per_run)
        for j, f in enumerate(fits)
        for k in range(len(f.pieces))
    ]
    if not pieces:
        raise QualityError(
            f"no stretch of {MIN_PIECE_SAMPLES} or more consecutive good samples in the recordings"
        )
    curves: dict[str, AllanCurve] = {}
    fits: dict[str, NoiseFit] = {}
    ramp_sign: dict[str, float] = {}
    triad_pieces: dict[str, list[AllanCurve]] = {"gyro": [], "accel": []}
    for ch, axis in enumerate(AXES):
        per_piece, num, den = [], 0.0, 0.0
        for i, j, k in pieces:
            curve, slope, weight = per_run[i][j].pieces[k][ch]
            per_piece.append(curve)
            num, den = num + slope * weight, den + weight
        curves[axis] = pool_curves(per_piece)
        triad_pieces["gyro" if ch < 3 else "accel"] += per_piece
        try:
            fits[axis] = fit_ieee952(curves[axis], terms)
        except HostConfigError as exc:
            raise InputError(f"{axis}: {exc}") from exc
        ramp_sign[axis] = 1.0 if num >= 0 else -1.0
    triad_fits = {k: fit_ieee952(pool_curves(v), terms) for k, v in triad_pieces.items()}
    hours = sum(per_run[i][j].piece_samples[k] for i, j, k in pieces) / fs / 3600.0
    notes: list[str] = []
    between, indexing = _between(per_run, fits, tau_s, heat_tau_s, design, notes)
    return Calibration(
        curves=curves,
        fits=fits,
        triad_fits=triad_fits,
        ramp_sign=ramp_sign,
        between=between,
        indexing=indexing,
        sample_rate_hz=fs,
        runs=len(runs),
        windows=sum(len(f) for f in per_run),
        pieces=len(pieces),
        hours=hours,
        notes=notes,
        unresolved=unresolved,
    )


def _between(
    runs: list[tuple[WindowFit, ...]],
    fits: dict[str, NoiseFit],
    tau_s: float,
    heat_tau_s: float,
    design: str,
    notes: list[str],
) -> tuple[BetweenFit | None, IndexingFit | None]:
    """Between-position terms and stop errors, when the runs have moves."""
    windows: list[RunWindows] = []
    stops: list[float] = []
    for run in runs:
        rows = [(f, f.means) for f in run if f.means is not None]
        if len(rows) < 2:
            continue
        means = np.array([m[0] for _, m in rows])
        table = np.array([m[1] for _, m in rows])
        commanded = np.array([f.commanded_deg for f, _ in rows])
        start = np.array([m[2] for _, m in rows])
        end = np.array([m[3] for _, m in rows])
        move = np.array(
            [0.0] + [shortest_delta_deg(a, b) for a, b in itertools.pairwise(commanded)]
        )
        # A move starts as the window before it ends (the procedure turns right after a window).
        move_start = np.concatenate([[math.nan], end[:-1]])
        windows.append(RunWindows(means, table, commanded, start, end, move, move_start))
        stops += [
            shortest_delta_deg(c, t) for c, t, m in zip(commanded, table, move, strict=True) if m
        ]
    n_moves = sum(r.moves for r in windows)
    if not windows or n_moves == 0:
        notes.append(
            "between-position terms (turn-on, move step and transient) need runs of several "
            "windows with table moves between them"
        )
        return None, None
    indexing = None
    if len(stops) >= 3:
        e = np.asarray(stops)
        ss = float(e @ e)
        n = e.size
        indexing = IndexingFit(
            sigma_deg=math.sqrt(ss / n),
            interval_deg=(
                math.sqrt(ss / _chi2(0.975, n)),
                math.sqrt(ss / _chi2(0.025, n)),
            ),
            stops=n,
        )

    # Slow noise the Allan fit resolves is known; what it does not resolve (short windows) is
    # left to the between-position terms, which then include it.
    def known(term: str) -> float:
        values = [fits[a].coefficients[term] if fits[a].resolved[term] else 0.0 for a in AXES[:2]]
        return float(np.sqrt(np.mean(np.square(values))))

    b_dph, k_dph = known("bias_instability"), known("rrw")
    if b_dph == 0.0:
        notes.append(
            "the Allan fit does not resolve the bias instability (windows too short): the "
            "between-position terms include whatever slow noise there is"
        )
    try:
        between = fit_between_positions(
            windows,
            tau_s=tau_s,
            design=design,
            slow=SlowNoise(b_dph, k_dph),
            heat_tau_s=heat_tau_s,
        )
    except InputError as exc:
        notes.append(f"between-position terms not estimated: {exc}")
        return None, indexing
    if len(windows) < 2:
        notes.append("turn-on repeatability needs two or more recordings (power-ons)")
    return between, indexing


def _chi2(q: float, dof: int) -> float:
    return float(chi2.ppf(q, dof))
