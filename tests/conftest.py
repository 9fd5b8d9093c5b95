"""Shared fixtures: the simulated instrument on every link it offers, and a driver connected to it.

``sim`` (one simulator per link for the test module) and ``link`` (a fresh
:class:`northfinder.driver.device.Device` per test, with the simulator's control channel) are parametrised
over the links of ``LINKS``:

- ``virtual``: python-can's ``virtual`` bus, the simulator in this process in **virtual time**
  (``northfinder.driver.clock.VirtualClock`` shared with the driver): time jumps to the next
  event whenever the test waits, so these tests are exact and do not depend on the machine's load;
- ``serial-pty``: ``northfinder sim --pty`` in another process, the driver on the pty with pyserial;
- ``slcan-pty``: ``northfinder sim --slcan-pty`` in another process, the driver through python-can's
  ``slcan`` interface;
- ``socketcan``: ``northfinder sim -i socketcan -c vcan0``; skipped where the kernel has no vcan0.

The processes on ptys and vcan0 run on the wall clock, ``SPEED`` times faster than real time
(``SPEEDS`` per link), and their tests are marked ``realtime``. A test reads time and waits through
``sim.clock`` (virtual or wall) and schedules an action during a wait with ``sim.later``. The
``link`` fixture restores the speed of a paced simulator and resets the simulated device afterwards.
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from simprocess import sim_process

from northfinder.driver.clock import VirtualClock, WallClock

SPEED = 5.0
"""Simulated seconds per wall second for the simulators of the driver tests."""
SPEEDS = {"slcan-pty": 1.0, "socketcan": 1.0}
"""Exceptions to ``SPEED``: python-can's ``slcan`` reads its port one byte per call, which keeps
up with about four times the real-time stream (820 frames/s) on an idle machine and about twice
on a loaded one, and less when the whole suite runs; beyond that the pseudo-terminal fills, and
statuses and replies queue behind samples until the driver declares the link lost. Real time
keeps the margin. ``socketcan`` runs where vcan0 exists, in practice the HIL's one-CPU virtual
machine, where every system call is a round trip through the tracing kernel: five times the
stream (3000 frames/s) saturates it and replies miss their deadline."""
LINKS = ("virtual", "serial-pty", "slcan-pty", "socketcan")
VCAN = "vcan0"


@contextlib.contextmanager
def later_on(clock: Any, delay: float, fn: Callable[..., Any], *args: Any, **kwargs: Any):
    """Call ``fn`` ``delay`` seconds of ``clock`` from now, in another thread, while the body runs
    (it typically waits on a device); join the thread on exit.

    On a virtual clock the thread, and the caller while the body runs, count as parties of the
    clock, so the call happens exactly ``delay`` virtual seconds from now and time moves only
    while the body waits.
    """
    if not isinstance(clock, VirtualClock):
        timer = threading.Timer(delay, fn, args, kwargs)
        timer.start()
        try:
            yield
        finally:
            timer.join(5.0)
        return
    ready = threading.Event()
    errors: list[BaseException] = []
    deadline = clock.now() + delay

    def run() -> None:
        with clock.participant():
            ready.set()
            clock.wait_until(lambda: False, deadline)
            try:
                fn(*args, **kwargs)
            except BaseException as exc:
                errors.append(exc)

    # The body's thread too is a party while it runs: else the waiting thread would move time
    # on while the body works between its calls.
    with clock.participant():
        thread = threading.Thread(target=run, name="later", daemon=True)
        thread.start()
        ready.wait()
        try:
            yield
        finally:
            thread.join(5.0)
    if errors:
        raise errors[0]


@dataclass
class SimHandle:
    """A running simulator: how to reach it, its clock, and how to stop it.

    ``clock`` is the clock the tests read and wait on: the simulator's virtual clock (shared with
    the devices from ``open_device``) or the wall clock for a simulator in another process.
    ``speed`` is the simulated seconds per second of that clock (1 in virtual time).
    """

    kind: str
    open_device: Callable[[], Any]
    control: Any  # northfinder.firmware_sim.control.ControlClient
    speed: float = SPEED
    closers: list[Callable[[], None]] = field(default_factory=list)
    clock: Any = field(default_factory=WallClock)

    @property
    def virtual(self) -> bool:
        return isinstance(self.clock, VirtualClock)

    def later(self, delay: float, fn: Callable[..., Any], *args: Any, **kwargs: Any):
        """``later_on(self.clock, ...)``."""
        return later_on(self.clock, delay, fn, *args, **kwargs)

    def close(self) -> None:
        for close in reversed(self.closers):
            try:
                close()
            except Exception as exc:  # teardown goes on; the message shows in the log
                print(f"simulator teardown: {exc!r}", file=sys.stderr)


def _start_in_process() -> SimHandle:
    from northfinder.embed import SimulatedInstrument
    from northfinder.firmware_sim.imu import Truth

    sim = SimulatedInstrument(
        "paper-rlg",
        Truth(azimuth_deg=30.0, latitude_deg=34.0),
        seed=3,
        clock="virtual",
        warmup_s=0.0,
        control="127.0.0.1:0",
    ).start()
    handle = SimHandle("virtual", sim.open_device, sim.control, 1.0, clock=sim.clock)
    handle.closers.append(sim.close)
    return handle


def _start_subprocess(kind: str, speed: float, seed: int) -> SimHandle:
    from northfinder.driver.device import Device
    from northfinder.firmware_sim.control import ControlClient

    link_args = {
        "serial-pty": ["--pty"],
        "slcan-pty": ["--slcan-pty"],
        "socketcan": ["-i", "socketcan", "-c", VCAN],
    }[kind]
    args = [*link_args, "--warmup", "0", "--seed", str(seed), "--speed", str(speed)]
    args += ["--azimuth", "30", "--control", "127.0.0.1:0"]
    wanted = {"control"} if kind == "socketcan" else {"pty", "control"}
    process = contextlib.ExitStack()
    try:
        facts = process.enter_context(sim_process(*args, wanted=wanted, check_exit=False))
        control = ControlClient(facts["control"])
    except BaseException:
        process.close()
        raise
    if kind == "serial-pty":
        path = facts["pty"]
        opener: Callable[[], Any] = lambda: Device.open_serial(path)  # noqa: E731
    elif kind == "slcan-pty":
        path = facts["pty"]
        opener = lambda: Device.open_can("slcan", path, 500_000, sleep_after_open=0)  # noqa: E731
    else:
        opener = lambda: Device.open_can("socketcan", VCAN)  # noqa: E731
    handle = SimHandle(kind, opener, control, speed)
    handle.closers += [process.close, control.close]
    return handle


REALTIME_ENV = "NORTHFINDER_REALTIME"
"""How this pytest process takes part in a run (unset, the default: every test selected runs in
this run, the ``realtime`` ones as one xdist group, see :func:`pytest_xdist_auto_num_workers`):

