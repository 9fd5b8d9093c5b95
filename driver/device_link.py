"""The link half of :class:`~northfinder.driver.device.Device`: what arrives, and requests.

:class:`DeviceLink` owns the transport and the state that the device's messages update. A reader
thread (on a virtual clock: a poller the clock calls at every instant) receives everything and
sorts it: replies go to the caller waiting for their sequence number, statuses and identify
update the device's state (and feed link supervision, protocol.md 6), samples and tick losses go
to an acquisition in progress. Requests are sent with a fresh sequence number and retried if
they are :data:`RETRYABLE`. :class:`~northfinder.driver.device.Device` builds the protocol's
operations (queries, configuration, motion, acquisition) on it; the module docstring of
:mod:`northfinder.driver.device` states the threads and the timing.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from northfinder.driver.clock import Clock, WallClock
from northfinder.driver.errors import (
    AnotherHost,
    ArgumentError,
    DeviceRefused,
    DriverError,
    LinkError,
    LinkLost,
    NodeConflict,
    ReplyTimeout,
)
from northfinder.driver.protocol.can import TickLoss
from northfinder.driver.protocol.constants import (
    HEARTBEAT_PERIOD_DEFAULT_MS,
    ConfigKey,
    DeviceState,
    Fault,
    Opcode,
    Result,
    result_meaning,
)
from northfinder.driver.protocol.messages import (
    Command,
    GetStatus,
    Identify,
    Reply,
    Sample,
    Status,
    Stop,
    StreamStop,
)
from northfinder.driver.protocol.motion import DEFAULT_MAX_ACCEL_DPS2, DEFAULT_MAX_RATE_DPS
from northfinder.driver.transport import READ_POLL_S, Received, Transport
from northfinder.driver.window import CountScales, SampleInbox

__all__ = [
    "HEARTBEATS_UNTIL_LOST",
    "REPLY_TIMEOUT_S",
    "RETRIES",
    "RETRYABLE",
    "AtRest",
    "DeviceLink",
    "DeviceStatus",
    "LinkStats",
]

log = logging.getLogger("northfinder.driver")

RETRYABLE = frozenset(
    {
        Opcode.IDENTIFY,
        Opcode.GET_STATUS,
        Opcode.GET_CONFIG,
        Opcode.SET_CONFIG,
        Opcode.STREAM_START,
        Opcode.STREAM_STOP,
        Opcode.STOP,
    }
)
"""Commands sent again (with a new sequence number) when their reply does not come.

Queries change nothing; STREAM_START/STOP and STOP leave the same state however often they
arrive; SET_CONFIG writes an absolute value, so applying it twice equals applying it once (its
reply echoes the value in effect). ROTATE_TO/BY and HOME are not repeated (a second copy arriving
during the move is refused BUSY, and ROTATE_BY would add up), nor RESET and SELF_TEST.
"""

REPLY_TIMEOUT_S = 0.25
#: Longest wait, s, after the STOP of :meth:`DeviceLink.leave_at_rest` beyond the braking time
#: from the table's rate limit for the table to be seen braked (SETTLING or READY).
STOP_WAIT_S = 2.0
#: How long, s beyond the supervision time, :meth:`DeviceLink.leave_at_rest` repeats STOP and
#: STREAM_STOP while the unit does not answer them (a unit silent for a moment, statuses late on a
#: busy host); a link proven gone ends the attempts at once.
LEAVE_RETRY_S = 5.0
RETRIES = 2
HEARTBEATS_UNTIL_LOST = 3
"""protocol.md 6: the device counts as lost after three heartbeat periods without a status."""
TWIN_WINDOW_S = 2.0
"""Seconds after a reply within which a second reply to the same command counts as a second
unit answering as this node (:meth:`DeviceLink.node_conflict`)."""
TWIN_REPLIES = 2
"""Commands answered twice before the driver calls it a second unit on this node id."""
CATCH_UP_S = 1.0
"""Longest extra wait, s, after a deadline for the reader to finish a read begun after it
(:meth:`DeviceLink._caught_up`): a host that runs its reader takes one read (0.05 s) for it."""
_HEARD = ("frames_received", "frames_rejected", "frames_foreign")
"""The transport's counters of frames taken in (:meth:`DeviceLink._heard_more`)."""
T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class DeviceStatus:
    """The device's status message in physical units.

    Attributes
    ----------
    state : DeviceState
    angle_deg : float
        Table angle from the encoder, deg in [0, 360).
    temperature_c : float
        Sensor temperature, degC (NaN: no reading).
    faults : Fault
        Fault flags (any set flag means state FAULT).
    sample_counter : int
        Counter of the device's most recent sample tick.
    rx_malformed, tx_dropped, cmd_rejected : int
        The device's wrapping counters (protocol.md 4.6).
    received_at : float
        The device clock's time (``time.monotonic()`` on the wall clock) when the status arrived.
    """

    state: DeviceState
    angle_deg: float
    temperature_c: float
    faults: Fault
    sample_counter: int
    rx_malformed: int
    tx_dropped: int
    cmd_rejected: int
    received_at: float


