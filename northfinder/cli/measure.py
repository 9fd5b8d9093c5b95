"""Measuring with a device, shared by ``find`` and ``record``: the device and plan options, opening
the device (or the embedded simulator, :class:`~northfinder.embed.SimulatedInstrument`),
running the plan, and writing the raw windows."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import math
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np

from northfinder.cli.argtypes import bounded_float
from northfinder.cli.exits import note_at_rest, note_ending
from northfinder.cli.files import add_log_rotation, can_log_path, check_log_rotation
from northfinder.cli.links import add_link_arguments, bus_given, open_can_bus
from northfinder.cli.options import (
    add_latitude_argument,
    add_positions_argument,
    add_solver_argument,
    add_truth_arguments,
)
from northfinder.cli.parsers import common_group
from northfinder.cli.progress import progress_mode
from northfinder.cli.simulated import (
    latitude_source,
    load_sensor,
    run_seed,
    sim_latitude,
    sim_truth,
)
from northfinder.driver.device import Device
from northfinder.driver.errors import DriverError
from northfinder.driver.framelog import FrameLog
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError, HostError
from northfinder.host.procedure import (
    MAX_SETTLE_S,
    METHOD_CHOICES,
    ON_GAP_CHOICES,
    WINDOW_RANGE_S,
    FindResult,
    Plan,
    Progress,
    find_north,
)
from northfinder.host.recording import RecordedWindow, Recording, RecordingWriter
from northfinder.host.results import device_identity, utc_now

#: Default warm-up of the embedded simulator, s (the paper's 2 min).
SIM_WARMUP_S = 120.0
#: Longest wait of a run, wall s (warm-up timeout, --link-timeout), and longest simulated warm-up.
MAX_WAIT_S = 86_400.0
#: Reply deadline per attempt the driver accepts, s (below 0.1 s a retry would outrun a reply).
REPLY_TIMEOUT_RANGE_S = (0.1, 60.0)
#: Options that only the embedded simulator uses (refused with a real device, not ignored).
SIM_ONLY = ("speed", "warmup", "sensor", "azimuth", "pitch", "roll", "seed")


def add_device_arguments(p: argparse.ArgumentParser) -> None:
    g = add_link_arguments(p, "serial link and simulation")
    g.add_argument(
        "--link-timeout", type=bounded_float(0.0, MAX_WAIT_S, "s", open_lo=True), default=None,
        metavar="SECONDS",
        help="seconds without a status before the link counts as lost (default 0.3: three "
        "heartbeats; paced --sim: 3)",
    )  # fmt: skip
    g.add_argument(
        "--reply-timeout",
        type=bounded_float(*REPLY_TIMEOUT_RANGE_S, "s"),
        default=None,
        metavar="SECONDS",
        help="seconds to wait for a reply before resending a safe command, "
        f"{REPLY_TIMEOUT_RANGE_S[0]:g} to {REPLY_TIMEOUT_RANGE_S[1]:g} (default 0.25; "
        "paced --sim: 2)",
    )
    g.add_argument(
        "--can-log",
        type=can_log_path,
        metavar="FILE",
        help="log every frame (.log, .asc, .blf, ...: by the ending)",
    )
    add_log_rotation(g, "--can-log")
    g = common_group(p, "embedded simulator (--sim only)")
    g.add_argument(
        "--sim",
        action="store_true",
        help="use the simulated instrument in this process, in virtual time",
    )
    g.add_argument(
        "--speed",
        type=bounded_float(0.0, 10_000.0, open_lo=True),
        default=None,
        metavar="S",
        help="pace --sim at S simulated seconds per wall second (up to 10000)",
    )
    g.add_argument(
        "--warmup",
        type=bounded_float(0.0, MAX_WAIT_S, "s"),
        default=None,
        metavar="SECONDS",
        help=f"--sim warm-up time (default {SIM_WARMUP_S:g})",
    )
    g.add_argument(
        "--sensor",
        default=None,
        metavar="PRESET|FILE",
        help="sensor preset name or TOML file (default: paper-rlg)",
    )
    add_latitude_argument(p, device=True)
    add_truth_arguments(p, latitude=False)


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("plan")
    add_positions_argument(g)
    g.add_argument(
        "--window",
        type=bounded_float(*WINDOW_RANGE_S, "s"),
        default=10.0,
        help=f"seconds per position, {WINDOW_RANGE_S[0]:g} to {WINDOW_RANGE_S[1]:g} (default 10)",
    )
    g.add_argument(
        "--settle",
        type=bounded_float(0.0, MAX_SETTLE_S, "s"),
        default=0.0,
        help=f"seconds after a move, up to {MAX_SETTLE_S:g} (default 0)",
    )
    g.add_argument(
        "--denoise", default="none", choices=list(METHODS), help="denoising method (default none)"
    )
    add_solver_argument(g, METHOD_CHOICES)
    g.add_argument(
        "--on-gap",
        choices=ON_GAP_CHOICES,
        default="remeasure",
        metavar="MODE",
        help="lost ticks: remeasure (default), report or fail",
    )
    g.add_argument(
        "--timeout",
        type=bounded_float(0.0, MAX_WAIT_S, "s", open_lo=True),
        default=600.0,
        help="longest wait for READY after the warm-up, device seconds (default 600)",
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The device and the plan options, as ``find`` and ``record`` take them."""
    add_device_arguments(p)
    add_plan_arguments(p)


