"""Measuring with a device, shared by ``find`` and ``record``: the device and plan options, opening
the device (or the embedded simulator, :class:`~northfinder.embed.SimulatedInstrument`),
running the plan, and writing the raw windows."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
from collections.abc import Iterator
from typing import Any

from northfinder import session
from northfinder.cli.argtypes import bounded_float
from northfinder.cli.files import add_log_rotation, can_log_path
from northfinder.cli.links import add_link_arguments
from northfinder.cli.options import (
    add_latitude_argument,
    add_positions_argument,
    add_solver_argument,
    add_truth_arguments,
)
from northfinder.cli.parsers import common_group
from northfinder.cli.progress import PlanProgress
from northfinder.config import (
    BUS_KEYS,
    DEFAULT_PLAN,
    RELAXED_LINK_TIMEOUT_S,
    RELAXED_REPLY_TIMEOUT_S,
    FindConfig,
    LinkConfig,
    OutputConfig,
    SimConfig,
    SpinConfig,
)
from northfinder.driver.device import Device
from northfinder.driver.device_link import HEARTBEATS_UNTIL_LOST, REPLY_TIMEOUT_S
from northfinder.driver.protocol.constants import HEARTBEAT_PERIOD_DEFAULT_MS
from northfinder.driver.protocol.units import DEFAULT_WARMUP_S
from northfinder.firmware_sim.sensors import DEFAULT_SENSOR
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError
from northfinder.host.procedure import (
    DEFAULT_ON_GAP,
    MAX_DEVICE_SETTLE_S,
    METHOD_CHOICES,
    ON_GAP_CHOICES,
    READY_TIMEOUT_S,
    WINDOW_RANGE_S,
    Plan,
)
from northfinder.session import Measured, check_config, check_link

__all__ = [
    "Measured",
    "add_arguments",
    "find_config",
    "link_config",
    "run_plan",
    "sim_config",
]

#: Default warm-up of the embedded simulator, s (its one definition is
#: :data:`~northfinder.driver.protocol.units.DEFAULT_WARMUP_S`).
SIM_WARMUP_S = DEFAULT_WARMUP_S
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
        help="seconds without a status before the link counts as lost (default "
        f"{HEARTBEATS_UNTIL_LOST * HEARTBEAT_PERIOD_DEFAULT_MS / 1000:g}: "
        f"{HEARTBEATS_UNTIL_LOST} heartbeats; paced --sim: {RELAXED_LINK_TIMEOUT_S:g})",
    )  # fmt: skip
    g.add_argument(
        "--reply-timeout",
        type=bounded_float(*REPLY_TIMEOUT_RANGE_S, "s"),
        default=None,
        metavar="SECONDS",
        help="seconds to wait for a reply before resending a safe command, "
        f"{REPLY_TIMEOUT_RANGE_S[0]:g} to {REPLY_TIMEOUT_RANGE_S[1]:g} (default "
        f"{REPLY_TIMEOUT_S:g}; paced --sim: {RELAXED_REPLY_TIMEOUT_S:g})",
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
        help=f"sensor preset name or TOML file (default: {DEFAULT_SENSOR})",
    )
    add_latitude_argument(p, device=True)
    add_truth_arguments(p, latitude=False)


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("plan")
    add_positions_argument(g)
    g.add_argument(
        "--window",
        type=bounded_float(*WINDOW_RANGE_S, "s"),
        default=DEFAULT_PLAN.window_s,
        help=f"seconds per position, {WINDOW_RANGE_S[0]:g} to {WINDOW_RANGE_S[1]:g} "
        f"(default {DEFAULT_PLAN.window_s:g})",
    )
    g.add_argument(
        "--settle",
        type=bounded_float(0.0, MAX_DEVICE_SETTLE_S, "s"),
        default=DEFAULT_PLAN.settle_s,
        help=f"seconds after a move, up to {MAX_DEVICE_SETTLE_S:g} (default {DEFAULT_PLAN.settle_s:g})",
    )
    g.add_argument(
        "--denoise",
        default=DEFAULT_PLAN.denoise,
        choices=list(METHODS),
        help=f"denoising method (default {DEFAULT_PLAN.denoise})",
    )
    add_solver_argument(g, METHOD_CHOICES)
    g.add_argument(
        "--on-gap",
        choices=ON_GAP_CHOICES,
        default=DEFAULT_ON_GAP,
        metavar="MODE",
        help=f"lost ticks: {DEFAULT_ON_GAP} (default), "
        + " or ".join(c for c in ON_GAP_CHOICES if c != DEFAULT_ON_GAP),
    )
    g.add_argument(
        "--timeout",
        type=bounded_float(0.0, MAX_WAIT_S, "s", open_lo=True),
        default=READY_TIMEOUT_S,
        help=f"longest wait for READY after the warm-up, device seconds (default {READY_TIMEOUT_S:g})",
    )


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The device and the plan options, as ``find`` and ``record`` take them."""
    add_device_arguments(p)
    add_plan_arguments(p)


