"""The one shape of every ``--json`` result (``find``, ``solve``, ``study``, ``conformance``).

Each result is an object with an envelope and the command's own keys::

    {"schema": "northfinder-result", "schema_version": 1, "command": "find",
     "created_utc": "2025-01-31T12:00:00.123Z", "northfinder_version": "0.1.0",
     "device": {"model": "NF-SIM", "serial_number": 1, "firmware_version": "0.1.0",
                "protocol_version": "1.0", "simulated": true, ...},
     "azimuth_deg": ..., ...}

The JSON Schema ``schemas/result.schema.json`` beside this module (installed with the package;
:func:`schema` loads it) states every key, unit and bound; docs/recordings.md, "JSON results",
explains it.
``schema_version`` rises when a key changes meaning or goes away; new keys may appear at any
version. Recordings carry the same ``device`` and ``created_utc`` in their metadata.
"""

from __future__ import annotations

import datetime as _dt
import json
from importlib import metadata, resources
from typing import Any

__all__ = [
    "SCHEMA",
    "SCHEMA_VERSION",
    "SIMULATOR_MODEL",
    "device_identity",
    "envelope",
    "package_version",
    "schema",
    "utc_now",
]

SCHEMA = "northfinder-result"
SCHEMA_VERSION = 1
SIMULATOR_MODEL = "NF-SIM"
"""The model name the simulated instrument reports in IDENTIFY (a log or recording of it is
marked ``simulated``)."""


def utc_now() -> str:
    """The time now in UTC, ISO 8601 with milliseconds and a ``Z``."""
    now = _dt.datetime.now(_dt.UTC)
    return now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 1000:03d}Z"


def package_version() -> str:
    """The installed northfinder's version ("unknown" when run from an uninstalled tree)."""
    try:
        return metadata.version("northfinder")
    except metadata.PackageNotFoundError:
        return "unknown"


def device_identity(
    ident: Any, *, simulated: bool = False, sensor: str | None = None
) -> dict[str, Any]:
    """A device's identity (an :class:`~northfinder.driver.protocol.messages.Identify`) as results
    and recordings state it."""
    out: dict[str, Any] = {
        "model": ident.model,
        "serial_number": int(ident.serial_number),
        "hardware_revision": int(ident.hardware_revision),
        "firmware_version": ".".join(str(int(v)) for v in ident.firmware_version),
        "protocol_version": ".".join(str(int(v)) for v in ident.protocol_version),
        "simulated": simulated,
    }
    if sensor is not None:
        out["sensor"] = sensor
    return out


def envelope(command: str, device: dict[str, Any] | None, body: dict[str, Any]) -> dict[str, Any]:
    """The result of ``command``: the envelope first, then ``body``'s keys."""
    return {
        "schema": SCHEMA,
        "schema_version": SCHEMA_VERSION,
        "command": command,
        "created_utc": utc_now(),
        "northfinder_version": package_version(),
        "device": device,
        **body,
    }


def schema() -> dict[str, Any]:
    """The JSON Schema of the results (a dict, for ``jsonschema.validate``)."""
    text = resources.files("northfinder.host").joinpath("schemas/result.schema.json").read_text()
    loaded: dict[str, Any] = json.loads(text)
    return loaded
