"""The session layer: open a unit (real or simulated) from a :class:`~northfinder.config.LinkConfig`,
run a plan on it, and leave it at rest however the run ends.

The command line (``find``, ``record``), the monitor and the pytest plugin reach a unit through
here, and so can a script, with the same configuration objects::

    import northfinder

    config = northfinder.FindConfig(northfinder.LinkConfig(sim=northfinder.SimConfig(seed=1)))
    measured = northfinder.find(config)
    print(measured.result.azimuth_deg, measured.truth.azimuth_deg)

This module is part of the application layer (it opens the simulator and the driver alike).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import secrets
import weakref
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from northfinder.config import (
    RELAXED_LINK_TIMEOUT_S,
    RELAXED_REPLY_TIMEOUT_S,
    FindConfig,
    LinkConfig,
    SimConfig,
    check_log_rotation,
)
from northfinder.driver.device import Device
from northfinder.driver.device_link import REPLY_TIMEOUT_S
from northfinder.driver.errors import DriverError, LinkError
from northfinder.driver.framelog import FrameLog
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.endings import note_at_rest, note_ending
from northfinder.firmware_sim.imu import Truth
from northfinder.host.errors import HostConfigError, HostError
from northfinder.host.procedure import (
    FindProgress,
    FindResult,
    Plan,
    SpinFind,
    find_north,
    find_north_spin,
)
from northfinder.host.recording import RecordedWindow, Recording, RecordingWriter
from northfinder.host.results import device_identity, utc_now

__all__ = [
    "Measured",
    "SimTruth",
    "SpinMeasured",
    "Unit",
    "check_config",
    "check_link",
    "draw_truth",
    "find",
    "find_spin",
    "latitude_source",
    "link_statistics",
    "open_unit",
    "real_unit",
    "recording_meta",
    "relaxed_device",
    "sensor_spec",
    "simulated_instrument",
    "simulated_unit",
    "site_latitude",
]

#: What the run's seed is drawn below when none is given (short to type again).
FRESH_SEED_BELOW = 2**32


@dataclass(frozen=True)
class SimTruth:
    """What the embedded simulator simulates: where the instrument really stands (the
    simulator's :class:`~northfinder.firmware_sim.imu.Truth`), the sensor's name, the pace
    (simulated s per wall s; None: virtual time) and the run's seed (``--seed`` repeats it)."""

    truth: Truth
    sensor: str
    speed: float | None
    seed: int

    @property
    def azimuth_deg(self) -> float:
        return self.truth.azimuth_deg

    @property
    def latitude_deg(self) -> float:
        return self.truth.latitude_deg

    @property
    def pitch_deg(self) -> float:
        return self.truth.pitch_deg

    @property
    def roll_deg(self) -> float:
        return self.truth.roll_deg

    def as_dict(self) -> dict[str, Any]:
        """As the JSON states it (``find --json``'s ``truth``, a recording's metadata): the
        truth's fields, then ``sensor``, ``speed`` and ``seed``."""
        fields = dataclasses.asdict(self.truth)
        return {**fields, "sensor": self.sensor, "speed": self.speed, "seed": self.seed}

    def __getitem__(self, key: str) -> Any:
        """``truth["azimuth_deg"]``: read as the mapping of version 0.2 (:meth:`as_dict`)."""
        return self.as_dict()[key]

    def get(self, key: str, default: Any = None) -> Any:
        """``truth.get("sensor")``, as the mapping of version 0.2 (:meth:`as_dict`)."""
        return self.as_dict().get(key, default)


@dataclass(frozen=True)
class Unit:
    """An open unit: the device, and for the embedded simulator what it simulates, else None."""

    device: Device
    truth: SimTruth | None = None

    @property
    def simulated(self) -> bool:
        return self.truth is not None


@dataclass(frozen=True)
class Measured:
    """What :func:`find` gives: the result, the raw windows and what is needed to solve them
    again (plan, latitude deg, sample rate Hz), and the simulated truth (None for a real unit)."""

    result: FindResult
    windows: list[Any]
    plan: Plan
    latitude_deg: float
    sample_rate_hz: float
    truth: SimTruth | None
    device: dict[str, Any] | None = None
    created_utc: str = ""
    #: Files that could not be written (the recording, the CAN log), after a result was found:
    #: the command reports the result first, then these, and exits 1.
    errors: tuple[Exception, ...] = ()
    #: What was recorded (``record_to``), as written: its metadata, and its windows when they
    #: were kept (``keep_windows``).
    recording: Recording | None = None
    #: Samples of each window recorded (``record_to``).
    recorded_sizes: tuple[int, ...] = ()


@dataclass(frozen=True)
class SpinMeasured:
    """What :func:`find_spin` gives: the spin's solution and raw window, the latitude it was
    solved at and where that came from, the simulated truth (None for a real unit) and the
    device's identity."""

    found: SpinFind
    latitude_deg: float
    latitude_source: str
    truth: SimTruth | None
    device: dict[str, Any]


# -- checks, once, before a unit is opened ---------------------------------------------------

#: The configurations checked, while they live (by identity: a frozen configuration checked
#: once, as the command line parses it, is not checked again when it is run).
_checked: weakref.WeakValueDictionary[int, Any] = weakref.WeakValueDictionary()


def _check_once(config: Any, check: Callable[[Any], None]) -> None:
    """``check(config)`` unless this very object was checked already."""
    if _checked.get(id(config)) is not config:
        check(config)


def check_link(link: LinkConfig) -> None:
    """Refuse a link configuration that names no unit or more than one.

    Raises
    ------
    HostConfigError
        Not exactly one of a bus, a serial port and the simulator; a log rotation the log
        cannot have.
    """
    if len(link.kinds) != 1:
        raise HostConfigError(
            "choose exactly one device: -i/-c (python-can), --serial PORT, or --sim"
        )
    check_log_rotation(link.can_log, link.can_log_rotate, "--can-log")
    _checked[id(link)] = link


def check_config(config: FindConfig) -> None:
    """Everything about a run that can be checked before the unit is opened.

    Raises
    ------
    HostConfigError
        As :func:`check_link`; no latitude for a real unit (never assumed: a wrong latitude
        gives a wrong heading without a word).
    """
    _check_once(config.link, check_link)
    if config.link.sim is None and config.latitude_deg is None:
        raise HostConfigError(
            "--latitude: give the site's latitude in degrees (north positive); a real "
            "device's latitude is never assumed"
        )
    _checked[id(config)] = config


def site_latitude(config: FindConfig) -> float:
    """The latitude the run solves with (and the simulated truth's), deg."""
    if config.latitude_deg is not None:
        return float(config.latitude_deg)
    if config.link.sim is None:
        raise HostConfigError("a real device's latitude is never assumed: give latitude_deg")
    return DEFAULT_LATITUDE_DEG


def latitude_source(config: FindConfig) -> str:
    """Where the latitude of a run comes from, as the result states it."""
    if config.latitude_deg is not None:
        return "--latitude"
    simulated = config.link.sim is not None
    return f"the simulated truth (default, {DEFAULT_LATITUDE_DEG:g} deg)" if simulated else ""


# -- opening a unit -------------------------------------------------------------------------


@contextlib.contextmanager
def open_unit(
    link: LinkConfig,
    *,
    latitude_deg: float = DEFAULT_LATITUDE_DEG,
    deferred: list[Exception] | None = None,
) -> Iterator[Unit]:
    """Open the unit ``link`` names (the embedded simulator at ``latitude_deg``, or a real one);
    on leaving, by any way, it is left at rest and closed.

    With ``deferred``, a CAN log that cannot be completed after a successful run is added to it
    instead of raised: the caller reports its result first, then the error.
    """
    _check_once(link, check_link)
    with contextlib.ExitStack() as stack:
        tap = None
        if link.can_log:
            max_bytes, max_seconds = link.can_log_rotate
            tap = FrameLog(link.can_log, max_bytes=max_bytes, max_seconds=max_seconds)
            stack.push(functools.partial(_close_log, tap, deferred))
        if link.sim is not None:
            with simulated_unit(link, link.sim, latitude_deg, tap) as unit:
                yield unit
            return
        with real_unit(link, tap) as device:
            yield Unit(device)


def _close_log(log: FrameLog, deferred: list[Exception] | None, *exc_info: Any) -> bool:
    """Close the CAN log as the run's context ends; after a successful run, a log that cannot be
    completed goes to ``deferred`` (the result is reported first)."""
    try:
        log.close()
    except DriverError as exc:
        if deferred is None or exc_info[0] is not None:
            raise
        deferred.append(exc)
    return False


def _deadlines(link: LinkConfig, relaxed: bool) -> tuple[float, float]:
    """The driver's reply deadline and least link supervision, s, for ``link``."""
    reply = RELAXED_REPLY_TIMEOUT_S if relaxed else REPLY_TIMEOUT_S
    supervision = RELAXED_LINK_TIMEOUT_S if relaxed else 0.0  # 0: three heartbeats
    if link.reply_timeout_s is not None:
        reply = link.reply_timeout_s
    if link.link_timeout_s is not None:
        supervision = link.link_timeout_s
    return reply, supervision


@contextlib.contextmanager
def real_unit(link: LinkConfig, tap: FrameLog | None) -> Iterator[Device]:
    reply, supervision = _deadlines(link, relaxed=False)
    if link.serial:
        device = Device.open_serial(
            link.serial, baudrate=link.baud, tap=tap, reply_timeout=reply,
            min_supervision_s=supervision,
        )  # fmt: skip
    else:
        device = Device.from_bus(
            open_bus(link), node_id=link.node_id, own_bus=True, tap=tap, reply_timeout=reply,
            min_supervision_s=supervision,
        )  # fmt: skip
    with device, leaving_at_rest(device):
        yield device


def open_bus(link: LinkConfig) -> Any:
    """The python-can bus of ``link.bus`` (``can.Bus(**link.bus)``).

    Raises
    ------
    HostConfigError
        An interface python-can does not know, or options it refuses (exit status 2).
    LinkError
        The bus exists but cannot be opened (exit status 1).
    """
    import can

    try:
        return can.Bus(single_handle=True, **link.bus)
    except (can.CanError, OSError, ValueError, TypeError) as exc:
        raise bus_error(exc) from exc


def bus_error(cause: BaseException) -> Exception:
    """The error a bus that python-can could not open raises: :class:`LinkError` for a bus that
    exists but cannot be opened now (exit status 1), :class:`HostConfigError` for an interface
    python-can does not know or options it refuses (exit status 2)."""
    import can

    from northfinder.driver.transport import bus_open_hint

    now = isinstance(cause, can.CanError | OSError) and not isinstance(
        cause, can.CanInterfaceNotImplementedError
    )
    return (LinkError if now else HostConfigError)(
        f"cannot open the CAN bus: {cause}{bus_open_hint(cause)}"
    )


@contextlib.contextmanager
def leaving_at_rest(device: Device) -> Iterator[None]:
    """On any exception, Ctrl-C or an ending signal: leave the device at rest now (STOP, STREAM_STOP
    for what this host started) and note on the exception what was done, for its one line."""

    try:
        yield
    except BaseException as exc:
        note_at_rest(exc, device.leave_at_rest())
        raise


def draw_truth(sim: SimConfig, latitude_deg: float) -> tuple[Truth, int, np.random.Generator]:
    """The truth of a simulated run, its seed (``sim.seed``, or a fresh one drawn now) and the
    generator of that seed, which drew the azimuth when none is given and then drives the
    sensor noise.

    Raises
    ------
    SimConfigError
        A field the simulated base cannot take.
    """
    seed = secrets.randbelow(FRESH_SEED_BELOW) if sim.seed is None else sim.seed
    rng = np.random.default_rng(seed)
    azimuth = float(rng.uniform(0.0, 360.0)) if sim.azimuth_deg is None else sim.azimuth_deg
    return Truth(azimuth, latitude_deg, sim.pitch_deg, sim.roll_deg), seed, rng


def sensor_spec(sim: SimConfig) -> Any:
    """The sensor of ``sim`` (a preset or a TOML file) that the simulated device can run
    (:func:`~northfinder.firmware_sim.firmware.check_device_spec`).

    Raises
    ------
    SimConfigError
        An unknown preset, or a field, its value and the bound it exceeds.
    """
    from northfinder.firmware_sim.firmware import check_device_spec
    from northfinder.firmware_sim.sensors import load_spec

    return check_device_spec(load_spec(sim.sensor))


def simulated_instrument(
    link: LinkConfig, sim: SimConfig, latitude_deg: float = DEFAULT_LATITUDE_DEG
) -> tuple[Any, SimTruth]:
    """The embedded simulator of ``sim`` (not started: enter it), on virtual CAN as node
    ``link.node_id``, in virtual time or paced at ``sim.speed``; and its truth."""
    from northfinder.embed import SimulatedInstrument

    truth, seed, rng = draw_truth(sim, latitude_deg)
    paced = sim.speed is not None
    instrument = SimulatedInstrument(
        sensor_spec(sim), truth, seed=rng, speed=sim.speed,
        clock=None if paced else "virtual", warmup_s=sim.warmup_s, node_id=link.node_id,
    )  # fmt: skip
    return instrument, SimTruth(truth, instrument.spec.name, instrument.speed, seed)


@contextlib.contextmanager
def simulated_unit(
    link: LinkConfig, sim: SimConfig, latitude_deg: float, tap: FrameLog | None
) -> Iterator[Unit]:
    """A device on the simulated instrument in this process (virtual CAN), and its truth.

    Virtual time by default; paced (``speed``) on a thread, with the driver's relaxed
    deadlines since the simulator shares this interpreter.
    """
    instrument, facts = simulated_instrument(link, sim, latitude_deg)
    paced = sim.speed is not None
    reply, supervision = _deadlines(link, relaxed=paced)
    if tap is not None and not paced:
        tap.use_clock(instrument.clock)  # the log's times are the instrument's, not the CPU's
    with (
        instrument,
        instrument.open_device(
            tap=tap, reply_timeout=reply, min_supervision_s=supervision
        ) as device,
        leaving_at_rest(device),
    ):
        try:
            yield Unit(device, facts)
        except DriverError:
            instrument.check()  # a simulator that failed is the cause, not the link: say so
            raise


def relaxed_device(instrument: Any) -> Device:
    """A device on a started :class:`~northfinder.embed.SimulatedInstrument` with the driver's
    relaxed deadlines (:data:`~northfinder.config.RELAXED_REPLY_TIMEOUT_S`,
    :data:`~northfinder.config.RELAXED_LINK_TIMEOUT_S`): the simulator shares this
    interpreter, as in the pytest plugin's ``northfinder_device``."""
    device: Device = instrument.open_device(
        reply_timeout=RELAXED_REPLY_TIMEOUT_S, min_supervision_s=RELAXED_LINK_TIMEOUT_S
    )
    return device


# -- running a plan -------------------------------------------------------------------------


def recording_meta(
    plan: Plan,
    latitude_deg: float,
    source: str,
    sample_rate_hz: float,
    created_utc: str,
    device: dict[str, Any] | None,
    truth: SimTruth | None,
) -> dict[str, Any]:
    """The metadata of a recording: what is needed to solve it again, the device's identity
    and the UTC time the run began."""
    meta: dict[str, Any] = {
        "latitude_deg": latitude_deg,
        "latitude_source": source,
        "sample_rate_hz": sample_rate_hz,
        "plan": dataclasses.asdict(plan),
        "created_utc": created_utc or utc_now(),
        "device": device,
    }
    if truth is not None:
        meta["truth"] = truth.as_dict()
    return meta


def find(
    config: FindConfig,
    *,
    progress: Callable[[FindProgress], None] | None = None,
    record_to: str | None = None,
    on_link_statistics: Callable[[str], None] | None = None,
    keep_windows: bool = True,
) -> Measured:
    """Check the run (:func:`check_config`, unless this very configuration was checked, as the
    command line checks it as it parses), open the unit, run the plan, solve, and leave the
    unit at rest.

    Parameters
    ----------
    config : FindConfig
        The run (its ``spin`` is not taken here).
    progress : callable, optional
        Called with a :class:`~northfinder.host.procedure.FindProgress` at every phase.
    record_to : str, optional
        Write each window to this recording (.csv, .npz) as soon as it is measured
        (:class:`~northfinder.host.recording.RecordingWriter`); an interrupted or failed run
        keeps every complete window, marked ``interrupted``. A write that fails after the
        result was found is returned in :attr:`Measured.errors`, not raised.
    on_link_statistics : callable, optional
        Called with the link's statistics (:func:`link_statistics`) as the run ends.
    keep_windows : bool
        Keep the raw windows (:attr:`Measured.windows`, and the recording's). False: each
        window is written, summarised and dropped, so that a run of hours holds one window's
        samples at a time (:attr:`Measured.windows` is then empty).
    """
    _check_once(config, check_config)
    latitude, source, created = site_latitude(config), latitude_source(config), utc_now()
    deferred: list[Exception] = []
    with open_unit(config.link, latitude_deg=latitude, deferred=deferred) as unit:
        device, truth = unit.device, unit.truth
        identity = device_identity(
            device.identity,
            simulated=unit.simulated,
            sensor=None if truth is None else truth.sensor,
        )
        rate = device.sample_rate_hz
        writer = None
        if record_to is not None:
            meta = recording_meta(config.plan, latitude, source, rate, created, identity, truth)
            writer = RecordingWriter(record_to, meta, keep_windows=keep_windows)
        try:
            result, windows = find_north(
                device, config.plan, latitude, warmup_timeout_s=config.ready_timeout_s,
                progress=progress, latitude_source=source, on_gap=config.on_gap,
                keep_windows=keep_windows,
                on_window=None if writer is None else functools.partial(_write, writer, config.plan),
            )  # fmt: skip
        except BaseException as exc:
            if writer is not None:
                note_ending(exc, _close_interrupted(writer))
            raise
        finally:
            if on_link_statistics is not None:
                on_link_statistics(link_statistics(device))
    recording = None if writer is None else _close_complete(writer, deferred)
    return Measured(
        result=result, windows=windows, plan=config.plan, latitude_deg=latitude,
        sample_rate_hz=rate, truth=truth, device=identity, created_utc=created,
        errors=tuple(deferred), recording=recording,
        recorded_sizes=() if writer is None else tuple(writer.sizes[: writer.written]),
    )  # fmt: skip


def find_spin(
    config: FindConfig,
    *,
    progress: Callable[[FindProgress], None] | None = None,
    on_ending: Callable[[BaseException, SpinMeasured], str] | None = None,
) -> SpinMeasured:
    """Open the unit, spin (``config.spin``), solve, and leave the unit at rest.

    ``on_ending`` is called when the spin ends early (an error, an interruption) with the
    exception and what is known of the run (its ``found`` None); the clause it returns (what it
    kept) is noted on the exception for its one line.
    """
    spin = config.spin
    if spin is None:
        raise HostConfigError("find_spin needs a spin (FindConfig.spin)")
    _check_once(config, check_config)
    latitude, source = site_latitude(config), latitude_source(config)
    with open_unit(config.link, latitude_deg=latitude) as unit:
        device, truth = unit.device, unit.truth
        identity = device_identity(
            device.identity,
            simulated=unit.simulated,
            sensor=None if truth is None else truth.sensor,
        )
        try:
            found = find_north_spin(
                device, spin.rate_dps, spin.seconds, latitude, drift=spin.drift,
                warmup_timeout_s=config.ready_timeout_s, latitude_source=source,
                progress=progress,
            )  # fmt: skip
        except BaseException as exc:
            if on_ending is not None:
                known = SpinMeasured(None, latitude, source, truth, identity)  # type: ignore[arg-type]
                note_ending(exc, on_ending(exc, known))
            raise
    return SpinMeasured(found, latitude, source, truth, identity)


def _write(writer: RecordingWriter, plan: Plan, i: int, window: Any) -> None:
    writer.add(RecordedWindow.from_window(window, plan.positions_deg[i]))


def _close_complete(writer: RecordingWriter, deferred: list[Exception]) -> Recording:
    """Close a recording whose run finished; a failure goes first in ``deferred``."""
    try:
        writer.close("complete")
    except HostError as exc:
        deferred.insert(0, exc)
    return Recording(tuple(writer.windows[: writer.written]), writer.meta)


def _close_interrupted(writer: RecordingWriter) -> str:
    """Close a recording whose run did not finish; the clause that says what it keeps."""
    try:
        writer.close("interrupted")
    except HostError as exc:
        return f"the recording is incomplete: {exc}"
    if not writer.written:
        left = f" ({writer.path} left as it was)" if writer.replaces else ""
        return f"no complete window: nothing written{left}"
    planned = len(writer.meta["plan"]["positions_deg"])
    return f"kept {writer.written} of {planned} windows in {writer.where}, marked interrupted"


def link_statistics(device: Device) -> str:
    """``-v``'s line about the link: what the driver counted, and what the device counted in
    its last status (malformed frames it received, frames it dropped, commands it rejected)."""
    line = f"link: {device.stats().summary()}"
    status = device.last_status
    if status is not None:
        line += (
            f"; the device counted {status.rx_malformed} malformed, {status.tx_dropped} dropped, "
            f"{status.cmd_rejected} rejected"
        )
    return line
