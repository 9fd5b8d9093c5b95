"""Exceptions of the host package, and the one helper that phrases a bad choice."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any


class HostError(Exception):
    """Root of every error raised by :mod:`northfinder.host`."""


class HostConfigError(HostError, ValueError):
    """A host-side argument or configuration value is invalid (the message names it)."""


class InputError(HostConfigError):
    """Measurements handed to a host computation have the wrong shape or non-finite values."""


class GeometryError(HostError, ValueError):
    """The table positions cannot determine a heading (too close together, too few, ill-conditioned)."""


class LatitudeError(HostError, ValueError):
    """The latitude is missing, not finite, out of range, or too close to a pole for north finding."""


class TiltError(HostError, ValueError):
    """The instrument is tilted beyond the solver's limit, or the accelerometers contradict gravity."""


class DenoiseError(HostError, ValueError):
    """A denoising method cannot run on this signal (too short for the window or wavelet level)."""


class AlignmentError(HostError):
    """The static alignment filter cannot start or has diverged."""


class QualityError(HostError):
    """A window is unusable: the table moved, samples are flagged bad, or data are missing."""


class RecordingError(HostError):
    """A recording cannot be read or is not valid; the message names the file and what is wrong."""


class OutputError(HostError):
    """A file the command writes (recording, plot, report) cannot be written."""


def check_choice(
    value: str, choices: Mapping[str, Any] | Sequence[str], name: str, what: str = "value"
) -> str:
    """Return ``value`` if it is one of ``choices``; else raise one error that lists them.

    Raises
    ------
    HostConfigError
        ``"{name}: unknown {what} {value!r}; choose one of ..."``.
    """
    if value not in choices:
        listed = ", ".join(repr(k) for k in choices)
        raise HostConfigError(f"{name}: unknown {what} {value!r}; choose one of {listed}")
    return value
