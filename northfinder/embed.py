"""The simulated instrument embedded in a host process: one helper for the CLI, tests and applications.

:class:`SimulatedInstrument` builds the simulated firmware for a sensor and a truth, puts it on a
link, drives it from a background thread with a clock, and hands back what a host needs: a CAN bus
or a ready :class:`~northfinder.driver.device.Device`, the truth, the control channel, and the
runner (whose failure :meth:`~SimulatedInstrument.check` reports)::

    from northfinder.firmware_sim.imu import Truth
    from northfinder.embed import SimulatedInstrument

    with SimulatedInstrument("nav-fog", Truth(azimuth_deg=42.0), seed=1, speed=50, warmup_s=0) as sim:
        with sim.open_device() as dev:
            dev.wait_ready()
            window = dev.acquire(10.0)

Links (``link=``):

- ``"virtual"``: python-can's ``virtual`` bus, reachable from this process only (:meth:`SimulatedInstrument.open_bus`);
- ``"serial-pty"``: the protocol's serial frames on a new pseudo-terminal (:attr:`SimulatedInstrument.path`);
- ``"slcan-pty"``: an SLCAN adapter on a new pseudo-terminal, for python-can's ``slcan`` interface.

A pty is reachable from other processes too (``northfinder find --serial PATH``).

Time (``clock=``):

- default, or ``speed=S``: paced, wall time times ``S``
  (:class:`~northfinder.firmware_sim.runner.RealTimeClock`) on a background thread;
- ``clock="virtual"`` or a :class:`~northfinder.driver.clock.VirtualClock`: virtual time, as fast
  as the CPU allows and the same for a seed whatever the machine's load. The simulator has no
  thread: it is a source of the clock, which the device from :meth:`SimulatedInstrument.open_device` shares
  (``sim.clock``). Time stands still while the host works and jumps to the next event (a
  message due, a deadline) whenever it waits, so a host waits with ``sim.clock.sleep(s)``, never
  ``time.sleep``. ``link="virtual"`` only (a pty is read by other processes on the wall clock);
- any other :class:`~northfinder.firmware_sim.runner.SimClock` (a lockstep clock, for instance).

This module is part of the application layer: it is the one place, with the CLI, that imports
the simulator and the driver.
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import time
import uuid
from pathlib import Path
from typing import Any

import can
import numpy as np
from can.interfaces.virtual import VirtualBus

from northfinder.config import RELAXED_LINK_TIMEOUT_S, RELAXED_REPLY_TIMEOUT_S
from northfinder.driver.clock import VirtualClock
from northfinder.driver.device import Device
from northfinder.driver.framelog import FrameLog
from northfinder.driver.protocol.constants import CAN_BITRATE_DEFAULT, SERIAL_BAUD_DEFAULT
from northfinder.driver.protocol.units import DEFAULT_WARMUP_S
from northfinder.firmware_sim.adapters import (
    CanLink,
    PseudoTerminal,
    SerialLink,
    SlcanAdapter,
)
from northfinder.firmware_sim.control import ControlClient, Controller, ControlServer
from northfinder.firmware_sim.errors import SimConfigError, SimError
from northfinder.firmware_sim.firmware import Firmware, LinkInfo
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.runner import BackgroundRunner, Link, RealTimeClock, Runner, SimClock
from northfinder.firmware_sim.sensors import DEFAULT_SENSOR, SensorSpec, load_spec
from northfinder.host.errors import HostConfigError

__all__ = [
    "LINKS",
    "RELAXED_DEVICE_OPTIONS",
    "SimulatedInstrument",
    "SimulatorSettingError",
    "Truth",
]


class SimulatorSettingError(SimConfigError, HostConfigError):
    """A setting of the embedded simulator it cannot take (an unknown link, both a speed and a
    clock, virtual time on a pty) or a use out of turn (not started, started twice): the
    simulator's configuration error (:class:`~northfinder.firmware_sim.errors.SimConfigError`,
    exit status 2 on the command line), and a
    :class:`~northfinder.host.errors.HostConfigError` as version 0.2 raised it."""


LINKS = ("virtual", "serial-pty", "slcan-pty")
"""The links :class:`SimulatedInstrument` can put the simulator on."""

RELAXED_DEVICE_OPTIONS: dict[str, float] = {
    "reply_timeout": RELAXED_REPLY_TIMEOUT_S,
    "min_supervision_s": RELAXED_LINK_TIMEOUT_S,
}
"""Driver options for a device whose simulator runs in the same interpreter on a busy machine: a
reply can wait for the other thread, so allow more than a real unit's deadlines
(``sim.open_device(**RELAXED_DEVICE_OPTIONS)``)."""


class _DeviceEndBus(VirtualBus):
    """The simulated device's end of a python-can ``virtual`` channel, without the copies.

    python-can's virtual bus gives every receiver a deep copy of each message sent, in case a
    receiver changes it; that copy costs more than the rest of a frame's journey. The device
    builds a new message for every frame and never touches it again, and receivers only read
    them, so this end hands every receiver on the channel the same message (stamped once).
    Receivers are ordinary ``virtual`` buses on the same channel.

    Noted 2026-12-04: python-can (4.6.1) has no public way to hand a message to the other
    receivers of a virtual channel without that copy: ``VirtualBus.send`` deep-copies it for
    every receiver. The review of hardbyte/python-can#779 (which added ``is_rx`` there) holds
    that a message should be seen as immutable and that one instance was shared for
    performance. So this end reads the bus's ``channel`` (the receivers' queues) and ``queue``
    (its own), attributes of ``VirtualBus`` without a leading underscore but not documented, and
    uses only the public API of :class:`queue.Queue` on them.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._ended = False
        super().__init__(*args, **kwargs)

    def shutdown(self) -> None:
        self._ended = True
        super().shutdown()

    def _refuse_if_ended(self) -> None:
        if self._ended:
            raise can.CanOperationError("Cannot operate on a closed bus")

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """python-can's ``recv``, which returns at once when nothing waits and no wait is asked
        (the device polls at every instant of a virtual clock)."""
        if timeout == 0 and self.queue.empty():
            self._refuse_if_ended()
            return None
        return super().recv(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.send_many([msg], timeout):
            raise can.CanOperationError("Could not send message to one or more recipients")

    def send_many(self, msgs: list[can.Message], timeout: float | None = None) -> list[can.Message]:
        """Send frames in order, handed to each receiver; return those that some receiver could
        not take (its queue full)."""
        self._refuse_if_ended()
        stamp = time.time()
        channel_id = self.channel_id
        for msg in msgs:
            msg.timestamp = stamp
            msg.channel = channel_id
            msg.is_rx = True
        dropped: list[can.Message] = []
        for bus_queue in self.channel:
            if bus_queue is self.queue:
                continue
            for msg in msgs:
                try:
                    bus_queue.put(msg, block=True, timeout=timeout)
                except queue.Full:
                    if msg not in dropped:
                        dropped.append(msg)
        return dropped


class SimulatedInstrument:
    """A simulated instrument running in this process on a link a host can open.

    Use it as a context manager (or call :meth:`start` and :meth:`close`); everything it opened is
    released on leaving, also when starting fails.

    Parameters
    ----------
    sensor : str, Path or SensorSpec
        A preset name (``"paper-rlg"``), a TOML file of the same layout, or a spec.
    truth : Truth, optional
        Where the instrument really stands (default ``Truth()``: azimuth 0, 34 deg N, level).
    seed : int, numpy Generator or None
        Seed of the sensor noise, or the generator itself (then it is used, not copied).
    speed : float, optional
        Simulated seconds per wall second of the default clock (default 1). Not with ``clock``.
    warmup_s : float
        The instrument's warm-up time, simulated s (default
        :data:`~northfinder.driver.protocol.units.DEFAULT_WARMUP_S`; 0 for none).
    link : {"virtual", "serial-pty", "slcan-pty"}
        Where the simulator is reachable (see the module docstring).
    node_id : int
        CAN node id of the simulated device.
    clock : SimClock, VirtualClock or "virtual", optional
        The clock that drives the firmware (default ``RealTimeClock(speed)``); ``"virtual"`` makes
        a new :class:`~northfinder.driver.clock.VirtualClock` (see the module docstring).
    control : str, optional
        Serve the control channel on this address (``"127.0.0.1:0"``: any free loopback port;
        ``"unix:PATH"``); :attr:`control` is then a connected client.
    bitrate : int
        CAN bit rate (``virtual``, ``slcan-pty``) or serial baud rate (``serial-pty``) the firmware
        reports and budgets its sample rates for; default the protocol's.
    log : str or Path, optional
        Log every frame the simulator receives and sends to this CAN log, in python-can's format
        for its ending (:class:`~northfinder.driver.framelog.FrameLog`; a serial session logs as
        the CAN frames of the same messages). Closed by :meth:`close`.

    Attributes
    ----------
    spec : SensorSpec
    truth : Truth
    firmware, runner : Firmware, Runner
        Available once started.
    channel : str or None
        The ``virtual`` bus channel.
    path : str or None
        The pseudo-terminal a host opens (``serial-pty``, ``slcan-pty``).
    control : ControlClient or None
        Client of the control channel, if one was asked for.
    control_address : str or None
        The control channel's address (the port chosen when 0 was asked for).

    Raises
    ------
    SimulatorSettingError
        An unknown link, both ``speed`` and ``clock``, or a virtual clock on a pty link.
    SimConfigError
        An unknown sensor preset or an invalid value (from the simulator).
    """

    def __init__(
        self,
        sensor: str | Path | SensorSpec = DEFAULT_SENSOR,
        truth: Truth | None = None,
        *,
        seed: int | np.random.Generator | None = None,
        speed: float | None = None,
        warmup_s: float = DEFAULT_WARMUP_S,
        link: str = "virtual",
        node_id: int = 1,
        clock: SimClock | VirtualClock | str | None = None,
        control: str | None = None,
        bitrate: int | None = None,
        log: str | Path | None = None,
    ) -> None:
        if link not in LINKS:
            raise SimulatorSettingError(f"link={link!r}: choose one of {', '.join(LINKS)}")
        if clock is not None and speed is not None:
            raise SimulatorSettingError("give speed or clock, not both (the speed is the clock's)")
        self.spec = sensor if isinstance(sensor, SensorSpec) else load_spec(sensor)
        self.truth = Truth() if truth is None else truth
        self.rng = np.random.default_rng(seed)
        self.warmup_s = warmup_s
        self.link = link
        self.node_id = node_id
        if isinstance(clock, str):
            if clock != "virtual":
                raise SimulatorSettingError(f"clock={clock!r}: give 'virtual' or a clock object")
            clock = VirtualClock()
        self.clock: SimClock | VirtualClock = (
            RealTimeClock(1.0 if speed is None else speed) if clock is None else clock
        )
        if self.virtual and link != "virtual":
            raise SimulatorSettingError(
                f"link={link!r}: virtual time needs the in-process link 'virtual' (a pty is "
                "read by other processes on the wall clock)"
            )
        self.bitrate = bitrate or (
            SERIAL_BAUD_DEFAULT if link == "serial-pty" else CAN_BITRATE_DEFAULT
        )
        self._control_request = control
        self._log_path = log
        self.log: FrameLog | None = None
        self.channel: str | None = None
        self.path: str | None = None
        self.control: ControlClient | None = None
        self.control_address: str | None = None
        self._firmware: Firmware | None = None
        self._runner: Runner | None = None
        self._background: BackgroundRunner | None = None
        self._stack: contextlib.ExitStack | None = None

    # -- life cycle -----------------------------------------------------------------------------
    def start(self) -> SimulatedInstrument:
        """Build the firmware, open the link, start the runner (and the control channel)."""
        if self._stack is not None:
            raise SimulatorSettingError("the simulated instrument is already started")
        kind = "serial" if self.link == "serial-pty" else "can"
        firmware = Firmware(
            self.spec,
            self.truth,
            self.rng,
            warmup_s=self.warmup_s,
            node_id=self.node_id,
            link=LinkInfo(kind, self.bitrate),
        )
        with contextlib.ExitStack() as stack:
            wire: Link
            if self._log_path is not None:
                self.log = stack.enter_context(FrameLog(self._log_path))
                if self.virtual:
                    self.log.use_clock(self.clock)
            tap = self.log
            if self.link == "virtual":
                self.channel = f"northfinder-sim-{uuid.uuid4().hex}"
                bus = _DeviceEndBus(channel=self.channel)
                stack.callback(bus.shutdown)
                wire = CanLink(bus, firmware, self.node_id, tap=tap)
            else:
                pty = PseudoTerminal()
                stack.callback(pty.close)
                self.path = pty.path
                if self.link == "serial-pty":
                    wire = SerialLink(pty.stream, firmware, tap=tap, node_id=self.node_id)
                else:
                    wire = CanLink(SlcanAdapter(pty.stream), firmware, self.node_id, tap=tap)
            runner = Runner(firmware, wire, self.clock)
            if self.virtual:
                runner.attach()
                stack.callback(runner.detach)
            else:
                self._background = stack.enter_context(BackgroundRunner(runner))
            if self._control_request is not None:
                server = ControlServer(Controller(runner), self._control_request).start()
                stack.callback(server.close)
                self.control_address = server.address
                self.control = ControlClient(server.address)
                stack.callback(self.control.close)
            self._firmware, self._runner = firmware, runner
            self._stack = stack.pop_all()
        return self

    def close(self) -> None:
        """Stop the runner and release the link and the control channel (idempotent)."""
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()

    def __enter__(self) -> SimulatedInstrument:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what a host needs ----------------------------------------------------------------------
    @property
    def firmware(self) -> Firmware:
        """The simulated firmware (lock :attr:`runner`'s ``lock`` to change it while it runs)."""
        if self._firmware is None:
            raise SimulatorSettingError("the simulated instrument is not started")
        return self._firmware

    @property
    def runner(self) -> Runner:
        """The loop that drives the firmware on its link."""
        if self._runner is None:
            raise SimulatorSettingError("the simulated instrument is not started")
        return self._runner

    @property
    def virtual(self) -> bool:
        """Whether the simulator runs in virtual time."""
        return bool(getattr(self.clock, "virtual", False))

    @property
    def speed(self) -> float | None:
        """Simulated seconds per wall second of the clock now (None in virtual time)."""
        return None if self.virtual else float(self.clock.speed)  # type: ignore[union-attr]

    def describe(self) -> dict[str, Any]:
        """The truth with the sensor's name and the speed, for printing beside a result."""
        return {**dataclasses.asdict(self.truth), "sensor": self.spec.name, "speed": self.speed}

    def check(self) -> None:
        """Raise if the simulator has stopped (its thread, or its part of a virtual clock).

        Raises
        ------
        SimError
            The runner failed (its exception is the cause) or was stopped.
        """
        if self.virtual and self._runner is not None and self._stack is not None:
            clock = self.clock
            assert isinstance(clock, VirtualClock)
            failed = [exc for party, exc in clock.errors if party is self._runner]
            if failed:
                raise SimError(f"the simulated instrument is not running: {failed[-1]!r}") from (
                    failed[-1]
                )
            return
        bg = self._background
        if bg is None or not bg.alive:
            error = None if bg is None else bg.error
            raise SimError(
                f"the simulated instrument is not running: {error!r}"
                if error is not None
                else "the simulated instrument is not running"
            ) from error

    def open_bus(self, **options: Any) -> can.BusABC:
        """A new python-can bus on the simulator's CAN link (``virtual`` or ``slcan-pty``); the
        caller shuts it down.

        Raises
        ------
        SimulatorSettingError
            The link is not CAN (``serial-pty``).
        """
        if self.link == "virtual":
            return can.Bus(interface="virtual", channel=self._started(self.channel), **options)
        if self.link == "slcan-pty":
            options.setdefault("sleep_after_open", 0)
            return can.Bus(
                interface="slcan", channel=self._started(self.path), bitrate=self.bitrate, **options
            )
        raise SimulatorSettingError(
            f"the {self.link} link is not a CAN bus: use open_device() or path"
        )

    def open_device(self, **options: Any) -> Device:
        """A :class:`~northfinder.driver.device.Device` on the simulator's link; closing it
        releases its bus or port.

        Parameters
        ----------
        **options
            Driver options (``reply_timeout``, ``retries``, ``min_supervision_s``); see also
            :data:`RELAXED_DEVICE_OPTIONS`. In virtual time the device shares :attr:`clock`.
        """
        if self.virtual:
            options.setdefault("clock", self.clock)
        if self.link == "serial-pty":
            return Device.open_serial(self._started(self.path), self.bitrate, **options)
        return Device.from_bus(self.open_bus(), self.node_id, own_bus=True, **options)

    def _started(self, where: str | None) -> str:
        if where is None or self._stack is None:
            raise SimulatorSettingError("the simulated instrument is not started")
        return where
