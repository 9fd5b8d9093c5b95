"""A conformance session on a link that receives nothing, for tests that hand it arrivals."""

from __future__ import annotations

from northfinder.driver.clock import WallClock
from northfinder.driver.conformance.session import Session
from northfinder.driver.conformance.wire import SerialRawLink


class NoLink:
    """A serial link that receives nothing."""

    kind = "serial"
    tick_bytes = SerialRawLink.tick_bytes
    after_send = None

    def receive(self, timeout: float) -> list:
        return []


def idle_session() -> Session:
    """A session on :class:`NoLink` with the wall clock."""
    return Session(NoLink(), clock=WallClock())  # type: ignore[arg-type]
