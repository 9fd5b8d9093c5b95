"""CAN 2.0A mapping: messages to and from ``(arbitration_id, data)``, and reassembly.

Identifier = :class:`~northfinder.driver.protocol.constants.CanFunction` base + node id (1..15). Data is
little-endian; every frame has the exact length of its message (no padding). CAN FD is not
offered. :class:`TickAssembler` joins the four frames of a sample tick, :class:`IdentifyAssembler`
the identify pages, and :class:`CanReceiver` does both plus status merging and counting.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from northfinder.driver.protocol.constants import NODE_ID_MAX, NODE_ID_MIN, UINT32_MAX, CanFunction
from northfinder.driver.protocol.counters import TickCounter
from northfinder.driver.protocol.errors import (
    EncodeError,
    PayloadError,
    ProtocolError,
    UnknownMessageError,
)
from northfinder.driver.protocol.messages import (
    Command,
    Identify,
    IdentifyPage,
    Message,
    Reply,
    Sample,
    SampleAux,
    SampleAxis,
    SampleX,
    SampleY,
    SampleZ,
    Status,
    StatusCounters,
    StatusMain,
    sample_aux_fields,
    sample_axis_fields,
    sample_tick_fields,
    validity_of,
)

__all__ = [
    "CAN_MAX_DLC",
    "CanDecoded",
    "CanFrame",
    "CanMessage",
    "CanReceiver",
    "IdentifyAssembler",
    "TickAssembler",
    "TickLoss",
    "can_id",
    "decode_can",
    "encode_can",
    "sample_ids",
    "split_can_id",
]

CAN_MAX_DLC = 8

CanMessage = (
    Command
    | Reply
    | SampleX
    | SampleY
    | SampleZ
    | SampleAux
    | StatusMain
    | StatusCounters
    | IdentifyPage
)
"""What one CAN frame decodes to."""

_DECODER: dict[int, Callable[[bytes], CanMessage]] = {
    CanFunction.COMMAND: Command.decode,
    CanFunction.REPLY: Reply.decode,
    CanFunction.SAMPLE_X: SampleX.decode,
    CanFunction.SAMPLE_Y: SampleY.decode,
    CanFunction.SAMPLE_Z: SampleZ.decode,
    CanFunction.SAMPLE_AUX: SampleAux.decode,
    CanFunction.STATUS: StatusMain.decode,
    CanFunction.STATUS_COUNTERS: StatusCounters.decode,
    CanFunction.IDENTIFY: IdentifyPage.decode,
}

_FUNCTION_OF: dict[type, CanFunction] = {
    Reply: CanFunction.REPLY,
    SampleX: CanFunction.SAMPLE_X,
    SampleY: CanFunction.SAMPLE_Y,
    SampleZ: CanFunction.SAMPLE_Z,
    SampleAux: CanFunction.SAMPLE_AUX,
    StatusMain: CanFunction.STATUS,
    StatusCounters: CanFunction.STATUS_COUNTERS,
    IdentifyPage: CanFunction.IDENTIFY,
}


class CanFrame(NamedTuple):
    """A classic CAN data frame with an 11-bit identifier."""

    arbitration_id: int
    data: bytes


class CanDecoded(NamedTuple):
    """A decoded CAN frame: the node it belongs to and its message."""

    node_id: int
    message: CanMessage


def can_id(function: CanFunction, node_id: int) -> int:
    """Arbitration id of ``function`` for ``node_id``.

    Raises
    ------
    EncodeError
        Node id outside 1..15.
    """
    if not isinstance(node_id, int) or not NODE_ID_MIN <= node_id <= NODE_ID_MAX:
        raise EncodeError(f"node_id={node_id!r} must be in [{NODE_ID_MIN}, {NODE_ID_MAX}]")
    return function + node_id


def split_can_id(arbitration_id: int) -> tuple[CanFunction, int]:
    """``(function, node_id)`` of an arbitration id.

    Raises
    ------
    UnknownMessageError
        The id is not in the protocol's table (including node id 0 and ids above 0x7FF).
    """
    node = arbitration_id & 0x0F
    try:
        function = CanFunction(arbitration_id & ~0x0F)
    except ValueError:
        node = 0
    if node == 0:
        raise UnknownMessageError(f"CAN id 0x{arbitration_id:03X} is not a protocol message")
    return function, node


def encode_can(message: Message | CanMessage, node_id: int = 1) -> list[CanFrame]:
    """CAN frames carrying ``message`` from or to ``node_id``, in sending order.

    A :class:`Sample` gives four frames, a :class:`Status` two, an :class:`Identify` seven;
    every other message one.

    Raises
    ------
    EncodeError
        A field does not fit, or the object is not a protocol message.
    """
    if type(message) is Sample:
        # The stream's message: its four frames packed directly (Sample.can_payloads).
        return [
            CanFrame(i, data)
            for i, data in zip(sample_ids(node_id), message.can_payloads(), strict=True)
        ]
    if isinstance(message, Sample):
        parts: tuple[CanMessage, ...] | list[IdentifyPage] = message.split()
    elif isinstance(message, Status):
        parts = message.split()
    elif isinstance(message, Identify):
        parts = message.pages()
    else:
        parts = (message,)
    frames = []
    for part in parts:
        function: CanFunction | None
        if isinstance(part, Command):
            function = CanFunction.COMMAND
        else:
            function = _FUNCTION_OF.get(type(part))
            if function is None:
                raise EncodeError(f"{type(part).__name__} is not a CAN message")
        frames.append(CanFrame(can_id(function, node_id), part.encode()))
    return frames


_SAMPLE_FUNCTIONS = (
    CanFunction.SAMPLE_X,
    CanFunction.SAMPLE_Y,
    CanFunction.SAMPLE_Z,
    CanFunction.SAMPLE_AUX,
)
#: Slot of each sample frame in its tick: x, y, z, aux.
_SAMPLE_SLOT = {function: slot for slot, function in enumerate(_SAMPLE_FUNCTIONS)}


@functools.cache
def sample_ids(node_id: int) -> tuple[int, int, int, int]:
    """The CAN identifiers of the four sample frames of a tick from ``node_id``, in sending
    order: SAMPLE_X, _Y, _Z, _AUX (checked once, then cached).

    Raises
    ------
    EncodeError
        ``node_id`` is not a node id (1..15).
    """
    return tuple(can_id(function, node_id) for function in _SAMPLE_FUNCTIONS)  # type: ignore[return-value]


def decode_can(
    arbitration_id: int, data: bytes | bytearray, *, is_extended_id: bool = False
) -> CanDecoded:
    """Decode one CAN frame.

    Raises
    ------
    UnknownMessageError
        Extended (29-bit) id, or an id outside the protocol's table.
    PayloadError
        More than 8 data bytes, wrong length for the message, undefined field value
        (:class:`~northfinder.driver.protocol.errors.BadCommandError` for a command the device must refuse).
    """
    if is_extended_id:
        raise UnknownMessageError(f"extended CAN id 0x{arbitration_id:08X} is not used")
    decoder = _DECODER.get(arbitration_id & 0x7F0)
    node = arbitration_id & 0x0F
    if decoder is None or node == 0 or arbitration_id > 0x7FF:
        raise UnknownMessageError(f"CAN id 0x{arbitration_id:03X} is not a protocol message")
    if len(data) > CAN_MAX_DLC:
        raise PayloadError(f"{len(data)} data bytes: only classic CAN (at most 8) is used")
    return CanDecoded(node, decoder(bytes(data)))


@dataclass(frozen=True, slots=True)
class TickLoss:
    """Sample ticks that did not arrive whole.

    Attributes
    ----------
    first_counter : int
        Sample counter of the first tick concerned.
    count : int
        Number of consecutive ticks concerned.
    incomplete : bool
        True: one tick of which some but not all four frames arrived. False: ``count`` ticks of
        which no frame arrived.
    """

    first_counter: int
    count: int
    incomplete: bool


_AXIS_SLOT = {SampleX: 0, SampleY: 1, SampleZ: 2}


class TickAssembler:
    """Joins the four CAN frames of each sample tick into a :class:`Sample`.

    Frames of one tick may come in any order, but ticks do not interleave (one sender, and
    CAN keeps its order). The full 32-bit counter is extended from the 8-bit tick by
    :attr:`counter` (a :class:`~northfinder.driver.protocol.counters.TickCounter`): forward from
    the previous tick, and anchored by :meth:`sync` with the counter from STATUS_COUNTERS (needed at
    start and after a gap of 256 ticks or more), so a gap of any length is measured and reported,
    not folded modulo 256. Before any sync the first tick seen gets counter = tick.
    :meth:`restart` forgets the previous tick, for a stream that was switched off and on again
    (ticks not sent are not lost).

    Attributes
    ----------
    counter : TickCounter
        The counter extension.
    complete : int
        Ticks delivered whole.
    incomplete : int
        Ticks of which only some frames arrived.
    lost : int
        Ticks of which no frame arrived.
    duplicates : int
        Frames repeating a part already held, or belonging to the tick just finished.
    """

    def __init__(self) -> None:
        self.counter = TickCounter()
        self._tick: int | None = None  # the tick in progress
        # The fields of the tick's frames held so far, by slot: x, y, z as (gyro, accel), aux as
        # (angle, temperature, validity bits).
        self._parts: list[tuple[int, ...] | None] = [None] * 4
        self.complete = 0
        self.incomplete = 0
        self.lost = 0
        self.duplicates = 0

    def sync(self, sample_counter: int) -> None:
        """Anchor the counter extension on a full 32-bit sample counter from the status."""
        self.counter.sync(sample_counter)

    def restart(self) -> list[TickLoss]:
        """Forget the previous tick: the stream was off, and ticks it did not send are not lost.

        The next tick is placed by the latest :meth:`sync` anchor. A tick still waiting for frames
        is reported as incomplete (returned).
        """
        out = self.flush()
        self.counter.restart()
        return out

    def add(self, part: SampleAxis | SampleAux) -> list[Sample | TickLoss]:
        """Add one sample frame; return completed samples and loss reports, in tick order."""
        if isinstance(part, SampleAux):
            return self._add(part.tick, 3, (part.angle, part.temperature, int(part.validity)))
        return self._add(part.tick, _AXIS_SLOT[type(part)], (part.gyro, part.accel))

    def add_frame(self, function: CanFunction, data: bytes | bytearray) -> list[Sample | TickLoss]:
        """:meth:`add` for the 8-byte data of a sample frame of ``function`` (SAMPLE_X, _Y, _Z
        or _AUX), without building the frame's message."""
        slot = _SAMPLE_SLOT[function]
        if slot == 3:
            tick, *fields = sample_aux_fields(data)
        else:
            tick, *fields = sample_axis_fields(data)
        return self._add(tick, slot, tuple(fields))

    def add_tick(
        self,
        x: bytes | bytearray,
        y: bytes | bytearray,
        z: bytes | bytearray,
        aux: bytes | bytearray,
    ) -> list[Sample | TickLoss]:
        """:meth:`add_frame` for the 8-byte data of the four frames of one tick in the order the
        device sends them (SAMPLE_X, _Y, _Z, _AUX): the same result, without the steps of each
        frame when the four carry the same tick and no other tick waits for frames (the stream
        as it comes, four frames a tick)."""
        (tx, gx, lx, hx, ty, gy, ly, hy, tz, gz, lz, hz,
         ta, angle, temperature, bits) = sample_tick_fields(x, y, z, aux)  # fmt: skip
        ax, ay, az = lx | (hx << 16), ly | (hy << 16), lz | (hz << 16)
        if self._tick is not None or not tx == ty == tz == ta:
            return [
                *self._add(tx, 0, (gx, ax)), *self._add(ty, 1, (gy, ay)),
                *self._add(tz, 2, (gz, az)), *self._add(ta, 3, (angle, temperature, bits)),
            ]  # fmt: skip
        counter, step = self.counter.place(tx)
        if step == 0:  # the previous tick again: each frame a part already held
            self.duplicates += 4
            return []
        out: list[Sample | TickLoss] = []
        if step is not None and step > 1:
            self.lost += step - 1
            out.append(TickLoss((counter - step + 1) & UINT32_MAX, step - 1, False))
        out.append(
            Sample.fast(counter, (gx, gy, gz), (ax, ay, az), angle, temperature, validity_of(bits))
        )
        self.complete += 1
        return out

    def _add(self, t: int, slot: int, fields: tuple[int, ...]) -> list[Sample | TickLoss]:
        out: list[Sample | TickLoss] = []
        if self._tick is not None and t != self._tick:
            out.append(self._finish_incomplete())
        if self._tick is None:
            counter, step = self.counter.place(t)
            if step == 0:
                self.duplicates += 1
                return out
            if step is not None and step > 1:
                self.lost += step - 1
                out.append(TickLoss((counter - step + 1) & UINT32_MAX, step - 1, False))
            self._tick = t
        parts = self._parts
        if parts[slot] is not None:
            self.duplicates += 1
            return out
        parts[slot] = fields
        x, y, z, aux = parts
        if x is not None and y is not None and z is not None and aux is not None:
            out.append(
                Sample.fast(
                    self._placed(),
                    (x[0], y[0], z[0]),
                    (x[1], y[1], z[1]),
                    aux[0],
                    aux[1],
                    validity_of(aux[2]),
                )
            )
            self.complete += 1
            self._end_tick()
        return out

    def flush(self) -> list[TickLoss]:
        """Report a tick still waiting for frames as incomplete (e.g. at the end of a record)."""
        return [self._finish_incomplete()] if self._tick is not None else []

    def _placed(self) -> int:
        last = self.counter.last
        assert last is not None  # a tick is in progress, so it was placed
        return last

    def _finish_incomplete(self) -> TickLoss:
        self.incomplete += 1
        loss = TickLoss(self._placed(), 1, True)
        self._end_tick()
        return loss

    def _end_tick(self) -> None:
        self._tick = None
        self._parts = [None] * 4


