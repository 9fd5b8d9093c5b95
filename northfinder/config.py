"""The configuration of a run, typed: what the command line parses once and a script builds the
same way (as python-can's ``can.Bus(**config)`` takes the same keys from a script as from its
command line)::

    import northfinder

    config = northfinder.FindConfig(
        northfinder.LinkConfig(sim=northfinder.SimConfig(seed=1, warmup_s=0.0)),
        plan=northfinder.Plan((0.0, 180.0), 10.0),
    )
    measured = northfinder.find(config)     # what ``northfinder find --sim --seed 1 ...`` runs

Each default is written once, in the layer that owns it, and read from there (by the command
line's help too): the warm-up and the latitude of a simulation in
:mod:`northfinder.driver.protocol.units`, the sensor in :mod:`northfinder.firmware_sim.sensors`,
the driver's deadlines in :mod:`northfinder.driver.device_link`, the plan's in
:mod:`northfinder.host.plan` and the procedure's in :mod:`northfinder.host.procedure`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from northfinder.driver.errors import ArgumentError
from northfinder.driver.protocol.constants import NODE_ID_DEFAULT, SERIAL_BAUD_DEFAULT
from northfinder.driver.protocol.units import DEFAULT_WARMUP_S
from northfinder.firmware_sim.sensors import DEFAULT_SENSOR
from northfinder.host.errors import HostConfigError
from northfinder.host.nmea import NMEA_BAUD
from northfinder.host.plan import DEFAULT_POSITIONS_DEG, Plan
from northfinder.host.procedure import DEFAULT_ON_GAP, READY_TIMEOUT_S

__all__ = [
    "BUS_KEYS",
    "DEFAULT_PLAN",
    "RELAXED_LINK_TIMEOUT_S",
    "RELAXED_REPLY_TIMEOUT_S",
    "FindConfig",
    "LinkConfig",
    "NmeaConfig",
    "OutputConfig",
    "SimConfig",
    "SpinConfig",
    "default_of",
]

#: The plan a run measures when none is given: the default positions, no settling beyond the
#: device's own (0 s, stated in a recording's plan), and :class:`Plan`'s own defaults for the
#: window, denoising and solver.
DEFAULT_PLAN = Plan(tuple(DEFAULT_POSITIONS_DEG), settle_s=0.0)

#: Deadlines of the driver for a simulator paced on a thread of the same interpreter on a busy
#: machine (a reply can wait for the other thread): reply deadline and link supervision, s.
RELAXED_REPLY_TIMEOUT_S = 2.0
RELAXED_LINK_TIMEOUT_S = 3.0

#: python-can's bus keywords the command line's ``-i/-c/-b ...`` options give (``bus_kwargs``
#: is merged into them), as ``can.cli.create_bus_from_namespace`` reads them.
BUS_KEYS = ("interface", "channel", "bitrate", "fd", "data_bitrate", "can_filters", "timing")


def default_of(cls: type, name: str) -> Any:
    """The default of the field ``name`` of the dataclass ``cls`` (for help texts)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    raise KeyError(f"{cls.__name__}.{name} has no default")


@dataclass(frozen=True)
class SimConfig:
    """The simulated instrument (the embedded simulator of ``--sim``) and its truth.

    Attributes
    ----------
    sensor : str
        A sensor preset name or a TOML file.
    seed : int or None
        Seed of the run (the truth's azimuth when drawn, then the sensor noise); None: a fresh
        one, drawn when the unit is opened and reported with the truth.
    speed : float or None
        Paced at this many simulated seconds per wall second; None: virtual time (the same
        result for a seed whatever the machine's load).
    warmup_s : float
        The instrument's warm-up, simulated s.
    azimuth_deg : float or None
        Where the instrument really points, deg; None: drawn from the seed.
    pitch_deg, roll_deg : float
        The simulated base's tilt, deg. The truth's latitude is the run's latitude
        (:attr:`FindConfig.latitude_deg`).
    """

    sensor: str = DEFAULT_SENSOR
    seed: int | None = None
    speed: float | None = None
    warmup_s: float = DEFAULT_WARMUP_S
    azimuth_deg: float | None = None
    pitch_deg: float = 0.0
    roll_deg: float = 0.0


