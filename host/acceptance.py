"""Acceptance of a unit against its datasheet: the datasheet file, and each of its lines judged
from measured data with a confidence interval (``northfinder accept``, docs/accept.md).

A line is judged at 95 % confidence on the side that decides it: **PASS** only when the upper
end of the measured value's interval is within the limit, **FAIL** only when its lower end is
beyond it, and **NOT RESOLVED** otherwise (the record too short to decide; the line then says
how long a record, or how many runs, would decide it). The intervals are two-sided 90 %
intervals, so each end is a one-sided 95 % bound.

- Allan lines (gyro ARW, bias instability, rate random walk; accelerometer noise and bias
  instability): the IEEE 952 fit of the static record (:mod:`northfinder.host.calibrate`), the
  fitted value +- 1.645 sigma when the term is resolved, else 0 to the 95 % bound the curve
  allows.
- Repeatability: the sample standard deviation of the headings of N runs about their circular
  mean, its chi-squared interval on N - 1 degrees of freedom, scaled to the datasheet's
  latitude by cos(site latitude) / cos(datasheet latitude) (the Earth rate's horizontal part).
- Time to ready (one measurement on the device's clock), the protocol version and the
  conformance checks are judged as they are: PASS or FAIL (a timing check the host could not
  judge is NOT RESOLVED).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from northfinder.driver.protocol.units import readable_duration as _duration
from northfinder.host.calibrate.core import _FLOOR  # one formula
from northfinder.host.errors import HostConfigError

__all__ = [
    "ALLAN_KEYS",
    "CONFORMANCE_GROUPS",
    "LIMITS",
    "REPEAT_KEY",
    "VERDICTS",
    "Datasheet",
    "Line",
    "allan_lines",
    "bias_repeatability_lines",
    "conformance_lines",
    "datasheet_from_sensor",
    "datasheet_toml",
    "judge",
    "load_datasheet",
    "overall",
    "repeatability_line",
]

PASS, FAIL, NOT_RESOLVED = "PASS", "FAIL", "NOT RESOLVED"
#: The verdicts, best first.
VERDICTS = (PASS, FAIL, NOT_RESOLVED)
#: Two-sided level of every interval: each end a one-sided 95 % bound.
LEVEL = 0.90
_Z = 1.6448536269514722  # standard normal 95 % quantile

#: Numeric limits a datasheet may state: (section, key) -> (lowest, highest, unit, what).
#: The lowest is excluded (a limit of 0 cannot be met by a measured noise).
LIMITS: Mapping[tuple[str, str], tuple[float, float, str, str]] = {
    ("gyro", "arw_dpsh"): (0.0, 100.0, "deg/sqrt(h)", "gyro angle random walk"),
    ("gyro", "bias_instability_dph"): (0.0, 1000.0, "deg/h", "gyro bias instability"),
    ("gyro", "rrw_dphpsh"): (0.0, 1000.0, "deg/h/sqrt(h)", "gyro rate random walk"),
    ("gyro", "bias_repeatability_dph"): (
        0.0,
        1000.0,
        "deg/h",
        "gyro bias repeatability between windows at one table angle, 1 sigma",
    ),
    ("accel", "vrw_ug_rthz"): (0.0, 1e5, "ug/sqrt(Hz)", "accelerometer noise"),
    ("accel", "bias_instability_ug"): (0.0, 1e5, "ug", "accelerometer bias instability"),
    ("north_finding", "sigma_deg"): (0.0, 180.0, "deg", "north-finding repeatability, 1 sigma"),
    ("unit", "time_to_ready_s"): (
        0.0,
        86_400.0,
        "s",
        "time to READY (unit: from RESET; simulator: from power-on)",
    ),
}
#: Settings of the north-finding line: key -> (lowest, highest, unit, what), lowest included.
_PLAN_KEYS: Mapping[str, tuple[float, float, str, str]] = {
    "latitude_deg": (-89.0, 89.0, "deg", "latitude the repeatability is stated at"),
    "window_s": (0.5, 3600.0, "s", "seconds per position"),
    "settle_s": (0.0, 600.0, "s", "seconds after a move"),
}
_TEXT_KEYS = {("unit", "protocol_version"), ("north_finding", "solver")}
_LIST_KEYS = {("unit", "conformance"), ("north_finding", "positions_deg")}
_SECTIONS = ("gyro", "accel", "north_finding", "unit")
_REPEAT = REPEAT_KEY = "gyro.bias_repeatability_dph"


@dataclass(frozen=True)
class Datasheet:
    """The limits a unit must meet (the file's layout: docs/accept.md).

    Attributes
    ----------
    name : str
        What the datasheet is of.
    limits : dict
        ``"section.key"`` -> upper limit, in the units of :data:`LIMITS`.
    positions_deg, window_s, settle_s, solver, latitude_deg
        The plan and latitude of the repeatability line (``positions_deg`` empty: no such line).
    protocol_version : str or None
        The protocol version the unit must report (``"1.1"``).
    conformance : tuple of str
        Glob patterns of the conformance checks that must pass (empty: no conformance line).
    source : str
        The file it came from, for messages.
    """

    name: str = "datasheet"
    limits: dict[str, float] = field(default_factory=dict)
    positions_deg: tuple[float, ...] = ()
    window_s: float = 10.0
    settle_s: float = 0.0
    solver: str = "auto"
    latitude_deg: float = 34.0
    protocol_version: str | None = None
    conformance: tuple[str, ...] = ()
    source: str = "<datasheet>"

    def limit(self, key: str) -> float | None:
        return self.limits.get(key)


def _bad(source: str, text: str) -> HostConfigError:
    return HostConfigError(f"{source}: {text}")


def _number(source: str, key: str, value: Any, lo: float, hi: float, unit: str, what: str,
            *, open_lo: bool) -> float:  # fmt: skip
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _bad(source, f"{key} = {value!r} must be a number of {unit} ({what})")
    v = float(value)
    below = v <= lo if open_lo else v < lo
    if not math.isfinite(v) or below or v > hi:
        span = f"more than {lo:g} and at most {hi:g}" if open_lo else f"{lo:g} to {hi:g}"
        raise _bad(source, f"{key} = {value!r} is outside its range {span} {unit} ({what})")
    return v


def parse_datasheet(data: Mapping[str, Any], source: str = "<datasheet>") -> Datasheet:
    """A :class:`Datasheet` from the parsed TOML ``data``.

    Raises
    ------
    HostConfigError
        One line naming the key and what is wrong (an unknown key lists the known ones; a
        number outside its range states the range and unit).
    """
    known = {f"{s}.{k}" for s, k in LIMITS} | {f"north_finding.{k}" for k in _PLAN_KEYS}
    known |= {f"{s}.{k}" for s, k in _TEXT_KEYS | _LIST_KEYS}
    limits: dict[str, float] = {}
    kw: dict[str, Any] = {"source": source}
    for key, value in data.items():
        if key == "name":
            if not isinstance(value, str):
                raise _bad(source, f"name = {value!r} must be a string")
            kw["name"] = value
            continue
        if key not in _SECTIONS:
            raise _bad(
                source,
                f"unknown key {key!r}; a datasheet has name and the sections "
                f"[{'], ['.join(_SECTIONS)}]",
            )
        if not isinstance(value, dict):
            raise _bad(source, f"{key} must be a section [{key}], got {value!r}")
        for sub, v in value.items():
            full = f"{key}.{sub}"
            if full not in known:
                choices = sorted(k.split(".", 1)[1] for k in known if k.startswith(key + "."))
                raise _bad(source, f"unknown key {full!r}; [{key}] takes {', '.join(choices)}")
            if (key, sub) in LIMITS:
                lo, hi, unit, what = LIMITS[(key, sub)]
                limits[full] = _number(source, full, v, lo, hi, unit, what, open_lo=True)
            elif key == "north_finding" and sub in _PLAN_KEYS:
                lo, hi, unit, what = _PLAN_KEYS[sub]
                kw[sub] = _number(source, full, v, lo, hi, unit, what, open_lo=False)
            elif full == "north_finding.solver" or full == "unit.protocol_version":
                if not isinstance(v, str) or not v.strip():
                    raise _bad(source, f"{full} = {v!r} must be a non-empty string")
                kw["solver" if sub == "solver" else "protocol_version"] = v.strip()
            elif full == "north_finding.positions_deg":
                if not isinstance(v, list) or len(v) < 2:
                    raise _bad(source, f"{full} = {v!r} must be a list of two or more angles")
                kw["positions_deg"] = tuple(
                    _number(source, full, a, -720.0, 720.0, "deg", "table angles", open_lo=False)
                    for a in v
                )
            else:  # unit.conformance
                if not isinstance(v, list) or not v or not all(isinstance(p, str) for p in v):
                    raise _bad(
                        source,
                        f"{full} = {v!r} must be a list of check names or glob patterns "
                        '(["*"]: every check)',
                    )
                kw["conformance"] = tuple(v)
    ds = Datasheet(limits=limits, **kw)
    if "north_finding.sigma_deg" in limits and not ds.positions_deg:
        raise _bad(source, "north_finding.sigma_deg needs north_finding.positions_deg (the plan)")
    if "gyro.bias_repeatability_dph" in limits and not ds.positions_deg:
        raise _bad(
            source,
            "gyro.bias_repeatability_dph needs north_finding.positions_deg (the plan whose "
            "windows at one angle it compares)",
        )
    if ds.positions_deg and not ({"north_finding.sigma_deg", _REPEAT} & set(limits)):
        raise _bad(source, "north_finding.positions_deg needs north_finding.sigma_deg (the limit)")
    if ds.positions_deg:
        _check_plan(ds)
    if _REPEAT in limits and not same_angle_pairs(ds.positions_deg):
        raise _bad(
            source,
            f"gyro.bias_repeatability_dph needs a plan that comes back to an angle; "
            f"north_finding.positions_deg = {list(ds.positions_deg)} visits each once",
        )
    if not (limits or ds.protocol_version or ds.conformance):
        raise _bad(source, "states no limit: give at least one line (docs/accept.md)")
    return ds


def _check_plan(ds: Datasheet) -> None:
    """Refuse a plan the procedure would refuse (angles too close, an unknown solver, a solver
    that needs another number of positions), before any work."""
    from northfinder.host.errors import GeometryError
    from northfinder.host.plan import Plan
    from northfinder.host.procedure import METHOD_CHOICES, check_plan_for_device

    if ds.solver not in METHOD_CHOICES:
        raise _bad(
            ds.source,
            f"north_finding.solver = {ds.solver!r}; choose one of {', '.join(METHOD_CHOICES)}",
        )
    try:
        check_plan_for_device(Plan(ds.positions_deg, ds.window_s, ds.settle_s, "none", ds.solver))
    except (HostConfigError, GeometryError) as exc:
        raise _bad(ds.source, f"north_finding: {exc}") from exc


def load_datasheet(path: str | Path) -> Datasheet:
    """Read and check a datasheet TOML file (:func:`parse_datasheet`).

    Raises
    ------
    HostConfigError
        The file cannot be read, is no TOML, or a key is wrong (one line naming it).
    """
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise HostConfigError(f"--datasheet {p}: cannot read ({exc})") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise HostConfigError(f"{p}: not a TOML file ({exc})") from exc
    return parse_datasheet(data, str(p))


def datasheet_from_sensor(
    sensor: Mapping[str, Any],
    margin: float,
    *,
    positions_deg: Sequence[float],
    window_s: float,
    latitude_deg: float,
    predicted_sigma_deg: float | None,
    time_to_ready_s: float | None,
    protocol_version: str | None,
    conformance: Sequence[str] = ("*",),
    source: str = "--datasheet-from",
    predicted_bias_repeatability_dph: float | None = None,
) -> Datasheet:
    """A datasheet whose limits are a sensor's figures times ``margin`` (a sensor in the layout
    of a sensor TOML file: ``SensorSpec.to_dict()``). A term the sensor does not have (0) gives
    no line; the repeatability limit is the planner's prediction for the plan times ``margin``,
    and the bias repeatability limit the predicted 1-sigma change of a gyro's window mean between
    the plan's windows at one table angle times ``margin``
    (:func:`northfinder.host.accuracy.window_change_dph`; a plan that comes back to an angle)."""
    limits: dict[str, float] = {}
    for section, key in LIMITS:
        value = sensor.get(section, {}).get(key) if section in ("gyro", "accel") else None
        if isinstance(value, int | float) and value > 0:
            limits[f"{section}.{key}"] = float(value) * margin
    if predicted_sigma_deg is not None and predicted_sigma_deg > 0:
        limits["north_finding.sigma_deg"] = min(predicted_sigma_deg * margin, 180.0)
    repeat = predicted_bias_repeatability_dph
    if repeat is not None and repeat > 0 and same_angle_pairs(positions_deg):
        limits[_REPEAT] = min(repeat * margin, LIMITS[("gyro", "bias_repeatability_dph")][1])
    if time_to_ready_s is not None and time_to_ready_s > 0:
        limits["unit.time_to_ready_s"] = time_to_ready_s * margin
    runs = {"north_finding.sigma_deg", _REPEAT} & set(limits)
    return Datasheet(
        name=f"{sensor.get('name', 'sensor')} x {margin:g}",
        limits=limits,
        positions_deg=tuple(float(a) for a in positions_deg) if runs else (),
        window_s=float(window_s),
        latitude_deg=float(latitude_deg),
        protocol_version=protocol_version,
        conformance=tuple(conformance),
        source=source,
    )


def datasheet_toml(ds: Datasheet, comment: str = "") -> str:
    """The datasheet as a TOML file :func:`load_datasheet` reads back."""

    def num(v: float) -> str:
        return repr(float(v))

    lines = [f"# {comment}"] if comment else []
    lines.append(f'name = "{ds.name}"')
    for section in _SECTIONS:
        rows = []
        for (sec, key), (_, _, unit, what) in LIMITS.items():
            full = f"{sec}.{key}"
            if sec == section and full in ds.limits:
                rows.append(f"{key} = {num(ds.limits[full])}  # at most, {unit}: {what}")
        if section == "north_finding" and ds.positions_deg:
            rows += [
                f"positions_deg = [{', '.join(num(a) for a in ds.positions_deg)}]",
                f"window_s = {num(ds.window_s)}",
                f"settle_s = {num(ds.settle_s)}",
                f'solver = "{ds.solver}"',
                f"latitude_deg = {num(ds.latitude_deg)}",
            ]
        if section == "unit":
            if ds.protocol_version:
                rows.append(f'protocol_version = "{ds.protocol_version}"')
            if ds.conformance:
                rows.append("conformance = [" + ", ".join(f'"{p}"' for p in ds.conformance) + "]")
        if rows:
            lines += ["", f"[{section}]", *rows]
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class Line:
    """One datasheet line judged.

    Attributes
    ----------
    key : str
        ``section.key`` of the datasheet.
    title, unit : str
    limit : float or str
        The datasheet's limit (a number: at most; a string: must equal).
    measured : float or str or None
    low, high : float
        The interval of the measured value (:data:`LEVEL`); NaN where there is none.
    verdict : str
        One of :data:`VERDICTS`.
    note : str
        How it was measured, and for NOT RESOLVED what would decide it.
    """

    key: str
    title: str
    unit: str
    limit: float | str
    measured: float | str | None
    low: float
    high: float
    verdict: str
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        def clean(v: Any) -> Any:
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {k: clean(getattr(self, k)) for k in self.__dataclass_fields__}


def judge(limit: float, low: float, high: float) -> str:
    """PASS when ``high <= limit``, FAIL when ``low > limit``, else NOT RESOLVED."""
    if high <= limit:
        return PASS
    if low > limit:
        return FAIL
    return NOT_RESOLVED


def overall(lines: Sequence[Line]) -> str:
    """FAIL if any line fails, else NOT RESOLVED if any is, else PASS."""
    verdicts = {line.verdict for line in lines}
    if FAIL in verdicts:
        return FAIL
    if NOT_RESOLVED in verdicts:
        return NOT_RESOLVED
    return PASS


#: (section.key) -> (triad, IEEE 952 term, factor from the coefficient to the datasheet unit).
_ALLAN = {
    "gyro.arw_dpsh": ("gyro", "arw", 1.0 / 60.0),
    "gyro.bias_instability_dph": ("gyro", "bias_instability", 1.0),
    "gyro.rrw_dphpsh": ("gyro", "rrw", 60.0),
    "accel.vrw_ug_rthz": ("accel", "arw", 1.0),
    "accel.bias_instability_ug": ("accel", "bias_instability", 1.0),
}
#: The lines the static recording judges.
ALLAN_KEYS = tuple(_ALLAN)


def allan_lines(ds: Datasheet, cal: Any, record_s: float) -> list[Line]:
    """The Allan lines of ``ds`` judged from a :class:`~northfinder.host.calibrate.Calibration`
    of a static record ``record_s`` seconds long (one still stretch)."""
    out = []
    for key, (triad, term, factor) in _ALLAN.items():
        limit = ds.limit(key)
        if limit is None:
            continue
        fit = cal.triad_fits[triad]
        _, _, unit, what = LIMITS[tuple(key.split("."))]  # type: ignore[index]
        c = fit.coefficients[term] * factor
        if fit.resolved[term]:
            sd = fit.sigma[term] * factor
            low, high = max(c - _Z * sd, 0.0), c + _Z * sd
            how = f"fitted {c:.4g} +- {sd:.2g} (1 sigma)"
        else:
            low, high = 0.0, fit.upper[term] * factor
            c = math.nan
            how = f"not resolved by the record: at most {high:.3g} (95 %)"
        verdict = judge(limit, low, high)
        note = how
        if verdict == NOT_RESOLVED:
            need = _needed_record_s(cal, triad, term, limit / factor, c / factor, low, high,
                                    factor, record_s, ds)  # fmt: skip
            note += f"; a static record of at least about {_duration(need)} would decide it"
        out.append(Line(key, what, unit, limit, None if math.isnan(c) else c, low, high,
                        verdict, note))  # fmt: skip
    return out


def _needed_record_s(
    cal: Any, triad: str, term: str, limit_c: float, value_c: float, low: float, high: float,
    factor: float, record_s: float, ds: Datasheet,
) -> float:  # fmt: skip
    """About how long a still record would decide a term (coefficients in the fit's units)."""
    fit = cal.triad_fits[triad]
    n = fit.coefficients["arw"]  # the white noise, rate sqrt(s)
    if math.isfinite(value_c):
        # A resolved term: its interval narrows as 1 / sqrt(record length).
        half = (high - value_c * factor) if value_c <= limit_c else (value_c * factor - low)
        gap = abs(limit_c - value_c) * factor
        return record_s * (half / gap) ** 2 if gap > 0 else math.inf
    # The bound on a term the record does not resolve falls about as 1 / sqrt(record length)
    # (the white noise's share at the longest cluster time), to the limit at least this long:
    shrink = record_s * (high / (limit_c * factor)) ** 2
    if term == "bias_instability" and n > 0:
        # The white noise's Allan deviation meets the floor 0.664 B at N^2 / (0.441 B^2); the
        # curve must reach three times that, its longest cluster a ninth of the record.
        return max(shrink, 30.0 * n * n / (_FLOOR * limit_c**2))
    if term == "rrw":
        b = fit.coefficients["bias_instability"] if fit.resolved["bias_instability"] else 0.0
        if not b:
            b_limit = ds.limit("gyro.bias_instability_dph")
            b = b_limit if b_limit is not None else fit.upper["bias_instability"]
        # K^2 tau / 3 passes the flicker floor 0.441 B^2 at tau = 3 * 0.441 B^2 / K^2.
        return max(shrink, 30.0 * 3.0 * _FLOOR * b * b / (limit_c**2))
    return shrink


def circular_spread(azimuths_deg: Sequence[float]) -> tuple[float, np.ndarray]:
    """The circular mean of headings, deg, and each heading's difference from it."""
    a = np.radians(np.asarray(azimuths_deg, dtype=float))
    mean = math.degrees(math.atan2(np.mean(np.sin(a)), np.mean(np.cos(a)))) % 360.0
    d = (np.asarray(azimuths_deg, dtype=float) - mean + 180.0) % 360.0 - 180.0
    return mean, d


def repeatability_line(
    ds: Datasheet, azimuths_deg: Sequence[float], site_latitude_deg: float
) -> Line:
    """The repeatability line from the headings of the runs (module doc)."""
    from scipy.stats import chi2

    limit = ds.limits["north_finding.sigma_deg"]
    n = len(azimuths_deg)
    _, _, unit, what = LIMITS[("north_finding", "sigma_deg")]
    if n < 2:
        return Line("north_finding.sigma_deg", what, unit, limit, None, math.nan, math.nan,
                    NOT_RESOLVED, f"{n} run(s): a spread needs two or more")  # fmt: skip
    _, d = circular_spread(azimuths_deg)
    scale = math.cos(math.radians(site_latitude_deg)) / math.cos(math.radians(ds.latitude_deg))
    s = float(np.sqrt(np.sum(d * d) / (n - 1))) * scale
    dof = n - 1
    low = s * math.sqrt(dof / chi2.ppf(0.5 + LEVEL / 2, dof))
    high = s * math.sqrt(dof / chi2.ppf(0.5 - LEVEL / 2, dof))
    verdict = judge(limit, low, high)
    note = f"{n} runs"
    if abs(scale - 1.0) > 1e-12:
        note += f" at {site_latitude_deg:g} deg, scaled by {scale:.4g} to {ds.latitude_deg:g} deg"
    if verdict == NOT_RESOLVED:
        need = _runs_needed(s, limit, chi2)
        note += (
            f"; about {need} runs would decide it"
            if need
            else "; the spread equals the limit: no number of runs decides it"
        )
    return Line("north_finding.sigma_deg", what, unit, limit, s, low, high, verdict, note)


def _runs_needed(s: float, limit: float, chi2: Any) -> int | None:
    """The fewest runs whose interval, at this spread, falls on one side of the limit."""
    if s == limit:
        return None
    for n in range(3, 100_001):
        dof = n - 1
        if s < limit and s * math.sqrt(dof / chi2.ppf(0.5 - LEVEL / 2, dof)) <= limit:
            return n
        if s > limit and s * math.sqrt(dof / chi2.ppf(0.5 + LEVEL / 2, dof)) > limit:
            return n
    return None


def value_line(key: str, limit: float, measured: float, note: str = "") -> Line:
    """A line measured once, without an interval (time to ready)."""
    _, _, unit, what = LIMITS[tuple(key.split("."))]  # type: ignore[index]
    return Line(key, what, unit, limit, measured, measured, measured,
                PASS if measured <= limit else FAIL, note)  # fmt: skip


def equal_line(key: str, title: str, required: str, measured: str | None) -> Line:
    """A line that must equal the datasheet's value (protocol version)."""
    verdict = PASS if measured == required else (NOT_RESOLVED if measured is None else FAIL)
    note = "" if measured is not None else "the unit did not identify itself"
    return Line(key, title, "", required, measured, math.nan, math.nan, verdict, note)


def conformance_line(patterns: Sequence[str], checks: Sequence[Mapping[str, Any]]) -> Line:
    """The conformance line from the suite's checks (``name``, ``outcome``: pass, fail,
    not judged, skip): FAIL if one failed, NOT RESOLVED if one was not judged, else PASS."""
    failed = [c["name"] for c in checks if c["outcome"] == "fail"]
    unjudged = [c["name"] for c in checks if c["outcome"] == "not judged"]
    passed = sum(c["outcome"] == "pass" for c in checks)
    skipped = sum(c["outcome"] == "skip" for c in checks)
    measured = f"{passed} passed, {len(failed)} failed, {skipped} skipped"
    if failed:
        verdict, note = FAIL, "failed: " + ", ".join(failed)
    elif unjudged:
        verdict = NOT_RESOLVED
        note = "not judged (the host could not keep pace): " + ", ".join(unjudged)
    elif not checks:
        verdict, note = NOT_RESOLVED, "no check ran"
    else:
        verdict, note = PASS, f"{len(checks)} checks"
    return Line("unit.conformance", "conformance checks (protocol.md)", "",
                ", ".join(patterns), measured, math.nan, math.nan, verdict, note)  # fmt: skip


def same_angle_pairs(positions_deg: Sequence[float]) -> list[tuple[int, int]]:
    """The windows of a plan at one table angle (mod 360, within 0.01 deg): each window paired
    with the one before it at that angle."""
    pairs = []
    for j, b in enumerate(positions_deg):
        for i in range(j - 1, -1, -1):
            if abs((positions_deg[i] - b + 180.0) % 360.0 - 180.0) < 0.01:
                pairs.append((i, j))
                break
    return pairs


AXES = ("x", "y", "z")


def bias_repeatability_lines(
    ds: Datasheet, runs_gyro_means_dph: Sequence[Sequence[Sequence[float]]]
) -> list[Line]:
    """A line per gyro axis: the root mean square change of the axis's mean rate between two
    windows of one run at one table angle (:func:`same_angle_pairs`), each change a bias change
    plus the windows' noise; its chi-squared interval on as many degrees of freedom as there
    are changes (their mean is zero: the Earth rate is the same at one angle).

    ``runs_gyro_means_dph[r][w]`` is the mean gyro rate (x, y, z) of window ``w`` of run ``r``.
    """
    from scipy.stats import chi2

    limit = ds.limits[_REPEAT]
    _, _, unit, what = LIMITS[("gyro", "bias_repeatability_dph")]
    pairs = same_angle_pairs(ds.positions_deg)
    d = np.array(
        [np.subtract(run[j], run[i]) for run in runs_gyro_means_dph for i, j in pairs], float
    ).reshape(-1, 3)
    n = len(d)
    out = []
    for a, axis in enumerate(AXES):
        key = f"{_REPEAT}.{axis}"
        title = f"{what}, {axis} axis"
        if n == 0:
            out.append(Line(key, title, unit, limit, None, math.nan, math.nan, NOT_RESOLVED,
                            "no pair of windows at one angle"))  # fmt: skip
            continue
        s = float(np.sqrt(np.mean(d[:, a] ** 2)))
        low = s * math.sqrt(n / chi2.ppf(0.5 + LEVEL / 2, n))
        high = s * math.sqrt(n / chi2.ppf(0.5 - LEVEL / 2, n))
        verdict = judge(limit, low, high)
        note = f"{n} changes in {len(runs_gyro_means_dph)} runs ({ds.window_s:g} s windows)"
        if verdict == NOT_RESOLVED:
            need = _changes_needed(s, limit, chi2)
            note += f"; about {need} changes would decide it" if need else ""
        out.append(Line(key, title, unit, limit, s, low, high, verdict, note))
    return out


def _changes_needed(s: float, limit: float, chi2: Any) -> int | None:
    """The fewest changes (degrees of freedom) whose interval falls on one side of the limit."""
    for n in range(2, 100_001):
        if s < limit and s * math.sqrt(n / chi2.ppf(0.5 - LEVEL / 2, n)) <= limit:
            return n
        if s > limit and s * math.sqrt(n / chi2.ppf(0.5 + LEVEL / 2, n)) > limit:
            return n
    return None


#: The conformance lines: (line, what it covers, check name patterns), the first match counts.
CONFORMANCE_GROUPS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("rates", "heartbeat and sample rate (protocol.md 6)",
     ("heartbeat.*", "stream.rate", "command.set_config")),
    ("stream", "sample stream: counters and validity (protocol.md 4.5, 8)", ("stream.*",)),
    ("table", "table moves and spin (protocol.md 4.1, 5)", ("rotation.*", "spin.*")),
    ("commands", "commands, replies and refusals (protocol.md 2, 4, 9)", ("*",)),
)  # fmt: skip


