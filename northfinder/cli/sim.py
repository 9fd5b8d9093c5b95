"""``northfinder sim``: run the simulated instrument on a CAN bus, a serial port or a pty.

One link: python-can bus options (``-i socketcan -c vcan0``), ``--serial PORT``, ``--pty`` or
``--slcan-pty`` (a pseudo-terminal it creates). It prints ``pty PATH``, ``control ADDRESS`` and
``truth ...`` lines on stdout and stops cleanly on SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

from northfinder import session
from northfinder.cli.argtypes import bounded_float, bounded_int
from northfinder.cli.files import add_log_rotation, can_log_path
from northfinder.cli.links import add_link_arguments, bus_given, open_can_bus, open_serial_option
from northfinder.cli.options import add_sensor_argument, add_truth_arguments
from northfinder.cli.simulated import simulated
from northfinder.config import check_log_rotation
from northfinder.driver.framelog import LOG_SUFFIXES, FrameLog
from northfinder.driver.protocol.constants import CAN_BITRATE_DEFAULT
from northfinder.firmware_sim.adapters import (
    CanLink,
    PseudoTerminal,
    SerialLink,
    SerialStream,
    SlcanAdapter,
)
from northfinder.firmware_sim.control import Controller, ControlServer, parse_address
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.firmware import Firmware, LinkInfo
from northfinder.firmware_sim.runner import Link, RealTimeClock, Runner
from northfinder.firmware_sim.sender import Capture, CaptureBus, CaptureStream, ProcessSender
from northfinder.host.errors import HostConfigError

#: Longest ``--warmup``, s, and ``--duration``, wall s.
MAX_WAIT_S = 86_400.0
MAX_DURATION_S = 365 * 86_400.0


def control_address(text: str) -> str:
    """argparse type: a control address the simulator may listen on (checked, not opened)."""
    try:
        parse_address(text)
    except SimConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_arguments(p: argparse.ArgumentParser) -> None:
    link = add_link_arguments(p, "serial and pseudo-terminal links")
    link.add_argument("--pty", action="store_true", help="serial frames on a new pseudo-terminal")
    link.add_argument(
        "--slcan-pty", action="store_true", help="an SLCAN adapter on a new pseudo-terminal"
    )
    add_sensor_argument(p)
    add_truth_arguments(p)
    p.add_argument(
        "--warmup",
        type=bounded_float(0.0, MAX_WAIT_S, "s"),
        default=120.0,
        metavar="SECONDS",
        help=f"warm-up time, 0 to {MAX_WAIT_S:g} (default 120)",
    )
    p.add_argument(
        "--speed",
        type=bounded_float(0.0, 10_000.0, open_lo=True),
        default=1.0,
        help="simulated seconds per wall second, up to 10000 (default 1)",
    )
    p.add_argument(
        "--paced-sender",
        action="store_true",
        help="send what the simulator computes ahead from a process of its own (a pty, a serial "
        "port, SocketCAN; a thread on other python-can buses; see protocol.md 12)",
    )
    p.add_argument(
        "--sender-priority",
        type=bounded_int(0, 99),
        default=ProcessSender.PRIORITY,
        metavar="N",
        help="SCHED_FIFO priority of the sender process where the system allows it, 0 for the "
        f"ordinary class (default {ProcessSender.PRIORITY})",
    )
    p.add_argument(
        "--control",
        type=control_address,
        metavar="ADDRESS",
        help="control channel: 127.0.0.1:PORT, [::1]:PORT or unix:PATH; 0 or HOST:0: any free port "
        "(printed as control ADDRESS)",
    )
    p.add_argument(
        "--duration",
        type=bounded_float(0.0, MAX_DURATION_S, "s", open_lo=True),
        default=None,
        help=f"stop after this many wall seconds (at most {MAX_DURATION_S:g}: a year)",
    )
    p.add_argument(
        "--log",
        type=can_log_path,
        metavar="FILE",
        help=f"log every frame to a CAN log, its format by the ending ({', '.join(LOG_SUFFIXES)})",
    )
    add_log_rotation(p, "--log")


def _socketcan_fd(bus: Any) -> int | None:
    """The file descriptor of a python-can SocketCAN bus's socket (None for other buses)."""
    try:
        from can.interfaces.socketcan.socketcan import SocketcanBus
    except ImportError:  # pragma: no cover - not Linux
        return None
    sock = getattr(bus, "socket", None)
    return sock.fileno() if isinstance(bus, SocketcanBus) and sock is not None else None