#: Bytes read since the last frame that parsed beyond which a silent serial link is reported as
#: garbled (wrong baud rate or protocol) rather than silent: several of the longest frames, and
#: a thirtieth of a second of a streaming unit at 115200 baud.
GARBLED_BYTES = 256


@dataclass(frozen=True, slots=True)
class LinkStats:
    """What the driver received and what it could not use, since the device object was created.

    Attributes
    ----------
    frames_received : int
        CAN frames, or serial frames that passed the CRC check.
    frames_rejected : int
        Frames dropped as corrupt: bad CRC or length (serial), or a protocol frame that did not
        decode (wrong length, undefined code).
    frames_foreign : int
        CAN frames of other nodes or other equipment (normal on a shared bus).
    frames_lost : int
        Serial only: frames missing from the device's sequence counter (dropped or rejected;
        a device restart also shows as a jump).
    ticks_lost, ticks_incomplete : int
        Sample ticks of which no frame / only some CAN frames arrived (while streaming).
    samples_received : int
        Whole samples delivered.
    stray_replies : int
        Replies nobody waited for (late replies to timed-out commands).
    retries : int
        Commands sent again after a reply timeout.
    reply_timeouts : int
        Commands that failed with :class:`~northfinder.driver.errors.ReplyTimeout`.
    resets_detected : int
        Device restarts noticed (BOOT status, unrequested IDENTIFY).
    commands_sent : int
        Commands sent, each resend counted.
    replies_received : int
        Replies matched to the command that waited for them.
    commands_refused : int
        Replies with a result other than OK (the device refused the command).
    foreign_commands : int
        CAN only: commands to this unit from another host on the bus.
    """

    frames_received: int
    frames_rejected: int
    frames_foreign: int
    frames_lost: int
    ticks_lost: int
    ticks_incomplete: int
    samples_received: int
    stray_replies: int
    retries: int
    reply_timeouts: int
    resets_detected: int
    commands_sent: int = 0
    replies_received: int = 0
    commands_refused: int = 0
    foreign_commands: int = 0

    def summary(self) -> str:
        """One line for people: commands and replies, then what was lost or rejected."""
        return (
            f"{self.commands_sent} commands sent ({self.retries} resent), "
            f"{self.replies_received} replies ({self.commands_refused} refused, "
            f"{self.stray_replies} stray), {self.reply_timeouts} reply timeouts; "
            f"frames {self.frames_received} received, {self.frames_rejected} rejected, "
            f"{self.frames_foreign} foreign, {self.frames_lost} lost; "
            f"{self.samples_received} samples, ticks {self.ticks_lost} lost, "
            f"{self.ticks_incomplete} incomplete; {self.resets_detected} device restarts; "
            f"{self.foreign_commands} commands of other hosts"
        )


#: Another host's commands that break a window or a move of this host (queries and STREAM_START
#: do not).
DISRUPTIVE = frozenset(
    {
        Opcode.STREAM_STOP,
        Opcode.STOP,
        Opcode.ROTATE_TO,
        Opcode.ROTATE_BY,
        Opcode.HOME,
        Opcode.RESET,
        Opcode.SET_CONFIG,
        Opcode.SELF_TEST,
    }
)


@dataclass(frozen=True, slots=True)
class AtRest:
    """What :meth:`DeviceLink.leave_at_rest` did to leave the unit at rest and quiet.

    Attributes
    ----------
    sent : tuple of str
        Commands sent and accepted, in order (``"STOP"``, ``"STREAM_STOP"``).
    failed : tuple of str
        Commands that were needed but could not be sent or were not answered (a lost link).
    state : str or None
        The device state read afterwards (``"READY"``, ``"SETTLING"``, ...), None if unknown.
    """

    sent: tuple[str, ...] = ()
    failed: tuple[str, ...] = ()
    state: str | None = None

    @property
    def needed(self) -> bool:
        """Whether this host had anything to undo."""
        return bool(self.sent or self.failed)

    def summary(self) -> str:
        """One clause: ``sent STOP and STREAM_STOP; the unit reads READY``."""
        parts = []
        if self.sent:
            parts.append(f"sent {' and '.join(self.sent)}")
        if self.failed:
            parts.append(
                f"could not send {' and '.join(self.failed)} (the unit may still move or stream)"
            )
        if not parts:
            parts.append("nothing to stop")
        text = "; ".join(parts)
        if self.state is not None:
            text += f"; the unit reads {self.state}"
        return text


@dataclass
class _Waiter:
    opcode: Opcode
    reply: Reply | None = None
    error: DriverError | None = None

    @property
    def done(self) -> bool:
        return self.reply is not None or self.error is not None

    def is_done(self) -> bool:
        return self.done


