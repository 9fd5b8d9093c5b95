"""Exceptions of the host package."""


class HostError(Exception):
    """Root of every error raised by :mod:`host`."""


class HostConfigError(HostError, ValueError):
    """A host-side argument or configuration value is invalid (the message names it)."""