@dataclass(frozen=True)
class LinkConfig:
    """Which unit, and how the driver speaks to it: exactly one of a python-can bus
    (``bus``: the keywords of ``can.Bus``), a serial port (``serial``) or the embedded
    simulator (``sim``).

    Attributes
    ----------
    bus : dict
        ``can.Bus(**bus)`` keywords (``interface``, ``channel``, ``bitrate``, ...); empty: no bus.
    serial : str or None
        Serial port path or pyserial URL.
    baud : int
        Serial baud rate.
    node_id : int
        CAN node id of the unit.
    sim : SimConfig or None
        The embedded simulator instead of a unit.
    link_timeout_s : float or None
        Seconds without a status before the link counts as lost; None: the driver's default
        (the paced simulator's relaxed one).
    reply_timeout_s : float or None
        Seconds to wait for a reply before resending a safe command; None: as above.
    can_log : str or None
        Log every frame to this CAN log (python-can's format by the ending).
    can_log_rotate : (int, float)
        Rotate that log at this size (bytes) or age (s); 0: never.
    """

    bus: Mapping[str, Any] = field(default_factory=dict)
    serial: str | None = None
    baud: int = SERIAL_BAUD_DEFAULT
    node_id: int = NODE_ID_DEFAULT
    sim: SimConfig | None = None
    link_timeout_s: float | None = None
    reply_timeout_s: float | None = None
    can_log: str | None = None
    can_log_rotate: tuple[int, float] = (0, 0.0)

    @property
    def kinds(self) -> tuple[str, ...]:
        """The links given, of ``can``, ``serial`` and ``sim`` (a unit needs exactly one)."""
        given = (
            ("can", "interface" in self.bus or "channel" in self.bus),
            ("serial", bool(self.serial)),
            ("sim", self.sim is not None),
        )
        return tuple(name for name, yes in given if yes)


#: Default spin time: the fewest whole turns that last at least this long, s.
DEFAULT_SPIN_MIN_S = 60.0


@dataclass(frozen=True)
class SpinConfig:
    """A spin instead of the stop-and-go plan (``find --spin RATE_DPS``): the table turns at
    ``rate_dps`` for ``spin_s`` seconds (None: the fewest whole turns lasting at least
    :data:`DEFAULT_SPIN_MIN_S`), and the fit takes a gyro drift too with ``drift``."""

    rate_dps: float
    spin_s: float | None = None
    drift: bool = False

    @property
    def seconds(self) -> float:
        """The spin's duration, s."""
        if self.spin_s is not None:
            return float(self.spin_s)
        turn = 360.0 / abs(self.rate_dps)
        return math.ceil(DEFAULT_SPIN_MIN_S / turn - 1e-9) * turn


@dataclass(frozen=True)
class NmeaConfig:
    """The heading sent as NMEA 0183 (``--nmea TARGET`` and its options)."""

    target: str
    rate_hz: float = 1.0
    count: int = 1
    baud: int = NMEA_BAUD
    max_sigma_deg: float = 1.0


@dataclass(frozen=True)
class OutputConfig:
    """What the command line writes besides the result: JSON instead of text, a plot, the raw
    windows, NMEA sentences, the link statistics (``verbose``)."""

    json: bool = False
    plot: str | None = None
    record: str | None = None
    nmea: NmeaConfig | None = None
    verbose: int = 0


@dataclass(frozen=True)
class FindConfig:
    """A north-finding run: the unit, what it measures and where its results go.

    Attributes
    ----------
    link : LinkConfig
        The unit (or the embedded simulator).
    plan : Plan
        The stop-and-go plan.
    spin : SpinConfig or None
        A spin instead of the plan (``find --spin``).
    latitude_deg : float or None
        The site's latitude, deg north positive: required with a unit (never assumed); with the
        simulator also the truth's (None: the simulation's default).
    on_gap : str
        A window with missing sample ticks: ``remeasure``, ``report`` or ``fail``.
    ready_timeout_s : float
        Longest wait for READY after the warm-up, device s.
    output : OutputConfig
        What the command line writes.
    """

    link: LinkConfig
    plan: Plan = DEFAULT_PLAN
    spin: SpinConfig | None = None
    latitude_deg: float | None = None
    on_gap: str = DEFAULT_ON_GAP
    ready_timeout_s: float = READY_TIMEOUT_S
    output: OutputConfig = OutputConfig()


def check_log_rotation(path: str | None, limits: tuple[int, float], option: str) -> None:
    """Refuse, before any work, a rotation the log cannot have: no log, a format python-can
    does not rotate, parts of an earlier rotated log in the way (they would be mixed with the
    new ones)."""
    from northfinder.driver.framelog import check_rotation, log_parts

    max_bytes, max_seconds = limits
    if not (max_bytes or max_seconds):
        return
    if path is None:
        raise HostConfigError(f"{option}-rotate: rotates a log; give {option} FILE")
    try:
        check_rotation(path, max_bytes, max_seconds)
    except ArgumentError as exc:
        raise HostConfigError(f"{option} {exc}") from None
    old = log_parts(path)
    if old:
        raise HostConfigError(
            f"{option} {path}: {len(old)} part(s) of an earlier rotated log are in the way "
            f"({old[0].name} ...); move them or choose another name"
        )