class DeviceLink:
    """The transport of one device, the reader that sorts what arrives, and requests.

    Parameters as :class:`~northfinder.driver.device.Device`, which documents them. The reader
    starts here, then :meth:`_connect` runs (``Device`` reads identify, status and configuration).
    """

    def __init__(
        self,
        transport: Transport,
        *,
        reply_timeout: float = REPLY_TIMEOUT_S,
        retries: int = RETRIES,
        min_supervision_s: float = 0.0,
        clock: Clock | None = None,
    ) -> None:
        if not reply_timeout >= 0.1:
            raise ArgumentError(f"reply_timeout={reply_timeout!r}: must be at least 0.1 s")
        if retries < 0:
            raise ArgumentError(f"retries={retries!r}: must be >= 0")
        self._transport = transport
        self.reply_timeout = float(reply_timeout)
        self.retries = int(retries)
        if not (math.isfinite(min_supervision_s) and min_supervision_s >= 0):
            raise ArgumentError(f"min_supervision_s={min_supervision_s!r}: must be >= 0 s")
        self.min_supervision_s = float(min_supervision_s)
        self._clock: Clock = WallClock() if clock is None else clock
        self._lock = threading.RLock()
        self._acquire_lock = threading.Lock()
        self._waiters: dict[int, _Waiter] = {}
        self._events = 0  # counts everything the reader delivered: waiters look again on a change
        # Whether the reader's latest read found nothing: supervision judges the time since the
        # last status only once the host has read everything that arrived (a busy host or a slow
        # adapter delivers statuses late behind the stream, while the link is plainly up).
        self._link_idle = True
        # When the reader's latest read that found nothing began: the link counts as lost only
        # once such a read began after the supervision deadline (the unit's silence, not a host
        # that did not run its reader while the unit's bytes waited in the link).
        self._quiet_read_at = -math.inf
        # When the reader's latest completed read began, whatever it found: a wait that ran out
        # is judged only once a read that began after its deadline is done (what waited in the
        # link by then has been dispatched), see :meth:`_caught_up`.
        self._read_began_at = -math.inf
        self._catching_up = 0  # callers waiting in :meth:`_caught_up`
        # When the reader's latest read that brought no sample (and no part of one) began: the
        # stream counts as stopped only once such a read began after the stall deadline.
        self._sampleless_read_at = -math.inf
        self._heard = 0  # the transport's count of frames and bytes, at the latest read
        self._seq = 0
        self._opened_at = self._clock.now()
        self._status: DeviceStatus | None = None
        self._status_count = 0
        self._motion_count = 0  # _status_count of the latest ROTATING or SETTLING status
        self._identify: Identify | None = None
        self._identify_count = 0
        self._identify_expected_until = 0.0
        self._scales = CountScales()
        self._boot_epoch = 0
        self._reset_reason = ""
        # What the reader hands to an acquire() in progress: (kind, item, clock time, wall time)
        # for samples, losses, resets and a lost link.
        self._inbox: SampleInbox | None = None
        self._inbox_since = 0.0  # clock time the inbox was registered
        self._inbox_alerts = 0  # items other than samples put in an inbox, and closings
        self._config: dict[ConfigKey, int] = {}
        self._config_stale = True
        self._streaming = False
        # What this host started and has not seen end: a stream (STREAM_START or SET_CONFIG
        # STREAMING=1 sent by this object) and a move (ROTATE_TO/BY or HOME sent, its settling
        # not yet seen). Only these are undone on leaving (:meth:`leave_at_rest`): another host's
        # stream or move on the same bus is never stopped.
        self._stream_owned = False
        self._move_open = False
        self._move_n0 = 0  # _status_count when the open move was commanded
        self.at_rest: AtRest | None = None
        self._dead: DriverError | None = None
        self._closed = False
        self._stop = threading.Event()
        self._counts = {
            "samples": 0, "stray": 0, "retries": 0, "timeouts": 0, "resets": 0,
            "sent": 0, "replies": 0, "refused": 0,
        }  # fmt: skip
        # Another host's commands seen on the bus (CAN): how many, and the latest disruptive one
        # (count, opcode); its IDENTIFY's answer is expected until _foreign_identify_until; its
        # RESET explains the restart that follows.
        self._foreign_count = 0
        self._foreign_disruptive: tuple[int, Opcode | None] = (0, None)
        self._foreign_identify_until = -math.inf
        self._foreign_reset_until = -math.inf
        # Replies to this host's commands by (seq): opcode and when; the other hosts' commands
        # likewise. A second reply to a command of this host's, within TWIN_WINDOW_S and to no
        # other host's command of that seq, came from a second unit answering as this node.
        self._answered: dict[int, tuple[int, float]] = {}
        self._foreign_seqs: dict[int, tuple[int, float]] = {}
        self._twin_replies = 0
        self._reader: threading.Thread | None = None
        if self._clock.virtual:
            self._clock.add_poller(self._pump)
        else:
            self._reader = threading.Thread(
                target=self._read_loop, name=f"northfinder-{transport.kind}-reader", daemon=True
            )
            self._reader.start()
        try:
            with self._clock.participant():
                self._connect()
        except BaseException:
            self.close()
            raise

    def _connect(self) -> None:
        """What to read from the device once the reader runs (``Device``: identify, status and
        configuration); an error closes the link again."""

    def leave_at_rest(self) -> AtRest:
        """Undo what this host started, nothing else: STOP a move or spin it commanded that has
        not been seen to settle, STREAM_STOP a stream it started; then read the state.

        Each command is repeated until the unit answers it, for up to :data:`LEAVE_RETRY_S` plus
        the supervision time: a unit silent for a moment, or statuses late on a busy host, do
        not leave the table turning. Only a link proven gone (the port or bus failed under the
        reader, the device closed) ends the attempts at once. After a STOP the host waits for
        the table to be seen braked (SETTLING or READY, :meth:`_settled_after_stop`), sending
        STOP again if the unit still reports SPINNING.

        Called by :meth:`close` (so a ``with`` block left by an exception or Ctrl-C leaves the
        unit at rest and quiet); callable before it to learn what was done. Never raises: what
        could not be sent is listed in :attr:`AtRest.failed`. Idempotent: a second call sends
        nothing and returns the first call's report.
        """
        if self.at_rest is not None and not (self._move_open or self._stream_owned):
            return self.at_rest
        sent: list[str] = []
        failed: list[str] = []
        state: str | None = None
        todo: list[tuple[type[Command], str]] = [(Stop, "STOP")] if self._move_open else []
        if self._stream_owned:
            todo.append((StreamStop, "STREAM_STOP"))
        with self._clock.participant():
            deadline = self._clock.now() + LEAVE_RETRY_S + self._supervision_s()
            for command, name in todo:
                (sent if self._insist(command, name, deadline) else failed).append(name)
            with self._lock:
                if "STOP" in sent:
                    self._move_open = False
                if "STREAM_STOP" in sent:
                    self._stream_owned = self._streaming = False
            if "STOP" in sent:
                state = self._settled_after_stop(deadline)
            elif todo and not self._gone():
                state = self._read_state()
            elif self._status is not None:
                state = self._status.state.name
        self.at_rest = AtRest(tuple(sent), tuple(failed), state)
        return self.at_rest

    def _gone(self) -> bool:
        """Whether the link is proven gone: closed, failed under the reader, or the reader
        stopped. A silent unit is not proof: it may speak again."""
        reading = self._reader.is_alive() if self._reader is not None else True
        return self._closed or self._dead is not None or not reading

    def _insist(self, command: type[Command], name: str, deadline: float) -> bool:
        """Send ``command`` until the unit answers OK; False once ``deadline`` passed, the unit
        refused it, or the link is proven gone (:meth:`_gone`)."""
        while not self._gone():
            try:
                self._request(command, attempts=1)
                return True
            except ReplyTimeout as exc:
                log.info("%s not answered on leaving: %s", name, exc)
                if self._clock.now() >= deadline:
                    return False
                with self._lock:
                    self._counts["retries"] += 1
            except DriverError as exc:
                log.info("%s not sent on leaving: %s", name, exc)
                return False
        return False

    def _settled_after_stop(self, deadline: float) -> str | None:
        """After an answered STOP: wait until a status reads neither ROTATING nor SPINNING (the
        table braked: SETTLING, READY, or FAULT), for the braking time at the configured limits
        plus :data:`STOP_WAIT_S`; send STOP again while a status that arrived after the answer
        still reads SPINNING. Return the latest state (None if none is known)."""
        limits = {
            k: self._config.get(k, d)
            for k, d in (
                (ConfigKey.TABLE_MAX_RATE_MDPS, round(DEFAULT_MAX_RATE_DPS * 1000)),
                (ConfigKey.TABLE_MAX_ACCEL_MDPS2, round(DEFAULT_MAX_ACCEL_DPS2 * 1000)),
            )
        }
        braking = limits[ConfigKey.TABLE_MAX_RATE_MDPS] / max(
            limits[ConfigKey.TABLE_MAX_ACCEL_MDPS2], 1
        )
        until = max(self._clock.now() + braking + STOP_WAIT_S, deadline)
        moving = (DeviceState.ROTATING, DeviceState.SPINNING)
        with self._lock:
            seen = self._status_count
        try:
            self._request(GetStatus, attempts=1)  # a fresh status now, not at the next heartbeat
        except DriverError:
            pass
        while not self._gone() and self._clock.now() < until:

            def heard(seen: int = seen) -> bool:
                return self._status_count > seen or self._gone()

            self._clock.wait_until(
                heard,
                min(until, self._clock.now() + self._heartbeat_period_s() + self.reply_timeout),
            )
            with self._lock:
                st, count = self._status, self._status_count
            if count <= seen or st is None:
                continue
            seen = count
            if st.state not in moving:
                break
            if st.state == DeviceState.SPINNING:
                # The STOP was answered, yet a later status still reads SPINNING: say it again.
                self._insist(Stop, "STOP", until)
        return self._status.state.name if self._status is not None else None

    def _read_state(self) -> str | None:
        """The state from one fresh status (GET_STATUS once), else the latest one received."""
        with self._lock:
            n0 = self._status_count
        try:
            self._request(GetStatus, attempts=1)
            self._clock.wait_until(
                lambda: self._status_count > n0, self._clock.now() + self.reply_timeout
            )
        except DriverError:
            pass
        return self._status.state.name if self._status is not None else None

    def close(self) -> None:
        """Leave the unit at rest (:meth:`leave_at_rest`: STOP a move and STREAM_STOP a stream
        this object started, nothing another host started), stop the reader, release the bus
        or port.

        Idempotent; never raises for a device that stopped answering.
        """
        if self._closed:
            return
        self.leave_at_rest()
        self._closed = True
        self._stop.set()
        if self._reader is None:
            self._clock.remove_poller(self._pump)
        elif self._reader is not threading.current_thread():
            self._reader.join(2.0)
        self._transport.close()
        with self._lock:
            for waiter in self._waiters.values():
                waiter.error = LinkError("the device was closed")
            self._events += 1
            self._inbox_alerts += 1
        self._clock.notify()

    @property
    def clock(self) -> Clock:
        """The clock every timeout and wait of this device reads."""
        return self._clock

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    @property
    def lost(self) -> DriverError | None:
        """The error that ended the link (the bus or port failed under the reader), None while
        it is up. A lost link stays lost: open the device again."""
        return self._dead

    @property
    def link_kind(self) -> str:
        """``"can"`` or ``"serial"``."""
        return self._transport.kind

    # -- the reader thread --------------------------------------------------------------------
    def _read_loop(self) -> None:
        try:
            while not self._stop.is_set():
                began = self._clock.now()
                items = self._transport.recv(READ_POLL_S)
                heard = self._heard_more()
                if items:
                    self._link_idle = False
                    if not self._dispatch(items, self._clock.now(), self._clock.wall()):
                        self._sampleless_read_at = began
                elif heard:
                    self._link_idle = False  # bytes or frames came that complete no message yet
                else:
                    self._quiet_read_at = self._sampleless_read_at = began
                    if not self._link_idle or began >= self._lost_at():
                        self._went_idle()
                self._read_began_at = began
                if self._catching_up:
                    self._clock.notify()
        except DriverError as exc:
            if not self._stop.is_set():
                self._fail(exc if isinstance(exc, LinkError) else LinkLost(str(exc)), exc)
        except Exception as exc:  # a bug must not leave callers waiting forever
            if not self._stop.is_set():
                self._fail(LinkLost(f"the driver's reader thread failed: {exc!r}"), exc)
                raise

    def _pump(self) -> bool:
        """On a virtual clock: receive all that has arrived, without blocking (the clock calls
        this at every instant); True if anything came. Nothing arrives between two instants, so
        the link is never left with frames to read (``_link_idle`` stays True): a device that
        falls silent is judged by its last status alone, whether or not the clock polls again."""
        got = False
        try:
            while not self._closed and self._dead is None:
                items = self._transport.recv(0.0)
                if not items:
                    break
                self._dispatch(items, self._clock.now(), self._clock.wall())
                got = True
        except DriverError as exc:
            self._fail(exc if isinstance(exc, LinkError) else LinkLost(str(exc)), exc)
            return True
        return got

    def _heard_more(self) -> bool:
        """Whether the transport took in frames, or bytes of a frame in progress, since the
        previous call (a read may take part of a message and return nothing yet); bytes that
        parse as nothing for :data:`GARBLED_BYTES` do not count (no unit is heard in them)."""
        c = self._transport.counters()
        heard = sum(c.get(k, 0) for k in _HEARD)
        if c.get("bytes_unparsed", 0) < GARBLED_BYTES:
            heard += c.get("bytes_received", 0)
        more, self._heard = heard != self._heard, heard
        return more

    def _went_idle(self) -> None:
        with self._lock:
            self._link_idle = True
            self._events += 1
        if self._reader is not None:
            self._clock.notify()

    def _fail(self, error: DriverError, cause: BaseException) -> None:
        error.__cause__ = cause
        log.error("link lost: %s", error)
        with self._lock:
            self._dead = error
            for waiter in self._waiters.values():
                waiter.error = error
            if self._inbox is not None:
                now = self._clock.now()
                self._inbox.add_event("lost", error, now, self._clock.wall())
                self._inbox_alerts += 1
            self._events += 1
        self._clock.notify()

    def _dispatch(self, items: list[Received], mono: float, wall: float) -> bool:
        """Hand each message to what waits for it; True if any was of the stream (a sample, or a
        tick whose frames were lost)."""
        stream = False
        with self._lock:
            for item in items:
                kind = type(item)  # Sample and TickLoss are final (frozen, slotted dataclasses)
                if kind is Sample or kind is TickLoss:
                    stream = True
                    if kind is Sample:
                        self._counts["samples"] += 1
                    # Only what was received after acquire() was called belongs to its window.
                    if self._inbox is not None and mono >= self._inbox_since:
                        if kind is Sample:
                            self._inbox.add_sample(item, mono, wall)  # type: ignore[arg-type]
                        else:
                            self._inbox.add_event("loss", item, mono, wall)
                            self._inbox_alerts += 1
                elif isinstance(item, Reply):
                    self._on_reply(item)
                elif isinstance(item, Status):
                    self._on_status(item, mono)
                elif isinstance(item, Identify):
                    self._on_identify(item, mono)
                elif isinstance(item, Command):
                    self._on_foreign_command(item, mono)
            self._events += 1
        if self._reader is not None:
            self._clock.notify()  # a virtual clock looks at its waiters after every poll anyway
        return stream

    def _on_foreign_command(self, cmd: Command, mono: float) -> None:
        """Another host's command to this unit (seen on a shared CAN bus)."""
        self._foreign_count += 1
        op = cmd.OPCODE
        self._foreign_seqs[cmd.seq] = (op, mono)
        # Its answers may come up to its own retries later; a second host's IDENTIFY answered
        # is not a restart of the device.
        answered_by = mono + (1 + RETRIES) * REPLY_TIMEOUT_S + 1.0
        if op == Opcode.IDENTIFY:
            self._foreign_identify_until = answered_by
        elif op == Opcode.RESET:
            self._foreign_reset_until = answered_by + 1.0
        if op in DISRUPTIVE:
            self._foreign_disruptive = (self._foreign_disruptive[0] + 1, op)
            log.warning("another host sent %s to this unit", op.name)
            if self._inbox is not None and op != Opcode.RESET:  # a reset shows as a restart
                self._inbox.add_event("foreign", op, mono, self._clock.wall())
                self._inbox_alerts += 1
        else:
            log.info("another host sent %s to this unit", op.name)

    def _another_host(self, op: Opcode | None, during: str) -> AnotherHost:
        name = op.name if op is not None else "a command"
        return AnotherHost(
            f"another host is commanding this unit: it sent {name} {during}; "
            "one host at a time should command a unit (protocol.md 13)"
        )

    def _on_reply(self, reply: Reply) -> None:
        waiter = self._waiters.get(reply.seq)
        now = self._clock.now()
        if waiter is None or waiter.opcode != reply.opcode or waiter.done:
            self._counts["stray"] += 1
            log.debug("stray reply %s", reply)
            first = self._answered.get(reply.seq)
            theirs = self._foreign_seqs.get(reply.seq)
            if (
                first is not None
                and first[0] == reply.opcode
                and now - first[1] <= TWIN_WINDOW_S
                and not (theirs is not None and theirs[0] == reply.opcode)
            ):
                self._twin_replies += 1
                if self._twin_replies == TWIN_REPLIES:
                    log.warning("%s", self.node_conflict())
            return
        waiter.reply = reply
        self._answered[reply.seq] = (reply.opcode, now)

    def node_conflict(self) -> str | None:
        """What says that another unit answers as this node (two replies to commands of this
        host's), or None. A :class:`~northfinder.driver.errors.NodeConflict` names it."""
        if self._twin_replies < TWIN_REPLIES:
            return None
        node = getattr(self._transport, "node_id", None)
        return (
            f"another unit answers as node {node if node is not None else '?'} on this bus: "
            f"{self._twin_replies} commands of this host got two replies each; give each unit "
            "its own node id (set outside the protocol; protocol.md 13)"
        )

    def _check_node_conflict(self, cause: BaseException | None = None) -> None:
        """Raise :class:`~northfinder.driver.errors.NodeConflict` once two units answer as
        this node (from ``cause``, the error they led to, if any)."""
        text = self.node_conflict()
        if text is None:
            return
        if cause is not None:
            text += f"; it explains: {cause}"
        raise NodeConflict(text) from cause

    def _on_status(self, status: Status, mono: float) -> None:
        sc = self._scales
        previous = self._status
        self._status = DeviceStatus(
            state=status.state,
            angle_deg=status.angle * sc.angle_deg,
            temperature_c=sc.temperature(status.temperature),
            faults=status.faults,
            sample_counter=status.sample_counter,
            rx_malformed=status.rx_malformed,
            tx_dropped=status.tx_dropped,
            cmd_rejected=status.cmd_rejected,
            received_at=mono,
        )
        self._status_count += 1
        if status.state in (DeviceState.ROTATING, DeviceState.SETTLING, DeviceState.SPINNING):
            self._motion_count = self._status_count
        elif (
            status.state == DeviceState.READY
            and self._move_open
            and self._motion_count > self._move_n0
        ):
            self._move_open = False  # the move this host commanded has settled
        if status.state == DeviceState.BOOT and previous is not None:
            if previous.state != DeviceState.BOOT:
                self._note_reset("the device reports state BOOT")

    def _on_identify(self, ident: Identify, mono: float) -> None:
        self._identify = ident
        self._identify_count += 1
        self._scales = CountScales.of(ident)
        booting = self._status is not None and self._status.state == DeviceState.BOOT
        asked = max(self._identify_expected_until, self._foreign_identify_until)
        if mono > asked and self._status is not None and not booting:
            # protocol.md 5: a device announces itself in BOOT; nobody asked, so it restarted.
            self._note_reset("the device sent IDENTIFY unrequested, as it does after a restart")

    def _note_reset(self, reason: str) -> None:
        """Called with the lock held, in the reader thread."""
        self._boot_epoch += 1
        self._counts["resets"] += 1
        if self._clock.now() <= self._foreign_reset_until:
            reason = f"another host sent RESET ({reason})"
        self._reset_reason = reason
        self._streaming = self._stream_owned = self._move_open = False
        self._config_stale = True
        self._transport.restart_stream()
        log.warning("device restart detected: %s", reason)
        if self._inbox is not None:
            self._inbox.add_event("reset", reason, self._clock.now(), self._clock.wall())
            self._inbox_alerts += 1

    # -- requests -----------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise LinkError("the device is closed")
        if self._dead is not None:
            raise LinkLost(f"the link is lost: {self._dead}") from self._dead

    def _heartbeat_period_s(self) -> float:
        return self._config.get(ConfigKey.HEARTBEAT_PERIOD_MS, HEARTBEAT_PERIOD_DEFAULT_MS) / 1000.0

    def _last_status_at(self) -> float:
        return self._status.received_at if self._status is not None else self._opened_at

    def _status_age_s(self) -> float:
        """Seconds since the latest status (or since opening, if none came yet)."""
        return self._clock.now() - self._last_status_at()

    def _supervision_s(self) -> float:
        """Seconds without a status before the link counts as lost (protocol.md 6: three
        heartbeat periods; never less than ``min_supervision_s``)."""
        return max(HEARTBEATS_UNTIL_LOST * self._heartbeat_period_s(), self.min_supervision_s)

    def _lost_at(self) -> float:
        """Clock time at which the link counts as lost if no status comes before. Judged by this
        one sum (never by an age ``now - last``, whose rounding could differ from it): a wait
        until this deadline ends with the link judged lost."""
        return self._last_status_at() + self._supervision_s()

    def _link_deadline(self) -> float:
        """Clock time at which supervision is to be judged again: when the link counts as lost if
        no status comes before, or (past that, while frames still arrive) a moment later."""
        deadline = self._lost_at()
        if deadline > self._clock.now():
            return deadline
        return self._clock.now() + READ_POLL_S

    def _link_alive(self) -> bool:
        """A status within the supervision time, or frames still being read (protocol.md 6: the
        time without a status counts once the host has read all that arrived). Past the
        deadline the link is lost only once a read that began after it found nothing: a host
        that stood still longer than the supervision time (a loaded machine) reads what waited in
        the link first, and a status among it keeps the link up."""
        lost_at = self._lost_at()
        if self._clock.now() < lost_at or not self._link_idle:
            return True
        return self._reader is not None and self._quiet_read_at < lost_at

    def _no_sample_since(self, t: float) -> bool:
        """Whether a read that began at or after ``t`` brought no sample: none waited in the link
        then, whatever else came (statuses at a short heartbeat, other nodes on a shared bus).
        Reads that each bring part of a frame only (a busy bus) decide nothing until one begins
        :data:`CATCH_UP_S` after ``t``. Always True without a reader thread: a virtual clock reads
        everything at each instant."""
        return (
            self._reader is None
            or self._sampleless_read_at >= t
            or self._read_began_at >= t + CATCH_UP_S
        )

    def _caught_up(self, since: float, done: Callable[[], bool]) -> bool:
        """After a wait that ran out at ``since``: wait until the reader has finished a read that
        began at or after it (or ``done()`` holds) and say whether ``done()`` holds then. A host
        that did not run the reader while the unit's messages waited in the link (a loaded
        machine) reads them first; a deadline is judged on what had arrived by then, not on what
        the host had got round to reading. At most :data:`CATCH_UP_S` more; no wait without a
        reader thread (a virtual clock delivers everything at each instant)."""
        if self._reader is None or not self._reader.is_alive() or self._read_began_at >= since:
            return done()
        with self._lock:
            self._catching_up += 1
        try:
            self._clock.wait_until(
                lambda: done() or self._read_began_at >= since or self._dead is not None,
                since + CATCH_UP_S,
            )
        finally:
            with self._lock:
                self._catching_up -= 1
        return done()

    def _wait_change(self, seen: int, until: float) -> None:
        """Wait until the reader delivered something after ``seen`` (:attr:`_events`) or the
        clock reaches ``until``."""
        self._clock.wait_until(lambda: self._events != seen, until)

    def _link_lost_error(self) -> LinkLost:
        return LinkLost(
            f"no status from the device for {self._status_age_s():.2f} s "
            f"(limit {self._supervision_s():.2f} s, {HEARTBEATS_UNTIL_LOST} heartbeat periods): "
            + (
                self._garbled_text()
                or "the device is silent, off or restarting, or the link is down"
            )
        )

    def _garbled_text(self) -> str | None:
        """What a serial link says when bytes keep arriving but no frame parses (the other end at
        another baud rate, or speaking another protocol); None when that is not the case."""
        counters = self._transport.counters()
        unparsed = counters.get("bytes_unparsed", 0)
        if unparsed < GARBLED_BYTES:
            return None
        return (
            f"bytes arrive but no frame parses ({unparsed} bytes since the last frame that did): "
            "wrong baud rate or protocol? (check the baud rate and that the port is the unit's)"
        )

    def _request(
        self,
        command: type[Command],
        *args: Any,
        timeout: float | None = None,
        attempts: int | None = None,
    ) -> Reply:
        """Send a command and return its OK reply; retry only commands in :data:`RETRYABLE`."""
        opcode = command.OPCODE
        per = self.reply_timeout if timeout is None else timeout
        if attempts is None:
            attempts = 1 + self.retries if opcode in RETRYABLE else 1
        for attempt in range(attempts):
            self._check_open()
            waiter = _Waiter(opcode)
            with self._lock:
                self._counts["sent"] += 1
                seq = self._next_seq()
                self._waiters[seq] = waiter
                if opcode == Opcode.IDENTIFY:
                    self._identify_expected_until = self._clock.now() + per + CATCH_UP_S + 1.0
            try:
                sent_at = self._clock.now()
                message = command(seq, *args)
                self._transport.send(message)
                log.debug("-> %r", message)
                if self._reader is None:
                    self._clock.notify()  # the virtual clock: the device takes it now
                answered = self._clock.wait_until(waiter.is_done, sent_at + per)
                if not answered:  # a reply that waited in the link while the host stood still
                    answered = self._caught_up(sent_at + per, waiter.is_done)
            finally:
                with self._lock:
                    self._waiters.pop(seq, None)
            if waiter.error is not None:
                raise type(waiter.error)(str(waiter.error)) from waiter.error
            if answered and waiter.reply is not None:
                reply = waiter.reply
                with self._lock:
                    self._counts["replies"] += 1
                    self._counts["refused"] += reply.result != Result.OK
                log.debug(
                    "<- %s %s (seq %d) after %.1f ms", opcode.name,
                    getattr(reply.result, "name", reply.result), reply.seq,
                    1e3 * (self._clock.now() - sent_at),
                )  # fmt: skip
                if reply.result != Result.OK:
                    raise DeviceRefused(opcode, reply.result, result_meaning(reply.result))
                return reply
            if attempt + 1 < attempts:
                self._counts["retries"] += 1
                log.info("no reply to %s (seq %d) in %.3f s; sending again", opcode.name, seq, per)
        self._counts["timeouts"] += 1
        deadline = attempts * per
        alive = self._link_alive()
        text = f"no reply to {opcode.name} within {deadline:.2f} s ({attempts} attempt(s) of {per:.2f} s)"
        if alive:
            text += "; the device's heartbeat still arrives: the command or its reply was lost"
        elif (garbled := self._garbled_text()) is not None:
            text += f"; {garbled}"
        else:
            text += (
                f"; no status for {self._status_age_s():.2f} s either: the device is silent or "
                "off, or the link is down (check power, cable, bus termination, port)"
            )
        if opcode in (Opcode.ROTATE_TO, Opcode.ROTATE_BY, Opcode.HOME, Opcode.RESET):
            text += f"; {opcode.name} may have been carried out: check the unit's status before repeating it"
        raise ReplyTimeout(text, deadline, opcode, attempts, alive)

    def _next_seq(self) -> int:
        for _ in range(256):
            self._seq = (self._seq + 1) & 0xFF
            if self._seq not in self._waiters:
                return self._seq
        raise DriverError("256 commands are waiting for replies")  # pragma: no cover

    def _wait_for(
        self,
        check: Callable[[], T | None],
        deadline: float,
        on_timeout: Callable[[], DriverError],
        *,
        supervise: bool = True,
    ) -> T:
        """Wait until ``check`` (called with the lock held) returns a value; it may raise."""
        while True:
            seen = self._events
            self._check_open()
            with self._lock:
                result = check()
            if result is not None:
                return result
            if self._clock.now() >= deadline:
                raise on_timeout()
            until = deadline
            if supervise:
                if not self._link_alive():
                    raise self._link_lost_error()
                until = min(until, self._link_deadline())
            self._wait_change(seen, until)

    @property
    def last_status(self) -> DeviceStatus | None:
        """The most recent status received (heartbeat or requested), without asking."""
        return self._status

    def stats(self) -> LinkStats:
        """Counters of what arrived and what was lost or rejected (see :class:`LinkStats`)."""
        t = self._transport.counters()
        c = self._counts
        return LinkStats(
            frames_received=t["frames_received"],
            frames_rejected=t["frames_rejected"],
            frames_foreign=t["frames_foreign"],
            frames_lost=t["frames_lost"],
            ticks_lost=t["ticks_lost"],
            ticks_incomplete=t["ticks_incomplete"],
            samples_received=c["samples"],
            stray_replies=c["stray"],
            retries=c["retries"],
            reply_timeouts=c["timeouts"],
            resets_detected=c["resets"],
            foreign_commands=self._foreign_count,
            commands_sent=c["sent"],
            replies_received=c["replies"],
            commands_refused=c["refused"],
        )
