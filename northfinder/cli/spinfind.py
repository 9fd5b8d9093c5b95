"""``find --spin``: north finding on a continuously turning table (protocol 1.1), on every link.

The options, the run (through :func:`northfinder.host.spin.find_north_spin`) and how the result
is shown (text and JSON); ``find`` calls :func:`run` when ``--spin`` is given.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from northfinder.cli.common import (
    bounded_float,
    dumps,
    finite_float,
    latitude_source,
    plain_numbers,
    sim_latitude,
)
from northfinder.host.errors import HostConfigError

#: Default spin time: the fewest whole turns that last at least this long, s.
DEFAULT_SPIN_MIN_S = 60.0
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
    if args.spin_time is not None:
        return float(args.spin_time)
    turn = 360.0 / abs(args.spin)
    return math.ceil(DEFAULT_SPIN_MIN_S / turn - 1e-9) * turn


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
    for name in ("record", "plot"):
        if getattr(args, name, None):
            raise HostConfigError(
                f"--{name}: not available with --spin in this version (northfinder record "
                "--spin writes a spin recording)"
            )


def run(args: argparse.Namespace) -> tuple[Any, dict[str, Any] | None, dict[str, Any]]:
    """Open the device, spin, solve; return (SpinFind, truth, device identity)."""
    from northfinder.cli.measure import check_arguments, open_device
    from northfinder.host.procedure import find_north_spin
    from northfinder.host.results import device_identity

    check_arguments(args)
    latitude = sim_latitude(args) if args.sim else float(args.latitude)
    with open_device(args) as (device, truth):
        identity = device_identity(
            device.identity,
            simulated=bool(args.sim),
            sensor=None if truth is None else truth.get("sensor"),
        )
        found = find_north_spin(
            device,
            args.spin,
            spin_seconds(args),
            latitude,
            drift=args.spin_drift,
            warmup_timeout_s=args.timeout,
            latitude_source=latitude_source(args, args.sim),
        )
    return found, truth, identity


def _error(sol: Any, truth: dict[str, Any] | None) -> float | None:
    if truth is None:
        return None
    return (sol.azimuth_deg - truth["azimuth_deg"] + 180.0) % 360.0 - 180.0


def text(found: Any, truth: dict[str, Any] | None) -> str:
    sol = found.solution
    lines = [
        f"azimuth {sol.azimuth_deg:.4f} deg +- {sol.sigma_deg:.4f} (1 sigma), clockwise from "
        "true north",
        f"pitch {sol.pitch_deg:.4f} deg, roll {sol.roll_deg:.4f} deg",
        f"spin {sol.rate_dps:+.3f} deg/s for {sol.duration_s:.1f} s ({sol.sweep_deg / 360.0:+.2f} "
        f"turns, {sol.samples} samples), latitude {found.latitude_deg:g} deg"
        + (f" from {found.latitude_source}" if found.latitude_source else ""),
    ]
    if sol.halves_deg is not None:
        verdict = "consistent" if sol.consistent else "NOT consistent"
        lines.append(f"halves {sol.halves_deg[0]:.4f}, {sol.halves_deg[1]:.4f} deg: {verdict}")
    err = _error(sol, truth)
    if truth is not None and err is not None:
        lines.append(
            f"truth   {truth['azimuth_deg']:.4f} deg (pitch {truth['pitch_deg']:g}, roll "
            f"{truth['roll_deg']:g}); error {err:+.4f} deg"
            + (f"; seed {truth['seed']}" if "seed" in truth else "")
        )
    if sol.consistent is False:
        lines.append("note: the two halves disagree beyond their noise: check for disturbances")
    return plain_numbers("\n".join(lines))


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


def save(path: str, args: argparse.Namespace, found: Any, truth: Any, identity: Any) -> Any:
    """Write a spin recording: its one window of samples, and in the metadata what solves it
    again (latitude, sample rate, ``spin``: rate, time, drift)."""
    from northfinder.host.recording import RecordedWindow, Recording
    from northfinder.host.results import utc_now

    w = found.window
    meta: dict[str, Any] = {
        "latitude_deg": found.latitude_deg,
        "latitude_source": found.latitude_source,
        "sample_rate_hz": float(w.sample_rate_hz),
        "spin": {
            "rate_dps": float(args.spin),
            "spin_s": spin_seconds(args),
            "drift": bool(args.spin_drift),
        },
        "created_utc": utc_now(),
        "device": identity,
    }
    if truth is not None:
        meta["truth"] = truth
    recording = Recording((RecordedWindow.from_window(w, 0.0),), meta)
    recording.save(path)
    return recording


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