- ``beside`` (set it to choose this): an xdist controller or worker whose ``realtime`` tests run
  in a pytest process of their own, started beside it (its workers, one per core but one, leave
  them out);
- ``alone``: that process (``-m realtime -n 0``): only the ``realtime`` tests that need the
  machine to themselves;
- ``separate``: leave the ``realtime`` tests out (``.ci/run`` used to run them in a step of its
  own, ``-m realtime``); without a value, in one process (``-n 0``) or with ``-m``, every test
  selected runs here."""
STARVED_FRACTION = 0.10
STARVED_STALL_S = 0.1
STARVED_WAIT_FRACTION = 0.25
"""A ``realtime`` test that failed while the host lost this share of its run (the timer loop of
:class:`northfinder.driver.conformance.pace.HostPace`), or stood still this long at once, or
while the test's thread, a driver's reader thread, or a thread of a process it started (a
simulator, a command) waited this share of the run for a CPU (the scheduler's figures), or while
the simulator of its ``sim`` fixture slipped its clock (the host starved the unit), is reported
**not judged** (skipped, with the host's figures and the failure), not failed: five times the
conformance suite's thresholds of keeping pace (docs/conformance.md), because these tests judge whole
conversations, not one measurement. A thread on a free core waits well under 1 % of the time; a
timer loop that sleeps between wakes is favoured by the scheduler and can keep pace while a busy
reader or simulator beside it waits most of the time. ``realtime(judge_host=False)`` marks a test
that must hold whatever the host does (the suite's own discrimination tests)."""


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one worker per core this process may use. The ``realtime`` tests form one
    xdist group, the largest, which pytest-xdist's ``loadgroup`` hands out first: one worker runs
    them one after the other from the start while the others (one per core but one) take the
    CPU-bound tests, so no more than cores - 1 CPU-bound workers ever run beside a realtime test;
    once the group is done that worker takes CPU-bound tests too. (``NORTHFINDER_REALTIME=beside``
    runs them in a pytest process of their own instead, beside one worker per core but one, which
    leaves that core idle once they are done.) Lowering the workers' priority instead (tried:
    niceness 10) starved them behind other jobs on a shared machine: not one test done in 12
    minutes at load 20."""
    affinity = getattr(os, "sched_getaffinity", None)  # Linux; elsewhere all the cores
    cores = len(affinity(0)) if affinity is not None else (os.cpu_count() or 1)
    beside = os.environ.get(REALTIME_ENV) == "beside"
    return max(1, cores - 1) if beside else cores


def _xdist_controller(config: pytest.Config) -> bool:
    n = config.getoption("numprocesses", None)
    return (
        not hasattr(config, "workerinput")
        and n not in (None, 0, "0")
        and config.getoption("dist", "no") != "no"
    )


def pytest_configure(config: pytest.Config) -> None:
    """With ``NORTHFINDER_REALTIME=beside`` (``-n auto``, no ``-m``) the realtime tests run in a
    pytest process of their own beside the xdist workers; by default they are one xdist group
    (:func:`pytest_xdist_auto_num_workers`)."""
    phase = os.environ.get(REALTIME_ENV)
    if (
        phase == "beside"
        and not hasattr(config, "workerinput")
        and not config.getoption("-m")
        and _xdist_controller(config)
    ):
        if not config.getoption("collectonly") and not config.getoption("help", False):
            os.environ[REALTIME_ENV] = "beside"  # the workers inherit it
            config.stash[_BESIDE] = _RealtimeBeside(config)


class _RealtimeBeside:
    """The ``alone`` pytest process: started with the session, its outcome folded into the run's."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.proc: subprocess.Popen[str] | None = None
        self.output = ""
        self.log = tempfile.TemporaryFile("w+")

    def start(self) -> None:
        args = [*self.config.invocation_params.args, "-m", "realtime", "-n", "0"]
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "pytest", *args, "-p", "no:cacheprovider"],
            cwd=self.config.invocation_params.dir,
            env={**os.environ, REALTIME_ENV: "alone"},
            stdout=self.log,
            stderr=subprocess.STDOUT,
            text=True,
        )

    def finish(self) -> int:
        if self.proc is None:
            return 0
        try:
            rc = self.proc.wait()
        except KeyboardInterrupt:
            self.proc.terminate()
            rc = self.proc.wait()
        self.log.seek(0)
        self.output = self.log.read()
        self.log.close()
        return 0 if rc == pytest.ExitCode.NO_TESTS_COLLECTED else rc


