"""``find --spin``: north finding on a continuously turning table (protocol 1.1), on every link.

The options, the run (through :func:`northfinder.host.procedure.find_north_spin`) and how the
result is shown (text and JSON); ``find`` calls :func:`run` when ``--spin`` is given.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from northfinder.cli.argtypes import bounded_float, finite_float
from northfinder.cli.output import dumps, plain_numbers
from northfinder.cli.plots import pyplot, save_figure
from northfinder.config import SpinConfig
from northfinder.host.consistency import FAILED_MARKER
from northfinder.host.errors import HostConfigError
from northfinder.host.heading import heading_text

#: Longest spin, s.
MAX_SPIN_S = 86_400.0


def _rate(text: str) -> float:
    value = finite_float(text)
    if value == 0.0:
        raise argparse.ArgumentTypeError("must be a non-zero rate in deg/s (either sign)")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``--spin``, ``--spin-time``, ``--spin-drift``, in the parser's ``plan`` group."""
    groups = [g for g in p._action_groups if g.title == "plan"]
    g: Any = groups[0] if groups else p
    g.add_argument(
        "--spin", type=_rate, default=None, metavar="RATE_DPS",
        help="turn at RATE deg/s instead (protocol 1.1)",
    )  # fmt: skip
    g.add_argument(
        "--spin-time", type=bounded_float(0.0, MAX_SPIN_S, "s", open_lo=True), default=None,
        metavar="SECONDS", help="spin seconds (default: whole turns, >= 60 s)",
    )  # fmt: skip
    g.add_argument("--spin-drift", action="store_true", help="spin: also fit a gyro drift")


def spin_seconds(args: argparse.Namespace) -> float:
    """``--spin-time``, or the fewest whole turns lasting at least :data:`DEFAULT_SPIN_MIN_S`."""
    return SpinConfig(args.spin, args.spin_time).seconds


def check(args: argparse.Namespace, plan_defaults: dict[str, Any]) -> None:
    """Refuse the options a spin does not use (they would be ignored)."""
    if args.spin is None:
        for name in ("spin_time", "spin_drift"):
            if getattr(args, name):
                raise HostConfigError(f"--{name.replace('_', '-')}: needs --spin RATE_DPS")
        return
    for name, default in plan_defaults.items():
        if getattr(args, name, default) != default:
            raise HostConfigError(
                f"--{name}: a stop-and-go plan option; with --spin the table turns instead"
            )
    if getattr(args, "record", None):
        raise HostConfigError(
            "--record: not available with --spin in this version (northfinder record "
            "--spin writes a spin recording)"
        )


def run(
    args: argparse.Namespace, record_to: str | None = None
) -> tuple[Any, dict[str, Any] | None, dict[str, Any]]:
    """Open the device, spin, solve; return (SpinFind, truth, device identity).

    With ``record_to``, a run that ends early (an interruption, an error) writes the samples
    received to that recording, marked ``interrupted`` (:func:`save`), and the line that
    reports the ending says where."""
    from northfinder import session
    from northfinder.cli.measure import find_config
    from northfinder.cli.progress import PlanProgress

    config = find_config(args)
    bar = PlanProgress(enabled=record_to is not None, label=args.command or "record")

    def keep_partial(exc: BaseException, spun: session.SpinMeasured) -> str:
        assert record_to is not None
        return _save_partial(
            record_to, args, exc, spun.latitude_deg, spun.latitude_source,
            None if spun.truth is None else spun.truth.as_dict(), spun.device,
        )  # fmt: skip

    try:
        spun = session.find_spin(
            config, progress=_spin_progress(bar),
            on_ending=None if record_to is None else keep_partial,
        )  # fmt: skip
    finally:
        bar.close()
    return spun.found, None if spun.truth is None else spun.truth.as_dict(), spun.device


def _spin_progress(bar: Any) -> Any:
    def report(p: Any) -> None:
        if bar.mode == "lines":
            print(f"{bar.label}: {p.phase}", file=bar.stream, flush=True)

    return report


