"""``northfinder monitor``: the observer on frames alone, the screen with Textual's headless driver
(key presses, panel content, snapshots) against the embedded simulator in virtual time, a passive
session, a lost link that comes back, and the screen on a pseudo-terminal to a ``northfinder sim``
process.

In virtual time the screen does not redraw by itself (``refresh_hz=0``): a test moves the clock
(``sim.clock.sleep``) and redraws (:meth:`MonitorApp.refresh_view`), so what it sees is the same
on every machine.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import shlex
import threading
import time
from pathlib import Path
from typing import Any

import can
import pytest

pytest.importorskip("textual")
pytest.importorskip("textual_plotext")

from textual.binding import Binding
from textual.widgets import Static

from northfinder.cli import main
from northfinder.driver.clock import VirtualClock
from northfinder.driver.errors import LinkLost
from northfinder.driver.protocol.can import encode_can
from northfinder.driver.protocol.constants import DeviceState, Fault, Opcode, Result
from northfinder.driver.protocol.messages import (
    Reply,
    RotateTo,
    Sample,
    Spin,
    Status,
    Validity,
)
from northfinder.embed import SimulatedInstrument, Truth
from northfinder.host.plan import Plan
from northfinder.monitor.app import FramesScreen, MonitorApp
from northfinder.monitor.observer import LinkObserver
from northfinder.monitor.session import ActiveSession, PassiveSession

SIZE = (120, 40)


def sync(fn):
    """A plain test function that runs the coroutine ``fn`` (Textual's pilot is async)."""

    def test(*args, **kwargs):
        return asyncio.run(fn(*args, **kwargs))

    test.__name__ = fn.__name__
    test.__doc__ = fn.__doc__
    return test


TRUTH_DEG = 42.0


# -- the observer, on frames alone ------------------------------------------------------------
class StepClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def frames(message, node_id=1):
    return [
        can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=False)
        for f in encode_can(message, node_id)
    ]


def status(counter, state=DeviceState.READY, angle=0, faults=0):
    return Status(state, angle, 2000, Fault(faults), counter, 0, 0, 0)


def sample(counter):
    return Sample(counter, (100, 200, 300), (10, 20, 1_000_000), 0, 2000, Validity(3))


def feed(obs, clock, message, at):
    clock.t = at
    for m in frames(message):
        obs.tap(m)


def test_observer_counts_a_gap_of_the_stream():
    clock = StepClock()
    obs = LinkObserver(clock)
    obs.configured_rate_hz = 200
    feed(obs, clock, status(99), 0.0)
    for k in range(100, 110):
        if k not in (104, 105, 106):  # three ticks lost
            feed(obs, clock, sample(k), (k - 100) / 200)
    obs.drain()
    v = obs.view()
    assert (v.samples, v.gaps, v.ticks_lost) == (7, 1, 3)
    assert v.state == "READY" and v.sample_counter == 99
    # 1e-4 deg/h and 1e-6 g per count (the protocol's scales)
    tr = obs.traces()
    assert tr is not None and tr.samples == 7
    assert tr.mean_gyro_dph == pytest.approx((0.01, 0.02, 0.03))
    assert tr.mean_accel_mps2[2] == pytest.approx(9.80665, rel=1e-9)


def test_observer_logs_a_command_with_its_reply_delay_and_counts_refusals():
    clock = StepClock()
    obs = LinkObserver(clock)
    feed(obs, clock, status(0), 0.0)
    feed(obs, clock, RotateTo(7, 90_000_000), 1.0)
    feed(obs, clock, Reply(7, Opcode.ROTATE_TO, Result.OK), 1.0125)
    feed(obs, clock, RotateTo(8, 10_000_000), 2.0)
    feed(obs, clock, Reply(8, Opcode.ROTATE_TO, Result.BUSY), 2.004)
    obs.drain()
    v = obs.view()
    texts = [e.text for e in v.log]
    assert "ROTATE_TO 90.000 deg -> OK in 12.5 ms" in texts
    assert "ROTATE_TO 10.000 deg -> BUSY in 4.0 ms" in texts
    assert (v.commands, v.replies, v.refused) == (2, 2, 1)


def test_observer_shows_the_target_while_the_table_moves():
    clock = StepClock()
    obs = LinkObserver(clock)
    feed(obs, clock, status(0), 0.0)
    feed(obs, clock, RotateTo(1, 90_000_000), 0.01)
    feed(obs, clock, status(1, DeviceState.ROTATING, angle=30_000_000), 0.1)
    obs.drain()
    v = obs.view()
    assert v.angle_deg == pytest.approx(30.0) and v.target_deg == pytest.approx(90.0)
    feed(obs, clock, status(2, DeviceState.READY, angle=90_000_000), 0.2)
    obs.drain()
    assert obs.view().target_deg is None


def test_observer_names_spinning_and_measures_the_table_rate_on_the_units_own_time():
    clock = StepClock()
    obs = LinkObserver(clock)
    obs.configured_rate_hz = 200
    feed(obs, clock, status(0), 0.0)
    feed(obs, clock, Spin(3, -6000), 0.05)
    feed(obs, clock, Reply(3, Opcode.SPIN, Result.OK), 0.06)
    # Heartbeats every 20 ticks (0.1 s of unit time) at -6 deg/s across 0 deg, read with 40 ms
    # of arrival jitter: the rate comes from the counters, not from the arrivals.
    angle = 2.0
    for k in range(1, 16):
        angle = (angle - 0.6) % 360.0
        feed(obs, clock, status(20 * k, DeviceState.SPINNING, round(angle * 1e6)),
             0.1 * k + (0.04 if k % 2 else 0.0))  # fmt: skip
    obs.drain()
    v = obs.view()
    assert v.state == "SPINNING"
    assert v.table_rate_dps == pytest.approx(-6.0, abs=1e-6)
    assert v.spin_rate_dps == pytest.approx(-6.0)
    assert "SPIN -6.000 deg/s -> OK in 10.0 ms" in [e.text for e in v.log]
    assert "state READY -> SPINNING" in [e.text for e in v.log]
    # At rest: no rate, the spin forgotten.
    feed(obs, clock, status(400, DeviceState.READY, round(angle * 1e6)), 2.0)
    obs.drain()
    v = obs.view()
    assert v.table_rate_dps is None and v.spin_rate_dps is None
    # Without the sample rate the arrivals are the clock (here without jitter).
    obs = LinkObserver(clock)
    for k in range(12):
        feed(obs, clock, status(k, DeviceState.ROTATING, round(10e6 * k * 0.1)), 5.0 + 0.1 * k)
    obs.drain()
    assert obs.view().table_rate_dps == pytest.approx(10.0, rel=1e-9)