def conformance_group(name: str) -> str:
    """The conformance line a check counts in (:data:`CONFORMANCE_GROUPS`)."""
    from fnmatch import fnmatchcase

    return next(g for g, _, pats in CONFORMANCE_GROUPS if any(fnmatchcase(name, p) for p in pats))


def conformance_lines(patterns: Sequence[str], checks: Sequence[Mapping[str, Any]]) -> list[Line]:
    """A conformance line per group of checks that ran (:data:`CONFORMANCE_GROUPS`), each
    :func:`conformance_line` of its checks; no check at all gives one NOT RESOLVED line."""
    if not checks:
        return [conformance_line(patterns, checks)]
    out = []
    for group, title, _ in CONFORMANCE_GROUPS:
        mine = [c for c in checks if conformance_group(c["name"]) == group]
        if mine:
            line = conformance_line(patterns, mine)
            out.append(replace(line, key=f"unit.conformance.{group}", title=title))
    return out


def static_length_s(ds: Datasheet, shortest_s: float, longest_s: float) -> tuple[float, str]:
    """The still record that can decide the datasheet's gyro bias instability line beside its
    ARW line: ``30 N^2 / (0.441 B^2)`` (the white noise of the ARW limit N meets the flicker
    floor of the limit B at N^2 / (0.441 B^2); the curve must reach three times that, its longest
    cluster a ninth of the record), between ``shortest_s`` and ``longest_s``; and why."""
    b = ds.limit("gyro.bias_instability_dph")
    n = ds.limit("gyro.arw_dpsh")
    if b is None or n is None:
        return shortest_s, "the default (no gyro bias instability and ARW lines to size it)"
    need = 30.0 * (n * 60.0) ** 2 / (_FLOOR * b * b)
    how = (
        f"to resolve gyro.bias_instability_dph <= {b:g} beside gyro.arw_dpsh <= {n:g}: "
        f"30 N^2 / (0.441 B^2) = {_duration(need)}"
    )
    if need > longest_s:
        return longest_s, how + f", capped at {_duration(longest_s)}"
    if need < shortest_s:
        return shortest_s, how + f", at least {_duration(shortest_s)}"
    return need, how
