"""Argument helpers shared by the subcommands, so every command spells an option the same way."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor

from northfinder.driver.protocol.constants import (
    NODE_ID_DEFAULT,
    NODE_ID_MAX,
    NODE_ID_MIN,
    SERIAL_BAUD_DEFAULT,
)


def finite_float(text: str) -> float:
    """argparse type: a finite float, with an error that quotes the bad text."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite: {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive: {text!r}")
    return value


def node_id(text: str) -> int:
    """argparse type: a CAN node id, 1..15 (protocol.md 2.1)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if not NODE_ID_MIN <= value <= NODE_ID_MAX:
        raise argparse.ArgumentTypeError(f"must be {NODE_ID_MIN}..{NODE_ID_MAX}, got {value}")
    return value


#: Highest serial baud rate accepted, bit/s (fast USB UARTs reach about 12 Mbaud).
MAX_BAUD = 100_000_000


def baud_rate(text: str) -> int:
    """argparse type: a serial baud rate, a whole number of bit/s from 1 to :data:`MAX_BAUD`."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if not 1 <= value <= MAX_BAUD:
        raise argparse.ArgumentTypeError(f"must be 1..{MAX_BAUD} bit/s, got {value}")
    return value


def add_link_arguments(parser: argparse.ArgumentParser, title: str) -> argparse._ArgumentGroup:
    """The links every command speaks: python-can bus options (``-i/-c/-b``, as python-can's own
    tools spell them), ``--serial PORT``, ``--baud`` and ``--node-id``. Returns the serial group so
    a command can add its own links to it."""
    import can.cli

    can.cli.add_bus_arguments(parser)
    group = parser.add_argument_group(title)
    group.add_argument("--serial", metavar="PORT", help="serial port path or pyserial URL")
    group.add_argument(
        "--baud",
        type=baud_rate,
        default=SERIAL_BAUD_DEFAULT,
        help=f"serial baud rate (default {SERIAL_BAUD_DEFAULT})",
    )
    group.add_argument(
        "--node-id",
        type=node_id,
        default=NODE_ID_DEFAULT,
        help=f"CAN node id {NODE_ID_MIN}..{NODE_ID_MAX} (default {NODE_ID_DEFAULT})",
    )
    return group


def bus_given(args: argparse.Namespace) -> bool:
    """Whether python-can bus options were given."""
    return any(getattr(args, k, None) is not None for k in ("interface", "channel"))


def angle_list(text: str) -> list[float]:
    """argparse type: comma-separated angles in degrees, e.g. ``0,60`` or ``0,90,180,270``."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError("expected comma-separated angles in degrees, e.g. 0,180")
    return [finite_float(p) for p in parts]


#: Latitude of a simulation when none is given (the source paper's site is near 34 deg N).
DEFAULT_LATITUDE_DEG = 34.0


def sim_latitude(args: argparse.Namespace) -> float:
    return DEFAULT_LATITUDE_DEG if args.latitude is None else args.latitude


def add_sensor_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sensor",
        default="paper-rlg",
        metavar="PRESET|FILE",
        help="sensor preset name or TOML file (default: paper-rlg)",
    )


def add_truth_arguments(parser: argparse.ArgumentParser) -> None:
    """The simulated truth: where the simulated instrument really stands."""
    g = parser.add_argument_group("simulated truth")
    g.add_argument(
        "--azimuth",
        type=finite_float,
        default=None,
        help="deg clockwise from north (default: random)",
    )
    g.add_argument(
        "--latitude", type=finite_float, default=34.0, help="deg, north positive (default: 34)"
    )
    g.add_argument("--pitch", type=finite_float, default=0.0, help="deg (default: 0)")
    g.add_argument("--roll", type=finite_float, default=0.0, help="deg (default: 0)")
    g.add_argument("--seed", type=int, default=None, help="random seed (default: fresh each run)")


def add_solver_argument(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, choices: Sequence[str]
) -> None:
    """``--solver`` as ``find``, ``record``, ``solve`` and ``study`` spell it (``--method``, the
    old spelling of ``find`` and ``solve``, is kept as a hidden alias)."""
    parser.add_argument(
        "--solver", choices=list(choices), default="auto", help="heading solver (default auto)"
    )
    parser.add_argument("--method", dest="solver", choices=list(choices), help=argparse.SUPPRESS)


def can_log_path(text: str) -> str:
    """argparse type: a CAN log file name whose ending names one of python-can's formats."""
    from northfinder.driver.errors import ArgumentError
    from northfinder.driver.framelog import log_suffix

    try:
        log_suffix(text)
    except ArgumentError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _workers(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


def _dask_address(text: str) -> str:
    from northfinder.host.distributed import parse_dask_address
    from northfinder.host.errors import HostConfigError

    try:
        parse_dask_address(text)
    except HostConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("dask: ")) from None
    return text


def add_execution_arguments(parser: argparse.ArgumentParser) -> None:
    """Where a Monte Carlo study runs: threads on this machine, or a Dask cluster."""
    g = parser.add_argument_group("execution (results for a seed are the same everywhere)")
    x = g.add_mutually_exclusive_group()
    x.add_argument(
        "--workers",
        type=_workers,
        default=None,
        metavar="N",
        help="threads on this machine (default: one per core)",
    )
    x.add_argument(
        "--dask",
        type=_dask_address,
        default=None,
        metavar="ADDRESS",
        help="run on the Dask cluster whose scheduler is at tcp://HOST:PORT, or on local:N "
        "(a local cluster of N worker processes); needs the dask extra",
    )


@contextlib.contextmanager
def study_executor(args: argparse.Namespace) -> Iterator[Executor | None]:
    """The executor of :func:`add_execution_arguments`' choice (None: run in this thread)."""
    from northfinder.host.montecarlo import local_executor

    if args.dask is not None:
        from northfinder.host.distributed import dask_executor

        with dask_executor(args.dask) as ex:
            yield ex
        return
    workers = args.workers or os.cpu_count() or 1
    if workers == 1:
        yield None
        return
    with local_executor(workers) as ex:
        yield ex
