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
NMEA 0183 says), ``udp://HOST:PORT`` (one datagram per sentence, as chart plotters and OpenCPN
listen for it; 10110 is the usual port), ``tcp://HOST:PORT`` (a TCP client; a server that
closed the connection is found before each write, not after the sentence was lost), another
pyserial URL (``socket://``, ``rfc2217://``, ...), or a file. A path
under ``/dev`` that does not exist is refused, never created as a regular file.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import socket
import stat
import sys
import urllib.parse
from dataclasses import dataclass
from functools import reduce
from typing import IO, Any, ClassVar

import pynmea2
import serial

from northfinder.host.errors import HostConfigError, OutputError
from northfinder.host.heading import heading_text

__all__ = [
    "NFDH",
    "NMEA_BAUD",
    "HeadingFix",
    "NmeaOutput",
    "checksum",
    "hdt_sentence",
    "nfdh_sentence",
    "parse_network_target",
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


def _fixed(value: float, digits: int) -> str:
    """``value`` with ``digits`` decimals, a value that rounds to zero without its sign (a
    consumer reads ``-0.000`` as a tilt the other way)."""
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def hdt_sentence(fix: HeadingFix) -> str:
    """``$HEHDT,x.xx,T*hh`` (empty heading when the fix is not valid)."""
    heading = heading_text(fix.azimuth_deg, 2) if fix.valid else ""
    return sentence(f"HEHDT,{heading},T")


def nfdh_sentence(fix: HeadingFix) -> str:
    """``$PNFDH,heading,sigma,status,pitch,roll,positions*hh``."""
    sigma = (
        "" if fix.sigma_deg is None or not math.isfinite(fix.sigma_deg) else f"{fix.sigma_deg:.4f}"
    )
    heading = heading_text(fix.azimuth_deg, 4) if fix.valid else ""
    status = "A" if fix.valid else "V"
    return sentence(
        f"PNFDH,{heading},{sigma},{status},{_fixed(fix.pitch_deg, 3)},{_fixed(fix.roll_deg, 3)},"
        f"{fix.positions}"
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


#: The network schemes of a target: ours (udp, tcp) and pyserial's URL handlers.
NETWORK_SCHEMES = ("udp", "tcp")
_PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "hwgrep", "alt", "cp2110")


def parse_network_target(target: str) -> tuple[str, str, int] | None:
    """``(scheme, host, port)`` of ``udp://HOST:PORT`` or ``tcp://HOST:PORT`` (IPv6 in
    brackets), None for another kind of target.

    Raises
    ------
    HostConfigError
        The scheme is ours but the host or port is missing or out of range.
    """
    scheme, sep, _ = target.partition("://")
    if not sep or scheme.lower() not in NETWORK_SCHEMES:
        return None
    url = urllib.parse.urlsplit(target)
    try:
        port = url.port
    except ValueError:
        port = None
    if not url.hostname or port is None or not 1 <= port <= 65535:
        raise HostConfigError(
            f"--nmea {target}: give {scheme.lower()}://HOST:PORT with a port 1..65535 "
            "(for example udp://127.0.0.1:10110)"
        )
    return scheme.lower(), url.hostname, port


def _under_dev(path: str) -> bool:
    return os.path.abspath(path).startswith("/dev/")


#: Seconds to connect to a TCP server, and to write a sentence to it.
NMEA_TIMEOUT_S = 2.0


class NmeaOutput:
    """Where the sentences go: ``-``, ``udp://HOST:PORT``, ``tcp://HOST:PORT``, a pyserial URL,
    a serial port or pty (a character device), or a file (see the module docstring). The target
    is opened here, so that a command can open it before it measures.

    Raises
    ------
    HostConfigError
        The target cannot be opened (the message names it and why).
    """

    def __init__(self, target: str, *, baudrate: int = NMEA_BAUD) -> None:
        self.target = target
        self._port: serial.SerialBase | None = None
        self._file: IO[str] | None = None
        self._socket: socket.socket | None = None
        self._stream: socket.socket | None = None
        self.sent = 0
        self._own = True
        network = parse_network_target(target)
        try:
            if target == "-":
                self._file = sys.stdout
                self._own = False
            elif network is not None and network[0] == "udp":
                _, host, port = network
                family, kind, proto, _, address = socket.getaddrinfo(
                    host, port, type=socket.SOCK_DGRAM
                )[0]
                self._socket = socket.socket(family, kind, proto)
                self._socket.connect(address)  # no packet: fixes the peer of every send
            elif network is not None:
                _, host, port = network
                self._stream = socket.create_connection((host, port), timeout=NMEA_TIMEOUT_S)
            elif target.split("://", 1)[0].lower() in _PYSERIAL_SCHEMES:
                self._port = serial.serial_for_url(target, baudrate=baudrate, write_timeout=2.0)
            elif _is_character_device(target):
                self._port = serial.serial_for_url(target, baudrate=baudrate, write_timeout=2.0)
            elif _under_dev(target):
                why = "no such device" if not os.path.exists(target) else "not a character device"
                raise HostConfigError(f"--nmea {target}: {why} (a port under /dev must exist)")
            else:
                if os.path.isdir(target):
                    raise HostConfigError(f"--nmea {target}: is a folder; give a file name")
                self._file = open(target, "w", newline="")
        except HostConfigError:
            raise
        except (OSError, serial.SerialException, ValueError) as exc:
            raise HostConfigError(f"--nmea {target}: cannot open ({exc})") from exc

    def send(self, *lines: str) -> None:
        """Write sentences, each ended by CR LF.

        Raises
        ------
        OutputError
            The write failed (port gone, disk full, the TCP server closed the connection).
        """
        data = "".join(f"{line}\r\n" for line in lines)
        try:
            if self._stream is not None:
                self._check_peer(self._stream)
                self._stream.sendall(data.encode("ascii"))
            elif self._socket is not None:
                for line in lines:  # one sentence a datagram
                    with contextlib.suppress(ConnectionRefusedError):
                        # Nobody listening (yet): a datagram is sent to whoever listens, as a
                        # compass on a network sends it; the next one may be heard.
                        self._socket.send(f"{line}\r\n".encode("ascii"))
            elif self._port is not None:
                self._port.write(data.encode("ascii"))
                self._port.flush()
            else:
                assert self._file is not None
                self._file.write(data)
                self._file.flush()
        except (OSError, serial.SerialException) as exc:
            raise OutputError(f"--nmea {self.target}: cannot write ({exc})") from exc
        self.sent += len(lines)

    @staticmethod
    def _check_peer(stream: socket.socket) -> None:
        """Read what the server sent (a listener need not send anything; it is dropped) up to
        its end: a server that closed the connection would lose the next sentence without an
        error (the first write after the close succeeds)."""
        while select.select([stream], [], [], 0.0)[0]:
            if not stream.recv(4096):
                raise ConnectionResetError("the server closed the connection")

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
        elif self._socket is not None:
            self._socket.close()
        elif self._port is not None:
            self._port.close()
        elif self._file is not None and self._own:
            self._file.close()

    def __enter__(self) -> NmeaOutput:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