def test_observer_says_silent_after_three_heartbeats_without_status():
    clock = StepClock()
    obs = LinkObserver(clock, silent_after_s=0.0)
    assert obs.view().silent  # nothing yet
    feed(obs, clock, status(0), 0.0)
    obs.drain()
    clock.t = 0.29
    assert not obs.view().silent
    clock.t = 0.31
    assert obs.view().silent


# -- the screen on the embedded simulator in virtual time --------------------------------------
def vclock(sim: SimulatedInstrument) -> VirtualClock:
    clock = sim.clock
    assert isinstance(clock, VirtualClock)
    return clock


@contextlib.contextmanager
def simulated(*, warmup_s=0.0, seed=7, stream=True, sensor="paper-rlg", ready=True):
    """A simulated unit in virtual time and an active session on it (the stream started; with
    ``ready=False`` the unit is left in its warm-up, nothing started)."""
    with SimulatedInstrument(
        sensor, Truth(azimuth_deg=TRUTH_DEG), seed=seed, clock="virtual", warmup_s=warmup_s
    ) as sim:

        @contextlib.contextmanager
        def opener(tap):
            with sim.open_device(tap=tap) as dev:
                yield dev, {**sim.describe(), "warmup_s": warmup_s}

        session = ActiveSession(
            opener, description="embedded simulator", clock=vclock(sim), stream=False
        )
        try:
            if not ready:
                yield sim, session
                return
            session.require().wait_ready(5.0)
            if stream:
                session.require().start_streaming()
            yield sim, session
        finally:
            session.close()


@contextlib.asynccontextmanager
async def on_screen(
    *,
    plan: Plan | None = None,
    size: tuple[int, int] = SIZE,
    record_path: str = "monitor.asc",
    **unit: Any,
):
    """The monitor on a simulated unit (:func:`simulated`, given ``unit``), run headless:
    ``(sim, session, app, pilot)``."""
    with simulated(**unit) as (sim, session):
        app = MonitorApp(session, refresh_hz=0, plan=plan, record_path=record_path)
        async with app.run_test(size=size) as pilot:
            yield sim, session, app, pilot


def text(app, wid):
    return str(app.query_one(f"#{wid}", Static).content)


def table_deg(app):
    line = next(x for x in text(app, "unit").splitlines() if x.startswith("table"))
    return float(line.split()[1])


def log_text(app):
    return "\n".join(e.text for e in app.session.observer.log)


async def advance(app, pilot, sim, seconds):
    vclock(sim).sleep(seconds)
    app.refresh_view()
    await pilot.pause()


async def settle(app, pilot, sim, seconds=0.5):
    """Let the command workers finish, then move the clock on and redraw. While they run this
    thread leaves the clock alone: a worker waiting on it moves it itself, at the instants its
    own commands call for, so the run is the same on every machine."""
    await app.workers.wait_for_complete()
    await advance(app, pilot, sim, seconds)


@sync
async def test_the_main_screen_shows_the_unit_and_its_stream():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 3.0)
        unit, stream = text(app, "unit"), text(app, "stream")
        assert "NF-SIM #1" in unit and "READY" in unit
        assert "truth    azimuth 42.000 deg" in unit
        assert "rate      200.0 / 200 Hz" in stream
        assert "gaps      0  lost 0" in stream
        assert text(app, "banner").startswith("READY")
        assert "received" in text(app, "link")


@sync
async def test_keys_rotate_the_table_and_the_log_shows_command_and_reply():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press("t")
        await pilot.press("9", "0", "enter")
        await settle(app, pilot, sim, 1.0)
        assert "target     90.0000 deg" in text(app, "unit")
        assert "ROTATE_TO 90.000 deg -> OK in" in log_text(app)
        await advance(app, pilot, sim, 40.0)  # the table turns and settles
        assert table_deg(app) == pytest.approx(90.0, abs=0.02)  # the encoder's indexing
        await pilot.press("b")
        await pilot.press("-", "3", "0", "enter")
        await settle(app, pilot, sim, 30.0)
        assert table_deg(app) == pytest.approx(60.0, abs=0.02)
        assert "ROTATE_BY -30.000 deg -> OK" in log_text(app)
        await pilot.press("h")
        await settle(app, pilot, sim, 40.0)
        assert table_deg(app) == pytest.approx(0.0, abs=0.02)


@sync
async def test_a_bad_angle_is_refused_in_the_question_and_escape_cancels():
    async with on_screen() as (sim, session, app, pilot):
        await pilot.press("t", "x", "enter")
        assert "not an angle" in str(app.screen.query_one("#problem", Static).content)
        await pilot.press("escape")
        await settle(app, pilot, sim)
        assert session.observer.commands == 10  # what opening and streaming sent, no more
        assert "ROTATE" not in log_text(app)


@sync
async def test_stream_key_stops_and_starts_the_stream():
    async with on_screen() as (sim, session, app, pilot):
        await advance(app, pilot, sim, 1.0)
        await pilot.press("o")
        await settle(app, pilot, sim, 1.0)
        assert "stream    off" in text(app, "stream")
        assert "STREAM_STOP -> OK" in log_text(app)
        n = session.observer.samples
        await advance(app, pilot, sim, 1.0)
        assert session.observer.samples == n
        await pilot.press("o")
        await settle(app, pilot, sim, 1.0)
        assert "stream    on" in text(app, "stream")
        assert session.observer.samples >= n + 190
        assert "gaps      0  lost 0" in text(app, "stream")  # a stream off is no loss


@sync
async def test_a_find_started_from_the_monitor_forms_its_heading():
    plan = Plan((0.0, 180.0, 180.0, 0.0), 5.0)
    async with on_screen(plan=plan) as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press("f")
        await settle(app, pilot, sim, 0.5)
        run = app.find_run
        assert run is not None and run.finished and run.error is None
        assert len(run.windows) == 4
        # a heading after 2, 3 and 4 windows, each with its sigma
        assert [s.windows for s in run.solutions] == [2, 3, 4]
        r = run.result
        assert r is not None and r.sigma_deg is not None
        err = (r.azimuth_deg - TRUTH_DEG + 180.0) % 360.0 - 180.0
        assert abs(err) < 4.0 * r.sigma_deg
        find = text(app, "find")
        assert f"azimuth {r.azimuth_deg:.3f}" in find and "truth   42.000" in find
        assert "consistent" in find
        assert "find: azimuth" in log_text(app)


