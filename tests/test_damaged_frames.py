"""A damaged frame costs at most its tick: the window is measured again or the gap is reported, as
the user chooses (``--on-gap``); a garbled SLCAN line is a frame error, not a lost link; a window
in hand is kept when the STREAM_STOP reply does not come."""

from __future__ import annotations

import subprocess
import sys

import can
import pytest
from conftest import later_on
from simprocess import sim_process

from northfinder.driver.errors import ReplyTimeout, StreamGap
from northfinder.driver.protocol.constants import Opcode
from northfinder.driver.transport import CanTransport
from northfinder.embed import SimulatedInstrument
from northfinder.host.plan import Plan
from northfinder.host.procedure import find_north

PLAN = Plan((0.0, 180.0), 2.0)


def _drop_one(sim: SimulatedInstrument) -> None:
    sim.firmware.faults.drop_frames = 2  # a sample frame or two: at least one tick lost


@pytest.mark.parametrize("on_gap", ["remeasure", "report", "fail"])
def test_a_lost_frame_in_a_window_by_on_gap(on_gap):
    with (
        SimulatedInstrument("ideal", seed=1, clock="virtual", warmup_s=0.0) as sim,
        sim.open_device() as dev,
    ):
        dev.wait_ready(5.0)
        with later_on(dev.clock, 1.5, _drop_one, sim):  # mid-window 1
            if on_gap == "fail":
                with pytest.raises(StreamGap):
                    find_north(dev, PLAN, 34.0, on_gap=on_gap)
                return
            result, raw = find_north(dev, PLAN, 34.0, on_gap=on_gap)
    notes = " ".join(result.windows[0].notes)
    if on_gap == "remeasure":
        assert raw[0].missing == 0 and "measured again 1 time(s)" in notes
    else:
        assert raw[0].missing >= 1 and "sample ticks missing" in notes
        assert result.windows[0].samples == 400 - raw[0].missing
    assert abs((result.azimuth_deg - sim.truth.azimuth_deg + 180) % 360 - 180) < 1e-3


def test_a_window_in_hand_is_kept_when_stream_stop_is_not_answered(monkeypatch):
    with (
        SimulatedInstrument("ideal", seed=1, clock="virtual", warmup_s=0.0) as sim,
        sim.open_device() as dev,
    ):
        dev.wait_ready(5.0)
        real = dev.release_stream
        calls = []

        def lost_reply() -> None:
            calls.append(1)
            if len(calls) == 1:
                raise ReplyTimeout("no reply to STREAM_STOP", 0.75, Opcode.STREAM_STOP, 3, True)
            real()

        monkeypatch.setattr(dev, "release_stream", lost_reply)
        result, raw = find_north(dev, PLAN, 34.0)
    assert len(raw) == 2 and "STREAM_STOP unanswered" in " ".join(result.windows[0].notes)


def test_a_garbled_slcan_line_is_a_frame_error_not_a_lost_link():
    bus = can.Bus(interface="slcan", channel="loop://", sleep_after_open=0)
    transport = CanTransport(bus, 1, own_bus=True)
    try:
        port = bus.serialPortOrig  # type: ignore[attr-defined]
        port.write(b"t1\xff38\r")  # a byte that is not ASCII: python-can cannot decode the line
        port.write(b"t12Z8\r")  # a length that is not a digit
        port.write(b"t7FF10A\r")  # a good line after them (an id of no protocol message)
        got = []
        for _ in range(20):
            got += transport.recv(0.05)
            if transport.counters()["frames_received"]:
                break
        assert transport.garbled == 2
        assert transport.counters()["frames_rejected"] == 2
        assert transport.counters()["frames_received"] == 1
    finally:
        transport.close()


CLI = [sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())"]


@pytest.mark.realtime
def test_find_over_serial_survives_a_corrupted_sample():
    # Five times real time: the two windows and the half turn in seconds, not half a minute
    # (at ten times a starved host made the simulator slip, which this run cannot excuse).
    args = ["--pty", "--warmup", "0", "--control", "127.0.0.1:0", "--sensor", "ideal"]
    with sim_process(*args, "--speed", "5", ready=True) as facts:
        from northfinder.firmware_sim.control import ControlClient

        argv = [*CLI, "find", "--serial", facts["pty"], "--latitude", "34", "--window", "2",
                "--positions", "0,180", "--json", "--link-timeout", "2"]  # fmt: skip
        with ControlClient(facts["control"]) as ctl:
            proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            while not ctl.call("status")["streaming"]:
                assert proc.poll() is None
            ctl.call("corrupt", count=1)
            out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "measured again 1 time(s)" in out