class IdentifyAssembler:
    """Joins CAN IDENTIFY pages into an :class:`Identify`.

    Page 0 starts a new identify; pages before a page 0 are dropped.

    Attributes
    ----------
    errors : int
        Page sets dropped: a page out of turn, or pages that did not decode.
    last_error : ProtocolError or None
        The most recent reason for a drop.
    """

    def __init__(self) -> None:
        self._pages: list[IdentifyPage] = []
        self.errors = 0
        self.last_error: ProtocolError | None = None

    def add(self, page: IdentifyPage) -> Identify | None:
        """Add one page; return the identify when its last page arrives, else None."""
        if page.index == 0:
            if self._pages:
                self._drop(PayloadError("identify restarted before its last page"))
            self._pages = [page]
        elif not self._pages or page.index != len(self._pages) or page.last != self._pages[0].last:
            self._drop(PayloadError(f"identify page {page.index} out of turn"))
            return None
        else:
            self._pages.append(page)
        if page.index == page.last:
            pages, self._pages = self._pages, []
            try:
                return Identify.from_pages(pages)
            except ProtocolError as exc:
                self._drop(exc)
        return None

    def _drop(self, exc: ProtocolError) -> None:
        self._pages = []
        self.errors += 1
        self.last_error = exc


class CanReceiver:
    """Decodes a stream of CAN frames into whole messages (host side, or a bus monitor).

    Samples, status (STATUS followed by STATUS_COUNTERS) and identify pages are reassembled;
    commands and replies pass through. Frames that do not decode are counted and dropped.

    Parameters
    ----------
    node_id : int or None
        Keep only this node's frames (others are counted in ``other_node``); None keeps all
        (then the frames of several devices must not be mixed).

    Attributes
    ----------
    frames : int
        Frames given to :meth:`feed`.
    unknown_id : int
        Frames with an id outside the protocol's table (normal on a shared bus).
    malformed : int
        Frames with a protocol id that did not decode.
    other_node : int
        Frames of another node.
    last_error : ProtocolError or None
        The most recent decode error.
    ticks : TickAssembler
    identify : IdentifyAssembler
    """

    def __init__(self, node_id: int | None = None) -> None:
        self.node_id = node_id
        self.ticks = TickAssembler()
        self.identify = IdentifyAssembler()
        self._status: StatusMain | None = None
        self.frames = 0
        self.unknown_id = 0
        self.malformed = 0
        self.other_node = 0
        self.last_error: ProtocolError | None = None

    def feed_tick(
        self,
        x: bytes | bytearray,
        y: bytes | bytearray,
        z: bytes | bytearray,
        aux: bytes | bytearray,
    ) -> list[Sample | TickLoss]:
        """:meth:`feed` for the four 8-byte sample frames of one tick of this receiver's node,
        in sending order (X, Y, Z, AUX): the caller has checked their ids, standard, and
        lengths (:meth:`TickAssembler.add_tick`)."""
        self.frames += 4
        return self.ticks.add_tick(x, y, z, aux)

    def feed(
        self, arbitration_id: int, data: bytes | bytearray, *, is_extended_id: bool = False
    ) -> list[Message | TickLoss]:
        """Add one received frame; return the messages and tick losses it completes."""
        self.frames += 1
        function = arbitration_id & 0x7F0
        if (
            function in _SAMPLE_SLOT
            and len(data) == 8
            and arbitration_id & 0x0F
            and arbitration_id <= 0x7FF
            and not is_extended_id
        ):
            # The stream's frames (four a tick): straight into the tick, as decode_can would.
            if self.node_id is not None and arbitration_id & 0x0F != self.node_id:
                self.other_node += 1
                return []
            return self.ticks.add_frame(function, data)  # type: ignore[arg-type,return-value]
        try:
            node, msg = decode_can(arbitration_id, data, is_extended_id=is_extended_id)
        except UnknownMessageError as exc:
            self.unknown_id += 1
            self.last_error = exc
            return []
        except ProtocolError as exc:
            self.malformed += 1
            self.last_error = exc
            return []
        if self.node_id is not None and node != self.node_id:
            self.other_node += 1
            return []
        if isinstance(msg, SampleAxis | SampleAux):
            return [*self.ticks.add(msg)]
        if isinstance(msg, StatusMain):
            self._status = msg
            return []
        if isinstance(msg, StatusCounters):
            self.ticks.sync(msg.sample_counter)
            main, self._status = self._status, None
            if main is None:
                self.malformed += 1
                self.last_error = PayloadError("STATUS_COUNTERS without a preceding STATUS")
                return []
            return [Status.from_parts(main, msg)]
        if isinstance(msg, IdentifyPage):
            ident = self.identify.add(msg)
            return [] if ident is None else [ident]
        return [msg]
