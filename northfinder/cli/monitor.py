"""``northfinder monitor``: a live view of a unit in the terminal (needs the ``monitor`` extra).

Panels: the unit (identity, state, faults, table angle and target, temperature), the stream
(rate, sample counter, gaps, lost, partial and late ticks, commands, refusals), the link's
counters, traces of the gyro and accelerometer channels over the last seconds with their means,
a find run's windows and its solution as it forms, and every command with its reply and delay.

Keys: t rotate to, b rotate by, s stop, h home, o stream on/off, f find (the plan options and
``--on-gap``), w record every frame to ``--record FILE`` (w again stops; ``--can-log FILE``
records from the start), r reset, m the frame view (one row per CAN id, decoded; / filters,
p pauses), p pause the traces, a their y scale fixed or automatic, q quit.

Links: python-can bus options (``-i socketcan -c vcan0``, ``-i slcan -c /dev/pts/3``),
``--serial PORT``, or ``--sim`` (the embedded simulated instrument, paced at ``--speed``,
default 1). ``--passive`` (CAN only) sends nothing: it decodes another host's session with the
unit as it passes on the bus. docs/monitor.md has the details and the CPU cost.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import time
from collections.abc import Iterator
from typing import Any

import northfinder.session as units
from northfinder.cli.argtypes import bounded_float
from northfinder.cli.files import check_output_path
from northfinder.cli.links import bus_given, open_can_bus
from northfinder.cli.measure import (
    add_device_arguments,
    add_plan_arguments,
    link_config,
    plan_from_args,
)
from northfinder.cli.options import add_duration_argument
from northfinder.config import LinkConfig
from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
from northfinder.host.errors import HostConfigError

SIM_ONLY = ("warmup", "sensor", "azimuth", "pitch", "roll", "seed")


#: The monitor runs the embedded simulator paced, not in virtual time as find and record do:
#: a live view needs its time to pass by itself.
PACED_HELP = {
    "--sim": "use the simulated instrument in this process, paced (--speed S simulated seconds "
    "per wall second, default 1: real time)",
    "--speed": "pace --sim at S simulated seconds per wall second (default 1, up to 10000)",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_device_arguments(p)
    add_plan_arguments(p)
    for action in p._actions:  # the shared options, as the monitor runs them
        for option in action.option_strings:
            if option in PACED_HELP:
                action.help = PACED_HELP[option]
    g = p.add_argument_group("monitor")
    g.add_argument(
        "--passive", action="store_true",
        help="send nothing, only listen (a CAN bus shared with another host)",
    )  # fmt: skip
    g.add_argument(
        "--refresh", type=bounded_float(1.0, 30.0, "Hz"), default=10.0, metavar="HZ",
        help="screen updates per second, 1 to 30 (default 10)",
    )  # fmt: skip
    g.add_argument(
        "--plot-rate", type=bounded_float(0.2, 30.0, "Hz"), default=2.0, metavar="HZ",
        help="trace redraws per second (default 2; at most --refresh)",
    )  # fmt: skip
    g.add_argument(
        "--trace-seconds", type=bounded_float(1.0, 60.0, "s"), default=10.0, metavar="S",
        help="seconds of samples in the traces (default 10)",
    )  # fmt: skip
    g.add_argument(
        "--record", default="monitor.asc", metavar="FILE",
        help="the CAN log the w key writes (ending: python-can's format; default monitor.asc)",
    )  # fmt: skip
    add_duration_argument(g, "quit after S seconds (a measurement run)", metavar="S")
    g.add_argument(
        "--summary", metavar="FILE",
        help="on quitting, write the stream's counters and the monitor's CPU use as JSON",
    )  # fmt: skip


def check_arguments(args: argparse.Namespace) -> None:
    """What can be refused before a link is opened (exit status 2)."""
    links = sum((bus_given(args), bool(args.serial), bool(args.sim)))
    if links != 1:
        raise HostConfigError(
            "choose exactly one link: -i/-c (python-can), --serial PORT, or --sim"
        )
    if args.passive and not bus_given(args):
        raise HostConfigError(
            "--passive listens on a CAN bus shared with another host: give -i/-c "
            "(a serial link or the embedded simulator has one host only)"
        )
    if not args.sim:
        given = [name for name in (*SIM_ONLY, "speed") if getattr(args, name, None) is not None]
        if given:
            raise HostConfigError(
                f"--{given[0]}: applies to the embedded simulator only (--sim), not to a device"
            )
    if args.summary:
        check_output_path(args.summary, "--summary", (".json",))


def _needs_textual() -> None:
    try:
        import textual  # noqa: F401
        import textual_plotext  # noqa: F401
    except ImportError as exc:
        raise HostConfigError(
            f"northfinder monitor needs Textual ({exc.name} is missing): "
            "pip install 'northfinder[monitor]'"
        ) from exc


def _describe(args: argparse.Namespace) -> str:
    if args.sim:
        return f"embedded simulator x{args.speed or 1.0:g}"
    if args.serial:
        return f"serial {args.serial}"
    return f"{args.interface or 'can'} {args.channel or ''} node {args.node_id}".replace("  ", " ")


def monitor_link(args: argparse.Namespace) -> LinkConfig:
    """The link of the arguments, as the session layer opens it; the embedded simulator runs
    paced (at 1 by default): a live view needs its time to pass by itself."""
    link = link_config(args)
    if link.sim is not None and link.sim.speed is None:
        link = dataclasses.replace(link, sim=dataclasses.replace(link.sim, speed=1.0))
    return link


def open_session(args: argparse.Namespace) -> Any:
    """The session the arguments name (active or passive)."""
    from northfinder.monitor.session import ActiveSession, PassiveSession

    if args.passive:
        return PassiveSession(
            lambda: open_can_bus(args),
            node_id=args.node_id,
            description=_describe(args),
            latitude_deg=args.latitude,
            trace_seconds=args.trace_seconds,
        )
    link = monitor_link(args)
    sim = link.sim
    latitude = DEFAULT_LATITUDE_DEG if args.latitude is None else float(args.latitude)

    @contextlib.contextmanager
    def opener(tap: Any) -> Iterator[tuple[Any, dict[str, Any] | None]]:
        if sim is not None:
            with units.simulated_unit(link, sim, latitude, tap) as unit:
                # how long it warms up: the screen counts the warm-up down
                truth = {} if unit.truth is None else unit.truth.as_dict()
                yield unit.device, {**truth, "warmup_s": sim.warmup_s}
        else:
            with units.real_unit(link, tap) as device:
                yield device, None

    return ActiveSession(
        opener,
        node_id=args.node_id,
        description=_describe(args),
        latitude_deg=args.latitude,
        trace_seconds=args.trace_seconds,
    )


def run(args: argparse.Namespace) -> int:
    check_arguments(args)
    _needs_textual()
    plan = plan_from_args(args)
    from northfinder.monitor.app import MonitorApp

    session = open_session(args)
    wall0, cpu0 = time.monotonic(), time.process_time()
    try:
        if args.can_log:
            session.start_recording(args.can_log)
        app = MonitorApp(
            session,
            plan=plan,
            refresh_hz=args.refresh,
            plot_hz=args.plot_rate,
            record_path=args.record,
            duration_s=args.duration,
            on_gap=args.on_gap,
        )
        status = app.run()
        session.poll()
        link = session.link_stats()
    finally:
        device = getattr(session, "device", None)
        session.close()  # the device left at rest: STOP, STREAM_STOP for what the monitor started
    rest = getattr(device, "at_rest", None)
    if rest is not None and rest.needed:
        print(f"monitor: on leaving, {rest.summary()}", file=sys.stderr)
    wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    counters = session.observer.counters()
    summary = {
        **counters,
        "wall_s": round(wall, 3),
        "cpu_s": round(cpu, 3),
        "cpu_percent": round(100.0 * cpu / wall, 2) if wall > 0 else None,
        "screen_updates": app.ticks,
        "screen_cpu_s": round(app.tick_seconds, 3),
        "link": link,
    }
    if args.summary:
        with open(args.summary, "w") as f:
            json.dump(summary, f, indent=2)
    print(
        f"monitor: {counters['samples']} samples, {counters['gaps']} gaps "
        f"({counters['ticks_lost']} ticks lost), {counters['commands']} commands, "
        f"{counters['refused']} refused; CPU {summary['cpu_percent']}% over {wall:.1f} s",
        file=sys.stderr,
    )
    return int(status or 0)
