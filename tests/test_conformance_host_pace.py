"""The host's pace as the scheduler and the unit's own clock show it, and the rule that excuses a
late reply only when the host, not the unit, made it late (docs/conformance.md, "On a busy host").

Lockstep: sessions and pace records fed by hand with synthetic figures; nothing waits on time.
One test starts a process that holds a pseudo-terminal (no timing in it)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest
from sessions import idle_session

from northfinder.driver.clock import WallClock
from northfinder.driver.conformance.core import Ctx, SuiteOptions
from northfinder.driver.conformance.pace import (
    HostPace,
    PaceFigures,
    _Series,
    excused,
    process_tree,
    pty_peer_pids,
)
from northfinder.driver.conformance.runner import judge
from northfinder.driver.conformance.session import Session
from northfinder.driver.conformance.wire import Arrival
from northfinder.driver.protocol.constants import ConfigKey, DeviceState, Fault, Opcode, Result
from northfinder.driver.protocol.messages import GetStatus, Reply, Status

RATE = 200


def _config_reply(seq: int) -> Reply:
    return Reply(
        seq,
        Opcode.GET_CONFIG,
        Result.OK,
        bytes([ConfigKey.SAMPLE_RATE_HZ]) + RATE.to_bytes(4, "little"),
    )


def _session(arrivals: list[tuple[float, float]]) -> Session:
    """A session that learnt the unit's rate (200 Hz) and then heard a heartbeat for each (unit
    time, arrival time) pair: the unit's sample counter at its unit time."""
    s = idle_session()
    a = s.track(bytes([1, Opcode.GET_CONFIG, ConfigKey.SAMPLE_RATE_HZ]))
    s._record(Arrival(0.0, _config_reply(a.seq)))
    for unit_t, t in arrivals:
        status = Status(DeviceState.READY, 0, 2500, Fault(0), round(unit_t * RATE), 0, 0, 0)
        s._record(Arrival(t, status))
    return s


def _heartbeats(t0: float, t1: float, delay=lambda t: 0.002) -> list[tuple[float, float]]:
    """Heartbeats every 0.1 s of the unit's time in [t0, t1), each read ``delay(t)`` after."""
    n = round((t1 - t0) / 0.1)
    return [(t0 + 0.1 * k, t0 + 0.1 * k + delay(t0 + 0.1 * k)) for k in range(n)]


def test_the_series_growth_is_the_running_total_over_the_interval():
    s = _Series()
    assert s.growth(0.0, 1.0) is None
    for k in range(11):
        s.add(0.1 * k, 0.02 * k)  # 20 % of the time waiting
    assert s.growth(0.2, 0.6) == pytest.approx(0.08)
    assert s.growth(-5.0, 50.0) == pytest.approx(0.2)


def test_waits_for_a_cpu_decide_whether_the_host_kept_pace():
    quiet = PaceFigures(1.0, 200, reader_wait_s=0.001, unit_wait_s=0.002)
    assert quiet.kept_pace and quiet.wait_fraction == pytest.approx(0.002)
    starved_unit = PaceFigures(1.0, 200, reader_wait_s=0.001, unit_wait_s=0.30)
    assert not starved_unit.kept_pace
    assert "the unit waited 0.30 s for a CPU (30%)" in starved_unit.text()
    assert not PaceFigures(1.0, 200, reader_wait_s=0.05).kept_pace  # 5 %: the limit
    assert PaceFigures(1.0, 200, reader_wait_s=0.049).kept_pace


def test_a_late_reply_is_excused_by_the_units_own_lag_only_on_a_host_that_did_not_keep_pace():
    starved = PaceFigures(1.5, 300, reader_wait_s=0.02, unit_wait_s=0.45)
    kept = PaceFigures(1.5, 300, reader_wait_s=0.001, unit_wait_s=0.002)
    assert excused(starved, 0.7, lag_s=0.75)
    assert not excused(starved, 0.7, lag_s=0.3)  # later than the unit's messages: the unit's
    assert not excused(kept, 0.7, lag_s=0.75)  # the host kept pace: a unit that stalled itself
    assert not excused(starved, 0.7)  # no lag measured
    # A reader starved before the interval is still behind in it, though it then ran at once.
    assert excused(kept, 0.7, lag_s=0.75, lag_pace=starved)


