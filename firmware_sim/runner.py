"""Clocks and the loop that drives the firmware on a link.

Three clocks: :class:`RealTimeClock` (paced from its start instant, so no drift accumulates),
the same with a speed factor (accelerated rehearsal), and :class:`LockstepClock` (the caller
advances time; for tests). The :class:`Runner` polls the link, advances the firmware to the
clock's time and sends what the firmware emits. A lock serialises the loop with the control
channel.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.firmware import Firmware, Outgoing


class Link(Protocol):
    """A wire adapter of the simulated device (:mod:`northfinder.firmware_sim.links`)."""

    def poll(self, timeout: float) -> int: ...
    def send(self, outgoing: list[Outgoing]) -> None: ...


class Clock(Protocol):
    """What a :class:`Runner` needs from a clock: simulated time, and how long to wait for it.

    :class:`RealTimeClock` and :class:`LockstepClock` are clocks; so is any object with these
    members (a virtual clock shared with a test, for instance).
    """

    @property
    def speed(self) -> float:
        """Simulated seconds per wall second."""
        ...

    @property
    def paused(self) -> bool: ...

    def now(self) -> float:
        """Simulated time, s."""
        ...

    def set_speed(self, speed: float) -> None: ...
    def pause(self) -> None: ...
    def resume(self) -> None: ...

    def wall_until(self, sim_t: float) -> float:
        """Wall seconds until simulated time ``sim_t`` (0 if past)."""
        ...


class RealTimeClock:
    """Simulated time = speed x wall time since start, re-anchored on every speed change or pause.

    Parameters
    ----------
    speed : float
        Simulated seconds per wall second (1 = real time).
    monotonic : callable
        Wall clock (``time.monotonic``); injectable for tests.
    """

    def __init__(self, speed: float = 1.0, monotonic: Callable[[], float] = time.monotonic) -> None:
        self._monotonic = monotonic
        self._check(speed)
        self._speed = float(speed)
        self._anchor_wall = monotonic()
        self._anchor_sim = 0.0
        self._paused = False

    @staticmethod
    def _check(speed: float) -> None:
        if not (isinstance(speed, int | float) and 0 < speed <= 10_000):
            raise SimConfigError(f"speed: must be a number in (0, 10000], got {speed!r}")

    @property
    def speed(self) -> float:
        return self._speed

    @property
    def paused(self) -> bool:
        return self._paused

    def now(self) -> float:
        if self._paused:
            return self._anchor_sim
        return self._anchor_sim + (self._monotonic() - self._anchor_wall) * self._speed

    def _reanchor(self) -> None:
        self._anchor_sim = self.now()
        self._anchor_wall = self._monotonic()

    def set_speed(self, speed: float) -> None:
        self._check(speed)
        self._reanchor()
        self._speed = float(speed)

    def pause(self) -> None:
        self._reanchor()
        self._paused = True

    def resume(self) -> None:
        if self._paused:
            self._anchor_wall = self._monotonic()
            self._paused = False

    def wall_until(self, sim_t: float) -> float:
        """Wall seconds until simulated time ``sim_t`` (0 if past; long if paused)."""
        if self._paused:
            return 0.05
        return max(0.0, (sim_t - self.now()) / self._speed)


class LockstepClock:
    """A clock that moves only when told: ``advance(dt)``."""

    def __init__(self) -> None:
        self._t = 0.0
        self.speed = 1.0
        self.paused = False

    def now(self) -> float:
        return self._t

    def advance(self, dt: float) -> None:
        self._t += dt

    def set_speed(self, speed: float) -> None:
        self.speed = speed

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        self.paused = False

    def wall_until(self, sim_t: float) -> float:
        return 0.0


class Runner:
    """Drives one firmware on one link with one clock.

    ``step()`` does one round (poll, advance, send); ``run(stop)`` loops until ``stop`` is set.
    """

    def __init__(self, firmware: Firmware, link: Link, clock: Clock) -> None:
        self.firmware = firmware
        self.link = link
        self.clock = clock
        self.lock = threading.RLock()
        self.sent = 0

    #: Most simulated time one step covers. When the simulator runs behind (a fast speed factor or
    #: a busy machine) it catches up in steps this long, polling the link between them, so
    #: commands are still answered within the protocol's reply deadline.
    MAX_STEP_S = 0.02
    #: Longest wait for incoming frames between steps, wall seconds.
    MAX_WAIT_S = 0.05

    def step(self, poll_timeout: float = 0.0) -> None:
        self.link.poll(poll_timeout)
        with self.lock:
            dt = min(self.clock.now() - self.firmware.now, self.MAX_STEP_S)
            if dt > 0:
                out = self.firmware.process(dt)
                self.sent += len(out)
                self.link.send(out)
                self.firmware.prefetch()

    def run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            # Sleep until the next message is due; a frame arriving ends the wait at once.
            with self.lock:
                due = self.firmware.next_output_s()
            self.step(min(self.MAX_WAIT_S, self.clock.wall_until(due)))


class BackgroundRunner:
    """A runner on its own thread: ``with BackgroundRunner(runner): ...`` starts and stops it.

    Used to embed a simulated instrument in a host process (``northfinder find --sim``, tests).
    """

    def __init__(self, runner: Runner) -> None:
        self.runner = runner
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="simulator", daemon=True)
        self.error: BaseException | None = None

    def _run(self) -> None:
        try:
            self.runner.run(self._stop)
        except BaseException as exc:  # reported to the owner; a dead simulator must not be silent
            self.error = exc
            raise

    def start(self) -> BackgroundRunner:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    @property
    def alive(self) -> bool:
        """Whether the runner's thread runs (False before :meth:`start`, after :meth:`stop` or a
        failure, whose exception is :attr:`error`)."""
        return self._thread.is_alive()

    def __enter__(self) -> BackgroundRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