_BESIDE = pytest.StashKey[_RealtimeBeside]()


def pytest_sessionstart(session: pytest.Session) -> None:
    beside = session.config.stash.get(_BESIDE, None)
    if beside is not None:
        beside.start()


@pytest.hookimpl(tryfirst=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    beside = session.config.stash.get(_BESIDE, None)
    if beside is None:
        return
    rc = beside.finish()
    if rc and session.exitstatus in (pytest.ExitCode.OK, pytest.ExitCode.NO_TESTS_COLLECTED):
        session.exitstatus = rc


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """The realtime process's report, and its counts in the run's last line."""
    beside = terminalreporter.config.stash.get(_BESIDE, None)
    if beside is None or not beside.output:
        return
    terminalreporter.section("realtime tests (a process of their own, beside the workers)")
    terminalreporter.write(beside.output)
    last = beside.output.strip().splitlines()[-1] if beside.output.strip() else ""
    for count, word in re.findall(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed)", last):
        key = f"realtime {word}"
        terminalreporter.stats.setdefault(key, []).extend(_Counted() for _ in range(int(count)))


class _Counted:
    """One test of the realtime process in the run's counts."""

    count_towards_summary = True


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Which tests this process runs (see :data:`REALTIME_ENV`).

    On pytest-xdist's workers without a process beside them (``-m realtime``, or ``separate``) the
    ``realtime`` tests form one group, so they run one at a time on one worker while the others
    share the rest; ``realtime(alone=False)`` marks one that may run beside other tests (its margin
    is not about the CPU it gets, such as an interrupt a few seconds after a process starts)."""

    def alone(item: pytest.Item) -> bool:
        marker = item.get_closest_marker("realtime")
        return marker is not None and marker.kwargs.get("alone", True)

    for item in items:
        if alone(item):
            item.add_marker(pytest.mark.xdist_group(REALTIME_GROUP))
    phase = os.environ.get(REALTIME_ENV)
    if phase == "alone":
        keep = [item for item in items if alone(item)]
    elif phase == "beside":
        keep = [item for item in items if not alone(item)]
    elif phase == "separate" and not config.getoption("-m"):
        keep = [item for item in items if item.get_closest_marker("realtime") is None]
    else:
        return
    if len(keep) != len(items):
        config.hook.pytest_deselected(items=[i for i in items if i not in keep])
        items[:] = keep


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    """The same while a ``realtime`` test's fixtures are set up (a device waited for on a link)."""
    yield from _measured(item)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    """Measure the host's pace while a ``realtime`` test runs (see :data:`STARVED_FRACTION`)."""
    yield from _measured(item)


def _measured(item: pytest.Item) -> Iterator[None]:
    marker = item.get_closest_marker("realtime")
    if marker is None or not marker.kwargs.get("judge_host", True):
        yield
        return
    from northfinder.driver.conformance.pace import HostPace, process_tree

    sim = getattr(item, "funcargs", {}).get("sim")
    slipped = _slipped(sim)
    clock = WallClock()
    me = os.getpid()
    runner = threading.get_native_id()
    with HostPace(
        clock, unit_pids=lambda: process_tree(me)[1:], own_threads=lambda: _watched(runner)
    ) as pace:
        t0 = clock.now()
        yield
        item.stash[_PACE] = pace.during(t0, clock.now())
    item.stash[_SLIPPED] = _slipped(sim) - slipped


def _watched(runner: int) -> list[int]:
    """This process's threads whose waits for a CPU count: the one running the test
    (``runner``) and the driver's readers (not the pace's timer loop, nor numpy's or a pool's
    workers)."""
    readers = [
        t.native_id
        for t in threading.enumerate()
        if t.native_id is not None and t.name.startswith("northfinder-")
    ]
    return [runner, *readers]


def host_starved(pace: Any, slipped: float = 0.0) -> bool:
    """The rule of :data:`STARVED_FRACTION`: whether a ``realtime`` test that failed over
    ``pace`` (:class:`~northfinder.driver.conformance.pace.PaceFigures`), its simulator having
    slipped ``slipped`` simulated seconds, is not judged."""
    return (
        pace.lost_fraction >= STARVED_FRACTION
        or pace.stall_s >= STARVED_STALL_S
        or pace.wait_fraction >= STARVED_WAIT_FRACTION
        or slipped > 0.0
    )


def _slipped(sim: Any) -> float:
    """Simulated seconds the test's simulator (the ``sim`` fixture) has lost so far by slipping
    its clock: a paced simulator slips when the host did not run it for 50 ms past a message's
    due time, so any slip during a test is the host starving the unit, whatever the test's own
    timer loop saw (0 without such a simulator)."""
    if not isinstance(sim, SimHandle) or sim.virtual:
        return 0.0
    try:
        return float(sim.control.call("status")["lag"]["slipped_s"])
    except Exception:  # a simulator that died says so in the test's own failure
        return 0.0


_PACE = pytest.StashKey[Any]()
_SLIPPED = pytest.StashKey[float]()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, Any, None]:
    """A ``realtime`` test that failed while the host starved is reported not judged: skipped,
    with the failure's first line and the host's figures."""
    outcome = yield
    report = outcome.get_result()
    pace = item.stash.get(_PACE, None)
    if call.when not in ("setup", "call") or not report.failed or pace is None:
        return
    if call.excinfo is None:
        return
    if call.excinfo.errisinstance(CODE_ERRORS):
        return  # a mistake in the code fails whatever the host did
    slipped = item.stash.get(_SLIPPED, 0.0)
    if not host_starved(pace, slipped):
        return
    why = call.excinfo.exconly().strip().splitlines()
    first = why[0][:300] if why else "failed"
    unit = f"; the simulated unit slipped {slipped:.2f} s" if slipped > 0.0 else ""
    report.outcome = "skipped"
    report.longrepr = (
        str(item.path),
        item.location[1] or 0,
        f"NOT JUDGED: the host could not keep pace ({pace.text()}{unit}); it failed: {first}",
    )