def plan_from_args(args: argparse.Namespace) -> Plan:
    return Plan(tuple(args.positions), args.window, args.settle, args.denoise, args.solver)


def check_arguments(args: argparse.Namespace) -> None:
    """Everything about the arguments that can be checked before a device is opened
    (:func:`find_config`).

    Raises
    ------
    HostConfigError
        Not exactly one device; an embedded-simulator option with a real device (it would be
        ignored); no ``--latitude`` for a real device (never assumed: a wrong latitude gives a
        wrong heading without a word).
    """
    _unit_config(args)


def _unit_config(args: argparse.Namespace) -> FindConfig:
    """The link and latitude of the arguments (the plan's options are not read: ``accept``
    opens a unit with these options and plans of its own)."""
    config = FindConfig(link=link_config(args), latitude_deg=args.latitude)
    check_config(config)
    return config


@contextlib.contextmanager
def open_device(
    args: argparse.Namespace, deferred: list[Exception] | None = None
) -> Iterator[tuple[Device, dict[str, Any] | None]]:
    """The device named by the arguments, and the simulated truth when it is simulated, as the
    JSON states it (:func:`northfinder.session.open_unit`, :meth:`SimTruth.as_dict`)."""
    config = _unit_config(args)
    latitude = session.site_latitude(config)
    with session.open_unit(config.link, latitude_deg=latitude, deferred=deferred) as unit:
        yield unit.device, None if unit.truth is None else unit.truth.as_dict()


def link_config(args: argparse.Namespace) -> LinkConfig:
    """The link of the device options: ``-i/-c/-b`` (python-can), ``--serial``, or ``--sim``
    with the simulator's options (refused without ``--sim``: they would be ignored)."""
    bus = {k: getattr(args, k) for k in BUS_KEYS if getattr(args, k, None) is not None}
    bus.update(getattr(args, "bus_kwargs", None) or {})
    link = LinkConfig(
        bus=bus, serial=args.serial or None, baud=args.baud, node_id=args.node_id,
        link_timeout_s=args.link_timeout, reply_timeout_s=args.reply_timeout,
        can_log=args.can_log, can_log_rotate=tuple(args.can_log_rotate),
    )  # fmt: skip
    if args.sim:
        link = dataclasses.replace(link, sim=sim_config(args))
    check_link(link)
    given = [name for name in SIM_ONLY if getattr(args, name, None) is not None]
    if given and not args.sim:
        raise HostConfigError(
            f"--{given[0]}: applies to the embedded simulator only (--sim), not to a device"
        )
    return link


def sim_config(args: argparse.Namespace) -> SimConfig:
    """The embedded simulator's options; an option not given (or that the command does not
    take) keeps :class:`SimConfig`'s default."""
    options = {
        "sensor": "sensor", "seed": "seed", "speed": "speed", "warmup_s": "warmup",
        "azimuth_deg": "azimuth", "pitch_deg": "pitch", "roll_deg": "roll",
    }  # fmt: skip
    given = {k: getattr(args, name, None) for k, name in options.items()}
    return SimConfig(**{k: v for k, v in given.items() if v is not None})


def find_config(args: argparse.Namespace) -> FindConfig:
    """The run the command line names, parsed once (:class:`~northfinder.config.FindConfig`)."""
    config = FindConfig(
        link=link_config(args), plan=plan_from_args(args), spin=spin_config(args),
        latitude_deg=args.latitude,
        on_gap=args.on_gap, ready_timeout_s=args.timeout,
        output=OutputConfig(verbose=getattr(args, "verbose", 0) or 0),
    )  # fmt: skip
    check_config(config)
    return config


def spin_config(args: argparse.Namespace) -> SpinConfig | None:
    """``--spin RATE_DPS`` and its options (None: the stop-and-go plan)."""
    if getattr(args, "spin", None) is None:
        return None
    return SpinConfig(args.spin, args.spin_time, bool(args.spin_drift))


def run_plan(
    args: argparse.Namespace, *, progress: bool = True, record_to: str | None = None
) -> Measured:
    """Run the plan of the arguments (:func:`northfinder.session.find`; ``progress``: draw the
    progress bar; ``record_to``: write the windows as they are measured)."""
    return run_config(
        find_config(args), progress=progress, record_to=record_to, label=args.command or "find"
    )


def run_config(
    config: FindConfig, *, progress: bool = True, record_to: str | None = None, label: str = "find"
) -> Measured:
    """:func:`northfinder.session.find` with the progress bar on stderr and ``-v``'s link line."""
    bar = PlanProgress(enabled=progress, label=label)
    statistics = None
    if config.output.verbose:

        def statistics(line: str) -> None:
            bar.close()
            print(line, file=sys.stderr, flush=True)

    try:
        # The raw windows are kept only for a plot: a run of hours holds one at a time.
        return session.find(
            config, progress=bar, record_to=record_to, on_link_statistics=statistics,
            keep_windows=config.output.plot is not None,
        )  # fmt: skip
    finally:
        bar.close()
