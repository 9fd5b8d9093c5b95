"""``find``: faults injected through the control channel during ``find`` (a section of
``bench_robustness.py``)."""

from __future__ import annotations

import argparse
import math
import threading
import time
from typing import Any

#: Control-channel faults injected during a run of ``find`` (each with the request that clears it
#: a moment later, or None when it stays).
FIND_FAULTS: list[tuple[str, dict[str, Any], dict[str, Any] | None]] = [
    ("drop 5 frames", {"op": "drop", "count": 5}, None),
    ("drop 200 frames", {"op": "drop", "count": 200}, None),
    ("corrupt 5 frames", {"op": "corrupt", "count": 5}, None),
    ("corrupt 200 frames", {"op": "corrupt", "count": 200}, None),
    ("garble 10000 (4 a frame)", {"op": "garble", "count": 10_000, "per_frame": 4}, None),
    ("skip the counter by 3", {"op": "skip_counter", "count": 3}, None),
    (
        "delay replies 0.3 s",
        {"op": "delay_replies", "seconds": 0.3},
        {"op": "delay_replies", "seconds": 0},
    ),
    ("delay replies 5 s", {"op": "delay_replies", "seconds": 5}, None),
    ("wrong result once", {"op": "wrong_result", "code": 7}, None),
    ("silent", {"op": "silent"}, None),
    ("silent 0.2 s", {"op": "silent"}, {"op": "silent", "on": False}),
    ("pause 0.2 s", {"op": "pause"}, {"op": "resume"}),
    ("stall the table", {"op": "stall"}, None),
    ("reset", {"op": "reset"}, None),
    ("bias step 0.05 deg/h x", {"op": "bias_step", "gyro_dph": [0.05, 0, 0]}, None),
    ("bias step 0.5 deg/h x", {"op": "bias_step", "gyro_dph": [0.5, 0, 0]}, None),
    ("bias step 5 deg/h y", {"op": "bias_step", "gyro_dph": [0, 5.0, 0]}, None),
    ("bias step 100 ug x", {"op": "bias_step", "accel_ug": [100.0, 0, 0]}, None),
    ("10 impulses of 50 deg/h", {"op": "impulses", "count": 10, "interval_s": 0.2}, None),
    ("vibration 35 Hz 5 deg/h", {"op": "vibration", "on": True}, None),
    ("base turned 1 deg", {"op": "set_truth", "azimuth_deg": None}, None),
    ("ARW x10", {"op": "set_sensor", "values": {"gyro.arw_dpsh": 0.015}}, None),
    ("speed x0.5", {"op": "speed", "value": 50.0}, None),
]
#: When a fault is injected: as the window of position 2 begins, or as the table leaves for it.
FIND_MOMENTS = ("acquire", "rotate")


def _find_with_fault(label: str, request: dict[str, Any], clear: dict[str, Any] | None,
                     moment: str, seed: int) -> dict[str, Any]:  # fmt: skip
    from northfinder.driver.errors import DriverError
    from northfinder.embed import RELAXED_DEVICE_OPTIONS, SimulatedInstrument
    from northfinder.firmware_sim.imu import Truth
    from northfinder.host.errors import HostError
    from northfinder.host.procedure import Plan, find_north

    truth = Truth(azimuth_deg=(37.0 * seed) % 360.0)
    plan = Plan((0.0, 180.0, 180.0, 0.0), 4.0)
    op = dict(request)
    if op["op"] == "set_truth":
        op["azimuth_deg"] = (truth.azimuth_deg + 1.0) % 360.0
    with SimulatedInstrument("paper-rlg", truth, seed=seed, speed=100, warmup_s=0,
                             control="127.0.0.1:0") as sim:  # fmt: skip
        control = sim.control
        assert control is not None
        try:
            with sim.open_device(**RELAXED_DEVICE_OPTIONS) as dev:
                fired: list[float] = []

                def progress(p: Any) -> None:
                    if p.phase == moment and p.position == 2 and not fired:
                        fired.append(time.monotonic())
                        name = op.pop("op")
                        control.call(name, **op)
                        if clear is not None:
                            threading.Timer(0.2, lambda: control.call(**clear)).start()

                result, _ = find_north(dev, plan, truth.latitude_deg, progress=progress)
        except (DriverError, HostError) as exc:
            return {"fault": label, "moment": moment, "outcome": "error",
                    "detail": f"{type(exc).__name__}: {str(exc)[:90]}"}  # fmt: skip
        sim.check()
        # The heading is judged against where the instrument stands when the result is given
        # (a base turned during the run stands at its new heading).
        final = float(control.call("get_truth")["truth"]["azimuth_deg"])
    err = (result.azimuth_deg - final + 180.0) % 360.0 - 180.0
    z = abs(err) / result.sigma_deg if result.sigma_deg else math.inf
    warned = result.consistent is False or any("impulsive" in n for n in result.notes)
    if warned:
        outcome = "warning"
    elif z <= 3.0:
        outcome = "right"
    else:
        outcome = "SILENTLY WRONG"
    return {"fault": label, "moment": moment, "outcome": outcome, "error_deg": err,
            "sigma_deg": result.sigma_deg, "z": z,
            "detail": next((n for n in result.notes if "CONSISTENCY" in n or "impulsive" in n), "")}  # fmt: skip


def find_faults(args: argparse.Namespace) -> dict[str, Any]:
    """Every control-channel fault injected during ``find`` (0,180,180,0, 4 s windows,
    paper-rlg, embedded simulator at 100x): a named error, a stated warning, or a heading within
    3 sigma of where the instrument stands at the end; never a wrong heading without a word."""
    rows = []
    for i, (label, request, clear) in enumerate(FIND_FAULTS):
        for moment in FIND_MOMENTS:
            rows.append(_find_with_fault(label, request, clear, moment, seed=100 + i))
    print("faults injected during find (0,180,180,0, 4 s windows, paper-rlg, 100x), at the start "
          "of window 2 (acquire) or of the move to it (rotate)")  # fmt: skip
    print(f"{'fault':<26} {'moment':<8} {'outcome':<15} {'error deg':>10} {'z':>6}  detail")
    for r in rows:
        e = f"{r['error_deg']:+10.4f}" if "error_deg" in r else f"{'-':>10}"
        z = f"{r['z']:6.1f}" if "z" in r else f"{'-':>6}"
        print(f"{r['fault']:<26} {r['moment']:<8} {r['outcome']:<15} {e} {z}  {r['detail'][:110]}")
    tally = {
        k: sum(r["outcome"] == k for r in rows)
        for k in ("error", "warning", "right", "SILENTLY WRONG")
    }
    print(f"runs {len(rows)}: {tally}")
    return {"rows": rows, "tally": tally}
