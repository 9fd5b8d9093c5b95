"""Studies on a Dask cluster: an executor for the study engine, from a scheduler's address.

The study engine (:mod:`northfinder.host.montecarlo`) hands its chunks to any
:class:`concurrent.futures.Executor`; :func:`dask_executor` gives it one that runs them on a
Dask cluster (``dask.distributed``, the optional ``dask`` extra):

- ``tcp://HOST:PORT`` (or ``tls://``): a running scheduler (``dask scheduler``) with workers
  (``dask worker tcp://HOST:PORT``) on as many machines as there are;
- ``local:N``: a ``LocalCluster`` of N single-threaded worker processes on this machine,
  listening on the loopback interface only, for the duration of the study.

A chunk draws from its own seed (the engine's module doc), so a study gives the same results on a
cluster as in one process, provided that every worker runs the same versions of northfinder,
numpy and its BLAS. Workers need northfinder installed (its simulator too: the window generator
travels to them by reference). Give each worker one thread (``--nthreads 1``) and as many
workers per machine as it has cores: a chunk keeps one core busy.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator
from concurrent.futures import Executor
from contextlib import contextmanager, suppress

from northfinder.host.errors import HostConfigError, HostError

__all__ = ["DASK_EXTRA_HINT", "DistributedError", "dask_executor", "parse_dask_address"]

#: What to install when dask.distributed is missing.
DASK_EXTRA_HINT = "install the dask extra: pip install 'northfinder[dask]'"

_REMOTE = re.compile(r"^(tcp|tls)://(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})$")
_LOCAL = re.compile(r"^local:(\d+)$")


class DistributedError(HostError):
    """The Dask cluster cannot be reached or started, or lost the study."""


def max_local_workers() -> int:
    """The most worker processes ``local:N`` starts: four per core of this machine.

    Each is a Python process of its own (about 100 MB); more than a few per core only adds
    start-up time and memory, and thousands would exhaust the machine.
    """
    return 4 * (os.cpu_count() or 1)


def parse_dask_address(text: str) -> tuple[str, int | str]:
    """``("local", N)`` for ``local:N``, ``("remote", address)`` for ``tcp://HOST:PORT``.

    Raises
    ------
    HostConfigError
        Anything else, with the forms that are accepted; ``local:N`` with N below 1 or above
        :func:`max_local_workers`.
    """
    m = _LOCAL.match(text.strip())
    if m:
        n = int(m.group(1))
        limit = max_local_workers()
        if not 1 <= n <= limit:
            raise HostConfigError(
                f"dask: local:N takes 1 to {limit} worker processes on this machine "
                f"(4 per core), got {text!r}; for more, start a cluster and give its "
                "scheduler's tcp://HOST:PORT"
            )
        return "local", n
    m = _REMOTE.match(text)
    if m and 0 < int(m.group(3)) < 65536:
        return "remote", text
    raise HostConfigError(
        f"dask: expected a scheduler address tcp://HOST:PORT (or tls://) or local:N, got {text!r}"
    )


@contextmanager
def dask_executor(address: str, *, timeout_s: float = 10.0) -> Iterator[Executor]:
    """An executor that runs study chunks on the Dask cluster at ``address`` (see module doc).

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT``, ``tls://HOST:PORT`` or ``local:N``.
    timeout_s : float
        How long to wait for the scheduler, s.

    Raises
    ------
    HostConfigError
        A malformed address, or dask.distributed not installed.
    DistributedError
        The scheduler does not answer, or the local cluster does not start.
    """
    kind, value = parse_dask_address(address)
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise HostConfigError(f"dask: needs dask.distributed; {DASK_EXTRA_HINT}") from exc
    cluster = None
    try:
        if kind == "local":
            cluster = LocalCluster(
                n_workers=int(value),
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address="127.0.0.1:0",
                silence_logs=logging.ERROR,
            )
            client = Client(cluster, timeout=timeout_s)
        else:
            client = Client(str(value), timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        what = "start a local Dask cluster" if kind == "local" else f"reach {value}"
        raise DistributedError(f"dask: cannot {what}: {exc}") from exc
    try:
        from distributed.comm.core import CommClosedError
        from distributed.scheduler import KilledWorker

        try:
            yield client.get_executor()
        except (CommClosedError, KilledWorker, OSError) as exc:
            raise DistributedError(f"dask: the cluster at {address} lost the study: {exc}") from exc
    finally:
        with suppress(Exception):
            client.close()
        if cluster is not None:
            with suppress(Exception):
                cluster.close()