@sync
async def test_a_spinning_table_is_named_with_its_rate():
    with simulated() as (sim, session):
        app = MonitorApp(session, refresh_hz=0)
        async with app.run_test(size=SIZE) as pilot:
            await advance(app, pilot, sim, 0.5)
            session.require().spin(-6.0, wait=True)  # moves the virtual clock itself
            await advance(app, pilot, sim, 3.0)
            unit = text(app, "unit")
            assert "SPINNING" in unit
            assert "rate     -6.000 / -6.000 deg/s" in unit
            assert text(app, "banner").startswith("SPINNING -6.000 deg/s")
            assert "SPIN -6.000 deg/s -> OK" in log_text(app)
            assert "state ROTATING -> SPINNING" in log_text(app)
            session.require().stop(wait=True)
            await advance(app, pilot, sim, 1.0)
            unit = text(app, "unit")
            assert "READY" in unit and "rate     ---" in unit


@sync
async def test_a_unit_in_fault_is_shown_and_reset_clears_it():
    async with on_screen() as (sim, _session, app, pilot):
        with sim.runner.lock:
            sim.firmware.stall_table(True)
        await pilot.press("t", "9", "0", "enter")
        await settle(app, pilot, sim, 60.0)
        banner = text(app, "banner")
        assert banner.startswith("FAULT: DRIVE") and "r resets" in banner
        assert "-> FAULT (faults DRIVE)" in log_text(app)
        with sim.runner.lock:
            sim.firmware.stall_table(False)
        await pilot.press("r")
        await settle(app, pilot, sim, 2.0)
        assert "RESET -> OK" in log_text(app)
        assert not text(app, "banner").startswith("FAULT")


@sync
async def test_a_silent_unit_is_shown_and_its_return_too():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 1.0)
        with sim.runner.lock:
            sim.firmware.faults.silent = True
        await advance(app, pilot, sim, 2.0)
        assert text(app, "banner").startswith("SILENT: no status for 2.0 s")
        with sim.runner.lock:
            sim.firmware.faults.silent = False
        await advance(app, pilot, sim, 1.0)
        assert text(app, "banner").startswith("READY")


@sync
async def test_a_lost_link_is_reopened_and_said_so():
    async with on_screen() as (sim, session, app, pilot):
        await advance(app, pilot, sim, 0.5)

        def unplugged(timeout):
            raise LinkLost("the adapter was unplugged")

        session.require()._transport.recv = unplugged
        await advance(app, pilot, sim, 0.1)
        assert text(app, "banner").startswith("LINK LOST")
        for _ in range(100):  # the session reopens in a thread, on the virtual clock
            if session.connected:
                break
            await advance(app, pilot, sim, 0.2)
        assert session.connected
        await advance(app, pilot, sim, 0.5)
        assert text(app, "banner").startswith("READY")
        assert "link back" in log_text(app)


@sync
async def test_a_terminal_too_small_says_so():
    async with on_screen(stream=False, size=(60, 20)) as (_sim, _session, app, pilot):
        await pilot.pause()
        assert "needs at least 100 x 30" in text(app, "toosmall")
        assert app.query_one("#toosmall").display
        assert not app.query_one("#top").display


@sync
async def test_passive_mode_decodes_another_hosts_session_and_sends_nothing():
    with SimulatedInstrument(
        "paper-rlg", Truth(azimuth_deg=TRUTH_DEG), seed=3, clock="virtual", warmup_s=0
    ) as sim:
        watch = PassiveSession(sim.open_bus, description="virtual bus", clock=vclock(sim))
        app = MonitorApp(watch, refresh_hz=0)
        try:
            async with app.run_test(size=SIZE) as pilot:
                with sim.open_device() as other:  # another host drives the unit
                    other.wait_ready(5.0)
                    other.start_streaming()
                    other.rotate_to(45.0, wait=True)
                    vclock(sim).sleep(1.0)
                    app.refresh_view()
                    await pilot.pause()
                    assert "PASSIVE" in text(app, "banner")
                    assert table_deg(app) == pytest.approx(45.0, abs=0.02)
                    assert "ROTATE_TO 45.000 deg -> OK in" in log_text(app)
                    assert "rate      200.0" in text(app, "stream")
                    await pilot.press("h")  # refused here: passive sends nothing
                    await pilot.pause()
                    assert "passive mode: the monitor sends nothing" in log_text(app)
            # every command seen came from the other host (its own sequence numbers)
            assert watch.observer.commands == watch.observer.replies
        finally:
            watch.close()


# -- snapshots of the main screens -------------------------------------------------------------
def test_snapshot_main_screen(snap_compare):
    with simulated() as (sim, session):

        async def before(pilot):
            await advance(pilot.app, pilot, sim, 3.0)

        assert snap_compare(
            MonitorApp(session, refresh_hz=0), terminal_size=SIZE, run_before=before
        )


def test_snapshot_find_done(snap_compare):
    plan = Plan((0.0, 180.0, 180.0, 0.0), 5.0)
    with simulated() as (sim, session):

        async def before(pilot):
            await advance(pilot.app, pilot, sim, 0.5)
            await pilot.press("f")
            await settle(pilot.app, pilot, sim, 0.5)

        app = MonitorApp(session, refresh_hz=0, plan=plan)
        assert snap_compare(app, terminal_size=SIZE, run_before=before)


def test_snapshot_spinning(snap_compare):
    with simulated() as (sim, session):

        async def before(pilot):
            await advance(pilot.app, pilot, sim, 0.5)
            session.require().spin(6.0, wait=True)
            await advance(pilot.app, pilot, sim, 3.0)

        assert snap_compare(
            MonitorApp(session, refresh_hz=0), terminal_size=SIZE, run_before=before
        )


def test_snapshot_silent_unit(snap_compare):
    with simulated() as (sim, session):

        async def before(pilot):
            await advance(pilot.app, pilot, sim, 1.0)
            with sim.runner.lock:
                sim.firmware.faults.silent = True
            await advance(pilot.app, pilot, sim, 2.0)

        assert snap_compare(
            MonitorApp(session, refresh_hz=0), terminal_size=SIZE, run_before=before
        )