def test_frames_lost_while_the_reader_was_behind_more_than_the_link_holds_are_never_the_units():
    # The reader 2 s behind the unit's stream, the link holding 0.23 s: the link was full, so the
    # loss is the reader's, even when the host's figures over the check's window look fine (they
    # can miss a stall of the reader's own). A reader that kept up: the loss is the unit's.
    kept = PaceFigures(2.0, 400, reader_wait_s=0.001, unit_wait_s=0.002)
    starved = PaceFigures(2.0, 400, reader_wait_s=0.5, unit_wait_s=0.002)
    assert excused(kept, 0.233, behind_s=1.996)
    assert excused(starved, 0.233, behind_s=1.996)
    assert not excused(kept, 0.233, behind_s=0.010)
    assert not excused(starved, 0.233, behind_s=0.010)


def test_lag_is_how_late_the_units_messages_came_by_its_own_clock():
    # Heartbeats read 2 ms after they were sent, then, from 3.0 s, 0.8 s late (the reader stood
    # still and read the backlog), then on time again.
    def delay(t: float) -> float:
        return 0.8 if 3.0 <= t < 3.5 else 0.002

    s = _session(_heartbeats(1.0, 6.0, delay))
    assert s.lag(1.5, 2.5) == pytest.approx(0.0, abs=1e-6)
    assert s.lag(3.6, 3.9) == pytest.approx(0.798, abs=1e-6)
    assert s.lag(5.0, 5.5) == pytest.approx(0.0, abs=1e-6)


def test_lag_is_not_measured_until_the_units_rate_is_known_and_restarts_at_a_reset():
    s = idle_session()
    for unit_t, t in _heartbeats(1.0, 2.0, lambda t: 0.5 if t > 1.5 else 0.0):
        s._record(
            Arrival(t, Status(DeviceState.READY, 0, 0, Fault(0), round(unit_t * 400), 0, 0, 0))
        )
    assert s.marks == [] and s.lag(1.0, 2.5) == 0.0  # 400 Hz, but the suite has not heard it
    s = _session(_heartbeats(1.0, 2.0))
    s._record(Arrival(2.05, Status(DeviceState.BOOT, 0, 0, Fault(0), 3, 0, 0, 0)))
    assert s.lag(1.9, 2.1) == pytest.approx(0.0, abs=1e-6)  # the counter restarted: a new run


def _late_get_status(s: Session, sent: float, received: float) -> Ctx:
    """A GET_STATUS sent at ``sent`` whose reply came at ``received``, judged by the rule."""
    a = s.track(GetStatus(7).encode())
    a.sent = sent
    s._record(Arrival(received, Reply(a.seq, Opcode.GET_STATUS, Result.OK)))
    ctx = Ctx(s, SuiteOptions(), {"config": {ConfigKey.SAMPLE_RATE_HZ: RATE}})
    ctx.late("GET_STATUS late", a.sent, received, (received - sent) - ctx.reply_limit_wall)
    return ctx


def _measuring(s: Session, t0: float, t1: float, reader_wait: float, unit_wait: float) -> None:
    """Pace records of a timer loop that kept every wake, and the scheduler's figures: the reader
    and the unit waited these shares of the time for a CPU."""
    pace: HostPace = s.pace
    pace._thread = threading.Thread()  # measuring, from the records below
    pace.unit_pids = (1,)
    pace.unit_waits[1] = _Series()
    t = t0
    while t <= t1:
        pace.timer.add(t, 0.0)
        t += 0.005
    for k in range(round((t1 - t0) / 0.02) + 1):
        tk = t0 + 0.02 * k
        pace.reader_waits.add(tk, reader_wait * (tk - t0))
        pace.unit_waits[1].add(tk, unit_wait * (tk - t0))


def test_a_reply_a_starved_unit_sent_late_is_not_judged():
    """The unit on this host was starved (it waited 40 % of the time for a CPU, its clock
    slipped 0.9 s): its reply came 0.95 s after GET_STATUS against a 0.1 s limit, its heartbeats
    as late by its own counters. Not judged, with the figures."""
    s = _session(_heartbeats(1.0, 6.0, lambda t: 0.9 if t >= 3.0 else 0.002))
    _measuring(s, 0.0, 6.0, reader_wait=0.01, unit_wait=0.4)
    outcome, message = judge(s, _late_get_status(s, 3.05, 4.0))
    assert outcome == "not judged", message
    assert "the unit waited" in message and "ms late by its own clock" in message