def _links(args: argparse.Namespace) -> int:
    return sum((bus_given(args), bool(args.serial), args.pty, args.slcan_pty))


def run(args: argparse.Namespace) -> int:
    if _links(args) != 1:
        raise HostConfigError(
            "choose exactly one link: -i/-c (python-can), --serial PORT, --pty or --slcan-pty"
        )
    check_log_rotation(args.log, args.log_rotate, "--log")
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(name)s %(message)s", stream=sys.stderr
    )
    sim, latitude = simulated(args)
    truth, seed, rng = session.draw_truth(sim, latitude)
    spec = session.sensor_spec(sim)
    closers: list[Callable[[], None]] = []
    frame_log = None
    if args.log:
        max_bytes, max_seconds = args.log_rotate
        frame_log = FrameLog(args.log, max_bytes=max_bytes, max_seconds=max_seconds)
        closers.append(frame_log.close)
    pty = None
    if args.pty or args.slcan_pty:
        pty = PseudoTerminal()
        closers.append(pty.close)
    if args.serial:
        port = open_serial_option(args.serial, args.baud)
        closers.append(port.close)
        info = LinkInfo("serial", args.baud)
    elif args.pty:
        info = LinkInfo("serial", args.baud)
    else:
        info = LinkInfo("can", getattr(args, "bitrate", None) or CAN_BITRATE_DEFAULT)
    firmware = Firmware(spec, truth, rng, warmup_s=sim.warmup_s, node_id=args.node_id, link=info)
    # With --paced-sender, a link on a file descriptor is written by a process of its own (the
    # simulator encodes into a capture); any other python-can bus by a thread of its own.
    paced = args.paced_sender
    send_from: tuple[Capture, int] | None = None  # what a sender process writes, and where
    link: Link
    if args.serial:
        stream: Any = SerialStream(port)
        if paced:
            stream = CaptureStream(stream)
            send_from = (stream, port.fileno())
        link = SerialLink(stream, firmware, tap=frame_log, node_id=args.node_id)
    elif pty is not None:
        stream = pty.stream
        if paced:
            stream = CaptureStream(stream)
            send_from = (stream, pty.master)
        link = (
            SerialLink(stream, firmware, tap=frame_log, node_id=args.node_id)
            if args.pty
            else CanLink(SlcanAdapter(stream), firmware, args.node_id, tap=frame_log)
        )
    else:
        bus = open_can_bus(args)
        closers.append(bus.shutdown)
        socket_fd = _socketcan_fd(bus)
        frames: Any = bus
        if paced and socket_fd is not None:
            frames = CaptureBus(bus)
            send_from = (frames, socket_fd)
        link = CanLink(frames, firmware, args.node_id, tap=frame_log)
    runner = Runner(firmware, link, RealTimeClock(args.speed))
    if send_from is not None:
        capture, out_fd = send_from
        sender = ProcessSender(out_fd, priority=args.sender_priority)
        closers.append(sender.close)
        runner.sender_process = (sender, capture)
    else:
        runner.paced_sender = paced
    server = None
    if args.control:
        server = ControlServer(Controller(runner), args.control).start()
        closers.append(server.close)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration:
        timer = threading.Timer(args.duration, stop.set)
        timer.daemon = True  # a SIGINT before the duration ends the process at once
        timer.start()
        closers.append(timer.cancel)
    if pty is not None:
        print(f"pty {pty.path}", flush=True)
    if server is not None:
        print(f"control {server.address}", flush=True)
    print(
        f"truth azimuth {truth.azimuth_deg:.6f} latitude {truth.latitude_deg:g} pitch {truth.pitch_deg:g} "
        f"roll {truth.roll_deg:g} sensor {spec.name} warmup {sim.warmup_s:g} speed {args.speed:g} "
        f"seed {seed}",
        flush=True,
    )
    try:
        runner.run(stop)
    finally:
        for close in reversed(closers):
            close()
        lag = runner.lag
        logging.getLogger("northfinder.sim").info(
            "stopped at t=%.3f s; fell behind its clock %d time(s), %.3f s of simulated time lost",
            firmware.now,
            lag.slips,
            lag.slipped_s,
        )
    return 0