def test_snapshot_too_small(snap_compare):
    with simulated(stream=False) as (_sim, session):
        assert snap_compare(MonitorApp(session, refresh_hz=0), terminal_size=(80, 24))


# -- the command line --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["monitor"], "choose exactly one link"),
        (["monitor", "--serial", "/dev/null", "--passive"], "--passive listens on a CAN bus"),
        (["monitor", "--serial", "/dev/null", "--speed", "3"], "--speed: applies to the embedded"),
        (["monitor", "--sim", "--summary", "x.txt"], "--summary x.txt: the file name must end"),
    ],
)
def test_the_command_refuses_bad_requests_in_one_line(argv, words, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err, err


# -- on a pseudo-terminal, against a simulator in another process -------------------------------
@pytest.mark.realtime
@pytest.mark.subprocess
@sync
async def test_the_screen_on_a_pty_to_a_simulator_process():
    from simprocess import sim_process

    from northfinder.driver.device import Device

    # Twice real time: the 600 samples in 1.5 s of wall time (the screen shows the configured rate).
    args = ["--pty", "--warmup", "0", "--speed", "2", "--control", "127.0.0.1:0"]
    with sim_process(*args, ready=True) as facts:

        @contextlib.contextmanager
        def opener(tap):
            with Device.open_serial(facts["pty"], tap=tap, min_supervision_s=1.0) as dev:
                yield dev, None

        session = ActiveSession(opener, description=f"serial {facts['pty']}", latitude_deg=34.0)
        app = MonitorApp(session, refresh_hz=10)
        try:
            async with app.run_test(size=SIZE) as pilot:
                t_end = time.monotonic() + 20.0
                while session.observer.samples < 600 and time.monotonic() < t_end:
                    await pilot.pause(0.2)
                await pilot.pause(0.3)
                assert session.observer.samples >= 600
                stream = text(app, "stream")
                assert "stream    on" in stream and "/ 200 Hz" in stream
                assert session.observer.view().gaps == 0
                assert "READY" in text(app, "banner")
        finally:
            session.close()


# -- recording ---------------------------------------------------------------------------------
def in_thread(fn, *args, limit_s=5.0):
    """Run the session's method ``fn`` in a thread and fail (instead of hanging) when it does not
    end in time: a lock taken twice by one thread never returns. The session then gets a new
    recording lock, so that closing it does not hang the test too."""
    out: list[Any] = []
    worker = threading.Thread(target=lambda: out.append(fn(*args)), daemon=True)
    worker.start()
    worker.join(limit_s)
    if worker.is_alive():
        fn.__self__._record_lock = threading.Lock()
        pytest.fail(f"{fn.__name__} did not return within {limit_s} s")
    return out[0] if out else None


def test_recording_starts_switches_and_stops_without_waiting_on_itself(tmp_path):
    first, second = tmp_path / "a.asc", tmp_path / "b.log"
    with simulated() as (sim, session):
        in_thread(session.start_recording, str(first))
        assert session.record_path == str(first)
        vclock(sim).sleep(1.0)
        in_thread(session.start_recording, str(second))  # closes the first log
        vclock(sim).sleep(1.0)
        assert in_thread(session.stop_recording) == str(second)
        assert session.record_path is None and in_thread(session.stop_recording) is None
    for log in (first, second):
        frames = list(can.LogReader(str(log)))
        # one second of a 200 Hz stream (two frames a sample) and the statuses, in virtual time
        assert len(frames) > 400
        assert frames[-1].timestamp - frames[0].timestamp == pytest.approx(1.0, abs=0.02)


@pytest.mark.realtime
def test_the_command_records_from_the_start_with_can_log(tmp_path, monkeypatch, capsys):
    """``monitor --sim --can-log FILE`` opens its screen, quits at ``--duration`` and leaves a
    complete log (headless: the command's own run, without a terminal)."""
    import functools

    monkeypatch.setattr(MonitorApp, "run", functools.partialmethod(MonitorApp.run, headless=True))
    log = tmp_path / "run.asc"
    summary = tmp_path / "summary.json"
    argv = ["monitor", "--sim", "--warmup", "0", "--speed", "4", "--can-log", str(log)]
    t0 = time.monotonic()
    status = in_thread_status(main, [*argv, "--duration", "1.5", "--summary", str(summary)])
    assert status == 0 and time.monotonic() - t0 < 20.0
    frames = list(can.LogReader(str(log)))
    assert len(frames) > 100  # statuses and samples of the stream the monitor started
    err = capsys.readouterr().err
    assert "monitor:" in err
    # The stream the monitor started is stopped on leaving, and the line says so.
    assert re.search(r"on leaving, sent STREAM_STOP; the unit reads (READY|SETTLING)", err), err


def in_thread_status(fn, argv, limit_s=30.0):
    """``fn(argv)`` in a thread: a command that hangs fails the test instead of hanging it."""
    out: list[Any] = []
    worker = threading.Thread(target=lambda: out.append(fn(argv)), daemon=True)
    worker.start()
    worker.join(limit_s)
    if worker.is_alive():
        pytest.fail(f"northfinder {' '.join(argv)} did not end within {limit_s} s")
    return out[0] if out else None


# -- every key of the screen, enumerated from its bindings ---------------------------------------
# Each key is pressed where it acts and, where it can be refused, where it is refused (the unit
# refuses, the monitor is passive, the request is incomplete); every case then quits with q and
# the screen must end within QUIT_WITHIN_S of wall time. A key bound without a case here fails.
QUIT_WITHIN_S = 2.0


async def quit_in_time(app, pilot):
    t0 = time.monotonic()
    await pilot.press("q")
    while app.is_running and time.monotonic() - t0 < QUIT_WITHIN_S:
        await asyncio.sleep(0.01)
    waited = time.monotonic() - t0
    assert app.return_code == 0 and not app.is_running, f"q not answered in {waited:.2f} s"


@contextlib.asynccontextmanager
async def watching():
    """A passive monitor on a virtual bus beside another host driving the unit:
    ``(sim, other, app, pilot)``."""
    with SimulatedInstrument(
        "paper-rlg", Truth(azimuth_deg=TRUTH_DEG), seed=3, clock="virtual", warmup_s=0
    ) as sim:
        watch = PassiveSession(sim.open_bus, description="virtual bus", clock=vclock(sim))
        app = MonitorApp(watch, refresh_hz=0)
        try:
            async with app.run_test(size=SIZE) as pilot:
                with sim.open_device() as other:
                    other.wait_ready(5.0)
                    yield sim, other, app, pilot
        finally:
            watch.close()


async def refused_passively(key, *typed):
    async with watching() as (sim, _other, app, pilot):
        await advance(app, pilot, sim, 0.5)
        sent = app.session.observer.commands
        await pilot.press(key, *typed)
        await advance(app, pilot, sim, 0.5)
        assert "passive mode: the monitor sends nothing" in log_text(app)
        assert app.session.observer.commands == sent  # nothing went on the bus
        await quit_in_time(app, pilot)


async def refused_in_warmup(key, *typed, opcode):
    """The unit warms up: a move is refused by the unit (NOT_READY), said in one log line."""
    async with on_screen(warmup_s=600.0, ready=False) as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 2.0)
        assert "WARMUP" in text(app, "unit")
        await pilot.press(key, *typed)
        await settle(app, pilot, sim, 0.5)
        assert f"the device refused {opcode}: NOT_READY" in log_text(app)
        assert "-> NOT_READY in" in log_text(app)
        await quit_in_time(app, pilot)


