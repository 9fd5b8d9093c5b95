"""Output files named on the command line: refused before any work when they cannot be
written; CAN log names and their rotation.
"""

from __future__ import annotations

import argparse
import os
import re
from typing import Any

from northfinder.driver.errors import ArgumentError
from northfinder.host.errors import HostConfigError


def check_output_path(path: str, option: str, suffixes: tuple[str, ...] = ()) -> str:
    """Refuse, before any work, an output file that cannot be written: a missing folder, a
    folder in its place, a path under /dev that does not exist, or (with ``suffixes``) a name
    of another kind."""
    if suffixes and not path.endswith(suffixes):
        raise HostConfigError(f"{option} {path}: the file name must end in {' or '.join(suffixes)}")
    if os.path.abspath(path).startswith("/dev/") and not os.path.exists(path):
        # A mistyped port name must not become a regular file under /dev.
        raise HostConfigError(f"{option} {path}: no such device (a path under /dev must exist)")
    if os.path.isdir(path):
        raise HostConfigError(f"{option} {path}: is a folder; give a file name")
    folder = os.path.dirname(path) or "."
    if not os.path.isdir(folder):
        raise HostConfigError(f"{option} {path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise HostConfigError(f"{option} {path}: the folder {folder} is not writable")
    return path


def can_log_path(text: str) -> str:
    """argparse type: a CAN log file name whose ending names one of python-can's formats."""
    from northfinder.driver.framelog import log_suffix

    try:
        log_suffix(text)
        check_output_path(text, "--can-log")
    except (ArgumentError, HostConfigError) as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--can-log ")) from None
    return text


_SIZE_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "d": 86_400.0}


def rotation_limits(text: str) -> tuple[int, float]:
    """argparse type: when a rotated log begins a new part, as ``(max_bytes, max_seconds)`` (0:
    not by that): a size with K, M, G or T (1024-based: ``10M`` is 10 MiB, a trailing B
    allowed), an age of log time with s, min, h or d (``90s``, ``1h``), or one of each
    (``10M,1h``: whichever comes first)."""
    from northfinder.driver.framelog import MAX_BYTES_RANGE, MAX_SECONDS_RANGE

    max_bytes, max_seconds = 0, 0.0
    for item in (part.strip() for part in text.split(",")):
        size = re.fullmatch(r"(\d+)\s*([KMGT])(?:i?B)?|(\d+)\s*B", item)
        age = re.fullmatch(r"(\d+(?:\.\d+)?)\s*(s|min|h|d)", item)
        if size is not None and not max_bytes:
            number, unit = (size.group(1), size.group(2)) if size.group(1) else (size.group(3), "")
            max_bytes = int(number) * _SIZE_UNITS[unit]
            lo, hi = MAX_BYTES_RANGE
            if not lo <= max_bytes <= hi:
                raise argparse.ArgumentTypeError(f"a size must be 4K to 1T, got {item!r}")
        elif age is not None and not max_seconds:
            max_seconds = float(age.group(1)) * _TIME_UNITS[age.group(2)]
            lo_s, hi_s = MAX_SECONDS_RANGE
            if not lo_s <= max_seconds <= hi_s:
                raise argparse.ArgumentTypeError(f"an age must be 1s to 366d, got {item!r}")
        else:
            raise argparse.ArgumentTypeError(
                f"expected a size (10M, 1G), an age (90s, 15min, 1h) or one of each (10M,1h), "
                f"got {text!r}"
            )
    return max_bytes, max_seconds


def add_log_rotation(group: Any, option: str) -> None:
    """``OPTION-rotate LIMIT``: rotation of the CAN log of ``OPTION`` (``--log``,
    ``--can-log``) by size or age, as python-can's rotating loggers rotate."""
    group.add_argument(
        f"{option}-rotate", type=rotation_limits, default=(0, 0.0), metavar="AT",
        help="new part at a size or an age: 10M, 1h or 10M,1h",
    )  # fmt: skip
