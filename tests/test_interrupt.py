"""A host that ends for any reason (SIGINT, SIGTERM, SIGHUP, an error) leaves the unit at rest and
quiet: STOP for a move it commanded, STREAM_STOP for a stream it started, nothing else.

The driver's part in virtual time; the command line's with real processes and real signals, the
unit's state read afterwards through the simulator's control channel (``tests/interruption.py``).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
from typing import Any

import can
import pytest
from conftest import later_on
from interruption import FIND, PLAN, host_link_args, interrupt_during_move, sim_link_args
from simprocess import sim_process

from northfinder.driver.clock import VirtualClock, WallClock
from northfinder.driver.errors import (
    LinkLost,
    MoveTimeout,
    ReplyTimeout,
    StreamGap,
    StreamTimeout,
)
from northfinder.driver.protocol.can import decode_can
from northfinder.driver.protocol.constants import DeviceState, Opcode
from northfinder.driver.protocol.messages import Command
from northfinder.embed import SimulatedInstrument


def _interrupt_as_a_python_enter_returns(frame, event, arg):
    """A trace function that raises KeyboardInterrupt as any Python-level ``__enter__`` of the
    threading module returns: where a signal handler can run after the lock was taken and before
    the ``with`` statement guards it (CPython issue 29988)."""
    if event == "call" and frame.f_code.co_name == "__enter__":
        caller = frame.f_back.f_code.co_filename if frame.f_back is not None else ""
        # only the product's own locks (not a finalizer's that the collector runs meanwhile)
        if frame.f_code.co_filename == threading.__file__ and caller.endswith(
            ("clock.py", "runner.py")
        ):

            def at_return(frame, event, arg):
                if event == "return":
                    raise KeyboardInterrupt
                return at_return

            return at_return
    return None


@pytest.mark.parametrize("clock", [WallClock, VirtualClock])
def test_an_interrupt_as_the_clock_takes_its_lock_leaves_the_lock_free(clock):
    # Seen on vcan0 (2 of 80 runs of find sent SIGINT during a move): the interrupted wait left
    # the clock's lock held; the reader thread's notify and the clean-up's next wait then blocked
    # for good. The clocks take their lock through its own C-level __enter__, which leaves no gap.
    c = clock()

    def interrupted(call):
        previous = sys.gettrace()
        sys.settrace(_interrupt_as_a_python_enter_returns)
        try:
            with contextlib.suppress(KeyboardInterrupt):
                call()
        finally:
            sys.settrace(previous)

    def lock_free() -> bool:  # another thread's notify, as the driver's reader makes it
        other = threading.Thread(target=c.notify, daemon=True)
        other.start()
        other.join(5.0)
        return not other.is_alive()

    interrupted(lambda: c.wait_until(lambda: True, None))
    assert lock_free(), "an interrupted wait_until left the clock's lock held"
    interrupted(c.notify)
    assert lock_free(), "an interrupted notify left the clock's lock held"
    assert c.wait_until(lambda: True, c.now() + 1.0)


def test_an_interrupt_as_the_simulators_sender_takes_its_lock_leaves_the_lock_free():
    from northfinder.firmware_sim.runner import PacedSender

    sender = PacedSender(runner=None)  # type: ignore[arg-type]  # put() needs no runner
    previous = sys.gettrace()
    sys.settrace(_interrupt_as_a_python_enter_returns)
    try:
        with contextlib.suppress(KeyboardInterrupt):
            sender.put([])
    finally:
        sys.settrace(previous)
    other = threading.Thread(target=sender.put, args=([],), daemon=True)
    other.start()
    other.join(5.0)
    assert not other.is_alive(), "an interrupted put left the sender's lock held"


def _instrument() -> SimulatedInstrument:
    return SimulatedInstrument("ideal", seed=1, clock="virtual", warmup_s=0.0)


def test_leaving_a_move_sends_stop_and_the_table_comes_to_rest():
    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        dev.rotate_to(180.0, wait=False)
        dev.clock.sleep(1.0)
        assert sim.firmware.state == DeviceState.ROTATING
        rest = dev.leave_at_rest()
        assert rest.sent == ("STOP",)
        assert rest.state in ("SETTLING", "READY")
        assert "sent STOP; the unit reads" in rest.summary()
        assert sim.firmware.state != DeviceState.ROTATING
        # Idempotent: nothing more to undo, the same report.
        assert dev.leave_at_rest() is rest


def test_leaving_a_window_sends_stream_stop_and_a_settled_move_needs_no_stop():
    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        dev.rotate_to(90.0)  # settled: nothing of it to undo
        dev.start_streaming()
        rest = dev.leave_at_rest()
        assert rest.sent == ("STREAM_STOP",)
        assert not sim.firmware.streaming


def test_close_after_an_error_in_a_with_block_leaves_the_unit_at_rest():
    with _instrument() as sim:
        with pytest.raises(RuntimeError), sim.open_device() as dev:
            dev.wait_ready(5.0)
            dev.start_streaming()
            dev.rotate_to(180.0, wait=False)
            dev.clock.sleep(0.5)
            raise RuntimeError("the host's own failure")
        assert dev.at_rest is not None and dev.at_rest.sent == ("STOP", "STREAM_STOP")
        assert not sim.firmware.streaming
        assert sim.firmware.state != DeviceState.ROTATING


def test_a_host_that_only_looks_stops_nothing():
    # Another host's stream and move are not this host's to stop (issue: a second Device that
    # merely connected and closed stopped the first one's stream).
    with _instrument() as sim, sim.open_device() as first:
        first.wait_ready(5.0)
        first.start_streaming()
        first.rotate_to(180.0, wait=False)
        with sim.open_device() as second:
            assert second.streaming  # it reads the configuration: the unit streams
            assert not second.leave_at_rest().needed
        assert sim.firmware.streaming
        assert sim.firmware.state == DeviceState.ROTATING


# -- the command line, with real processes and real signals -----------------------------------


def _case(link: str, signum: signal.Signals | int) -> Any:
    name = signal.Signals(signum).name if signum else "silence"
    return pytest.param(
        link,
        signum,
        id=f"{name}-{link}",
        marks=pytest.mark.skipif(
            link == "socketcan" and not os.path.exists("/sys/class/net/vcan0"),
            reason="no vcan0 (scripts/hil runs benchmarks/bench_robustness.py there)",
        ),
    )


# Each signal once and each pseudo-terminal link at least once (the handler is one for every
# signal and the STOP it sends one for every link: the whole cross product on ptys took twice as
# long and showed nothing more); every signal on vcan0 where it exists.
SIGNAL_CASES = [
    _case("serial-pty", signal.SIGINT),
    _case("slcan-pty", signal.SIGTERM),
    _case("serial-pty", signal.SIGHUP),
    *(_case("socketcan", s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)),
]


# Beside other tests (realtime(alone=False)): nothing here is about the CPU the processes get.
# The signal goes once the control channel reads ROTATING (a move of seconds) or streaming, the
# host has 30 s to exit, and the unit is read afterwards; all green beside two CPU-bound processes.
@pytest.mark.realtime(alone=False)
@pytest.mark.parametrize(("link", "signum"), SIGNAL_CASES)
def test_a_signal_during_a_move_leaves_the_unit_at_rest(link, signum):
    run = interrupt_during_move(link, signum)
    assert run.caught_moving
    assert run.returncode == 128 + signum
    assert run.state in ("READY", "SETTLING"), run
    assert not run.streaming
    assert "sent STOP" in run.last_line and "the unit reads" in run.last_line, run.last_line
    if signum != signal.SIGINT:
        assert signal.Signals(signum).name in run.last_line


# A spin, ended by each signal and by the unit's silence (0: no signal; the unit sends nothing
# for 0.8 s, the host's link supervision ends the run after 0.3 s): the table braked, the stream
# stopped, the last line saying so.
SPIN_CASES = [
    _case("serial-pty", signal.SIGINT),
    _case("slcan-pty", signal.SIGTERM),
    _case("serial-pty", 0),
    _case("slcan-pty", 0),
    *(_case("socketcan", s) for s in (signal.SIGINT, 0)),
]


@pytest.mark.realtime(alone=False)
@pytest.mark.parametrize(("link", "signum"), SPIN_CASES)
def test_a_signal_or_a_silence_during_a_spin_leaves_the_unit_at_rest(link, signum):
    run = interrupt_during_move(link, signum, spin=True)
    assert run.caught_moving
    assert run.returncode == (128 + signum if signum else 1), run
    assert run.state in ("READY", "SETTLING"), run
    assert not run.streaming
    assert "sent STOP and STREAM_STOP" in run.last_line, run.last_line
    assert re.search(r"the unit reads (READY|SETTLING)\b", run.last_line), run.last_line


def _commands(log_path: str) -> list[Opcode]:
    out = []
    with can.LogReader(log_path) as reader:
        for msg in reader:
            try:
                decoded = decode_can(msg.arbitration_id, msg.data).message
            except Exception:
                continue
            if isinstance(decoded, Command):
                out.append(decoded.OPCODE)
    return out


@pytest.mark.realtime(alone=False)
def test_sigterm_during_a_window_stops_the_stream_and_flushes_the_can_log(tmp_path):
    log = tmp_path / "run.log"
    # Ten times real time: the first window begins after the move to 0 and its settle time
    # (10 s of the unit's time), 1 s of wall time instead of 10; the signal and what it leaves
    # are the same at any speed.
    args = [*sim_link_args("serial-pty"), "--warmup", "0", "--control", "127.0.0.1:0"]
    args += ["--speed", "10"]
    with sim_process(*args, ready=True) as facts:
        from northfinder.firmware_sim.control import ControlClient

        argv = [*FIND, *host_link_args("serial-pty", facts), *PLAN, "--can-log", str(log)]
        argv += ["--link-timeout", "2"]  # a loaded machine reads its link late
        with ControlClient(facts["control"]) as ctl:
            proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True)
            try:
                while not ctl.call("status")["streaming"]:
                    assert proc.poll() is None
                proc.send_signal(signal.SIGTERM)
                _, err = proc.communicate(timeout=30)
            finally:
                if proc.poll() is None:
                    proc.kill()
            status = ctl.call("status")
    assert proc.returncode == 143, err
    assert "sent STREAM_STOP" in err.strip().splitlines()[-1]
    assert not status["streaming"]
    sent = _commands(str(log))
    last_start = max(i for i, op in enumerate(sent) if op == Opcode.STREAM_START)
    assert Opcode.STREAM_STOP in sent[last_start:]  # sent on leaving, and in the log


def test_signal_exit_statuses_are_stated():
    from northfinder.cli import main
    from northfinder.cli.exits import SignalInterrupt

    assert SignalInterrupt(signal.SIGTERM).signum == 15
    assert isinstance(SignalInterrupt(signal.SIGHUP), KeyboardInterrupt)
    # A subcommand ended by SIGTERM in this process: the handler main() installs raises.
    done = subprocess.run(
        [sys.executable, "-c", "import os, signal, sys\n"
         "from northfinder.cli import main\n"
         "import northfinder.cli.simulate as s\n"
         "s.run = lambda args: os.kill(os.getpid(), signal.SIGTERM) or signal.pause()\n"
         "sys.exit(main(['simulate']))"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 143, done.stderr
    assert done.stderr.strip() == "northfinder simulate: interrupted (SIGTERM)"
    assert main is not None


def test_a_stream_start_whose_reply_is_lost_is_still_stopped_on_leaving(monkeypatch):
    # Under load the reply to STREAM_START can be lost while the stream did start: leaving must
    # stop it (else the stream runs on with nobody reading it).
    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        prepare = dev._prepare_stream_start

        def then_late_replies() -> None:
            prepare()
            sim.firmware.faults.reply_delay_s = 5.0  # STREAM_START's replies all come too late

        monkeypatch.setattr(dev, "_prepare_stream_start", then_late_replies)
        with pytest.raises(ReplyTimeout):
            dev.start_streaming()
        sim.firmware.faults.reply_delay_s = 0.0
        assert sim.firmware.streaming
        assert dev.leave_at_rest().sent == ("STREAM_STOP",)
        assert not sim.firmware.streaming


# -- a spin: the table turns until told to stop ---------------------------------------------------

MOVING = (DeviceState.ROTATING, DeviceState.SPINNING)


def _silent(sim: SimulatedInstrument, on: bool) -> None:
    sim.firmware.faults.silent = on


def test_leaving_a_spin_sends_stop_and_waits_until_the_table_braked():
    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        dev.start_streaming()
        dev.spin(9.0)
        assert sim.firmware.state == DeviceState.SPINNING
        rest = dev.leave_at_rest()
        assert rest.sent == ("STOP", "STREAM_STOP") and not rest.failed
        assert rest.state in ("SETTLING", "READY"), rest
        assert sim.firmware.state not in MOVING and not sim.firmware.streaming
        assert dev.leave_at_rest() is rest


def test_a_spin_whose_start_reply_is_lost_is_still_stopped_on_leaving():
    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        sim.firmware.faults.drop_replies = 1  # SPIN carried out, its answer never comes
        with pytest.raises(ReplyTimeout):
            dev.spin(9.0, wait=False)
        dev.clock.sleep(1.0)
        assert sim.firmware.state in MOVING
        assert dev.leave_at_rest().sent == ("STOP",)
        assert sim.firmware.state not in MOVING


@pytest.mark.parametrize("silence_s", [0.8, 3.0])
@pytest.mark.parametrize("when_s", [0.2, 1.0, 4.0], ids=["mid-ramp", "spinning", "late"])
def test_a_spin_ended_by_a_silent_unit_is_stopped_once_it_speaks_again(when_s, silence_s):
    # The unit falls silent (mid-ramp, mid-spin): the link counts as lost after three heartbeat
    # periods and the spin fails, but the unit has not gone: STOP and STREAM_STOP are repeated
    # until it answers, and the table is seen braked.
    from northfinder.host.procedure import find_north_spin

    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        t0 = dev.clock.now()
        with (
            later_on(dev.clock, when_s, _silent, sim, True),
            later_on(dev.clock, when_s + silence_s, _silent, sim, False),
            pytest.raises((LinkLost, StreamTimeout, ReplyTimeout)),
        ):
            find_north_spin(dev, 9.0, 12.0, 34.0)
        rest = dev.at_rest
        assert rest is not None and rest.sent[:1] == ("STOP",) and not rest.failed, rest
        assert rest.state in ("SETTLING", "READY"), rest
        assert sim.firmware.state not in MOVING and not sim.firmware.streaming
        assert dev.clock.now() - t0 < when_s + silence_s + 10.0


def test_a_unit_silent_beyond_the_retries_is_reported_not_stopped():
    # Silent for good: the host gives up after its retries and says what it could not send.
    from northfinder.driver.device_link import LEAVE_RETRY_S

    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        dev.spin(9.0)
        sim.firmware.faults.silent = True
        t0 = dev.clock.now()
        rest = dev.leave_at_rest()
        assert rest.failed == ("STOP",) and rest.sent == ()
        assert "could not send STOP" in rest.summary()
        assert LEAVE_RETRY_S <= dev.clock.now() - t0 < LEAVE_RETRY_S + 3.0
        assert sim.firmware.state == DeviceState.SPINNING


def test_an_error_in_a_spin_leaves_the_table_stopped_before_it_goes_on(monkeypatch):
    # An exception in the middle of the spin (a user's callback, a bug): the procedure stops
    # the table before the exception leaves it, whatever the caller does with the device next.
    from northfinder.host.procedure import find_north_spin

    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)

        def boom(*args, **kwargs):
            raise RuntimeError("the host's own failure")

        monkeypatch.setattr(dev, "acquire", boom)
        with pytest.raises(RuntimeError):
            find_north_spin(dev, 9.0, 12.0, 34.0)
        assert dev.at_rest is not None and dev.at_rest.sent[0] == "STOP"
        assert sim.firmware.state not in MOVING


def test_an_exception_in_a_progress_callback_leaves_the_table_stopped():
    # The caller's own callback fails mid-move: find_north stops the table and the stream it
    # started before the exception goes on.
    from northfinder.host.plan import Plan
    from northfinder.host.procedure import find_north

    with _instrument() as sim, sim.open_device() as dev:

        def failing(progress):
            if progress.phase == "acquire" and progress.position == 2:
                dev.rotate_to(90.0, wait=False)  # the callback turns the table, then fails
                dev.clock.sleep(0.2)
                raise RuntimeError("the caller's callback failed")

        dev.wait_ready(5.0)
        with pytest.raises(RuntimeError):
            find_north(dev, Plan((0.0, 180.0), 1.0), 34.0, progress=failing)
        assert dev.at_rest is not None and dev.at_rest.sent == ("STOP",), dev.at_rest
        assert sim.firmware.state not in MOVING and not sim.firmware.streaming


def _slow(sim: SimulatedInstrument, seconds: float) -> None:
    sim.firmware.faults.reply_delay_s = seconds


@pytest.mark.parametrize(
    ("fault", "when_s", "lasting_s"),
    [
        ("silent", 0.3, 0.8),  # mid-move to the first position
        ("silent", 1.6, 0.8),  # in the first window
        ("silent", 2.05, 0.8),  # between the windows: the move to 180
        ("slow", 0.0, 1.5),  # replies 0.6 s late (beyond 0.25 s): ROTATE_TO's reply too
    ],
    ids=["silent-mid-move", "silent-in-window", "silent-between-windows", "slow-replies"],
)
def test_a_find_ended_by_a_silent_or_slow_unit_leaves_it_at_rest(fault, when_s, lasting_s):
    from northfinder.host.plan import Plan
    from northfinder.host.procedure import find_north

    on, off = (
        ((_silent, True), (_silent, False)) if fault == "silent" else ((_slow, 0.6), (_slow, 0.0))
    )
    with _instrument() as sim, sim.open_device() as dev:
        dev.wait_ready(5.0)
        dev.rotate_to(90.0)  # the plan starts with a move
        with (
            later_on(dev.clock, when_s, on[0], sim, on[1]),
            later_on(dev.clock, when_s + lasting_s, off[0], sim, off[1]),
        ):
            with pytest.raises((LinkLost, StreamTimeout, ReplyTimeout, MoveTimeout, StreamGap)):
                find_north(dev, Plan((0.0, 180.0), 1.0), 34.0, on_gap="fail")
        rest = dev.at_rest
        assert rest is not None and not rest.failed, rest
        assert sim.firmware.state not in MOVING and not sim.firmware.streaming