def plan_from_args(args: argparse.Namespace) -> Plan:
    return Plan(tuple(args.positions), args.window, args.settle, args.denoise, args.solver)


def check_arguments(args: argparse.Namespace) -> None:
    """Everything about the arguments that can be checked before a device is opened.

    Raises
    ------
    HostConfigError
        Not exactly one device; an embedded-simulator option with a real device (it would be
        ignored); no ``--latitude`` for a real device (never assumed: a wrong latitude gives a
        wrong heading without a word).
    """
    links = sum((bus_given(args), bool(args.serial), bool(args.sim)))
    if links != 1:
        raise HostConfigError(
            "choose exactly one device: -i/-c (python-can), --serial PORT, or --sim"
        )
    check_log_rotation(args.can_log, args.can_log_rotate, "--can-log")
    if not args.sim:
        given = [name for name in SIM_ONLY if getattr(args, name, None) is not None]
        if given:
            raise HostConfigError(
                f"--{given[0]}: applies to the embedded simulator only (--sim), not to a device"
            )
        if args.latitude is None:
            raise HostConfigError(
                "--latitude: give the site's latitude in degrees (north positive); a real "
                "device's latitude is never assumed"
            )


@contextlib.contextmanager
def open_device(
    args: argparse.Namespace, deferred: list[Exception] | None = None
) -> Iterator[tuple[Device, dict[str, Any] | None]]:
    """The device named by the arguments, and the simulated truth when it is simulated.

    With ``deferred``, a CAN log (``--can-log``) that cannot be completed after a successful
    run is added to it instead of raised: the caller reports its result first, then the error.
    """
    check_arguments(args)
    with contextlib.ExitStack() as stack:
        tap = None
        if args.can_log:
            max_bytes, max_seconds = args.can_log_rotate
            tap = FrameLog(args.can_log, max_bytes=max_bytes, max_seconds=max_seconds)
            stack.push(functools.partial(_close_log, tap, deferred))
        if args.sim:
            with embedded_simulator(args, tap) as (device, truth):
                yield device, truth
            return
        with _open_unit(args, tap) as device:
            yield device, None


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


@contextlib.contextmanager
def _open_unit(args: argparse.Namespace, tap: FrameLog | None) -> Iterator[Device]:
    options: dict[str, Any] = {"tap": tap, **device_options(args)}
    if args.serial:
        device = Device.open_serial(args.serial, baudrate=args.baud, **options)
    else:
        bus = open_can_bus(args)
        device = Device.from_bus(bus, node_id=args.node_id, own_bus=True, **options)
    with device, leaving_at_rest(device):
        yield device


@contextlib.contextmanager
def leaving_at_rest(device: Device) -> Iterator[None]:
    """On any exception, Ctrl-C or an ending signal: leave the device at rest now (STOP, STREAM_STOP
    for what this host started) and note on the exception what was done, for its one line."""
    try:
        yield
    except BaseException as exc:
        note_at_rest(exc, device.leave_at_rest())
        raise


def device_options(args: argparse.Namespace) -> dict[str, Any]:
    """Driver options from ``--link-timeout`` and ``--reply-timeout``."""
    options: dict[str, Any] = {}
    if args.link_timeout is not None:
        options["min_supervision_s"] = args.link_timeout
    if args.reply_timeout is not None:
        options["reply_timeout"] = args.reply_timeout
    return options


@contextlib.contextmanager
def embedded_simulator(
    args: argparse.Namespace, tap: FrameLog | None = None
) -> Iterator[tuple[Device, dict[str, Any]]]:
    """A device on the simulated instrument in this process (virtual CAN), and its truth.

    Virtual time by default; paced (``--speed S``) on a thread, with the driver's relaxed
    deadlines since the simulator shares this interpreter.
    """
    from northfinder.embed import RELAXED_DEVICE_OPTIONS, SimulatedInstrument

    seed = run_seed(args)
    rng = np.random.default_rng(seed)
    truth = sim_truth(args, rng)
    paced = args.speed is not None
    sim = SimulatedInstrument(
        load_sensor(args.sensor or "paper-rlg"),
        truth,
        seed=rng,
        speed=args.speed,
        clock=None if paced else "virtual",
        warmup_s=SIM_WARMUP_S if args.warmup is None else args.warmup,
        node_id=args.node_id,
    )
    options = {**(RELAXED_DEVICE_OPTIONS if paced else {}), **device_options(args)}
    if tap is not None and not paced:
        tap.use_clock(sim.clock)  # the log's times are the instrument's, not the CPU's
    with sim, sim.open_device(tap=tap, **options) as device, leaving_at_rest(device):
        try:
            yield device, {**sim.describe(), "seed": seed}
        except DriverError:
            sim.check()  # a simulator that failed is the cause, not the link: say so
            raise