REALTIME_GROUP = "realtime"
CODE_ERRORS = (NameError, AttributeError, TypeError, ImportError, SyntaxError)
"""Failures never excused by the host's pace: mistakes in the code, not late data."""


def link_params(links: tuple[str, ...] = LINKS) -> list[Any]:
    """Fixture parameters for ``links``: the processes on ptys and vcan0 marked ``realtime``."""
    return [
        pytest.param(kind, marks=() if kind == "virtual" else pytest.mark.realtime, id=kind)
        for kind in links
    ]


@pytest.fixture(scope="module", params=link_params())
def sim(request: pytest.FixtureRequest) -> Iterator[SimHandle]:
    """A simulator on one link, shared by the tests of a module (warm-up 0; virtual time, or
    ``SPEED`` x on the wall clock for a simulator in another process)."""
    kind = request.param
    speed = SPEEDS.get(kind, SPEED)
    if kind == "socketcan" and not os.path.exists(f"/sys/class/net/{VCAN}"):
        pytest.skip(
            f"no {VCAN}: this kernel has no SocketCAN/vcan (`scripts/hil --steps driver` runs "
            "these tests in a VM whose kernel has it)"
        )
    if kind == "virtual":
        handle = _start_in_process()
    else:
        handle = _start_subprocess(kind, speed, seed=LINKS.index(kind) + 10)
    try:
        yield handle
    finally:
        handle.close()


@pytest.fixture
def link(sim: SimHandle) -> Iterator[tuple[Any, Any]]:
    """A connected ``(Device, ControlClient)`` pair with the device READY.

    Afterwards the device is closed, and the simulated device is reset (faults cleared, defaults
    back) at the fixture's speed.
    """
    if not sim.virtual:
        sim.control.call("speed", value=sim.speed)
    device = sim.open_device()
    try:
        device.wait_ready(timeout=5.0)
        yield device, sim.control
    finally:
        device.close()
        if not sim.virtual:
            sim.control.call("speed", value=sim.speed)
        sim.control.call("resume")
        sim.control.call("reset")
