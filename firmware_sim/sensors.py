"""Sensor specifications in datasheet units, loaded from TOML files or named presets.

A :class:`SensorSpec` describes one instrument: gyro triad, accelerometer triad, thermal behaviour,
disturbances and turntable. Every error term is switched off by setting it to zero; the ``ideal``
preset has every term at zero. Presets live as TOML files in ``firmware_sim/presets/``.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from northfinder.driver.protocol.motion import (
    DEFAULT_MAX_ACCEL_DPS2,
    DEFAULT_MAX_RATE_DPS,
    DEFAULT_SETTLE_S,
)
from northfinder.firmware_sim.errors import SimConfigError

_VEC3 = "vec3"
_NONNEG = "nonneg"
_POSITIVE = "positive"
_ANY = "any"


def _f(default: float, check: str = _NONNEG, doc: str = "", *, lo: float, hi: float) -> Any:
    """A figure of the spec: its default, sign check, meaning with its unit, and the range a
    sensor file may give it (refused beyond, naming the key, the value and the range)."""
    return field(default=default, metadata={"check": check, "doc": doc, "range": (lo, hi)})


def _v(doc: str = "", *, lo: float, hi: float) -> Any:
    return field(default=(0.0, 0.0, 0.0), metadata={"check": _VEC3, "doc": doc, "range": (lo, hi)})


@dataclass(frozen=True)
class GyroSpec:
    """Gyro triad errors. Random terms (``turn_on_*``, scale factor, misalignment) are 1-sigma draws.

    Turn-on terms are drawn once per power-on (one :class:`~northfinder.firmware_sim.imu.Instrument`,
    one run of the batch generator); a firmware reset keeps them, as a restart of the electronics
    leaves a powered sensor alone. Move terms are drawn at the start of every table move.
    """

    bias_dph: tuple[float, float, float] = _v("constant bias per axis, deg/h", lo=-1e5, hi=1e5)
    turn_on_bias_dph: float = _f(
        0.0,
        doc="turn-on to turn-on bias repeatability (per power-on), 1 sigma, deg/h",
        lo=0.0,
        hi=1e5,
    )
    bias_instability_dph: float = _f(
        0.0, doc="flicker bias instability B; Allan floor 0.664 B, deg/h", lo=0.0, hi=1e4
    )
    arw_dpsh: float = _f(0.0, doc="angle random walk, deg/sqrt(h)", lo=0.0, hi=100.0)
    rrw_dphpsh: float = _f(0.0, doc="rate random walk, deg/h/sqrt(h)", lo=0.0, hi=1e4)
    scale_factor_ppm: float = _f(
        0.0, doc="scale-factor error per axis, 1 sigma, ppm", lo=0.0, hi=1e5
    )
    misalignment_urad: float = _f(
        0.0, doc="axis misalignment, 1 sigma per off-diagonal, urad", lo=0.0, hi=1e5
    )
    lsb_dph: float = _f(
        0.0, doc="output quantisation (pulse weight as a rate), deg/h; 0 = none", lo=0.0, hi=1e4
    )
    range_dps: float = _f(200.0, _POSITIVE, "measurement range, deg/s", lo=0.0, hi=1e5)
    temp_coeff_dph_per_c: tuple[float, float, float] = _v(
        "bias temperature sensitivity, deg/h/degC", lo=-1e3, hi=1e3
    )
    warmup_bias_dph: tuple[float, float, float] = _v(
        "warm-up transient at power-on, deg/h", lo=-1e5, hi=1e5
    )
    warmup_tau_s: float = _f(60.0, _POSITIVE, "warm-up transient time constant, s", lo=0.0, hi=1e6)
    rate_ramp_dph_per_h: tuple[float, float, float] = _v(
        "rate ramp: linear bias trend from power-on, deg/h per hour", lo=-1e6, hi=1e6
    )
    move_walk_dph_per_rtdeg: float = _f(
        0.0,
        doc="bias random walk in the angle turned: each move adds a lasting bias step of "
        "1 sigma this times sqrt(|move| in deg), deg/h/sqrt(deg)",
        lo=0.0,
        hi=1e3,
    )
    move_transient_dph_per_rtdeg: float = _f(
        0.0,
        doc="each move starts a bias transient of random amplitude, 1 sigma this times "
        "sqrt(|move| in deg) at the start of the move, deg/h/sqrt(deg)",
        lo=0.0,
        hi=1e3,
    )
    move_transient_tau_s: float = _f(
        10.0,
        _POSITIVE,
        "time constant of the move transient's decay from the start of the move, s",
        lo=0.0,
        hi=1e6,
    )
    impulse_dph: float = _f(0.0, doc="peak rate of one impulse (shock), deg/h", lo=0.0, hi=1e8)
    vibration_dph: float = _f(
        0.0, doc="vibration amplitude seen by each gyro axis, deg/h", lo=0.0, hi=1e8
    )


@dataclass(frozen=True)
class AccelSpec:
    """Accelerometer triad errors, micro-g based (1 ug = 9.80665e-6 m/s^2)."""

    bias_ug: tuple[float, float, float] = _v("constant bias per axis, ug", lo=-1e6, hi=1e6)
    turn_on_bias_ug: float = _f(0.0, doc="turn-on bias repeatability, 1 sigma, ug", lo=0.0, hi=1e6)
    bias_instability_ug: float = _f(0.0, doc="flicker bias instability, ug", lo=0.0, hi=1e5)
    vrw_ug_rthz: float = _f(
        0.0, doc="velocity random walk (white noise density), ug/sqrt(Hz)", lo=0.0, hi=1e5
    )
    random_walk_ug_rts: float = _f(0.0, doc="bias random walk, ug/sqrt(s)", lo=0.0, hi=1e5)
    scale_factor_ppm: float = _f(
        0.0, doc="scale-factor error per axis, 1 sigma, ppm", lo=0.0, hi=1e5
    )
    misalignment_urad: float = _f(0.0, doc="axis misalignment, 1 sigma, urad", lo=0.0, hi=1e5)
    lsb_ug: float = _f(0.0, doc="output quantisation, ug; 0 = none", lo=0.0, hi=1e5)
    range_g: float = _f(10.0, _POSITIVE, "measurement range, g", lo=0.0, hi=1e3)
    temp_coeff_ug_per_c: tuple[float, float, float] = _v(
        "bias temperature sensitivity, ug/degC", lo=-1e4, hi=1e4
    )
    warmup_bias_ug: tuple[float, float, float] = _v(
        "warm-up transient at power-on, ug", lo=-1e6, hi=1e6
    )
    warmup_tau_s: float = _f(60.0, _POSITIVE, "warm-up transient time constant, s", lo=0.0, hi=1e6)
    ramp_ug_per_h: tuple[float, float, float] = _v(
        "linear bias trend from power-on, ug per hour", lo=-1e7, hi=1e7
    )
    move_walk_ug_per_rtdeg: float = _f(
        0.0,
        doc="lasting bias step per move, 1 sigma per sqrt(deg turned), ug/sqrt(deg)",
        lo=0.0,
        hi=1e4,
    )
    move_transient_ug_per_rtdeg: float = _f(
        0.0,
        doc="decaying bias transient per move, 1 sigma per sqrt(deg turned), ug/sqrt(deg)",
        lo=0.0,
        hi=1e4,
    )
    move_transient_tau_s: float = _f(
        10.0, _POSITIVE, "time constant of that transient, s", lo=0.0, hi=1e6
    )
    impulse_ug: float = _f(0.0, doc="peak specific force of one impulse, ug", lo=0.0, hi=1e8)
    vibration_ug: float = _f(
        0.0, doc="vibration amplitude seen by each accelerometer axis, ug", lo=0.0, hi=1e8
    )


@dataclass(frozen=True)
class ThermalSpec:
    """Sensor temperature: T(t) = ambient + rise (1 - exp(-t / tau)) + ramp t."""

    ambient_c: float = _f(20.0, _ANY, "ambient temperature at power-on, degC", lo=-100.0, hi=150.0)
    warmup_rise_c: float = _f(
        0.0, _ANY, "self-heating rise after power-on, degC", lo=-50.0, hi=150.0
    )
    warmup_tau_s: float = _f(600.0, _POSITIVE, "self-heating time constant, s", lo=0.0, hi=1e6)
    ramp_c_per_h: float = _f(
        0.0, _ANY, "slow ambient drift, degC/h (gives linear bias trends)", lo=-100.0, hi=100.0
    )


@dataclass(frozen=True)
class DisturbanceSpec:
    """Environment: random impulses (doors, footsteps) and a vibration line (engines, pumps)."""

    impulse_rate_hz: float = _f(0.0, doc="mean rate of impulses (Poisson), 1/s", lo=0.0, hi=1e3)
    impulse_duration_s: float = _f(
        0.05, _POSITIVE, "duration of one half-sine impulse, s", lo=0.0, hi=10.0
    )
    vibration_hz: float = _f(0.0, doc="vibration frequency, Hz; 0 = none", lo=0.0, hi=1e4)


@dataclass(frozen=True)
class TableSpec:
    """Turntable about body z."""

    max_rate_dps: float = _f(DEFAULT_MAX_RATE_DPS, _POSITIVE, "speed limit, deg/s", lo=0.0, hi=1e3)
    max_accel_dps2: float = _f(
        DEFAULT_MAX_ACCEL_DPS2, _POSITIVE, "acceleration limit, deg/s^2", lo=0.0, hi=1e4
    )
    settle_s: float = _f(
        DEFAULT_SETTLE_S, doc="settling time after the motion profile ends, s", lo=0.0, hi=600.0
    )
    encoder_resolution_deg: float = _f(
        360.0 / 2**24, doc="encoder resolution, deg; 0 = exact", lo=0.0, hi=1.0
    )
    indexing_error_deg: float = _f(
        0.0, doc="stop-position error per move, 1 sigma, deg", lo=0.0, hi=10.0
    )
    overshoot_deg: float = _f(
        0.0, doc="amplitude of the damped oscillation after a stop, deg", lo=0.0, hi=10.0
    )
    overshoot_hz: float = _f(4.0, _POSITIVE, "frequency of that oscillation, Hz", lo=0.0, hi=1e3)
    heat_tau_s: float = _f(
        0.0,
        doc="time constant of the heat the motor holds, s: the bias disturbance a move starts has "
        "the variance of all angles turned, each decayed with it; 0 = of this move's angle alone",
        lo=0.0,
        hi=1e6,
    )
    spin_heat: float = _f(
        0.0,
        doc="while spinning: the drive's heat, as the fraction of a move's bias disturbance per "
        "degree that steady turning carries (northfinder.driver.protocol.heat); 0 = none",
        lo=0.0,
        hi=1.0,
    )
    rate_ripple: float = _f(
        0.0,
        doc="while spinning: once-per-turn rate ripple, amplitude as a fraction of the rate "
        "(0.001 = 0.1 %); the rate is v (1 + k cos(mu - rate_ripple_phase_deg))",
        lo=0.0,
        hi=0.5,
    )
    rate_ripple_phase_deg: float = _f(
        0.0, _ANY, "table angle of the ripple's fastest point, deg", lo=-360.0, hi=360.0
    )
    wobble_urad: float = _f(
        0.0,
        doc="tilt of the table top (and the sensor block on it) against the axis it turns "
        "about, urad: seen from the base it wobbles once per turn; in the sensor frame it is a "
        "fixed tilt, so the gyros see the table rate and the vertical Earth rate through it",
        lo=0.0,
        hi=1e5,
    )
    wobble_phase_deg: float = _f(
        0.0, _ANY, "table-frame direction the top tilts towards, deg", lo=-360.0, hi=360.0
    )
    encoder_error_deg: float = _f(
        0.0,
        doc="periodic encoder error, amplitude, deg (e.g. eccentricity for harmonic 1): the "
        "encoder reads mu + e sin(n mu + phase)",
        lo=0.0,
        hi=10.0,
    )
    encoder_error_harmonic: float = _f(
        1.0, _POSITIVE, "encoder error cycles per turn, 1/turn", lo=0.0, hi=1e3
    )
    encoder_error_phase_deg: float = _f(
        0.0, _ANY, "phase of the encoder error, deg", lo=-360.0, hi=360.0
    )


_SECTIONS: dict[str, type] = {
    "gyro": GyroSpec,
    "accel": AccelSpec,
    "thermal": ThermalSpec,
    "disturbance": DisturbanceSpec,
    "table": TableSpec,
}


@dataclass(frozen=True)
class SensorSpec:
    """A whole instrument: sensors, environment and turntable."""

    name: str = "custom"
    description: str = ""
    gyro: GyroSpec = field(default_factory=GyroSpec)
    accel: AccelSpec = field(default_factory=AccelSpec)
    thermal: ThermalSpec = field(default_factory=ThermalSpec)
    disturbance: DisturbanceSpec = field(default_factory=DisturbanceSpec)
    table: TableSpec = field(default_factory=TableSpec)

    def to_dict(self) -> dict[str, Any]:
        """A plain dict in the TOML layout (sections of datasheet values)."""
        out: dict[str, Any] = {"name": self.name, "description": self.description}
        for section in _SECTIONS:
            out[section] = {
                k: list(v) if isinstance(v, tuple) else v
                for k, v in dataclasses.asdict(getattr(self, section)).items()
            }
        return out

    def with_values(self, values: dict[str, Any]) -> SensorSpec:
        """A copy with dotted fields replaced, e.g. ``{"gyro.arw_dpsh": 0.002}``; validated."""
        data = self.to_dict()
        for dotted, value in values.items():
            section, _, key = str(dotted).partition(".")
            if section not in _SECTIONS or not key:
                raise SimConfigError(
                    f"{dotted}: not a sensor field; use SECTION.FIELD with SECTION one of "
                    f"{', '.join(_SECTIONS)}"
                )
            data[section][key] = value
        return spec_from_dict(data, source=self.name)


def _check_value(where: str, spec: Any, value: Any) -> float | tuple[float, float, float]:
    """A value of the field ``spec`` (a dataclass field) from a sensor file, checked: a number
    (three for a vector), of the field's sign, within its range."""
    check, (lo, hi), doc = spec.metadata["check"], spec.metadata["range"], spec.metadata["doc"]
    if check == _VEC3:
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise SimConfigError(f"{where}: expected a list of three numbers, got {value!r}")
        x, y, z = (
            _in_range(f"{where}[{i}]", _check_number(f"{where}[{i}]", _ANY, v), lo, hi, doc)
            for i, v in enumerate(value)
        )
        return x, y, z
    return _in_range(where, _check_number(where, check, value), lo, hi, doc)


