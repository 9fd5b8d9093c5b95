"""Exceptions of the host package."""


class HostError(Exception):
    """Root of every error raised by :mod:`host`."""


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
