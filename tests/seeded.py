"""Recordings of seeded random windows, for the tests of the window-by-window readers
(``summarise_npz``, ``summarise_csv``), and ``solve --json`` of a file read both ways."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from clirun import run_cli

import northfinder.cli.solve as solve
from northfinder.host.recording import RecordedWindow, Recording

RATE_HZ = 200.0


def seeded_windows(
    windows: int, n: int, seed: int, *, spacing: int = 10, dt: float = 1.0, biased: bool = True
) -> list[RecordedWindow]:
    """``windows`` windows of ``n`` samples at 0, 90, 180, 270, ... deg, their counters
    ``spacing * n`` apart, their steps ``dt`` periods; ``biased``: each angle's own gyro mean
    (else none) and a tilt."""
    rng = np.random.default_rng(seed)
    made = []
    for k in range(windows):
        counter = np.arange(n) + k * spacing * n
        angle = 90.0 * (k % 4)
        gyro = [10.0 * (k % 4 - 1.5), 5.0, -8.0] if biased else 0.0
        accel = [0.01, -0.02, 9.8] if biased else [0.0, 0.0, 9.8]
        made.append(
            RecordedWindow(
                angle, counter, (counter + 1) / RATE_HZ * dt, rng.normal(gyro, 3.0, (n, 3)),
                rng.normal(accel, 1e-3, (n, 3)), np.full(n, angle), np.full(n, 20.0),
                np.full(n, 3, dtype=np.uint8),
            )
        )  # fmt: skip
    return made


def saved(path: Path, windows: list[RecordedWindow], meta: dict[str, Any] | None = None) -> Path:
    """``windows`` saved as a recording at 34 deg N (its format by ``path``'s ending)."""
    Recording(
        tuple(windows), {"latitude_deg": 34.0, "sample_rate_hz": RATE_HZ, **(meta or {})}
    ).save(path)
    return path


def solved_both_ways(path: Path, monkeypatch: pytest.MonkeyPatch, *options: str) -> list[Any]:
    """``solve --json`` read window by window and read whole (every window held): exit status,
    the JSON (without its time of creation) and stderr of each."""
    out = []
    for streamed in (True, False):
        with monkeypatch.context() as m:
            if not streamed:
                m.setattr(solve, "summarise_recording", lambda *_: None)
            code, text, err = run_cli("solve", str(path), "--json", *options)
        doc = json.loads(text) if text else {}
        doc.pop("created_utc", None)
        out.append((code, doc, err))
    return out
