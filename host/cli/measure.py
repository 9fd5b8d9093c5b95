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
    add_sensor_argument,
    add_truth_arguments,
    angle_list,
    bus_given,
    finite_float,
    positive_float,
    sim_latitude,
)
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import METHOD_CHOICES, FindResult, Plan, Progress, find_north
from northfinder.host.recording import RecordedWindow, Recording

#: Default acceleration of the embedded simulator (simulated seconds per wall second).
SIM_SPEED = 100.0


def add_device_arguments(p: argparse.ArgumentParser) -> None:
    g = add_link_arguments(p, "serial link and simulation")
    g.add_argument(
        "--link-timeout", type=positive_float, default=None, metavar="SECONDS",
        help="seconds without a status before the link counts as lost (default: 3 heartbeat periods, "
        "as protocol.md says; raise it on a slow or busy host)",
    )  # fmt: skip
    g.add_argument(
        "--reply-timeout",
        type=positive_float,
        default=None,
        metavar="SECONDS",
        help="seconds to wait for each reply before resending a safe command (default: the driver's)",
    )
    g.add_argument("--sim", action="store_true", help="use the embedded simulated instrument")
    g.add_argument(
        "--speed",
        type=positive_float,
        default=SIM_SPEED,
        help=f"--sim acceleration (default {SIM_SPEED:g})",
    )
    g.add_argument(
        "--warmup",
        type=finite_float,
        default=120.0,
        metavar="SECONDS",
        help="--sim warm-up time (default 120)",
    )
    add_sensor_argument(p)
    add_truth_arguments(p)


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("plan")
    g.add_argument(
        "--positions",
        type=angle_list,
        default=[0.0, 180.0],
        help="table angles, deg (default 0,180)",
    )
    g.add_argument(
        "--window", type=positive_float, default=10.0, help="seconds per position (default 10)"
    )
    g.add_argument(
        "--settle",
        type=finite_float,
        default=0.0,
        help="extra settle seconds after READY (default 0)",
    )
    g.add_argument(
        "--denoise", default="none", choices=list(METHODS), help="denoising method (default none)"
    )
    g.add_argument("--method", default="auto", choices=METHOD_CHOICES, help="solver (default auto)")
    g.add_argument(
        "--timeout", type=positive_float, default=600.0, help="warm-up timeout, s (default 600)"
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The device and the plan options, as ``find`` and ``record`` take them."""
    add_device_arguments(p)
    add_plan_arguments(p)


def plan_from_args(args: argparse.Namespace) -> Plan:
    return Plan(tuple(args.positions), args.window, args.settle, args.denoise, args.method)


@contextlib.contextmanager
def open_device(args: argparse.Namespace) -> Iterator[tuple[Device, dict[str, Any] | None]]:
    """The device named by the arguments, and the simulated truth when it is simulated."""
    links = sum((bus_given(args), bool(args.serial), bool(args.sim)))
    if links != 1:
        raise HostConfigError(
            "choose exactly one device: -i/-c (python-can), --serial PORT, or --sim"
        )
    if args.sim:
        with embedded_simulator(args) as (device, truth):
            yield device, truth
        return
    options: dict[str, Any] = {}
    if args.link_timeout:
        options["min_supervision_s"] = args.link_timeout
    if args.reply_timeout:
        options["reply_timeout"] = args.reply_timeout
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
    from northfinder.firmware_sim.imu import Truth
    from northfinder.host.embed import RELAXED_DEVICE_OPTIONS, SimulatedInstrument

    if args.warmup < 0:
        raise HostConfigError(f"--warmup: must be >= 0 seconds, got {args.warmup}")
    rng = np.random.default_rng(args.seed)
    azimuth = float(rng.uniform(0.0, 360.0)) if args.azimuth is None else args.azimuth
    truth = Truth(azimuth, sim_latitude(args), args.pitch, args.roll)
    sim = SimulatedInstrument(
        args.sensor,
        truth,
        seed=rng,
        speed=args.speed,
        warmup_s=args.warmup,
        node_id=args.node_id,
    )
    with sim, sim.open_device(**RELAXED_DEVICE_OPTIONS) as device:
        yield device, sim.describe()


class ProgressLine:
    """One updating line on a terminal: phase, position, table angle, seconds left."""

    def __init__(self, stream: Any = None) -> None:
        # The stream of the moment (default stderr), not the one there was at import.
        self.stream = sys.stderr if stream is None else stream
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())

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
    with open_device(args) as (device, truth):
        latitude = sim_latitude(args) if args.sim else args.latitude
        if latitude is None:
            raise HostConfigError(
                "--latitude: give the site's latitude in degrees (north positive)"
            )
        result, windows = find_north(
            device, plan, latitude, warmup_timeout_s=args.timeout, progress=ProgressLine()
        )
        return Measured(result, windows, plan, latitude, device.sample_rate_hz, truth)


def save_recording(path: str, measured: Measured) -> Recording:
    """Write the raw windows of a run with what is needed to solve them again."""
    meta: dict[str, Any] = {
        "latitude_deg": measured.latitude_deg,
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