async def move_by_key(keys: tuple[str, ...], settle_s: float, logged: str, table: float):
    """Type a move key and its angle: the line the move logs, and where the table ends, deg."""
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press(*keys)
        await settle(app, pilot, sim, settle_s)
        assert logged in log_text(app)
        assert table_deg(app) == pytest.approx(table, abs=0.02)
        await quit_in_time(app, pilot)


async def key_t():
    await move_by_key(("t", "9", "0", "enter"), 40.0, "ROTATE_TO 90.000 deg -> OK in", 90.0)


async def key_b():
    await move_by_key(("b", "4", "5", "enter"), 30.0, "ROTATE_BY +45.000 deg -> OK in", 45.0)


async def key_s():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press("t", "1", "8", "0", "enter")
        await settle(app, pilot, sim, 3.0)
        assert "ROTATING" in text(app, "unit")
        await pilot.press("s")
        await settle(app, pilot, sim, 10.0)
        assert "STOP -> OK in" in log_text(app)
        stopped = table_deg(app)
        assert 1.0 < stopped < 170.0  # it stopped on the way
        await advance(app, pilot, sim, 10.0)
        assert table_deg(app) == pytest.approx(stopped, abs=0.02)
        await quit_in_time(app, pilot)


async def key_h():
    async with on_screen() as (sim, session, app, pilot):
        session.require().rotate_to(30.0, wait=True)
        await advance(app, pilot, sim, 0.5)
        await pilot.press("h")
        await settle(app, pilot, sim, 30.0)
        assert "HOME -> OK in" in log_text(app)
        assert (table_deg(app) + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=0.02)
        await quit_in_time(app, pilot)


async def key_o():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 1.0)
        await pilot.press("o")
        await settle(app, pilot, sim, 1.0)
        assert "stream    off" in text(app, "stream")
        await pilot.press("o")
        await settle(app, pilot, sim, 1.0)
        assert "stream    on" in text(app, "stream")
        await quit_in_time(app, pilot)


async def key_f():
    async with on_screen(plan=Plan((0.0, 180.0), 2.0)) as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press("f")
        await settle(app, pilot, sim, 0.5)
        run = app.find_run
        assert run is not None and run.finished and run.result is not None
        assert "find: azimuth" in log_text(app)
        await quit_in_time(app, pilot)


async def key_f_without_latitude():
    async with on_screen() as (sim, session, app, pilot):
        session.latitude_deg = None  # a real unit without --latitude
        await advance(app, pilot, sim, 0.5)
        await pilot.press("f")
        await advance(app, pilot, sim, 0.5)
        assert "find: give the site's latitude (--latitude)" in log_text(app)
        assert app.find_run is None
        await quit_in_time(app, pilot)


async def key_w(tmp_path):
    log = tmp_path / "bench.asc"
    async with on_screen(record_path=str(log)) as (sim, session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press("w")
        await advance(app, pilot, sim, 2.0)
        assert "recording" in text(app, "banner") and session.record_path == str(log)
        await pilot.press("w")
        await settle(app, pilot, sim, 0.5)
        assert session.record_path is None and "recording stopped" in log_text(app)
        assert len(list(can.LogReader(str(log)))) > 800  # 2 s of the 200 Hz stream
        await quit_in_time(app, pilot)


async def key_w_unwritable(tmp_path):
    log = tmp_path / "missing" / "bench.asc"
    async with on_screen(record_path=str(log)) as (sim, session, app, pilot):
        await pilot.press("w")
        await advance(app, pilot, sim, 0.5)
        assert "record: cannot write the CAN log" in log_text(app)
        assert session.record_path is None and "recording" not in text(app, "banner")
        await quit_in_time(app, pilot)


async def key_r():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await pilot.press("r")
        await settle(app, pilot, sim, 3.0)
        assert "RESET -> OK in" in log_text(app)
        assert "state READY -> BOOT" in log_text(app)
        await quit_in_time(app, pilot)


async def key_q():
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        await quit_in_time(app, pilot)


def frame_lines(app):
    return str(app.screen.query_one("#frames", Static).content).splitlines()


def frame_row(app, name):
    return next((x for x in frame_lines(app) if f" {name} " in x), None)


async def key_m():
    """m: the frame view, one row per CAN id with its decoded signals, count, rate, last seen."""
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 2.0)
        await pilot.press("m")
        await advance(app, pilot, sim, 2.0)
        assert isinstance(app.screen, FramesScreen)
        status = frame_row(app, "STATUS")
        assert status is not None and status.startswith("201      rx ")
        assert "State READY" in status or "READY" in status
        sample = frame_row(app, "SAMPLE_X").split()
        assert sample[:3] == ["101", "rx", "SAMPLE_X"]
        assert float(sample[4]) == pytest.approx(200.0, abs=1.0)  # Hz over the last 2 s
        assert float(sample[5]) < 0.01  # seen just now
        command = frame_row(app, "COMMAND")
        assert command is not None and command.split()[1] == "tx"
        await pilot.press("escape")
        await advance(app, pilot, sim, 0.5)
        assert not isinstance(app.screen, FramesScreen) and "READY" in text(app, "banner")
        await quit_in_time(app, pilot)


