"""Measuring with a device, shared by ``find`` and ``record``: the device and plan options, opening
the device (or the embedded simulator, :class:`~northfinder.host.embed.SimulatedInstrument`),
running the plan, and writing the raw windows."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import sys
from collections.abc import Iterator
from typing import Any

import can
import can.cli
import numpy as np

from northfinder.driver.device import Device
from northfinder.host.cli.common import (
    add_link_arguments,
    add_truth_arguments,
    angle_list,
    bounded_float,
    bus_given,
    latitude_source,
    load_sensor,
    sim_latitude,
    sim_truth,
)
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import (
    MAX_SETTLE_S,
    METHOD_CHOICES,
    WINDOW_RANGE_S,
    FindResult,
    Plan,
    Progress,
    find_north,
)
from northfinder.host.recording import RecordedWindow, Recording

#: Default acceleration of the embedded simulator (simulated seconds per wall second).
SIM_SPEED = 100.0
#: Default warm-up of the embedded simulator, s (the paper's 2 min).
SIM_WARMUP_S = 120.0
#: The default plan: each position twice, in the symmetric order 0, 180, 180, 0. Opposite
#: positions give the most heading per second (notes 4); the symmetric order cancels a linear
#: drift; and the two redundant windows let the solver test the windows against their noise, so
#: a bias step or drift between windows is flagged instead of giving a silently wrong heading
#: (a two-position plan cannot check itself). README, "Finding north", says more.
DEFAULT_POSITIONS_DEG = (0.0, 180.0, 180.0, 0.0)
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
        help="seconds without a status before the link counts as lost (default: 3 heartbeat periods, "
        "as protocol.md says; raise it on a slow or busy host; with --sim too)",
    )  # fmt: skip
    g.add_argument(
        "--reply-timeout",
        type=bounded_float(*REPLY_TIMEOUT_RANGE_S, "s"),
        default=None,
        metavar="SECONDS",
        help="seconds to wait for each reply before resending a safe command, "
        f"{REPLY_TIMEOUT_RANGE_S[0]:g} to {REPLY_TIMEOUT_RANGE_S[1]:g} (default: the driver's "
        "0.25; with --sim 2, for a simulator sharing this process; given, it applies to --sim too)",
    )
    g = p.add_argument_group("embedded simulator (--sim only)")
    g.add_argument("--sim", action="store_true", help="use the embedded simulated instrument")
    g.add_argument(
        "--speed",
        type=bounded_float(0.0, 10_000.0, open_lo=True),
        default=None,
        help=f"simulated seconds per wall second, up to 10000 (default {SIM_SPEED:g})",
    )
    g.add_argument(
        "--warmup",
        type=bounded_float(0.0, MAX_WAIT_S, "s"),
        default=None,
        metavar="SECONDS",
        help=f"warm-up time (default {SIM_WARMUP_S:g})",
    )
    p.add_argument(
        "--sensor",
        default=None,
        metavar="PRESET|FILE",
        help="sensor preset name or TOML file of the simulated instrument (default: paper-rlg)",
    )
    add_truth_arguments(p)


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("plan")
    g.add_argument(
        "--positions",
        type=angle_list,
        default=list(DEFAULT_POSITIONS_DEG),
        help="table angles, deg (default 0,180,180,0: redundant, so the result is checked; "
        "0,180 is the shortest plan, unchecked)",
    )
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
        help=f"settle seconds from the end of a move to the window, up to {MAX_SETTLE_S:g} "
        "(default 0: the device's own)",
    )
    g.add_argument(
        "--denoise", default="none", choices=list(METHODS), help="denoising method (default none)"
    )
    g.add_argument("--method", default="auto", choices=METHOD_CHOICES, help="solver (default auto)")
    g.add_argument(
        "--timeout",
        type=bounded_float(0.0, MAX_WAIT_S, "s", open_lo=True),
        default=600.0,
        help="warm-up timeout, wall s (default 600)",
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The device and the plan options, as ``find`` and ``record`` take them."""
    add_device_arguments(p)
    add_plan_arguments(p)


def plan_from_args(args: argparse.Namespace) -> Plan:
    return Plan(tuple(args.positions), args.window, args.settle, args.denoise, args.method)


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


