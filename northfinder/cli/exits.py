"""The error policy of every command: one line per error and a stated exit status.

Exit status
-----------
- 0: done.
- 1 (:data:`EXIT_RUNTIME`): the work failed: the device or link (refusals, timeouts, a lost link,
  gaps, faults), measured data unusable (quality, tilt), a file that cannot be written.
- 2 (:data:`EXIT_USAGE`): the request is wrong: a command-line argument or option, a combination of
  them, or the content of a file named on the command line (a sensor TOML, a recording). Fix the
  command and run it again. argparse's own errors exit 2 as well.
- 3 (:data:`EXIT_INCONSISTENT`): ``find`` and ``solve`` found a heading, but its windows failed
  their consistency check (they disagree beyond their noise: a bias step, a drift, a table angle
  error, a wrong latitude), or a spin's two halves did. The result is printed (JSON, plot,
  record) with the warning, its sigma scaled; NMEA sends it as not valid. A script must not take
  it as a good heading.
- 4 (:data:`EXIT_NOT_RESOLVED`): ``accept`` failed no datasheet line, but the data could not
  decide at least one (NOT RESOLVED: the record too short); the report says what would decide it.
- 130, 143, 129: interrupted by SIGINT (Ctrl-C), SIGTERM, SIGHUP (128 + the signal's number);
  a device the command opened is left at rest first (:class:`SignalInterrupt`).

:func:`exit_status` maps an exception to its status by :data:`EXIT_STATUS` (the most specific
class of the error's MRO decides); :func:`report_error` prints the one line. An exception of no
listed class is a bug of the program: it is reported as an internal error (exit 1) in one line
that names its type, and ``--debug`` shows its traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import TextIO

from northfinder.driver.errors import ArgumentError, DriverError
from northfinder.endings import ending_of
from northfinder.firmware_sim.errors import ControlRefused, SimConfigError, SimError
from northfinder.host.errors import (
    DenoiseError,
    GeometryError,
    HostConfigError,
    HostError,
    LatitudeError,
    RecordingError,
)

EXIT_RUNTIME = 1
EXIT_USAGE = 2
EXIT_INCONSISTENT = 3
EXIT_NOT_RESOLVED = 4
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


class SignalInterrupt(KeyboardInterrupt):
    """SIGTERM, SIGHUP (or SIGINT) turned into the interrupt Ctrl-C raises, so that every
    ending runs the same clean-up; ``signum`` names the signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = int(signum)


#: Exception class -> exit status. The first class of an error's MRO found here decides, so a
#: subclass listed overrides its base (a HostConfigError is a HostError, and exits 2).
EXIT_STATUS: Mapping[type[BaseException], int] = {
    HostConfigError: EXIT_USAGE,
    LatitudeError: EXIT_USAGE,
    GeometryError: EXIT_USAGE,
    DenoiseError: EXIT_USAGE,
    RecordingError: EXIT_USAGE,
    SimConfigError: EXIT_USAGE,
    ControlRefused: EXIT_USAGE,
    ArgumentError: EXIT_USAGE,
    HostError: EXIT_RUNTIME,
    SimError: EXIT_RUNTIME,
    DriverError: EXIT_RUNTIME,
    OSError: EXIT_RUNTIME,
}


def result_status(consistent: bool | None) -> int:
    """The exit status of a heading: :data:`EXIT_INCONSISTENT` when its consistency check failed,
    else 0 (passed, or not checked: a two-position plan)."""
    return EXIT_INCONSISTENT if consistent is False else 0


def exit_status(exc: BaseException) -> int | None:
    """The exit status of an error of a known kind (:data:`EXIT_STATUS`), None for a bug."""
    for cls in type(exc).__mro__:
        if cls in EXIT_STATUS:
            return EXIT_STATUS[cls]
    return None


def error_line(command: str, exc: BaseException) -> str:
    """``northfinder COMMAND: error: MESSAGE`` on one line (a multi-line message is joined)."""
    text = "; ".join(part.strip() for part in str(exc).splitlines() if part.strip())
    if isinstance(exc, OSError) and not isinstance(exc, DriverError | HostError | SimError):
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        text = f"{where}{exc.strerror or text or type(exc).__name__}"
    if exit_status(exc) is None:
        return (
            f"northfinder {command}: internal error ({type(exc).__name__}: {text or 'no message'}); "
            "run with --debug for the traceback and report it"
        )
    return f"northfinder {command}: error: {text or type(exc).__name__}"


def report_error(command: str, exc: BaseException, stream: TextIO | None = None) -> int:
    """Print the one line for ``exc`` and return the exit status (internal errors: 1); what was
    done to leave a device at rest (:func:`note_at_rest`) ends the line."""
    line = error_line(command, exc)
    ending = ending_of(exc)
    if ending is not None:
        line += f" ({ending})"
    print(line, file=stream or sys.stderr)
    status = exit_status(exc)
    return EXIT_RUNTIME if status is None else status