async def key_p():
    """p: the traces freeze while the link is read on; p again resumes them."""
    async with on_screen() as (sim, session, app, pilot):
        await advance(app, pilot, sim, 2.0)
        plot = app.query_one("#gyro")
        await pilot.press("p")
        assert "PAUSED" in plot.border_title
        n = session.observer.samples
        await advance(app, pilot, sim, 2.0)
        assert session.observer.samples >= n + 390  # read on
        assert app._last_plot <= vclock(sim).now() - 2.0  # not redrawn
        await pilot.press("p")
        assert "PAUSED" not in plot.border_title
        assert app._last_plot == pytest.approx(vclock(sim).now())
        await quit_in_time(app, pilot)


async def key_a():
    """a: the traces' y scale fixed at the range shown, then automatic again."""
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 2.0)
        shown = dict(app._trace_ranges)
        await pilot.press("a")
        assert app.trace_limits == shown and "y fixed" in app.query_one("#gyro").border_title
        await advance(app, pilot, sim, 2.0)
        assert app.trace_limits == shown  # kept while the data move
        await pilot.press("a")
        assert app.trace_limits is None and "y auto" in app.query_one("#gyro").border_title
        await quit_in_time(app, pilot)


KEY_CASES: dict[str, dict[str, Any]] = {
    "t": {
        "acts": key_t,
        "passive": lambda: refused_passively("t"),
        "warm-up": lambda: refused_in_warmup("t", "9", "0", "enter", opcode="ROTATE_TO"),
    },
    "b": {
        "acts": key_b,
        "passive": lambda: refused_passively("b"),
        "warm-up": lambda: refused_in_warmup("b", "9", "0", "enter", opcode="ROTATE_BY"),
    },
    "s": {"acts": key_s, "passive": lambda: refused_passively("s")},
    "h": {
        "acts": key_h,
        "passive": lambda: refused_passively("h"),
        "warm-up": lambda: refused_in_warmup("h", opcode="HOME"),
    },
    "o": {"acts": key_o, "passive": lambda: refused_passively("o")},
    "f": {
        "acts": key_f,
        "passive": lambda: refused_passively("f"),
        "no latitude": key_f_without_latitude,
    },
    "w": {"acts": key_w, "unwritable": key_w_unwritable},
    "r": {"acts": key_r, "passive": lambda: refused_passively("r")},
    "m": {"acts": key_m},
    "p": {"acts": key_p},
    "a": {"acts": key_a},
    "q": {"acts": key_q},
}


def _bound_keys() -> list[str]:
    return [b.key if isinstance(b, Binding) else b[0] for b in MonitorApp.BINDINGS]


@pytest.mark.parametrize("key", _bound_keys())
def test_every_bound_key_has_its_cases(key):
    cases = KEY_CASES.get(key)
    assert cases, f"key {key!r} is bound but has no test: add its cases to KEY_CASES"
    assert "acts" in cases


@pytest.mark.parametrize(
    ("key", "case"),
    [(k, c) for k in _bound_keys() for c in KEY_CASES.get(k, {"acts": None})],
)
def test_key(key, case, tmp_path):
    fn = KEY_CASES[key][case]
    needs_path = "tmp_path" in getattr(fn, "__code__", fn).co_varnames[:1]
    asyncio.run(fn(tmp_path) if needs_path else fn())


def test_a_find_recorded_from_the_monitor_solves_offline_to_the_same_heading(tmp_path, capsys):
    """w, f, the windows pass, w again: ``northfinder solve`` reads the log back to the heading
    the monitor showed."""
    import json

    log = tmp_path / "find.asc"
    plan = Plan((0.0, 180.0, 180.0, 0.0), 5.0)

    async def on_the_screen():
        async with on_screen(plan=plan, record_path=str(log)) as (sim, session, app, pilot):
            session.stream_on_ready(True)  # as the command's session does
            await advance(app, pilot, sim, 0.5)
            await pilot.press("w", "f")
            await settle(app, pilot, sim, 0.5)
            await advance(app, pilot, sim, 0.5)  # the monitor starts its own stream again...
            await advance(app, pilot, sim, 6.0)  # ...a 5th window
            await pilot.press("w")
            await settle(app, pilot, sim, 0.1)
            run = app.find_run
            assert run is not None and run.result is not None and session.record_path is None
            latitude = session.latitude_deg
            await quit_in_time(app, pilot)
        return run, latitude

    run, latitude = asyncio.run(on_the_screen())
    capsys.readouterr()
    solve = ["solve", str(log), "--latitude", str(latitude), "--window", "5", "--json"]
    assert main(solve) in (0, 3)
    assert len(json.loads(capsys.readouterr().out)["windows"]) == 5
    status = main([*solve, "--windows", "1,2,3,4"])  # the find's own windows
    out = json.loads(capsys.readouterr().out)
    assert status == 0
    assert out["azimuth_deg"] == pytest.approx(run.result.azimuth_deg, abs=1e-9)
    assert out["sigma_deg"] == pytest.approx(run.result.sigma_deg, rel=1e-9)
    assert [w["samples"] for w in out["windows"]] == [1000] * 4


# -- reply waits, time left, gaps ----------------------------------------------------------------
@sync
async def test_a_reply_later_than_the_drivers_wait_is_the_drivers_verdict_and_then_its_reply():
    """The driver decides that a reply did not come (its deadline); the monitor keeps that
    verdict, sets no deadline of its own, and shows the reply that came later as that command's
    late reply (the table turned), not as a reply without a command."""
    async with on_screen() as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 0.5)
        with sim.runner.lock:
            sim.firmware.apply(lambda: setattr(sim.firmware.faults, "reply_delay_s", 1.0))
        await pilot.press("t", "9", "0", "enter")
        await settle(app, pilot, sim, 0.2)
        log = log_text(app)
        assert "rotate to: no reply to ROTATE_TO within 0.25 s" in log
        assert "may have been carried out" in log
        await advance(app, pilot, sim, 1.0)
        log = log_text(app)
        assert (
            "ROTATE_TO 90.000 deg -> OK in 1001.0 ms, after the driver had stopped waiting "
            "(it was carried out)" in log
        )
        assert "no command seen" not in log and "-> no reply" not in log
        assert "unanswered 1" in text(app, "stream")
        await advance(app, pilot, sim, 40.0)
        assert table_deg(app) == pytest.approx(90.0, abs=0.02)
        await quit_in_time(app, pilot)


