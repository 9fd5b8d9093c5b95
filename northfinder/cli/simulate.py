"""``northfinder simulate``: generate windows from the simulated instrument and summarise them.

A look at the physics alone (no wire, no driver): for each table position it prints the mean gyro
and accelerometer readings of one window beside the noise-free values.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from northfinder import session
from northfinder.cli.argtypes import bounded_float
from northfinder.cli.options import add_positions_argument, add_sensor_argument, add_truth_arguments
from northfinder.cli.output import dumps, say
from northfinder.cli.simulated import simulated
from northfinder.driver.protocol.units import DPH, UG
from northfinder.firmware_sim.earth import mat_table
from northfinder.firmware_sim.imu import Instrument, body_rates
from northfinder.host.heading import heading_text
from northfinder.host.results import envelope
from northfinder.simwindows import MAX_RATE_HZ, MAX_WINDOW_S, simulator_identity


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_sensor_argument(p)
    add_truth_arguments(p)
    add_positions_argument(p)
    p.add_argument(
        "--window",
        type=bounded_float(0.0, MAX_WINDOW_S, "s", open_lo=True),
        default=10.0,
        help=f"window length, s, up to {MAX_WINDOW_S:g} (default: 10)",
    )
    p.add_argument(
        "--rate",
        type=bounded_float(0.0, MAX_RATE_HZ, "Hz", open_lo=True),
        default=200.0,
        help=f"sample rate, Hz, up to {MAX_RATE_HZ:g} (default: 200)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args: argparse.Namespace) -> int:
    sim, latitude = simulated(args)
    truth, seed, rng = session.draw_truth(sim, latitude)
    spec = session.sensor_spec(sim)
    ins = Instrument(spec, truth, rng, sample_rate_hz=args.rate)
    omega_b, f_b = body_rates(
        truth.azimuth_deg, truth.pitch_deg, truth.roll_deg, truth.latitude_deg
    )
    rows = []
    for mu in args.positions:
        end = ins.table.move_to(ins.time_s, mu)
        ins.advance(max(end - ins.time_s, 0.0) + spec.table.settle_s)
        w = ins.advance(args.window)
        c = mat_table(math.radians(mu))
        rows.append(
            {
                "table_deg": float(np.mean(w.table_deg)),
                "samples": len(w),
                "gyro_dph": (w.gyro_rps.mean(0) / DPH).tolist(),
                "gyro_true_dph": (c @ omega_b / DPH).tolist(),
                "gyro_std_dph": (w.gyro_rps.std(0) / DPH).tolist(),
                "accel_ug": (w.accel_mps2.mean(0) / UG).tolist(),
                "accel_true_ug": (c @ f_b / UG).tolist(),
            }
        )
    if args.json:
        body = {"sensor": spec.name, "seed": seed, "truth": truth.__dict__, "windows": rows}
        say(dumps(envelope("simulate", simulator_identity(spec.name), body)))
        return 0
    say(
        f"sensor {spec.name}; truth azimuth {heading_text(truth.azimuth_deg, 4)} deg, latitude {truth.latitude_deg:g} deg, "
        f"pitch {truth.pitch_deg:g} deg, roll {truth.roll_deg:g} deg; {args.window:g} s windows at {args.rate:g} Hz; "
        f"seed {seed}"
    )
    say(f"{'table deg':>10} {'gyro x/y/z deg/h (noise-free)':>50} {'accel x/y/z ug':>36}")
    for r in rows:
        g = " ".join(
            f"{m:8.4f}({t:8.4f})" for m, t in zip(r["gyro_dph"], r["gyro_true_dph"], strict=True)
        )
        a = " ".join(f"{m:11.1f}" for m in r["accel_ug"])
        say(f"{r['table_deg']:10.4f} {g} {a}")
    say(f"simulated {ins.time_s:.1f} s")
    return 0
