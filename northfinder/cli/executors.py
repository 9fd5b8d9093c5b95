"""Where a Monte Carlo study runs: ``--workers`` threads on this machine or ``--dask``."""

from __future__ import annotations

import argparse
import contextlib
import os
from collections.abc import Iterator
from concurrent.futures import Executor

from northfinder.cli.argtypes import whole_number
from northfinder.cli.parsers import common_group
from northfinder.host.errors import HostConfigError


def _workers(text: str) -> int:
    value = whole_number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


def _dask_address(text: str) -> str:
    from northfinder.host.distributed import parse_dask_address

    try:
        parse_dask_address(text)
    except HostConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("dask: ")) from None
    return text


def add_execution_arguments(parser: argparse.ArgumentParser) -> None:
    """Where a Monte Carlo study runs: threads on this machine, or a Dask cluster."""
    g = common_group(parser, "execution (results for a seed are the same everywhere)")
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