def test_the_observer_measures_the_units_pace_from_its_statuses():
    clock = StepClock()
    obs = LinkObserver(clock)
    obs.configured_rate_hz = 200
    # A unit paced at 2.5 units seconds per second: its counter runs 500 ticks per second.
    for k in range(41):
        feed(obs, clock, status(1000 + 50 * k), 0.1 * k + (0.03 if k % 3 else 0.0))
    obs.drain()
    assert obs.pace() == pytest.approx(2.5, rel=0.02)
    assert obs.unit_seconds() == pytest.approx((1000 + 50 * 40) / 200)
    # Too short a span says nothing.
    obs = LinkObserver(clock)
    obs.configured_rate_hz = 200
    for k in range(5):
        feed(obs, clock, status(20 * k), 10.0 + 0.1 * k)
    obs.drain()
    assert obs.pace() is None


async def until_phase(app, pilot, sim, phase, position, limit_s=120.0):
    """Move the clock in steps of 0.5 s until the find reports ``phase`` at ``position``."""
    for _ in range(int(limit_s / 0.5)):
        p = app.find_run.progress if app.find_run is not None else None
        if p is not None and (p.phase, p.position) == (phase, position):
            return
        await advance(app, pilot, sim, 0.5)
    pytest.fail(f"the find did not reach {phase} at position {position}")


def left_s(app):
    line = text(app, "find").splitlines()[0]
    return int(line.split("~")[1].split()[0])


@sync
async def test_the_find_panel_counts_the_time_left_down():
    """The time left is the procedure's remaining device time at its last step, less the time
    since then at the measured pace: it counts down between the steps."""
    plan = Plan((0.0, 180.0), 30.0)
    async with on_screen(plan=plan) as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 4.0)  # the pace measured: 1 in virtual time
        with vclock(sim).participant():  # the find's worker moves the clock no further than this
            await pilot.press("f")
            await until_phase(app, pilot, sim, "acquire", 1)
            first = left_s(app)
            assert text(app, "find").startswith("acquire position 1/2")
            await advance(app, pilot, sim, 10.0)
            assert left_s(app) == pytest.approx(first - 10, abs=1)
            await advance(app, pilot, sim, 10.0)
            assert left_s(app) == pytest.approx(first - 20, abs=1)
            await quit_in_time(app, pilot)


def test_the_time_left_of_a_paced_unit_is_its_device_time_over_its_pace():
    from northfinder.host.procedure import FindProgress
    from northfinder.monitor.session import FindRun

    class Clock:
        t = 100.0

        def now(self):
            return self.t

    class Session:
        clock = Clock()

    run = FindRun(Plan((0.0, 180.0), 30.0), 34.0, _session=Session())
    run._progress(FindProgress("acquire", 1, 2, 0.0, 99.0))
    assert run.seconds_left(100.0, 3.0) == pytest.approx(33.0)  # a simulator at 3x
    assert run.seconds_left(111.0, 3.0) == pytest.approx(22.0)
    assert run.seconds_left(140.0, 3.0) == 0.0
    assert run.seconds_left(111.0, None) == pytest.approx(88.0)  # pace not measured: 1


@sync
async def test_the_warm_up_counts_down_on_the_unit_and_in_a_find():
    async with on_screen(warmup_s=300.0, ready=False) as (sim, _session, app, pilot):
        await advance(app, pilot, sim, 10.0)
        unit = text(app, "unit")
        assert "WARMUP" in unit
        line = next(x for x in unit.splitlines() if x.startswith("warm-up"))
        left = int(line.split("~")[1].split()[0])
        assert 288 <= left <= 291
        with vclock(sim).participant():
            await pilot.press("f")
            await until_phase(app, pilot, sim, "warm-up", 0)
            first = left_s(app)
            assert left - 2 <= first <= left
            assert text(app, "find").startswith(f"warm-up: ~{first} s left (warm-up 300 s")
            await advance(app, pilot, sim, 30.0)
            assert left_s(app) == pytest.approx(first - 30, abs=1)
            await advance(app, pilot, sim, 30.0)
            assert left_s(app) == pytest.approx(first - 60, abs=1)
            await quit_in_time(app, pilot)


@pytest.mark.parametrize("on_gap", ["remeasure", "report", "fail"])
def test_a_gap_in_a_find_is_named_with_what_it_cost(on_gap):
    plan = Plan((0.0, 180.0), 2.0)

    async def run():
        async with on_screen(plan=plan) as (sim, _session, app, pilot):
            app.on_gap = on_gap
            await advance(app, pilot, sim, 0.5)
            with vclock(sim).participant():
                await pilot.press("f")
                await until_phase(app, pilot, sim, "acquire", 1)
                planned = app.find_run.progress.seconds_left
                await advance(app, pilot, sim, 1.0)  # within the first window
                with sim.runner.lock:
                    sim.firmware.apply(lambda: setattr(sim.firmware.faults, "skip_counter", 5))
                await advance(app, pilot, sim, 0.5)
                if on_gap == "remeasure":  # the time left counts the window measured again
                    assert app.find_run.progress.seconds_left == planned + plan.window_s
                    assert "window 1: 5 tick(s) lost" in text(app, "find")
            await settle(app, pilot, sim, 0.5)  # the worker runs the rest of the find
            find_run = app.find_run
            assert find_run is not None and find_run.finished
            assert (find_run.result is None) == (on_gap == "fail"), find_run.error
            find, log = text(app, "find"), log_text(app)
            await quit_in_time(app, pilot)
        return find_run, find, log

    find_run, find, log = asyncio.run(run())
    assert len(find_run.gaps) == 1, find_run.gaps
    gap = find_run.gaps[0]
    assert gap.startswith("window 1: 5 tick(s) lost from counter")
    if on_gap == "remeasure":
        assert "measured again (attempt 2), " in gap
        assert [w.samples for w in find_run.windows] == [400, 400]
    elif on_gap == "fail":
        assert gap.endswith("the run stops (on-gap fail)") and not find_run.windows
        assert "find failed:" in log and "failed:" in find
    else:
        assert "kept and reported in the result" in gap
        assert [w.samples for w in find_run.windows] == [395, 400]
    assert gap in find and f"find: {gap}" in log


# -- the help and the page say what the command does --------------------------------------------
DOCS_PAGE = Path(__file__).resolve().parents[1] / "docs" / "monitor.md"