class ProgressBar:
    """Progress of a plan on stderr. On a terminal that reports its width, a tqdm bar in
    wall-clock seconds: it counts the plan's device seconds done, so elapsed and remaining are
    what the user waits (an embedded simulator at ``--speed 100`` finishes 100 times sooner than
    the plan's device time). Elsewhere (a pipe, a log, a terminal of no width) one plain line
    per step (:mod:`northfinder.cli.progress`): ``find: rotate position 2/4``.

    Off when ``enabled`` is False (``--json``, ``--nmea -``).
    """

    def __init__(self, *, enabled: bool = True, stream: Any = None, label: str = "find") -> None:
        self.stream = sys.stderr if stream is None else stream
        self.mode = progress_mode(self.stream, enabled)
        self.enabled = self.mode != "off"
        self.label = label
        self._bar: Any = None
        self._last: tuple[str, int] | None = None

    def __call__(self, p: Progress) -> None:
        if self.mode == "lines":
            if (p.phase, p.position) != self._last:
                self._last = (p.phase, p.position)
                where = f" position {p.position}/{p.positions}" if p.position else ""
                print(f"{self.label}: {p.phase}{where}", file=self.stream, flush=True)
            return
        if self.mode != "bar":
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=None, file=self.stream, leave=False, dynamic_ncols=True,
                bar_format="{desc} {percentage:3.0f}%|{bar}| {elapsed} elapsed, ~{remaining} left",
            )  # fmt: skip
        bar = self._bar
        angle = "---" if p.table_deg is None else f"{p.table_deg:.3f}"
        bar.set_description_str(
            f"{p.phase:<8} position {p.position}/{p.positions} table {angle} deg"
        )
        if p.seconds_left is not None and math.isfinite(p.seconds_left):
            if bar.total is None:
                bar.total = max(p.seconds_left, 1e-9)
            bar.n = max(0.0, min(bar.total, bar.total - p.seconds_left))
        bar.refresh()
        if p.phase == "done":
            self.close()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


@dataclasses.dataclass(frozen=True)
class Measured:
    """What :func:`run_plan` gives: the result, the raw windows and what is needed to solve them
    again (plan, latitude deg, sample rate Hz), and the simulated truth (None for a real unit)."""

    result: FindResult
    windows: list[Any]
    plan: Plan
    latitude_deg: float
    sample_rate_hz: float
    truth: dict[str, Any] | None
    device: dict[str, Any] | None = None
    created_utc: str = ""
    #: Files that could not be written (the recording, the CAN log), after a result was found:
    #: the command reports the result first, then these, and exits 1.
    errors: tuple[Exception, ...] = ()
    #: What was recorded (``record_to``), as written.
    recording: Recording | None = None


def recording_meta(
    plan: Plan,
    latitude_deg: float,
    source: str,
    sample_rate_hz: float,
    created_utc: str,
    device: dict[str, Any] | None,
    truth: dict[str, Any] | None,
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
        meta["truth"] = truth
    return meta


def run_plan(
    args: argparse.Namespace, *, progress: bool = True, record_to: str | None = None
) -> Measured:
    """Open the device, run the plan and solve (``progress``: draw the progress bar).

    With ``record_to``, each window is written to that recording as soon as it is measured
    (:class:`~northfinder.host.recording.RecordingWriter`); an interrupted or failed run keeps
    every complete window, marked ``interrupted``. A write that fails after the result was
    found is returned in :attr:`Measured.errors`, not raised.
    """
    plan = plan_from_args(args)
    check_arguments(args)
    latitude = sim_latitude(args) if args.sim else float(args.latitude)
    created = utc_now()
    source = latitude_source(args, args.sim)
    deferred: list[Exception] = []
    writer: RecordingWriter | None = None
    with open_device(args, deferred) as (device, truth):
        identity = device_identity(
            device.identity,
            simulated=bool(args.sim),
            sensor=None if truth is None else truth.get("sensor"),
        )
        rate = device.sample_rate_hz
        on_window = None
        if record_to is not None:
            meta = recording_meta(plan, latitude, source, rate, created, identity, truth)
            writer = RecordingWriter(record_to, meta)
            w = writer

            def on_window(i: int, window: Any) -> None:
                w.add(RecordedWindow.from_window(window, plan.positions_deg[i]))

        bar = ProgressBar(enabled=progress, label=args.command or "find")
        try:
            clock = device.clock
            result, windows = find_north(
                device,
                plan,
                latitude,
                warmup_timeout_s=args.timeout,
                progress=bar,
                sleep=clock.sleep,
                clock=clock.now,
                latitude_source=source,
                on_window=on_window,
                on_gap=args.on_gap,
            )
        except BaseException as exc:
            if writer is not None:
                note_ending(exc, _close_interrupted(writer))
            raise
        finally:
            bar.close()
            if getattr(args, "verbose", 0):
                print(link_statistics(device), file=sys.stderr, flush=True)
    recording = None
    if writer is not None:
        try:
            writer.close("complete")
        except HostError as exc:
            deferred.insert(0, exc)
        recording = Recording(tuple(writer.windows[: writer.written]), writer.meta)
    return Measured(
        result, windows, plan, latitude, rate, truth, identity, created, tuple(deferred), recording
    )


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
