"""``northfinder sim``: run the simulated instrument on a CAN bus, a serial port or a pty.

Links (choose one):
  -i/-c/-b          any python-can bus, e.g. ``-i socketcan -c vcan0`` or ``-i virtual -c nf``
  --serial PORT     the protocol's serial frames on a serial port (path or pyserial URL)
  --pty             serial frames on a pseudo-terminal the simulator creates (prints its path)
  --slcan-pty       an SLCAN adapter on a pseudo-terminal (prints its path), so a host in another
                    process reaches the simulated CAN node with ``can.Bus(interface="slcan", ...)``

The simulator prints one line per fact a caller needs (``pty PATH``, ``control ADDRESS``,
``truth ...``) on stdout, logs state changes on stderr, and stops cleanly on SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Callable

import can
import can.cli
import numpy as np
import serial

from northfinder.driver.framelog import LOG_SUFFIXES, FrameLog
from northfinder.driver.protocol.constants import CAN_BITRATE_DEFAULT
from northfinder.firmware_sim.control import Controller, ControlServer, parse_address
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.firmware import Firmware, LinkInfo
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.links import (
    CanLink,
    PseudoTerminal,
    SerialLink,
    SerialStream,
    SlcanAdapter,
)
from northfinder.firmware_sim.runner import Link, RealTimeClock, Runner
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.cli.common import (
    add_link_arguments,
    add_sensor_argument,
    add_truth_arguments,
    bus_given,
    can_log_path,
    finite_float,
    positive_float,
    sim_latitude,
)
from northfinder.host.errors import HostConfigError


def control_address(text: str) -> str:
    """argparse type: a control address the simulator may listen on (checked, not opened)."""
    try:
        parse_address(text)
    except SimConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "sim",
        help="run the simulated instrument on a link",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    link = add_link_arguments(p, "serial and pseudo-terminal links")
    link.add_argument("--pty", action="store_true", help="serial frames on a new pseudo-terminal")
    link.add_argument(
        "--slcan-pty", action="store_true", help="an SLCAN adapter on a new pseudo-terminal"
    )
    add_sensor_argument(p)
    add_truth_arguments(p)
    p.add_argument(
        "--warmup",
        type=finite_float,
        default=120.0,
        metavar="SECONDS",
        help="warm-up time (default 120; 0 allowed)",
    )
    p.add_argument(
        "--speed",
        type=positive_float,
        default=1.0,
        help="simulated seconds per wall second (default 1)",
    )
    p.add_argument(
        "--control",
        type=control_address,
        metavar="ADDRESS",
        help="control channel: 127.0.0.1:PORT or [::1]:PORT (0 = any free port) or unix:PATH",
    )
    p.add_argument(
        "--duration", type=positive_float, default=None, help="stop after this many wall seconds"
    )
    p.add_argument(
        "--log",
        type=can_log_path,
        metavar="FILE",
        help="log every frame received and sent to a CAN log; the ending picks python-can's "
        f"format ({', '.join(LOG_SUFFIXES)}); a serial link logs the CAN frames of its messages",
    )
    return p


def _links(args: argparse.Namespace) -> int:
    return sum((bus_given(args), bool(args.serial), args.pty, args.slcan_pty))


def run(args: argparse.Namespace) -> int:
    if _links(args) != 1:
        raise HostConfigError(
            "choose exactly one link: -i/-c (python-can), --serial PORT, --pty or --slcan-pty"
        )
    if args.warmup < 0:
        raise HostConfigError(f"--warmup: must be >= 0 seconds, got {args.warmup}")
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(name)s %(message)s", stream=sys.stderr
    )
    rng = np.random.default_rng(args.seed)
    azimuth = float(rng.uniform(0.0, 360.0)) if args.azimuth is None else args.azimuth
    truth = Truth(azimuth, sim_latitude(args), args.pitch, args.roll)
    spec = load_spec(args.sensor)
    closers: list[Callable[[], None]] = []
    frame_log = None
    if args.log:
        frame_log = FrameLog(args.log)
        closers.append(frame_log.close)
    pty = None
    if args.pty or args.slcan_pty:
        pty = PseudoTerminal()
        closers.append(pty.close)
    if args.serial:
        try:
            port = serial.serial_for_url(args.serial, baudrate=args.baud, timeout=0)
        except (serial.SerialException, ValueError) as exc:
            raise HostConfigError(f"--serial {args.serial}: {exc}") from exc
        closers.append(port.close)
        info = LinkInfo("serial", args.baud)
    elif args.pty:
        info = LinkInfo("serial", args.baud)
    else:
        info = LinkInfo("can", getattr(args, "bitrate", None) or CAN_BITRATE_DEFAULT)
    firmware = Firmware(spec, truth, rng, warmup_s=args.warmup, node_id=args.node_id, link=info)
    link: Link
    if args.serial:
        link = SerialLink(SerialStream(port), firmware, tap=frame_log, node_id=args.node_id)
    elif pty is not None:
        stream = pty.stream
        link = (
            SerialLink(stream, firmware, tap=frame_log, node_id=args.node_id)
            if args.pty
            else CanLink(SlcanAdapter(stream), firmware, args.node_id, tap=frame_log)
        )
    else:
        try:
            bus = can.cli.create_bus_from_namespace(args)
        except (argparse.ArgumentError, can.CanError, OSError, ValueError) as exc:
            raise HostConfigError(f"cannot open the CAN bus: {exc.__cause__ or exc}") from exc
        closers.append(bus.shutdown)
        link = CanLink(bus, firmware, args.node_id, tap=frame_log)
    runner = Runner(firmware, link, RealTimeClock(args.speed))
    server = None
    if args.control:
        server = ControlServer(Controller(runner), args.control).start()
        closers.append(server.close)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration:
        threading.Timer(args.duration, stop.set).start()
    if pty is not None:
        print(f"pty {pty.path}", flush=True)
    if server is not None:
        print(f"control {server.address}", flush=True)
    print(
        f"truth azimuth {truth.azimuth_deg:.6f} latitude {truth.latitude_deg:g} pitch {truth.pitch_deg:g} "
        f"roll {truth.roll_deg:g} sensor {spec.name} warmup {args.warmup:g} speed {args.speed:g}",
        flush=True,
    )
    try:
        runner.run(stop)
    finally:
        for close in reversed(closers):
            close()
        logging.getLogger("northfinder.sim").info("stopped at t=%.3f s", firmware.now)
    return 0
