"""The sample counter's arithmetic, defined once for the driver, the conformance suite and monitors.

The device numbers its sample ticks with a 32-bit counter that wraps (protocol.md 4.5). Serial
samples carry it whole; CAN sample frames carry only its low byte, the *tick*, and a receiver
extends the tick to the full counter (protocol.md 8): forward from the previous tick, anchored by
the full counter that every STATUS_COUNTERS frame carries. :class:`TickCounter` is that extension;
:func:`counter_diff` compares two counters across the wrap.

Pure code: no I/O, no clock.
"""

from __future__ import annotations

from northfinder.driver.protocol.constants import UINT32_MAX

__all__ = ["TickCounter", "counter_diff", "nearest_counter"]

_HALF = 1 << 31


def nearest_counter(low8: int, reference: int) -> int:
    """The 32-bit counter whose low byte is ``low8`` (taken modulo 256) nearest to ``reference``.

    Ties (128 ticks either way) resolve to the earlier counter.
    """
    return (reference + ((low8 - reference + 128) & 0xFF) - 128) & UINT32_MAX


def counter_diff(later: int, earlier: int) -> int:
    """``later - earlier`` for two 32-bit counters across the wrap, in [-2**31, 2**31).

    Positive: ``later`` follows ``earlier`` by that many ticks; 0: the same tick; negative: the
    counter went back (the device restarted).
    """
    return ((later - earlier + _HALF) & UINT32_MAX) - _HALF


class TickCounter:
    """Extends the 8-bit CAN tick to the 32-bit sample counter.

    Each new tick is placed forward from the previous one. :meth:`sync` anchors the extension on
    the full counter of a status: the first tick after a :meth:`restart` takes the counter with its
    low byte nearest the anchor, and the first tick after a new anchor takes it too when that lies
    further ahead than the forward step, so a gap of 256 ticks or more is measured, not folded
    modulo 256. Before any anchor the first tick gets ``counter = tick`` (unanchored); the next
    anchor moves such a counter to where it belongs.

    Attributes
    ----------
    last : int or None
        Full counter of the latest tick placed (None after :meth:`restart` and at start).
    anchored : bool
        Whether :attr:`last` was placed relative to an anchor (else it is known modulo 256 only).
    """

    def __init__(self) -> None:
        self._anchor: int | None = None
        self._fresh = False  # an anchor from sync() not yet used by a new tick
        self.last: int | None = None
        self.anchored = False

    def sync(self, sample_counter: int) -> bool:
        """Anchor on the full sample counter of a status (the device's latest tick).

        Returns
        -------
        bool
            True if :attr:`last` was unanchored and has been moved to the anchor's neighbourhood.
        """
        counter = sample_counter & UINT32_MAX
        self._anchor = counter
        self._fresh = True
        if self.last is not None and not self.anchored:
            self.last = nearest_counter(self.last, counter)
            self.anchored = True
            return True
        return False

    def restart(self) -> None:
        """Forget the previous tick: the stream was off, and ticks it did not send are not lost.

        The next tick is placed by the latest anchor.
        """
        self.last = None
        self.anchored = False

    def place(self, tick: int) -> tuple[int, int | None]:
        """Place a tick that starts now: its full counter and its step from the previous tick.

        Parameters
        ----------
        tick : int
            The tick (low byte of the counter) of a sample frame that does not belong to the tick in
            progress.

        Returns
        -------
        counter : int
            Full 32-bit counter of the tick.
        step : int or None
            Ticks since the previous tick: 1 consecutive, ``n`` when ``n - 1`` ticks are missing,
            0 when it repeats the previous tick (then nothing changes); None for the first tick
            after a restart.
        """
        if self.last is None:
            if self._anchor is None:
                counter, self.anchored = tick & 0xFF, False
            else:
                counter, self.anchored = nearest_counter(tick, self._anchor), True
            self._fresh = False
            self.last = counter
            return counter, None
        step = (tick - self.last) & 0xFF
        if self._fresh and self._anchor is not None:
            ahead = (nearest_counter(tick, self._anchor) - self.last) & UINT32_MAX
            if ahead != step and 0 < ahead < _HALF:
                step = ahead
        if step == 0:
            return self.last, 0
        self._fresh = False
        self.last = (self.last + step) & UINT32_MAX
        return self.last, step
