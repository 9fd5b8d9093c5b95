"""Exceptions of the conformance suite.

:class:`ConformanceError` derives from :class:`~northfinder.driver.errors.DriverError`, the root of
the driver package, so a caller of the suite catches everything the driver raises with one
``except``. :class:`Skipped` is not an error: a check raises it to say it does not apply.
"""

from __future__ import annotations

from northfinder.driver.errors import ArgumentError, DriverError

__all__ = ["ConformanceError", "LinkFault", "NoReply", "Skipped", "SuiteConfigError"]


class ConformanceError(DriverError):
    """Root of the errors of :mod:`northfinder.driver.conformance`."""


class SuiteConfigError(ConformanceError, ArgumentError):
    """An option of the suite is invalid, or a check pattern matches nothing (the message names it;
    an :class:`~northfinder.driver.errors.ArgumentError`, so a command line exits 2 for it)."""


class LinkFault(ConformanceError):
    """The unit stopped answering in a way that makes the current check meaningless."""


class NoReply(LinkFault):
    """A command the check cannot go on without got no reply within the wait.

    ``answer`` is the session's record of it (a reply that comes later is attached to it, late);
    ``what`` names the command.
    """

    def __init__(self, answer: object, what: str) -> None:
        super().__init__(f"no reply to {what}")
        self.answer = answer
        self.what = what


class Skipped(Exception):
    """Raised by a check that cannot apply to this unit or link; the reason is its message."""
