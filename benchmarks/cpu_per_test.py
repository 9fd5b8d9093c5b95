"""A pytest plugin: the CPU time of each test (this process and the children it waited for), which
does not depend on the machine's load as wall time does.

    PYTHONPATH=benchmarks CPU_PER_TEST=cpu.tsv .venv/bin/python -m pytest -q -n 0 -p cpu_per_test

writes one line a test, dearest first: CPU s in the process, CPU s in its children, wall s, test.
"""

from __future__ import annotations

import os
import resource
import time
from collections.abc import Iterator

import pytest

_rows: list[tuple[float, float, float, str]] = []


def _cpu() -> tuple[float, float]:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    own, children = _cpu()
    wall = time.monotonic()
    yield
    own2, children2 = _cpu()
    _rows.append((own2 - own, children2 - children, time.monotonic() - wall, item.nodeid))


def pytest_sessionfinish(session: pytest.Session) -> None:
    out = os.environ.get("CPU_PER_TEST")
    if out:
        with open(out, "w") as f:
            for own, children, wall, nodeid in sorted(_rows, key=lambda r: -(r[0] + r[1])):
                f.write(f"{own:.2f}\t{children:.2f}\t{wall:.2f}\t{nodeid}\n")