def _in_range(where: str, x: float, lo: float, hi: float, doc: str) -> float:
    if not lo <= x <= hi:
        raise SimConfigError(f"{where} = {x:g} is outside its range {lo:g} to {hi:g} ({doc})")
    return x


def field_ranges() -> dict[str, tuple[float, float, str]]:
    """``section.field`` -> (lowest, highest, meaning and unit) of every figure a sensor file
    may give (docs/instrument.md lists them)."""
    return {
        f"{section}.{f.name}": (*f.metadata["range"], f.metadata["doc"])
        for section, cls in _SECTIONS.items()
        for f in dataclasses.fields(cls)
    }


def _check_number(where: str, check: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SimConfigError(f"{where}: expected a number, got {value!r}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise SimConfigError(f"{where}: must be finite, got {value!r}")
    if check == _NONNEG and x < 0:
        raise SimConfigError(f"{where}: must not be negative, got {x}")
    if check == _POSITIVE and x <= 0:
        raise SimConfigError(f"{where}: must be positive, got {x}")
    return x


def _section_from_dict(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise SimConfigError(f"{where}: expected a table of fields, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise SimConfigError(
            f"{where}.{unknown[0]}: unknown field; known fields are {', '.join(fields)}"
        )
    kwargs = {k: _check_value(f"{where}.{k}", fields[k], v) for k, v in data.items()}
    return cls(**kwargs)


def spec_from_dict(data: dict[str, Any], source: str = "<dict>") -> SensorSpec:
    """Build and validate a :class:`SensorSpec` from the TOML layout; errors name the field."""
    if not isinstance(data, dict):
        raise SimConfigError(f"{source}: expected a table, got {type(data).__name__}")
    unknown = sorted(set(data) - set(_SECTIONS) - {"name", "description"})
    if unknown:
        raise SimConfigError(
            f"{source}: unknown section or key {unknown[0]!r}; expected name, description, "
            f"{', '.join(_SECTIONS)}"
        )
    kwargs: dict[str, Any] = {
        "name": str(data.get("name", Path(source).stem)),
        "description": str(data.get("description", "")),
    }
    for section, cls in _SECTIONS.items():
        kwargs[section] = _section_from_dict(cls, data.get(section, {}), f"{source}: {section}")
    return SensorSpec(**kwargs)


#: The sensor a simulation runs when none is named (the source paper's ring-laser gyro unit).
DEFAULT_SENSOR = "paper-rlg"


def preset_names() -> list[str]:
    """Names of the presets shipped with the package."""
    files = resources.files("northfinder.firmware_sim").joinpath("presets").iterdir()
    return sorted(f.name[: -len(".toml")] for f in files if f.name.endswith(".toml"))


def load_spec(name_or_path: str | Path) -> SensorSpec:
    """Load a preset by name (``paper-rlg``) or a TOML file by path.

    Raises
    ------
    SimConfigError
        Unknown preset (the message lists the presets), unreadable file, invalid TOML or field.
    """
    text = str(name_or_path)
    path = Path(text)
    if text.endswith(".toml") or path.exists():
        raw = _read_sensor_file(path, text)
        source = text
    else:
        if text not in preset_names():
            raise SimConfigError(
                f"unknown sensor preset {text!r}; presets are {', '.join(preset_names())} "
                "(or give a path to a .toml file)"
            )
        raw = (
            resources.files("northfinder.firmware_sim")
            .joinpath("presets", f"{text}.toml")
            .read_bytes()
        )
        source = text
    try:
        data = tomllib.loads(raw.decode("utf-8-sig"))  # a byte-order mark is no error
    except UnicodeDecodeError as exc:
        raise SimConfigError(f"sensor file {source}: not UTF-8 text ({exc.reason})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise SimConfigError(f"sensor file {source}: not valid TOML ({exc})") from exc
    if not data:
        raise SimConfigError(
            f"sensor file {source}: specifies nothing (empty); give the sections and fields "
            "to change, or the preset 'ideal' for an ideal sensor"
        )
    return spec_from_dict(data, source=source)


#: Largest sensor file read, bytes: a sensor TOML is a few kB.
MAX_SENSOR_FILE_BYTES = 1 << 20


def _read_sensor_file(path: Path, text: str) -> bytes:
    """A sensor file's bytes: a regular file of at most :data:`MAX_SENSOR_FILE_BYTES` (a FIFO
    would block, ``/dev/zero`` never ends)."""
    import stat

    try:
        mode = path.stat().st_mode
        if not stat.S_ISREG(mode):
            kind = "a folder" if stat.S_ISDIR(mode) else "not a regular file (a FIFO or a device)"
            raise SimConfigError(f"sensor file {text}: {kind}; give a .toml file")
        with path.open("rb") as fh:
            raw = fh.read(MAX_SENSOR_FILE_BYTES + 1)
    except OSError as exc:
        raise SimConfigError(f"sensor file {text}: cannot read it ({exc.strerror})") from exc
    if len(raw) > MAX_SENSOR_FILE_BYTES:
        raise SimConfigError(
            f"sensor file {text}: larger than {MAX_SENSOR_FILE_BYTES >> 20} MiB; a sensor "
            "TOML is a few kB"
        )
    return raw
