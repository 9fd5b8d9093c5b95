"""Sending from a process of its own: a paced simulator's output, computed ahead, written at its
due times by :mod:`~northfinder.firmware_sim.sender_child` (protocol.md 12).

A paced simulator that computes and sends in one interpreter sends late whenever a due message
waits for a computation (or, embedded, for the host) to let go of the interpreter. With a
:class:`ProcessSender` the runner's loop (:meth:`northfinder.firmware_sim.runner.Runner.run`)
computes a little ahead, as before, and encodes what the link would write (a :class:`Capture`
around the link's stream or bus collects the bytes instead of writing them); the sender process
writes them on the link's file descriptor when they are due, and nothing else runs there.

Links with a file descriptor can be sent from a process: a pseudo-terminal or serial port (the
protocol's serial frames, or SLCAN lines) and a SocketCAN socket (one ``can_frame`` per write).
Commands are still read, and answered, by the simulator's own loop.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can

from northfinder.firmware_sim import sender_child
from northfinder.firmware_sim.errors import SimError

__all__ = ["Capture", "CaptureBus", "CaptureStream", "ProcessSender"]

_SCRIPT = Path(sender_child.__file__)
log = logging.getLogger("northfinder.sim.sender")


class Capture:
    """Collects what a link writes between :meth:`begin` and :meth:`take`; writes outside that
    go to the link at once (an SLCAN adapter's acknowledgements, for instance)."""

    def __init__(self) -> None:
        self._chunks: list[bytes] | None = None

    def begin(self) -> None:
        self._chunks = []

    def take(self) -> list[bytes]:
        """What was written since :meth:`begin`, one chunk per write; capturing stops."""
        chunks, self._chunks = self._chunks or [], None
        return chunks

    def _captured(self, data: bytes) -> bool:
        if self._chunks is None:
            return False
        self._chunks.append(bytes(data))
        return True


class CaptureStream(Capture):
    """A byte stream (:class:`~northfinder.firmware_sim.adapters.ByteStream`) whose writes can be
    captured; reads go to the stream."""

    def __init__(self, stream: Any) -> None:
        super().__init__()
        self.stream = stream

    def read(self, timeout: float) -> bytes:
        data: bytes = self.stream.read(timeout)
        return data

    def write(self, data: bytes) -> None:
        if not self._captured(data):
            self.stream.write(data)

    def take(self) -> list[bytes]:
        """What was written since :meth:`begin`, as one chunk: a byte stream keeps no write
        boundaries, and one write lets a host read a due time's frames in one go."""
        chunks = super().take()
        return [b"".join(chunks)] if chunks else []

    def close(self) -> None:
        self.stream.close()


class CaptureBus(Capture):
    """A python-can SocketCAN bus whose sent frames can be captured as the ``can_frame`` structs
    a CAN_RAW socket takes; receiving goes to the bus."""

    def __init__(self, bus: can.BusABC) -> None:
        from can.interfaces.socketcan.socketcan import build_can_frame

        super().__init__()
        self.bus = bus
        self._build = build_can_frame

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.bus.recv(timeout)

    def send(self, msg: can.Message) -> None:
        if not self._captured(self._build(msg)):
            self.bus.send(msg)


class ProcessSender:
    """The sender process on one file descriptor (see the module docstring).

    Parameters
    ----------
    out_fd : int
        Where the output goes: a pseudo-terminal's master, a serial port, a CAN_RAW socket.
    spin_s : float
        The last part of each wait spent re-reading the clock rather than asleep, s.
    max_lag_s : float
        How late a message may be before the sender slips instead of catching up, wall s.
    priority : int
        ``SCHED_FIFO`` priority asked for (1..99) where the system allows it (root,
        ``CAP_SYS_NICE``, an ``RLIMIT_RTPRIO``); 0 for the ordinary class. :attr:`priority`
        says what was granted once the process reported it.

    Raises
    ------
    SimError
        The process could not be started.
    """

    SPIN_S = sender_child.SPIN_S
    PRIORITY = 10

    def __init__(
        self,
        out_fd: int,
        *,
        spin_s: float = SPIN_S,
        max_lag_s: float = 0.05,
        priority: int = PRIORITY,
    ) -> None:
        if not 0 <= priority <= 99:
            raise SimError(f"priority: must be 0 to 99, got {priority!r}")
        r, self._w = os.pipe()
        self._back, bw = os.pipe()
        try:
            self._proc = subprocess.Popen(
                [
                    sys.executable, "-I", str(_SCRIPT), str(out_fd), str(r), str(bw),
                    str(round(spin_s * 1e9)), str(round(max_lag_s * 1e9)), str(priority),
                ],
                pass_fds=(out_fd, r, bw),
                stdin=subprocess.DEVNULL,
            )  # fmt: skip
        except OSError as exc:
            os.close(self._w)
            os.close(self._back)
            raise SimError(f"cannot start the sender process: {exc}") from exc
        finally:
            os.close(r)
            os.close(bw)
        os.set_blocking(self._back, False)
        self._pending = bytearray()
        self.epoch = 0
        """How many of the sender's slips the simulator has applied to its clock."""
        self._closed = False
        self.priority: int | None = None
        """The ``SCHED_FIFO`` priority the process runs at (0: the ordinary class; None: not
        reported yet)."""

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    @property
    def returncode(self) -> int | None:
        """The process's exit status once it has ended (negative: the signal that ended it)."""
        return self._proc.poll()

    def put(self, due_s: float, chunks: Sequence[bytes]) -> None:
        """Send ``chunks`` (one write each) at ``due_s`` on the monotonic clock.

        Raises
        ------
        SimError
            The sender process has ended.
        """
        record = bytearray(sender_child.HEADER.pack(round(due_s * 1e9), self.epoch, len(chunks)))
        for chunk in chunks:
            record += sender_child.LENGTH.pack(len(chunk))
            record += chunk
        view = memoryview(bytes(record))
        try:
            while view:
                view = view[os.write(self._w, view) :]
        except BrokenPipeError as exc:
            raise SimError(f"the sender process has ended (exit {self._proc.poll()})") from exc

    def reports(self) -> list[tuple[int, int]]:
        """What the sender reported since the last call: ``(kind, value)`` records, kinds
        :data:`~northfinder.firmware_sim.sender_child.SLIP`, ``DROPPED`` and ``FAILED``."""
        while True:  # the pipe is non-blocking: read what is there
            try:
                data = os.read(self._back, 4096)
            except BlockingIOError:
                break
            if not data:
                break
            self._pending += data
        n = len(self._pending) // sender_child.BACK.size * sender_child.BACK.size
        out = [
            sender_child.BACK.unpack_from(self._pending, i)
            for i in range(0, n, sender_child.BACK.size)
        ]
        del self._pending[:n]
        for kind, value in out:
            if kind == sender_child.SCHEDULING:
                self.priority = value
                log.info(
                    "sender process %d runs %s", self.pid,
                    f"at SCHED_FIFO priority {value}" if value else
                    "in the ordinary scheduling class (real-time scheduling not permitted)",
                )  # fmt: skip
        return out

    def close(self) -> None:
        """End the sender process (what is not yet due is not sent); idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            # Never blocks: a sender that stopped reading (stopped, or starved) is killed below.
            os.set_blocking(self._w, False)
            os.write(self._w, sender_child.HEADER.pack(-1, 0, 0))
        except OSError:
            pass
        os.close(self._w)
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        os.close(self._back)
