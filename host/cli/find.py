"""``northfinder find``: find true north with a device, or with the embedded simulator (``--sim``).

Device links: python-can bus options as python-can's own tools spell them (``-i socketcan -c vcan0``),
or ``--serial PORT``. With ``--sim`` an in-process simulated instrument on python-can's ``virtual``
bus runs accelerated (``--speed``), and its truth is printed beside the result.

The plan: ``--positions`` any table angles (default 0,180), ``--window`` seconds per position,
``--settle`` extra seconds after the device reports READY, ``--denoise`` a method of northfinder.host.denoise,
``--method`` the solver. A progress line shows on a terminal; ``--json`` prints a machine-readable
result; ``--plot FILE`` draws the windows and per-pair azimuths (needs matplotlib).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import sys
import uuid
from collections.abc import Iterator
from typing import Any

import can
import can.cli
import numpy as np

from northfinder.driver.device import Device
from northfinder.host.cli import report
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

#: Default acceleration of the embedded simulator (simulated seconds per wall second).
SIM_SPEED = 100.0
#: The embedded simulator shares this process's interpreter with the driver; on a busy machine a
#: reply can wait for the other thread, so allow more than a real unit's reply deadline.
EMBEDDED_REPLY_TIMEOUT_S = 2.0
EMBEDDED_SUPERVISION_S = 3.0


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


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "find",
        help="find true north",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_device_arguments(p)
    add_plan_arguments(p)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument(
        "--plot", metavar="FILE", help="plot the windows and per-pair azimuths (needs matplotlib)"
    )
    p.add_argument("--record", metavar="FILE", help="also write the raw windows (.csv or .npz)")
    return p


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
    options: dict[str, float] = {}
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
    from northfinder.firmware_sim.firmware import Firmware, LinkInfo
    from northfinder.firmware_sim.imu import Truth
    from northfinder.firmware_sim.links import CanLink
    from northfinder.firmware_sim.runner import BackgroundRunner, RealTimeClock, Runner
    from northfinder.firmware_sim.sensors import load_spec

    if args.warmup < 0:
        raise HostConfigError(f"--warmup: must be >= 0 seconds, got {args.warmup}")
    rng = np.random.default_rng(args.seed)
    azimuth = float(rng.uniform(0.0, 360.0)) if args.azimuth is None else args.azimuth
    truth = Truth(azimuth, sim_latitude(args), args.pitch, args.roll)
    spec = load_spec(args.sensor)
    channel = f"northfinder-sim-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as sim_bus:
        firmware = Firmware(
            spec,
            truth,
            rng,
            warmup_s=args.warmup,
            node_id=args.node_id,
            link=LinkInfo("can", 500_000),
        )
        runner = Runner(
            firmware, CanLink(sim_bus, firmware, args.node_id), RealTimeClock(args.speed)
        )
        with (
            BackgroundRunner(runner),
            Device.from_bus(
                can.Bus(interface="virtual", channel=channel),
                node_id=args.node_id,
                own_bus=True,
                reply_timeout=EMBEDDED_REPLY_TIMEOUT_S,
                min_supervision_s=EMBEDDED_SUPERVISION_S,
            ) as device,
        ):
            yield device, {**dataclasses.asdict(truth), "sensor": spec.name, "speed": args.speed}


class ProgressLine:
    """One updating line on a terminal: phase, position, table angle, seconds left."""

    def __init__(self, stream: Any = sys.stderr) -> None:
        self.stream = stream
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


def run_plan(
    args: argparse.Namespace,
) -> tuple[FindResult, list[Any], Plan, float, int, dict[str, Any] | None]:
    """Open the device, run the plan and solve: result, raw windows, plan, latitude, sample rate
    and (when simulated) the truth. Shared by ``find`` and ``record``."""
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
        return result, windows, plan, latitude, device.sample_rate_hz, truth


def run(args: argparse.Namespace) -> int:
    result, windows, plan, latitude, rate, truth = run_plan(args)
    if args.record:
        from northfinder.host.cli.record import save_recording

        save_recording(args.record, windows, plan, latitude, rate, truth)
    if args.plot:
        report.plot(args.plot, result, windows, plan.denoise)
    print(report.as_json(result, truth) if args.json else report.text(result, truth))
    return 0