def _partial_window(exc: BaseException) -> Any:
    """The samples an error or interruption during the spin carried (``partial_window``)."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        window = getattr(current, "partial_window", None)
        if window is not None:
            return window
        seen.add(id(current))
        current = current.__context__ or current.__cause__
    return None


def _save_partial(
    path: str,
    args: argparse.Namespace,
    exc: BaseException,
    latitude: float,
    source: str,
    truth: dict[str, Any] | None,
    identity: dict[str, Any],
) -> str:
    """Write the samples of a spin that ended early; the clause that says what was kept."""
    from northfinder.host.errors import HostError

    window = _partial_window(exc)
    if window is None or len(window.counter) == 0:
        return "no sample received: nothing written"
    try:
        rec, where = save(path, args, window, latitude, source, truth, identity, "interrupted")
    except HostError as error:
        return f"the spin's samples were not kept: {error}"
    held = str(rec.partial).split(": ", 1)[-1]  # "6000 of 12000 samples (...)"
    return f"kept {held} in {where}, marked interrupted"


def _error(sol: Any, truth: dict[str, Any] | None) -> float | None:
    if truth is None:
        return None
    return (sol.azimuth_deg - truth["azimuth_deg"] + 180.0) % 360.0 - 180.0


def text(found: Any, truth: dict[str, Any] | None) -> str:
    sol = found.solution
    lines = [
        f"azimuth {heading_text(sol.azimuth_deg, 4)} deg +- {sol.sigma_deg:.4f} (1 sigma), "
        "clockwise from true north",
        f"pitch {sol.pitch_deg:.4f} deg, roll {sol.roll_deg:.4f} deg",
        f"spin {sol.rate_dps:+.3f} deg/s for {sol.duration_s:.1f} s ({sol.sweep_deg / 360.0:+.2f} "
        f"turns, {sol.samples} samples), latitude {found.latitude_deg:g} deg"
        + (f" from {found.latitude_source}" if found.latitude_source else ""),
    ]
    if sol.halves_deg is not None:
        verdict = "consistent" if sol.consistent else "NOT consistent"
        first, second = (heading_text(a, 4) for a in sol.halves_deg)
        lines.append(f"halves {first}, {second} deg: {verdict}")
    err = _error(sol, truth)
    if truth is not None and err is not None:
        lines.append(
            f"truth   {heading_text(truth['azimuth_deg'], 4)} deg (pitch {truth['pitch_deg']:g}, "
            f"roll {truth['roll_deg']:g}); error {err:+.4f} deg"
            + (f"; seed {truth['seed']}" if "seed" in truth else "")
        )
    lines += [f"note: {n}" for n in notes(sol)]  # as find prints its notes
    return plain_numbers("\n".join(lines))


def notes(sol: Any) -> list[str]:
    """The result's warnings (text and JSON): when the halves disagree, find's marker for a
    heading its data cannot vouch for (exit 3), so a script or a reader does not take it as good."""
    if sol.consistent is not False:
        return []
    return [
        f"{FAILED_MARKER}: the two halves disagree beyond their noise (more than 3 "
        "sigma of their difference); the azimuth may be wrong by more than its noise: sigma "
        f"scaled x{sol.sigma_scale:.2f}; check for disturbances during the spin (a knock, a "
        "rate change, a bias step)"
    ]


def as_json(
    found: Any,
    truth: dict[str, Any] | None,
    device: dict[str, Any] | None,
    command: str = "find",
    **extra: Any,
) -> str:
    from northfinder.host.results import envelope

    sol = found.solution
    body: dict[str, Any] = {
        "azimuth_deg": sol.azimuth_deg,
        "sigma_deg": sol.sigma_deg,
        "pitch_deg": sol.pitch_deg,
        "roll_deg": sol.roll_deg,
        "consistent": sol.consistent,
        "notes": notes(sol),
        "solver": "spin",
        "latitude_deg": found.latitude_deg,
        "latitude_source": found.latitude_source,
        "spin": sol.to_dict(),
    }
    err = _error(sol, truth)
    if truth is not None:
        body["truth"] = truth
        body["error_deg"] = err
    body.update(extra)
    return dumps(envelope(command, device, body))


def save(
    path: str,
    args: argparse.Namespace,
    window: Any,
    latitude_deg: float,
    latitude_source: str,
    truth: Any,
    identity: Any,
    status: str = "complete",
) -> tuple[Any, str]:
    """Write a spin recording: its one window of samples, and in the metadata what solves it
    again (latitude, sample rate, ``spin``: rate, time, drift) and ``status``. A spin that
    ended early never replaces an existing file: it goes beside it (``run.partial.csv``).
    Returns the recording and where it went (with a note of the file left as it was)."""
    import os
    from pathlib import Path

    from northfinder.host.recording import RecordedWindow, Recording, partial_name
    from northfinder.host.results import utc_now

    meta: dict[str, Any] = {
        "latitude_deg": latitude_deg,
        "latitude_source": latitude_source,
        "sample_rate_hz": float(window.sample_rate_hz),
        "spin": {
            "rate_dps": float(args.spin),
            "spin_s": spin_seconds(args),
            "drift": bool(args.spin_drift),
        },
        "created_utc": utc_now(),
        "device": identity,
        "status": status,
    }
    if truth is not None:
        meta["truth"] = truth
    recording = Recording((RecordedWindow.from_window(window, 0.0),), meta)
    target = Path(path)
    where = str(target)
    if status != "complete" and os.path.lexists(target):
        target = partial_name(target)
        where = f"{target} ({path}, the earlier recording, left as it was)"
    recording.save(target)
    return recording, where


def solve_recording(rec: Any, latitude: float | None, drift: bool | None) -> Any:
    """The spin solution of a spin recording (``drift`` None: as recorded)."""
    from northfinder.host.procedure import SpinFind
    from northfinder.host.spin import solve_spin, spin_samples

    if latitude is None and "latitude_deg" not in rec.meta:
        raise HostConfigError("--latitude: the recording has no latitude_deg; give --latitude")
    lat = float(rec.meta["latitude_deg"] if latitude is None else latitude)
    spin = rec.meta.get("spin")
    if not isinstance(spin, dict):
        raise HostConfigError("the recording's spin entry must be a table of key = value")
    fit_drift = bool(spin.get("drift", False)) if drift is None else drift
    (w,) = rec.windows[:1]
    data = spin_samples(w.gyro_dph, w.accel_mps2, w.table_deg, w.counter,
                        float(rec.meta["sample_rate_hz"]), w.validity)  # fmt: skip
    source = "--latitude" if latitude is not None else "the recording"
    return SpinFind(solve_spin(data, latitude_deg=lat, drift=fit_drift), w, lat, source)


#: Bins of table angle per turn in the plot's demodulated panel.
PLOT_BINS_PER_TURN = 36
#: Most raw samples drawn per gyro (every k-th sample beyond it).
PLOT_MAX_POINTS = 8000


def plot(
    path: str,
    found: Any,
    truth: dict[str, Any] | None = None,
    sample_rate_hz: float | None = None,
) -> None:
    """The figure of a spin: the x and y gyro over the table angle with the fitted sinusoids;
    the gyros demodulated (bias removed, turned back to table angle 0) in bins of table angle,
    which the fit says are the Earth rate at every angle; the azimuths of the two halves with
    their 1-sigma bars beside the solution (and the simulated truth). ``sample_rate_hz``: of a
    recorded window (which does not carry it); a live window's own by default.

    Raises
    ------
    HostConfigError
        matplotlib is not installed.
    OutputError
        The file cannot be written.
    """
    import numpy as np

    from northfinder.driver.protocol.units import DPH
    from northfinder.host.spin import fitted_rates, spin_samples

    plt = pyplot()
    sol, w = found.solution, found.window
    rate_hz = float(w.sample_rate_hz if sample_rate_hz is None else sample_rate_hz)
    data = spin_samples(w.gyro_dph, w.accel_mps2, w.table_deg, w.counter, rate_hz, w.validity)
    model, demod, h = fitted_rates(data, sol, found.latitude_deg)
    angle = np.degrees(np.unwrap(data.mu1_rad))
    angle -= angle[0] - math.degrees(data.mu1_rad[0] - data.mu0_rad[0]) * 0.5
    gyro = data.gyro_rps[:, :2] / DPH
    model, demod, h = model / DPH, demod / DPH, h / DPH
    step = max(1, len(angle) // PLOT_MAX_POINTS)

    fig, axes = plt.subplots(3, 1, figsize=(10, 9), constrained_layout=True,
                             gridspec_kw={"height_ratios": [1.2, 1, 0.9]})  # fmt: skip
    failed = sol.consistent is False
    err = _error(sol, truth)
    head = (
        (f"{FAILED_MARKER}: " if failed else "")
        + f"azimuth {heading_text(sol.azimuth_deg, 3)} ± {sol.sigma_deg:.3f}° (1σ)"
        + ("" if err is None else f", error {err:+.3f}° against the simulated truth")
    )
    sub = (
        f"spin {sol.rate_dps:+.2f} deg/s for {sol.duration_s:.1f} s ({sol.sweep_deg / 360.0:+.2f} "
        f"turns, {sol.samples} samples), pitch {sol.pitch_deg:.3f}°, roll {sol.roll_deg:.3f}°, "
        f"latitude {found.latitude_deg:g}°" + (", drift fitted" if sol.drift else "")
        + (f", sensor {truth['sensor']}" if truth and "sensor" in truth else "")
    )  # fmt: skip
    fig.suptitle(plain_numbers(head + "\n" + sub), fontsize=10.5,
                 color="tab:red" if failed else "black")  # fmt: skip
    colours = ("tab:blue", "tab:orange")

    ax = axes[0]
    for j, name in enumerate("xy"):
        ax.plot(angle[::step], gyro[::step, j], lw=0, marker=".", ms=1.0, alpha=0.3,
                color=colours[j])  # fmt: skip
        ax.plot(angle, model[:, j], lw=1.6, color=colours[j], label=f"gyro {name}: fit")
    lo, hi = np.percentile(gyro, [1, 99])
    lo, hi = min(lo, model.min()), max(hi, model.max())
    pad = 0.05 * (hi - lo or 1.0)
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_ylabel("gyro, deg/h")
    ax.set_title("gyro x and y over the table angle: samples (dots) and the fitted "
                 "Earth rate + bias (line)", fontsize=9)  # fmt: skip
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(True, alpha=0.3)

    ax = axes[1]
    turns = abs(sol.sweep_deg) / 360.0
    nbins = int(min(max(8, round(PLOT_BINS_PER_TURN * turns)), max(8, len(angle) // 8)))
    edges = np.linspace(angle.min(), angle.max(), nbins + 1)
    which = np.clip(np.searchsorted(edges, angle, side="right") - 1, 0, nbins - 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    for j, name in enumerate("xy"):
        count = np.bincount(which, minlength=nbins).astype(float)
        total = np.bincount(which, weights=demod[:, j], minlength=nbins)
        sq = np.bincount(which, weights=demod[:, j] ** 2, minlength=nbins)
        keep = count >= 2
        mean = total[keep] / count[keep]
        var = np.maximum(sq[keep] / count[keep] - mean**2, 0.0) * count[keep] / (count[keep] - 1)
        label = f"gyro {name} demodulated, bin mean ± 1σ"
        ax.errorbar(centres[keep], mean, yerr=np.sqrt(var / count[keep]), fmt="o", ms=3,
                    capsize=2, color=colours[j], label=label)  # fmt: skip
        ax.axhline(
            h[j], color=colours[j], lw=1.2, ls="--", label=f"fitted h_{name} {h[j]:.3f} deg/h"
        )
    ax.set_ylabel("Earth rate at table angle 0, deg/h")
    ax.set_xlabel("table angle turned since the first sample, deg")
    ax.set_title("the gyros less their fitted bias, turned back to table angle 0: flat where the "
                 "model holds (a once-per-turn error shows as a ripple)", fontsize=9)  # fmt: skip
    ax.legend(fontsize=8, loc="best", ncol=2)
    ax.grid(True, alpha=0.3)
    axes[0].sharex(axes[1])

    ax = axes[2]
    ref = sol.azimuth_deg
    if sol.halves_deg is not None and sol.halves_sigma_deg is not None:
        y = [ref + (a - ref + 180.0) % 360.0 - 180.0 for a in sol.halves_deg]
        ax.errorbar([1, 2], y, yerr=list(sol.halves_sigma_deg), fmt="o", capsize=3,
                    label="half azimuth ± 1σ")  # fmt: skip
    ax.set_xticks([1, 2], ["first half", "second half"], fontsize=8)
    ax.set_xlim(0.5, 2.5)
    ax.axhline(ref, color="k", lw=1.0, label="solution")
    ax.axhspan(ref - sol.sigma_deg, ref + sol.sigma_deg, color="k", alpha=0.1,
               label="solution ± 1σ")  # fmt: skip
    if truth is not None and err is not None:
        ax.axhline(ref - err, color="tab:red", lw=1.0, ls="--", label="simulated truth")
    ax.set_ylabel("azimuth, deg")
    ax.set_title(
        "azimuth of each half of the samples alone"
        + (": they disagree beyond their noise" if failed else ""),
        fontsize=9, color="tab:red" if failed else "black",
    )  # fmt: skip
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, alpha=0.3)
    save_figure(fig, path)
