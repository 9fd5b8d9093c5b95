"""The paced sender's own process: writes output computed ahead to a link at its due times.

:class:`northfinder.firmware_sim.sender.ProcessSender` starts this file as a script
(``python -I sender_child.py OUT_FD IN_FD BACK_FD SPIN_NS MAX_LAG_NS PRIORITY``). It uses the standard library
only, so it starts in milliseconds, and nothing else runs in its interpreter: no computation and
no host can hold it up when a message is due. It sleeps until shortly before each due time, spins
the last ``SPIN_NS`` on the monotonic clock, and writes.

Input on ``IN_FD`` (a pipe from the simulator), one record per due time::

    <q due_ns> <q epoch> <I count>  then count x (<I length> bytes)

``due_ns`` is on ``CLOCK_MONOTONIC`` (shared by every process of the machine); each chunk is one
``write`` on ``OUT_FD`` (a pseudo-terminal, a serial port or a CAN_RAW socket, where one write is
one frame). ``due_ns < 0``, or the end of the input, ends the process (what was not yet due is
not sent: the simulator stopped). ``epoch`` is how many of this process's slips the
simulator had applied to its clock when it computed the record.

A record found more than ``MAX_LAG_NS`` late (this process was stalled or starved) is written at
once and everything after it moves by the same delay (a *slip*), so the stream goes on at its pace
instead of sending a backlog in a burst; records computed before the simulator learnt of the slip
(lower ``epoch``) move with it. Output on ``BACK_FD``, records ``<q kind> <q value>``: kind 1, a
slip of ``value`` ns; kind 2, ``value`` chunks the link did not take (its buffer full for
:data:`WRITE_WAIT_S`); kind 3, the link failed (``value``: errno) and this process ends; kind 4,
once at the start, the ``SCHED_FIFO`` priority it runs at (``PRIORITY`` > 0 asks for it where
the system allows it; 0: the ordinary class).
"""

from __future__ import annotations

import os
import select
import struct
import sys
import time
from collections import deque

HEADER = struct.Struct("<qqI")
LENGTH = struct.Struct("<I")
BACK = struct.Struct("<qq")
SLIP, DROPPED, FAILED, SCHEDULING = 1, 2, 3, 4
#: The last part of a wait spent re-reading the clock rather than asleep (a sleep wakes up
#: late), s: the default of the sender process and of the simulator's own paced loop.
SPIN_S = 0.0003
#: Spin on the clock only where one read costs less than this, ns.
CHEAP_CLOCK_READ_NS = 5_000
#: Longest wait for a link that does not take a chunk (its buffer full), s; then it is dropped.
WRITE_WAIT_S = 0.05


def cheap_clock() -> bool:
    """Whether a read of the monotonic clock costs less than :data:`CHEAP_CLOCK_READ_NS` here
    (measured over 100 reads): in user-mode Linux each is a system call of 30 to 120 us, and a
    spin would take the guest's one CPU from the processes beside the instrument."""
    t0 = time.perf_counter_ns()
    for _ in range(100):
        time.monotonic_ns()
    return time.perf_counter_ns() - t0 < 100 * CHEAP_CLOCK_READ_NS


def parse(buf: bytearray, out: deque[tuple[int, int, list[bytes]]]) -> bool:
    """Move the whole records at the start of ``buf`` to ``out``; False once the stop record came."""
    pos = 0
    while len(buf) - pos >= HEADER.size:
        due, epoch, count = HEADER.unpack_from(buf, pos)
        if due < 0:
            return False
        p = pos + HEADER.size
        chunks = []
        for _ in range(count):
            if len(buf) - p < LENGTH.size:
                break
            (n,) = LENGTH.unpack_from(buf, p)
            if len(buf) - p - LENGTH.size < n:
                break
            chunks.append(bytes(buf[p + LENGTH.size : p + LENGTH.size + n]))
            p += LENGTH.size + n
        if len(chunks) < count:
            break  # the rest of this record has not arrived yet
        out.append((due, epoch, chunks))
        pos = p
    del buf[:pos]
    return True


def write_all(fd: int, chunk: bytes) -> bool:
    """One write of ``chunk`` (waiting up to WRITE_WAIT_S for room); False if it was dropped."""
    deadline = time.monotonic() + WRITE_WAIT_S
    view = memoryview(chunk)
    while view:
        try:
            n = os.write(fd, view)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            if exc.errno == 105:  # ENOBUFS: a CAN socket's transmit queue is full
                n = 0
            else:
                raise
        view = view[n:]
        if view:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            select.select([], [fd], [], left)
    return True


def main(argv: list[str]) -> int:
    out_fd, in_fd, back_fd = (int(a) for a in argv[1:4])
    spin_ns, max_lag_ns, priority = int(argv[4]), int(argv[5]), int(argv[6])
    os.set_blocking(in_fd, False)
    granted = 0
    if priority > 0:
        # A real-time scheduling class, where the system allows it (root, CAP_SYS_NICE or an
        # RLIMIT_RTPRIO): woken by its timer, this process then runs before any ordinary one.
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            granted = priority
        except (OSError, AttributeError):
            granted = 0
    os.write(back_fd, BACK.pack(SCHEDULING, granted))
    if not cheap_clock():
        spin_ns = 0  # each clock read a costly system call (user-mode Linux): no spin
    buf = bytearray()
    items: deque[tuple[int, int, list[bytes]]] = deque()
    slips: list[int] = []
    running = True
    monotonic_ns = time.monotonic_ns

    def read_input(timeout: float | None) -> bool:
        """Wait up to ``timeout`` s for input and parse it; False at end of input."""
        ready, _, _ = select.select([in_fd], [], [], timeout)
        if not ready:
            return True
        try:
            data = os.read(in_fd, 1 << 16)
        except BlockingIOError:
            return True
        if not data:
            return False
        buf.extend(data)
        return parse(buf, items)

    while running:
        if not items:
            running = read_input(None)
            continue
        due, epoch, chunks = items[0]
        if epoch < len(slips):
            due += sum(slips[epoch:])
        wait_ns = due - monotonic_ns()
        if wait_ns > spin_ns:
            # Sleep (reading what comes meanwhile) until shortly before the due time.
            running = read_input((wait_ns - spin_ns) / 1e9)
            continue
        while monotonic_ns() < due:
            pass  # the last moments on the clock itself: a sleep wakes up late
        late = monotonic_ns() - due
        if late > max_lag_ns:
            slips.append(late)
            os.write(back_fd, BACK.pack(SLIP, late))
        items.popleft()
        dropped = 0
        for chunk in chunks:
            try:
                if not write_all(out_fd, chunk):
                    dropped += 1
            except OSError as exc:
                os.write(back_fd, BACK.pack(FAILED, exc.errno or 0))
                return 1
        if dropped:
            os.write(back_fd, BACK.pack(DROPPED, dropped))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
