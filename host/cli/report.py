"""How ``find`` and ``solve`` show a result: a short text for people, JSON for machines, a plot."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from northfinder.host.errors import HostConfigError, OutputError
from northfinder.host.procedure import FindResult


def angle_error(a_deg: float, b_deg: float) -> float:
    """Signed difference a - b wrapped to [-180, 180)."""
    return (a_deg - b_deg + 180.0) % 360.0 - 180.0


def text(result: FindResult, truth: dict[str, float] | None = None) -> str:
    sigma = f" +- {result.sigma_deg:.4f}" if result.sigma_deg is not None else ""
    lines = [
        f"azimuth {result.azimuth_deg:.4f} deg{sigma} (1 sigma), clockwise from true north",
        f"pitch {result.pitch_deg:.4f} deg, roll {result.roll_deg:.4f} deg",
        f"method {result.method}, denoise {result.denoise}, latitude {result.latitude_deg:g} deg"
        + (f" from {result.latitude_source}" if result.latitude_source else "")
        + f", positions {', '.join(f'{w.encoder_deg:.4f}' for w in result.windows)} deg (encoder)",
    ]
    if result.pairwise_deg:
        lines.append(
            "pairwise azimuths " + ", ".join(f"{a:.4f}" for a in result.pairwise_deg) + " deg"
        )
    if truth is not None:
        err = angle_error(result.azimuth_deg, truth["azimuth_deg"])
        lines.append(
            f"truth   {truth['azimuth_deg']:.4f} deg (pitch {truth['pitch_deg']:g}, roll {truth['roll_deg']:g}); "
            f"error {err:+.4f} deg"
        )
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)


def as_json(result: FindResult, truth: dict[str, float] | None = None, **extra: Any) -> str:
    out = result.to_dict()
    if truth is not None:
        out["truth"] = truth
        out["error_deg"] = angle_error(result.azimuth_deg, truth["azimuth_deg"])
    out.update(extra)
    return json.dumps(out, indent=2)


def require_matplotlib() -> None:
    """Refuse ``--plot`` before any work when matplotlib is not installed."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        raise HostConfigError("--plot needs matplotlib: pip install 'northfinder[plot]'") from exc


def plot(path: str | Path, result: FindResult, windows: list[Any], denoise_method: str) -> None:
    """Windows raw and denoised (gyro x, y) and the per-pair azimuths, to an image file."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise HostConfigError("--plot needs matplotlib: pip install 'northfinder[plot]'") from exc
    from northfinder.host.denoise import denoise

    n = len(windows)
    fig, axes = plt.subplots(n + 1, 1, figsize=(9, 2.2 * (n + 1)), squeeze=False)
    for i, (w, s) in enumerate(zip(windows, result.windows, strict=True)):
        ax = axes[i, 0]
        t = np.asarray(w.time_s) - w.time_s[0]
        for j, name in enumerate("xy"):
            raw = np.asarray(w.gyro_dph)[:, j]
            ax.plot(t, raw, lw=0.4, alpha=0.5, label=f"gyro {name} raw")
            if denoise_method != "none":
                ax.plot(
                    t, denoise(raw, denoise_method), lw=1.0, label=f"gyro {name} {denoise_method}"
                )
        ax.set_ylabel("deg/h")
        ax.set_title(f"position {i + 1}: encoder {s.encoder_deg:.4f} deg", fontsize=9)
        ax.legend(fontsize=7, loc="upper right")
    ax = axes[n, 0]
    pairs = result.pairwise_deg or (result.azimuth_deg,)
    ax.plot(range(1, len(pairs) + 1), pairs, "o-")
    ax.axhline(result.azimuth_deg, color="k", lw=0.8, label="solution")
    ax.set_xlabel("pair")
    ax.set_ylabel("azimuth deg")
    ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise OutputError(f"--plot {path}: cannot write ({exc.strerror})") from exc
    finally:
        plt.close(fig)
