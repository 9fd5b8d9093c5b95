"""The heading as NMEA 0183 sentences, as gyrocompasses send it.

Two sentences, each ``$...*hh`` with the NMEA checksum (XOR of the characters between ``$`` and
``*``) and CR LF:

``$HEHDT,x.xx,T*hh``
    Heading, true (talker HE: north-seeking gyro), deg, two decimals. The heading field is
    empty when the result is not valid (see the status below), as a compass sends it while it
    has no heading.

``$PNFDH,h.hhhh,s.ssss,S,p.ppp,r.rrr,N*hh`` (proprietary, manufacturer code ``NFD``, type ``H``)
    ``h`` heading deg true, four decimals; ``s`` its 1-sigma estimate, deg; ``S`` status: ``A``
    valid (sigma known and at most the limit, and the windows' consistency check did not fail),
    ``V`` not valid (sigma unknown or above the limit, or the windows disagree beyond their
    noise so the heading is not vouched for); when not valid the heading field is empty in both
    sentences, so that no consumer can take a heading the instrument does not stand behind;
    ``p``, ``r`` pitch and roll of the base, deg; ``N`` positions measured.

pynmea2 parses both (``pynmea2.parse(line, check=True)``); importing this module registers
:class:`NFDH` so that the proprietary sentence's fields have names (``heading``, ``sigma``,
``status``, ``pitch``, ``roll``, ``positions``).

:class:`NmeaOutput` writes them to a target: ``-`` (standard output), a serial port or
pseudo-terminal (a character device, opened with pyserial at ``baudrate``, 4800 by default as
NMEA 0183 says), or a file.
"""

from __future__ import annotations

import math
import os
import stat
import sys
from dataclasses import dataclass
from functools import reduce
from typing import IO, Any, ClassVar

import pynmea2
import serial

from northfinder.host.errors import HostConfigError

__all__ = [
    "NFDH",
    "NMEA_BAUD",
    "HeadingFix",
    "NmeaOutput",
    "checksum",
    "hdt_sentence",
    "nfdh_sentence",
    "sentence",
]

NMEA_BAUD = 4800
"""NMEA 0183's baud rate."""


def checksum(body: str) -> int:
    """The NMEA checksum of the characters between ``$`` and ``*``."""
    return reduce(lambda a, c: a ^ ord(c), body, 0)


def sentence(body: str) -> str:
    """``$BODY*hh`` with its checksum, without the line ending."""
    return f"${body}*{checksum(body):02X}"


@dataclass(frozen=True)
class HeadingFix:
    """What the sentences carry: the heading and its quality."""

    azimuth_deg: float
    sigma_deg: float | None
    pitch_deg: float
    roll_deg: float
    positions: int
    max_sigma_deg: float = 1.0
    consistent: bool | None = None
    """The windows' consistency check: False (they disagree beyond their noise) makes the fix
    not valid; None (no check: too few windows) leaves it to sigma."""

    @property
    def valid(self) -> bool:
        """Whether the heading may be used: a finite heading, sigma known and at most
        :attr:`max_sigma_deg`, and a consistency check that did not fail."""
        s = self.sigma_deg
        return (
            math.isfinite(self.azimuth_deg)
            and s is not None
            and math.isfinite(s)
            and s <= self.max_sigma_deg
            and self.consistent is not False
        )


def hdt_sentence(fix: HeadingFix) -> str:
    """``$HEHDT,x.xx,T*hh`` (empty heading when the fix is not valid)."""
    heading = f"{fix.azimuth_deg % 360.0:.2f}" if fix.valid else ""
    if heading == "360.00":
        heading = "0.00"
    return sentence(f"HEHDT,{heading},T")


def nfdh_sentence(fix: HeadingFix) -> str:
    """``$PNFDH,heading,sigma,status,pitch,roll,positions*hh``."""
    sigma = (
        "" if fix.sigma_deg is None or not math.isfinite(fix.sigma_deg) else f"{fix.sigma_deg:.4f}"
    )
    heading = f"{fix.azimuth_deg % 360.0:.4f}" if fix.valid else ""
    status = "A" if fix.valid else "V"
    return sentence(
        f"PNFDH,{heading},{sigma},{status},{fix.pitch_deg:.3f},{fix.roll_deg:.3f},{fix.positions}"
    )


class NFD(pynmea2.ProprietarySentence):
    """pynmea2's base for the ``$PNFD...`` sentences: picks the type by the letter after NFD."""

    sentence_types: ClassVar[dict[str, type[Any]]] = {}

    def __new__(cls, manufacturer: str, data: list[str]) -> Any:
        name = manufacturer + (data[0] if data else "")
        chosen = cls.sentence_types.get(name, cls)
        return super().__new__(chosen)


class NFDH(NFD):
    """``$PNFDH``: heading, sigma, status, pitch, roll, positions (see the module docstring)."""

    fields = (
        ("Subtype", "subtype"),
        ("Heading, deg true", "heading", float),
        ("Heading 1-sigma, deg", "sigma", float),
        ("Status, A valid / V not valid", "status"),
        ("Pitch, deg", "pitch", float),
        ("Roll, deg", "roll", float),
        ("Positions", "positions", int),
    )


NFD.sentence_types["NFDH"] = NFDH


def _is_character_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False


class NmeaOutput:
    """Where the sentences go: ``-``, a serial port or pty (a character device), or a file.

    Raises
    ------
    HostConfigError
        The target cannot be opened (the message names it and why).
    """

    def __init__(self, target: str, *, baudrate: int = NMEA_BAUD) -> None:
        self.target = target
        self._port: serial.SerialBase | None = None
        self._file: IO[str] | None = None
        self.sent = 0
        try:
            if target == "-":
                self._file = sys.stdout
                self._own = False
            elif _is_character_device(target):
                self._port = serial.serial_for_url(target, baudrate=baudrate, write_timeout=2.0)
                self._own = True
            else:
                self._file = open(target, "w", newline="")
                self._own = True
        except (OSError, serial.SerialException, ValueError) as exc:
            raise HostConfigError(f"--nmea {target}: cannot open ({exc})") from exc

    def send(self, *lines: str) -> None:
        """Write sentences, each ended by CR LF.

        Raises
        ------
        HostConfigError
            The write failed (port gone, disk full).
        """
        data = "".join(f"{line}\r\n" for line in lines)
        try:
            if self._port is not None:
                self._port.write(data.encode("ascii"))
                self._port.flush()
            else:
                assert self._file is not None
                self._file.write(data)
                self._file.flush()
        except (OSError, serial.SerialException) as exc:
            raise HostConfigError(f"--nmea {self.target}: cannot write ({exc})") from exc
        self.sent += len(lines)

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
        elif self._file is not None and self._own:
            self._file.close()

    def __enter__(self) -> NmeaOutput:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
