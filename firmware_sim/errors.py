"""Exceptions of the simulator package."""


class SimError(Exception):
    """Root of every error raised by :mod:`firmware_sim`."""


class SimConfigError(SimError, ValueError):
    """A simulator parameter is invalid; the message names the field and what is wrong."""