def device_options(args: argparse.Namespace) -> dict[str, Any]:
    """Driver options given on the command line (``--link-timeout``, ``--reply-timeout``)."""
    options: dict[str, Any] = {}
    if args.link_timeout is not None:
        options["min_supervision_s"] = args.link_timeout
    if args.reply_timeout is not None:
        options["reply_timeout"] = args.reply_timeout
    return options


@contextlib.contextmanager
def open_device(args: argparse.Namespace) -> Iterator[tuple[Device, dict[str, Any] | None]]:
    """The device named by the arguments, and the simulated truth when it is simulated."""
    check_arguments(args)
    if args.sim:
        with embedded_simulator(args) as (device, truth):
            yield device, truth
        return
    options = device_options(args)
    if args.serial:
        device = Device.open_serial(args.serial, baudrate=args.baud, **options)
    else:
        try:
            bus = can.cli.create_bus_from_namespace(args)
        except (argparse.ArgumentError, can.CanError, OSError, ValueError) as exc:
            raise HostConfigError(f"cannot open the CAN bus: {exc.__cause__ or exc}") from exc
        device = Device.from_bus(bus, node_id=args.node_id, own_bus=True, **options)
    with device:
        yield device, None


@contextlib.contextmanager
def embedded_simulator(args: argparse.Namespace) -> Iterator[tuple[Device, dict[str, Any]]]:
    """A device on the simulated instrument in this process (virtual CAN), and its truth."""
    from northfinder.host.embed import RELAXED_DEVICE_OPTIONS, SimulatedInstrument

    rng = np.random.default_rng(args.seed)
    truth = sim_truth(args, rng)
    sim = SimulatedInstrument(
        load_sensor(args.sensor or "paper-rlg"),
        truth,
        seed=rng,
        speed=SIM_SPEED if args.speed is None else args.speed,
        warmup_s=SIM_WARMUP_S if args.warmup is None else args.warmup,
        node_id=args.node_id,
    )
    options = {**RELAXED_DEVICE_OPTIONS, **device_options(args)}
    with sim, sim.open_device(**options) as device:
        yield device, sim.describe()


class ProgressLine:
    """One updating line on a terminal: phase, position, table angle, seconds left."""

    def __init__(self, stream: Any = None) -> None:
        self.stream = sys.stderr if stream is None else stream  # the stderr of now, not of import
        self.enabled = bool(getattr(stream, "isatty", lambda: False)())

    def __call__(self, p: Progress) -> None:
        if not self.enabled:
            return
        angle = "   ---   " if p.table_deg is None else f"{p.table_deg:9.4f}"
        left = (
            ""
            if p.seconds_left is None or not math.isfinite(p.seconds_left)
            else f"  ~{p.seconds_left:5.0f} s left"
        )
        self.stream.write(
            f"\r{p.phase:<8} position {p.position}/{p.positions}  table {angle} deg{left}   "
        )
        self.stream.flush()
        if p.phase == "done":
            self.stream.write("\n")


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


def run_plan(args: argparse.Namespace) -> Measured:
    """Open the device, run the plan and solve."""
    plan = plan_from_args(args)
    check_arguments(args)
    latitude = sim_latitude(args) if args.sim else float(args.latitude)
    with open_device(args) as (device, truth):
        result, windows = find_north(
            device, plan, latitude, warmup_timeout_s=args.timeout, progress=ProgressLine(),
            latitude_source=latitude_source(args, args.sim),
        )  # fmt: skip
        return Measured(result, windows, plan, latitude, device.sample_rate_hz, truth)


def save_recording(path: str, measured: Measured) -> Recording:
    """Write the raw windows of a run with what is needed to solve them again."""
    meta: dict[str, Any] = {
        "latitude_deg": measured.latitude_deg,
        "latitude_source": measured.result.latitude_source,
        "sample_rate_hz": measured.sample_rate_hz,
        "plan": dataclasses.asdict(measured.plan),
    }
    if measured.truth is not None:
        meta["truth"] = measured.truth
    recorded = tuple(
        RecordedWindow.from_window(w, p)
        for w, p in zip(measured.windows, measured.plan.positions_deg, strict=True)
    )
    recording = Recording(recorded, meta)
    recording.save(path)
    return recording