def page_commands() -> list[list[str]]:
    """Every ``$ northfinder monitor ...`` line of docs/monitor.md, as argv."""
    lines = re.findall(r"^\$ northfinder (monitor .*)$", DOCS_PAGE.read_text(), re.M)
    return [shlex.split(line.partition("  #")[0]) for line in lines]


def test_the_help_and_the_page_say_the_simulator_runs_paced():
    from test_cli_help import help_text

    text = " ".join(help_text("monitor").split())
    sim = text[text.index("--sim use") :][:200]
    assert "paced" in sim and "virtual time" not in sim, sim
    page = " ".join(DOCS_PAGE.read_text().split())
    assert "which the monitor runs paced, not in virtual time" in page
    # and the code does so: a paced simulator by default
    from northfinder.cli import build_parser
    from northfinder.cli.monitor import monitor_link, open_session

    args = build_parser("monitor").parse_args(["monitor", "--sim", "--warmup", "0"])
    session = open_session(args)
    try:
        link = monitor_link(args)
        assert link.sim is not None and link.sim.speed == 1.0 and not session.clock.virtual
    finally:
        session.close()


def test_the_pages_commands_parse_and_need_no_wait():
    from northfinder.cli import build_parser

    argvs = page_commands()
    assert len(argvs) >= 4
    parser = build_parser("monitor")
    for argv in argvs:
        args = parser.parse_args(argv)
        channel = getattr(args, "channel", None) or ""
        if getattr(args, "interface", None) == "slcan" and "/dev/pts/" in channel:
            # a pseudo-terminal: no 2 s wait for an adapter to boot
            assert (getattr(args, "bus_kwargs", None) or {}).get("sleep_after_open") == 0, argv
    first = parser.parse_args(argvs[0])
    assert first.sim and first.warmup == 0.0  # f runs at once, no 2 min of warm-up


@pytest.mark.realtime
@pytest.mark.parametrize(
    "argv", [a for a in page_commands() if "--sim" in a], ids=lambda a: " ".join(a)
)
def test_the_pages_simulator_commands_run(argv, monkeypatch, tmp_path):
    import functools

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(MonitorApp, "run", functools.partialmethod(MonitorApp.run, headless=True))
    assert in_thread_status(main, [*argv, "--duration", "1"]) == 0


# -- the frame view's keys, enumerated from its bindings -----------------------------------------
@contextlib.asynccontextmanager
async def frame_view():
    async with on_screen() as (sim, session, app, pilot):
        await advance(app, pilot, sim, 2.0)
        await pilot.press("m")
        await advance(app, pilot, sim, 1.0)
        yield sim, session, app, pilot


async def frames_filter():
    async with frame_view() as (sim, _session, app, pilot):
        await pilot.press("slash", *"sample", "enter")
        await advance(app, pilot, sim, 0.5)
        names = [x.split()[2] for x in frame_lines(app)[1:]]
        assert names == ["SAMPLE_X", "SAMPLE_Y", "SAMPLE_Z", "SAMPLE_AUX"]
        head = str(app.screen.query_one("#frames_head", Static).content)
        assert "filter 'sample', 4 ids" in head
        await pilot.press("slash", *"201", "enter")  # by id
        await advance(app, pilot, sim, 0.5)
        assert [x.split()[2] for x in frame_lines(app)[1:]] == ["STATUS"]
        await pilot.press("slash", *["backspace"] * 3, "enter")  # empty: every frame
        await advance(app, pilot, sim, 0.5)
        assert len(frame_lines(app)) > 6
        await quit_in_time(app, pilot)


async def frames_filter_cancelled():
    async with frame_view() as (sim, _session, app, pilot):
        await pilot.press("slash", *"zzz", "escape")
        await advance(app, pilot, sim, 0.5)
        assert isinstance(app.screen, FramesScreen) and app.screen.filter == ""
        assert len(frame_lines(app)) > 6
        await quit_in_time(app, pilot)


async def frames_pause():
    async with frame_view() as (sim, _session, app, pilot):
        await pilot.press("p")
        before = frame_lines(app)
        await advance(app, pilot, sim, 1.0)
        assert frame_lines(app) == before  # frozen while the link is read on
        assert "PAUSED" in str(app.screen.query_one("#frames_head", Static).content)
        await pilot.press("p")
        await advance(app, pilot, sim, 0.5)
        assert frame_lines(app) != before
        await quit_in_time(app, pilot)


async def frames_back():
    async with frame_view() as (sim, _session, app, pilot):
        await pilot.press("escape")
        await advance(app, pilot, sim, 0.5)
        assert not isinstance(app.screen, FramesScreen)
        assert text(app, "banner").startswith("READY")
        assert "display error" not in log_text(app)
        await quit_in_time(app, pilot)


FRAME_KEY_CASES: dict[str, dict[str, Any]] = {
    "slash": {"acts": frames_filter, "cancelled": frames_filter_cancelled},
    "p": {"acts": frames_pause},
    "escape": {"acts": frames_back},
}


def _frame_keys() -> list[str]:
    return [b.key if isinstance(b, Binding) else b[0] for b in FramesScreen.BINDINGS]


@pytest.mark.parametrize("key", _frame_keys())
def test_every_key_of_the_frame_view_has_its_cases(key):
    assert FRAME_KEY_CASES.get(key), f"key {key!r} of the frame view has no test"


@pytest.mark.parametrize(
    ("key", "case"), [(k, c) for k in _frame_keys() for c in FRAME_KEY_CASES.get(k, {"acts": 0})]
)
def test_frame_view_key(key, case):
    asyncio.run(FRAME_KEY_CASES[key][case]())


def test_the_frame_view_decodes_with_the_protocols_dbc():
    from northfinder.monitor.app import decoded
    from northfinder.monitor.observer import FrameRow

    def row(frame):
        return FrameRow(frame.arbitration_id, False, 1, None, 0.0, bytes(frame.data), True)

    name, signals = decoded(row(frames(status(1234, DeviceState.READY, angle=90_000_000))[0]))
    assert name == "STATUS" and "READY" in signals and "90" in signals
    assert decoded(row(frames(status(1), node_id=2)[0]))[0] == "STATUS node 2"
    assert decoded(FrameRow(0x7FF, False, 1, None, 0.0, b"\x01\x02", True)) == (
        "not protocol",
        "01 02",
    )