def test_a_unit_that_delays_its_reply_fails_however_starved_the_host():
    """The same host, the unit's heartbeats on time by its own counters: the reply's 0.9 s
    beyond the limit are the unit's."""
    s = _session(_heartbeats(1.0, 6.0))
    _measuring(s, 0.0, 6.0, reader_wait=0.3, unit_wait=0.4)
    outcome, message = judge(s, _late_get_status(s, 3.05, 4.05))
    assert outcome == "fail", message
    assert "more than the host explains: 0.90 s beyond the limit" in message


def test_a_unit_late_by_its_own_clock_on_a_host_that_kept_pace_fails():
    """Heartbeats and the reply late by the unit's own clock while neither the reader nor the
    unit waited for a CPU: the unit stalled by itself."""
    s = _session(_heartbeats(1.0, 6.0, lambda t: 0.9 if t >= 3.0 else 0.002))
    _measuring(s, 0.0, 6.0, reader_wait=0.001, unit_wait=0.001)
    outcome, message = judge(s, _late_get_status(s, 3.05, 4.05))
    assert outcome == "fail", message


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
def test_the_process_holding_a_pseudo_terminal_is_found_as_the_unit():
    child = subprocess.Popen(
        [sys.executable, "-c", "import os, pty, sys\nm, s = pty.openpty()\n"
         "print(os.ttyname(s), flush=True)\nsys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert child.stdout is not None and child.stdin is not None
        path = child.stdout.readline().strip()
        assert pty_peer_pids(path) == (child.pid,)
        assert pty_peer_pids("/dev/null") == ()
        assert pty_peer_pids("/nonexistent/tty") == ()
    finally:
        child.stdin.close()  # type: ignore[union-attr]
        child.wait(10)


@pytest.mark.skipif(
    not os.path.exists(f"/proc/self/task/{os.getpid()}/children"), reason="reads /proc children"
)
def test_the_processes_a_test_started_and_their_waits_are_measured():
    """A realtime test's pace counts its own threads and every process it started (a command that
    started a simulator): the grandchild is found, and its threads' waits are read."""
    child = subprocess.Popen(
        [sys.executable, "-c", "import subprocess, sys\n"
         "g = subprocess.Popen([sys.executable, '-c', 'import sys; sys.stdin.read()'], "
         "stdin=subprocess.PIPE)\nprint(g.pid, flush=True)\nsys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert child.stdout is not None and child.stdin is not None
        grandchild = int(child.stdout.readline())
        me = os.getpid()
        tree = process_tree(me)
        assert tree[0] == me and child.pid in tree and grandchild in tree
        mine = threading.get_native_id()
        other_done = threading.Event()
        other = threading.Thread(target=other_done.wait, daemon=True)  # not watched
        other.start()
        pace = HostPace(
            WallClock(), unit_pids=lambda: process_tree(me)[1:], own_threads=lambda: [mine]
        )
        pace._sample_waits(0.0)
        pace._sample_waits(1.0)
        other_done.set()
        assert grandchild in pace.unit_waits and child.pid in pace.unit_waits
        assert mine in pace.unit_waits and other.native_id not in pace.unit_waits
        assert pace.unit_waits[mine].growth(0.0, 1.0) is not None
    finally:
        child.stdin.close()  # type: ignore[union-attr]
        child.wait(10)


def test_a_realtime_test_that_failed_while_its_processes_waited_for_a_cpu_is_not_judged():
    from conftest import STARVED_WAIT_FRACTION, host_starved

    quiet = PaceFigures(10.0, 2000, 0.002, 0.0, 0.003, 0.0, 0.01, 0.02)
    assert not host_starved(quiet)
    assert host_starved(quiet, slipped=0.05)
    starved_reader = PaceFigures(
        10.0, 2000, 0.002, 0.0, 0.003, 0.0, 10 * STARVED_WAIT_FRACTION, 0.0
    )
    assert host_starved(starved_reader)
    just_under = PaceFigures(10.0, 2000, 0.002, 0.0, 0.003, 0.0, 0.0, 9.9 * STARVED_WAIT_FRACTION)
    assert not host_starved(just_under)
    assert host_starved(PaceFigures(10.0, 1500, 0.05, 2.5, 0.0, 0.0))  # the timer lost 25 %
    assert host_starved(PaceFigures(10.0, 2000, 0.15, 0.0, 0.0, 0.0))  # one stall of 150 ms
