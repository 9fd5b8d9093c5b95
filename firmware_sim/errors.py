"""Exceptions of the simulator package."""


class SimError(Exception):
    """Root of every error raised by :mod:`firmware_sim`."""


class SimConfigError(SimError, ValueError):
    """A simulator parameter is invalid; the message names the field and what is wrong."""


class ControlError(SimError):
    """A control request that cannot be carried out (bad op or argument, or no answer)."""


class ControlRefused(ControlError):
    """The simulator answered a request with ``ok: false`` (a bad op, key or value); the
    message is the simulator's."""
