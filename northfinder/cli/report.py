"""How ``find`` and ``solve`` show a result: a short text for people, JSON for machines, a plot."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from northfinder.cli.output import dumps, plain_numbers
from northfinder.cli.plots import pyplot, save_figure
from northfinder.host.consistency import FAILED_MARKER
from northfinder.host.heading import heading_text
from northfinder.host.procedure import FindResult, pairwise_solutions
from northfinder.host.results import envelope


def angle_error(a_deg: float, b_deg: float) -> float:
    """Signed difference a - b wrapped to [-180, 180)."""
    return (a_deg - b_deg + 180.0) % 360.0 - 180.0


def text(result: FindResult, truth: dict[str, float] | None = None) -> str:
    sigma = f" +- {result.sigma_deg:.4f}" if result.sigma_deg is not None else ""
    positions = ", ".join(heading_text(w.encoder_deg, 4) for w in result.windows)
    lines = [
        f"azimuth {heading_text(result.azimuth_deg, 4)} deg{sigma} (1 sigma), clockwise from "
        "true north",
        f"pitch {result.pitch_deg:.4f} deg, roll {result.roll_deg:.4f} deg",
        f"solver {result.method}, denoise {result.denoise}, latitude {result.latitude_deg:g} deg"
        + (f" from {result.latitude_source}" if result.latitude_source else "")
        + f", positions {positions} deg (encoder)",
    ]
    if result.pairwise_deg:
        lines.append(
            "pairwise azimuths "
            + ", ".join(heading_text(a, 4) for a in result.pairwise_deg)
            + " deg"
        )
    if truth is not None:
        err = angle_error(result.azimuth_deg, truth["azimuth_deg"])
        lines.append(
            f"truth   {heading_text(truth['azimuth_deg'], 4)} deg (pitch {truth['pitch_deg']:g}, "
            f"roll {truth['roll_deg']:g}); "
            f"error {err:+.4f} deg"
            + (
                f"; seed {truth['seed']} (--seed {truth['seed']} repeats the run)"
                if "seed" in truth
                else ""
            )
        )
    lines += [f"note: {n}" for n in result.notes]
    return plain_numbers("\n".join(lines))


def as_json(
    command: str,
    result: FindResult,
    truth: dict[str, Any] | None = None,
    device: dict[str, Any] | None = None,
    **extra: Any,
) -> str:
    """The result as the documented JSON (:mod:`northfinder.host.results`, schema version
    :data:`~northfinder.host.results.SCHEMA_VERSION`)."""
    body = result.to_dict()
    body["solver"] = result.method
    if truth is not None:
        body["truth"] = truth
        body["error_deg"] = angle_error(result.azimuth_deg, truth["azimuth_deg"])
    body.update(extra)
    return dumps(envelope(command, device, body))


def _title(result: FindResult, truth: dict[str, Any] | None) -> str:
    sigma = "" if result.sigma_deg is None else f" ± {result.sigma_deg:.4f}"
    head = f"azimuth {heading_text(result.azimuth_deg, 4)}{sigma} deg (1σ)"
    if truth is not None:
        err = angle_error(result.azimuth_deg, truth["azimuth_deg"])
        head += (
            f"   simulated truth {heading_text(truth['azimuth_deg'], 4)} deg, error {err:+.4f} deg"
        )
    return head


def _subtitle(result: FindResult, truth: dict[str, Any] | None) -> str:
    n = len(result.windows)
    parts = [
        f"{n} positions",
        f"{result.windows[0].samples} samples a window" if n else "",
        f"solver {result.method}",
        f"denoise {result.denoise}",
        f"latitude {result.latitude_deg:g} deg",
        f"pitch {result.pitch_deg:.3f} deg, roll {result.roll_deg:.3f} deg",
    ]
    if truth is not None and "sensor" in truth:
        parts.insert(0, f"sensor {truth['sensor']}")
    return ", ".join(p for p in parts if p)


def plot(
    path: str | Path,
    result: FindResult,
    windows: list[Any],
    denoise_method: str,
    truth: dict[str, Any] | None = None,
) -> None:
    """The figure of a find or solve: gyro x and y over device time, raw and denoised, per window
    (with its mean), and the azimuth of every pair of consecutive windows with its 1-sigma bar
    beside the solution (and the simulated truth). One size for any number of positions.

    Raises
    ------
    HostConfigError
        matplotlib is not installed, or the file cannot be written.
    """
    plt = pyplot()
    from northfinder.host.denoise import denoise

    fig, axes = plt.subplots(
        3, 1, figsize=(10, 8.5), gridspec_kw={"height_ratios": [1, 1, 1.1]}, constrained_layout=True
    )
    sub = "\n".join(textwrap.wrap(_subtitle(result, truth), 135))
    failed = result.consistent is False
    head = (f"{FAILED_MARKER}: " if failed else "") + _title(result, truth)
    fig.suptitle(
        plain_numbers(head + "\n" + sub), fontsize=10.5, color="tab:red" if failed else "black"
    )
    t0 = min(float(np.asarray(w.time_s)[0]) for w in windows) if windows else 0.0
    colours = plt.get_cmap("tab10")
    for j, name in enumerate("xy"):
        ax = axes[j]
        for i, (w, s) in enumerate(zip(windows, result.windows, strict=True)):
            t = np.asarray(w.time_s, dtype=float) - t0
            raw = np.asarray(w.gyro_dph, dtype=float)[:, j]
            c = colours(i % 10)
            ax.plot(t, raw, lw=0.3, alpha=0.35, color=c)
            if denoise_method != "none":
                ax.plot(t, denoise(raw, denoise_method), lw=1.1, color=c)
            mean = s.gyro_dph[j]
            ax.hlines(mean, t[0], t[-1], colors="k", lw=1.0)
            ax.annotate(
                f"{i + 1}", (0.5 * (t[0] + t[-1]), mean), textcoords="offset points",
                xytext=(0, 4), ha="center", fontsize=7,
            )  # fmt: skip
        # Scale to the means and their spread, not to single spikes.
        means = np.array([s.gyro_dph[j] for s in result.windows])
        sem = max(max((s.gyro_sem_dph[j] for s in result.windows), default=0.0), 1e-6)
        spread = np.concatenate(
            [np.percentile(np.asarray(w.gyro_dph, dtype=float)[:, j], [1, 99]) for w in windows]
        )
        lo, hi = min(spread.min(), means.min() - 5 * sem), max(spread.max(), means.max() + 5 * sem)
        pad = 0.05 * (hi - lo or 1.0)
        ax.set_ylim(lo - pad, hi + pad)
        label = "raw (thin)" + ("" if denoise_method == "none" else f", {denoise_method} (thick)")
        ax.set_ylabel(f"gyro {name}, deg/h")
        ax.set_title(f"gyro {name}: {label}, window mean (black), window number above", fontsize=9)
        ax.grid(True, alpha=0.3)
    axes[1].set_xlabel("device time since the first window, s")
    axes[0].sharex(axes[1])
    ax = axes[2]
    pairs = pairwise_solutions(result.windows, result.latitude_deg)
    if pairs:
        x = np.arange(1, len(pairs) + 1)
        ref = result.azimuth_deg
        y = np.array([ref + angle_error(p.azimuth_deg, ref) for p in pairs])
        err = [0.0 if p.sigma_deg is None else p.sigma_deg for p in pairs]
        ax.errorbar(x, y, yerr=err, fmt="o", capsize=3, label="pair azimuth ± 1σ")
        ax.set_xticks(
            x,
            [
                f"{p.first + 1}-{p.first + 2}\n"
                f"{heading_text(result.windows[p.first].encoder_deg, 0)}→"
                f"{heading_text(result.windows[p.first + 1].encoder_deg, 0)}°"
                for p in pairs
            ],
            fontsize=8,
        )
        ax.set_xlim(0.5, len(pairs) + 0.5)
    ax.axhline(result.azimuth_deg, color="k", lw=1.0, label="solution")
    if result.sigma_deg is not None:
        ax.axhspan(
            result.azimuth_deg - result.sigma_deg, result.azimuth_deg + result.sigma_deg,
            color="k", alpha=0.1, label="solution ± 1σ",
        )  # fmt: skip
    if truth is not None:
        tv = result.azimuth_deg + angle_error(truth["azimuth_deg"], result.azimuth_deg)
        ax.axhline(tv, color="tab:red", lw=1.0, ls="--", label="simulated truth")
    ax.set_xlabel("pair of consecutive windows (positions, encoder angles)")
    ax.set_ylabel("azimuth, deg")
    if failed:
        ax.set_title(
            "azimuth of each pair of consecutive windows: they disagree beyond their noise, "
            "the heading is not vouched for",
            fontsize=9,
            color="tab:red",
        )
    else:
        ax.set_title("azimuth of each pair of consecutive windows", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    save_figure(fig, path)
