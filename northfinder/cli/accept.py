"""``northfinder accept --datasheet FILE``: a unit's acceptance test against its datasheet.

Stages, each kept in the output folder (``-o DIR``) so that ``--resume`` skips those done:
the conformance checks the datasheet names; the time from RESET to READY and a static
recording (``--static-s``) whose IEEE 952 Allan fit judges the noise lines; ``--runs``
north-finding runs at ``--orientations`` table orientations that judge the repeatability.
Each line is PASS, FAIL or NOT RESOLVED (the data cannot decide it: the line says how long a
record would). ``DIR/report.html`` is the report (one self-contained page); ``--junit`` and
``--json`` for machines. Exit status: 0 every line passed, 1 a line failed, 4 no line failed
but one is not resolved. ``--datasheet-from PRESET --margin X`` makes a datasheet of a sensor
preset (``--write-datasheet FILE`` writes it; without a link that is all). The runs follow the
datasheet's plan, ``--plan ANGLES:SECONDS`` or the planner's best within ``--budget SECONDS``
(:func:`choose_plan`), stated with its predicted repeatability; ``--batch UNITS.TOML`` accepts
several units (:mod:`northfinder.cli.accept_batch`).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from northfinder.cli import measure
from northfinder.cli.accept_batch import run_batch, stage_line, verdict_status
from northfinder.cli.argtypes import bounded_float, bounded_int
from northfinder.cli.files import check_output_path
from northfinder.cli.links import bus_given
from northfinder.cli.output import dumps, say
from northfinder.cli.simulated import load_sensor, run_seed
from northfinder.host.errors import HostConfigError

#: Shortest default length of the static recording, s (device time: virtual seconds with --sim);
#: the default is the length that decides the datasheet's bias instability, within these bounds.
STATIC_S = 1800.0
#: Longest default length of the static recording, s.
STATIC_DEFAULT_MAX_S = 2 * 3600.0
#: Longest static recording, s: one still window held in memory (8 h at 200 Hz: 5.8 M samples).
MAX_STATIC_S = 8 * 3600.0
RUNS = 16
ORIENTATIONS = 4
MARGIN = 2.0
#: Longest plan time ``--budget`` takes, s (the planner's longest search).
MAX_BUDGET_S = 4 * 3600.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("datasheet")
    x = g.add_mutually_exclusive_group()
    x.add_argument("--datasheet", metavar="FILE", help="the datasheet TOML (docs/accept.md)")
    x.add_argument(
        "--datasheet-from",
        metavar="PRESET|FILE",
        help="make the datasheet of a sensor preset or file: its figures times --margin",
    )
    g.add_argument(
        "--margin",
        type=bounded_float(1.0, 1000.0),
        default=None,
        metavar="X",
        help=f"--datasheet-from: limits are the sensor's figures times X (default {MARGIN:g})",
    )
    g.add_argument(
        "--write-datasheet",
        metavar="FILE",
        help="write the datasheet made by --datasheet-from to FILE (without a link: only that)",
    )
    g = p.add_argument_group("stages")
    g.add_argument(
        "-o",
        "--output",
        metavar="DIR",
        default="acceptance",
        help="folder of the recordings and the report (default ./acceptance)",
    )
    g.add_argument(
        "--static-s",
        type=bounded_float(10.0, MAX_STATIC_S, "s"),
        default=None,
        metavar="SECONDS",
        help="length of the static recording, device seconds (default: the length that decides "
        f"the datasheet's gyro bias instability beside its ARW, {STATIC_S:g} to "
        f"{STATIC_DEFAULT_MAX_S:g})",
    )
    g.add_argument(
        "--runs",
        type=bounded_int(2, 1000),
        default=RUNS,
        metavar="N",
        help=f"north-finding runs (default {RUNS})",
    )
    g.add_argument(
        "--orientations",
        type=bounded_int(1, 36),
        default=ORIENTATIONS,
        metavar="K",
        help=f"table orientations the runs take in turn, 360/K apart (default {ORIENTATIONS})",
    )
    _add_plan_arguments(g)
    g.add_argument("--resume", action="store_true", help="keep the stages already in DIR")
    g.add_argument(
        "--time-scale",
        type=bounded_float(0.0, 10_000.0, open_lo=True),
        default=1.0,
        metavar="S",
        help="the unit's seconds per wall second, for the conformance checks' timing (a "
        "simulator's --speed; default 1)",
    )
    p.add_argument(
        "--batch",
        metavar="UNITS.TOML",
        help="accept several units, each named with its link in the file (docs/accept.md): a "
        "folder each in -o DIR, and DIR/index.html the summary; exit status the worst verdict",
    )
    p.add_argument("--junit", metavar="FILE", help="also write JUnit XML, a case per line")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    measure.add_device_arguments(p)


def _add_plan_arguments(g: Any) -> None:
    """``--plan`` and ``--budget``: the plan of the north-finding runs."""
    g.add_argument(
        "--plan",
        metavar="ANGLES:SECONDS",
        help="the runs' plan: table angles and seconds per position, as find's --positions "
        "and --window, e.g. 0,90,180,270:20 (default: the datasheet's plan)",
    )
    g.add_argument(
        "--budget",
        type=bounded_float(1.0, MAX_BUDGET_S, "s"),
        default=None,
        metavar="SECONDS",
        help="the runs' plan: the planner's best stop-and-go plan within SECONDS of plan time "
        "for the unit's sensor at the datasheet's latitude",
    )


def _datasheet(args: argparse.Namespace) -> Any:
    """The datasheet of ``--datasheet`` or ``--datasheet-from``."""
    from northfinder.host.acceptance import datasheet_from_sensor, load_datasheet

    if args.datasheet:
        if args.margin is not None:
            raise HostConfigError("--margin: applies to --datasheet-from, not to --datasheet")
        return load_datasheet(args.datasheet)
    if args.margin is None:
        args.margin = MARGIN
    if not args.datasheet_from:
        raise HostConfigError("give --datasheet FILE or --datasheet-from PRESET")
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG
    from northfinder.host.acceptance import same_angle_pairs
    from northfinder.host.accuracy import predict, window_change_dph
    from northfinder.host.plan import DEFAULT_POSITIONS_DEG, Plan
    from northfinder.simwindows import error_model

    spec = load_sensor(args.datasheet_from)
    plan = Plan(tuple(DEFAULT_POSITIONS_DEG), 10.0, 0.0, "none", "auto")
    latitude = DEFAULT_LATITUDE_DEG if args.latitude is None else args.latitude
    model = error_model(spec)
    sigma = predict(model, plan, latitude, warmup_s=measure.SIM_WARMUP_S).sigma_deg
    pairs = same_angle_pairs(plan.positions_deg)
    repeat = window_change_dph(model, plan, pairs, warmup_s=measure.SIM_WARMUP_S) if pairs else None
    return datasheet_from_sensor(
        spec.to_dict(),
        args.margin,
        positions_deg=plan.positions_deg,
        window_s=plan.window_s,
        latitude_deg=latitude,
        predicted_sigma_deg=sigma,
        time_to_ready_s=measure.SIM_WARMUP_S + 10.0,
        protocol_version="1.1",
        conformance=("*",),
        source=f"--datasheet-from {args.datasheet_from} --margin {args.margin:g}",
        predicted_bias_repeatability_dph=repeat,
    )


def _link_given(args: argparse.Namespace) -> bool:
    """Whether a unit's link is given on the command line."""
    return bool(args.sim or args.serial or bus_given(args))


def run(args: argparse.Namespace) -> int:
    from northfinder.host.acceptance import datasheet_toml

    ds = _datasheet(args)
    if args.write_datasheet:
        check_output_path(args.write_datasheet, "--write-datasheet")
        if not args.datasheet_from:
            raise HostConfigError("--write-datasheet: writes the datasheet of --datasheet-from")
        Path(args.write_datasheet).write_text(
            datasheet_toml(
                ds,
                f"made by northfinder accept --datasheet-from "
                f"{args.datasheet_from} --margin {args.margin:g}",
            )
        )
        if not (_link_given(args) or args.batch):
            say(f"wrote {args.write_datasheet}")
            return 0
    out = _output_folder(args)
    if args.batch:
        return run_batch(
            args, ds, out, accept_unit=accept_unit, check_unit_arguments=check_unit_arguments
        )
    result = accept_unit(args, ds, out)
    if args.json:
        say(dumps(result))
    else:
        say(_text(result, out))
    return verdict_status(result["verdict"])


def _output_folder(args: argparse.Namespace) -> Path:
    """``-o DIR``, checked: a folder (or none yet) in a folder that exists, empty or resumed."""
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise HostConfigError(f"-o {out}: is a file; give a folder")
    if not out.parent.is_dir():
        raise HostConfigError(f"-o {out}: the folder {out.parent} does not exist")
    if out.is_dir() and any(out.iterdir()) and not args.resume:
        raise HostConfigError(
            f"-o {out}: holds an earlier acceptance; give --resume to keep its stages, or "
            "another folder"
        )
    return out


def check_unit_arguments(args: argparse.Namespace, ds: Any) -> tuple[Any, dict[str, Any] | None]:
    """Everything about one unit's arguments checked before a device is opened; the datasheet
    the runs follow (the plan of ``--plan`` or ``--budget``) and that plan's description."""
    if args.junit:
        check_output_path(args.junit, "--junit")
    if args.sim and args.time_scale != 1.0:
        raise HostConfigError("--time-scale: not with --sim (the unit runs in virtual time)")
    if args.sim and args.latitude is None:
        args.latitude = ds.latitude_deg  # the simulated site is the datasheet's
    measure.check_arguments(args)
    return choose_plan(args, ds)


def accept_unit(args: argparse.Namespace, ds: Any, out: Path) -> dict[str, Any]:
    """One unit's acceptance into ``out`` (checked by :func:`_output_folder`): its result."""
    from northfinder.host.acceptance import datasheet_toml, static_length_s

    runs_ds, plan = check_unit_arguments(args, ds)
    if args.sim:
        from numpy.random import default_rng

        seed = run_seed(args)
        if args.azimuth is None:  # one simulated mount for every run
            args.azimuth = float(default_rng(seed).uniform(0.0, 360.0))
    if args.static_s is None:
        args.static_s, args.static_from = static_length_s(ds, STATIC_S, STATIC_DEFAULT_MAX_S)
    else:
        args.static_from = "--static-s"
    out.mkdir(exist_ok=True)
    _keep_plan(args, out, plan)
    started = time.monotonic()
    stages = Stages(args, runs_ds, out, sheet=ds, plan=plan)
    stages.conformance()
    stages.static()
    stages.runs()
    result = stages.judge(time.monotonic() - started)
    from northfinder.host.acceptance_report import html_report, junit_xml

    (out / "datasheet.toml").write_text(datasheet_toml(ds, f"as used; from {ds.source}"))
    (out / "result.json").write_text(dumps(result) + "\n")
    (out / "report.html").write_text(html_report(result))
    if args.junit:
        Path(args.junit).write_text(junit_xml(result))
    return result


def _keep_plan(args: argparse.Namespace, out: Path, plan: dict[str, Any] | None) -> None:
    """The runs' plan in ``out/plan.json``; a resumed folder whose runs followed another plan
    is refused (its runs and the new ones would not be one sample)."""
    path = out / "plan.json"
    if plan is None:
        return
    keys = ("positions_deg", "window_s", "settle_s", "solver")
    if args.resume and path.exists():
        kept = _read_json(path)
        if any(kept.get(k) != plan[k] for k in keys):
            raise HostConfigError(
                f"--resume: the runs in {out} followed the plan {kept['positions_deg']} deg, "
                f"{kept['window_s']:g} s windows ({kept.get('from')}), not this one; give the "
                "same plan, or another folder"
            )
    path.write_text(dumps(plan) + "\n")


def _planning_sensor(args: argparse.Namespace, ds: Any) -> tuple[Any, str]:
    """The sensor the planner predicts for: the simulated one (``--sim``), else the
    datasheet's noise limits on paper-rlg's other figures; and what it is."""
    from northfinder.firmware_sim.sensors import DEFAULT_SENSOR
    from northfinder.host.acceptance import ALLAN_KEYS

    if args.sim:
        name = args.sensor or DEFAULT_SENSOR
        return load_sensor(name), f"the simulated sensor {name}"
    values = {k: v for k, v in ds.limits.items() if k in ALLAN_KEYS}
    if not values:
        return load_sensor("paper-rlg"), "paper-rlg's figures (the datasheet states no noise)"
    return load_sensor("paper-rlg", values), "the datasheet's noise limits on paper-rlg's figures"


def choose_plan(args: argparse.Namespace, ds: Any) -> tuple[Any, dict[str, Any] | None]:
    """The datasheet the runs follow: the datasheet's plan, ``--plan``'s or the planner's best
    within ``--budget``; and that plan with the planner's prediction of its repeatability at
    the datasheet's latitude (None: the datasheet has no runs)."""
    import dataclasses

    from northfinder.host.accuracy import predict
    from northfinder.host.plan import Plan
    from northfinder.simwindows import error_model

    given = [f for f, v in (("--plan", args.plan), ("--budget", args.budget)) if v is not None]
    if len(given) == 2:
        raise HostConfigError("--plan, --budget: give one (a plan, or the time a plan may take)")
    if given and not ds.positions_deg:
        raise HostConfigError(
            f"{given[0]}: {ds.source} has no north-finding line (north_finding.sigma_deg or "
            "gyro.bias_repeatability_dph) for runs to judge"
        )
    if not ds.positions_deg:
        return ds, None
    spec, sensor_from = _planning_sensor(args, ds)
    model = error_model(spec)
    warmup = measure.SIM_WARMUP_S if args.warmup is None else args.warmup
    how = "the datasheet's plan"
    if args.plan is not None:
        positions, window = _parse_plan(args.plan, ds)
        ds = dataclasses.replace(ds, positions_deg=positions, window_s=window, solver="auto")
        how = f"--plan {args.plan}"
    elif args.budget is not None:
        ds = _budget_plan(args.budget, ds, model, warmup)
        how = f"the planner's best stop-and-go plan within --budget {args.budget:g} s"
    plan = Plan(tuple(ds.positions_deg), ds.window_s, ds.settle_s, "none", ds.solver)
    pred = predict(model, plan, ds.latitude_deg, warmup_s=warmup)
    return ds, {
        "positions_deg": list(ds.positions_deg),
        "window_s": ds.window_s,
        "settle_s": ds.settle_s,
        "solver": ds.solver,
        "from": how,
        "plan_time_s": pred.plan_time_s,
        "predicted_sigma_deg": pred.sigma_deg,
        "predicted_from": f"{sensor_from} at {ds.latitude_deg:g} deg",
    }


def _parse_plan(text: str, ds: Any) -> tuple[tuple[float, ...], float]:
    """``--plan ANGLES:SECONDS``: the table angles and the window, checked as a datasheet's."""
    from northfinder.cli.argtypes import angle_list
    from northfinder.host.acceptance import REPEAT_KEY, same_angle_pairs
    from northfinder.host.errors import GeometryError
    from northfinder.host.plan import Plan
    from northfinder.host.procedure import check_plan_for_device

    angles, sep, seconds = text.rpartition(":")
    try:
        positions = tuple(angle_list(angles)) if sep else ()
        window = float(seconds)
    except (argparse.ArgumentTypeError, ValueError):
        positions, window = (), math.nan
    if len(positions) < 2 or not 0.5 <= window <= 3600.0:
        raise HostConfigError(
            f"--plan {text!r}: give two or more table angles and the seconds per position "
            "(0.5 to 3600), e.g. 0,90,180,270:20"
        )
    try:
        check_plan_for_device(Plan(positions, window, ds.settle_s, "none", "auto"))
    except (HostConfigError, GeometryError) as exc:
        raise HostConfigError(f"--plan {text}: {exc}") from exc
    if REPEAT_KEY in ds.limits and not same_angle_pairs(positions):
        raise HostConfigError(
            f"--plan {text}: visits each angle once; {ds.source}'s {REPEAT_KEY} needs a plan "
            "that comes back to an angle"
        )
    return positions, window


def _budget_plan(budget_s: float, ds: Any, model: Any, warmup_s: float) -> Any:
    """The datasheet with the planner's best stop-and-go plan within ``budget_s`` (one that
    comes back to an angle when the datasheet judges the bias repeatability)."""
    import dataclasses

    from northfinder.host.acceptance import REPEAT_KEY, same_angle_pairs
    from northfinder.host.plan_search import GEOMETRIES, search_plans

    shapes = [g for g in GEOMETRIES if REPEAT_KEY not in ds.limits or same_angle_pairs(g)]
    cands = search_plans(model, ds.latitude_deg, budget_s, settle_s=ds.settle_s,
                         geometries=shapes, warmup_s=warmup_s)  # fmt: skip
    if not cands:
        raise HostConfigError(
            f"--budget {budget_s:g}: no plan fits in {budget_s:g} s (the moves alone take "
            "longer); give more seconds"
        )
    best = cands[0].plan
    return dataclasses.replace(
        ds, positions_deg=tuple(best.positions_deg), window_s=float(best.window_s), solver="auto"
    )


def _text(result: dict[str, Any], out: Path) -> str:
    rows = [f"northfinder accept: {result['verdict']} ({result['datasheet']['name']})"]
    for line in result["lines"]:
        m = line["measured"]
        shown = f"{m:.4g}" if isinstance(m, float) else ("-" if m is None else str(m))
        lim = line["limit"]
        lim_s = f"<= {lim:.4g}" if isinstance(lim, float) else str(lim)
        rows.append(
            f"  {line['verdict']:<12} {line['key']:<31} {lim_s:>12} {line['unit']:<14} "
            f"measured {shown}  {line['note']}"
        )
    plan = result.get("plan")
    if plan is not None:
        line = next((x for x in result["lines"] if x["key"] == "north_finding.sigma_deg"), None)
        measured = line["measured"] if line else None
        shown = "-" if measured is None else f"{measured:.4g}"
        rows.append(
            f"runs: {','.join(f'{a:g}' for a in plan['positions_deg'])} deg, "
            f"{plan['window_s']:.4g} s windows ({plan['from']}); repeatability predicted "
            f"{plan['predicted_sigma_deg']:.4g} deg, measured {shown} deg"
        )
    rows.append(f"report: {out / 'report.html'}")
    return "\n".join(rows)


def _time_to_ready(device: Any, simulated: bool) -> dict[str, Any]:
    """Seconds to READY on the device's clock: for the embedded simulator from its power-on
    (its clock starts there), for a unit from a RESET sent now (its BOOT seen first), by its
    sample counter, which restarts at the RESET and ticks at its sample rate whatever the
    host's pace (a simulator at ``--speed S`` counts its own seconds, not the wall's)."""
    from northfinder.driver.protocol.constants import DeviceState
    from northfinder.host.procedure import wait_until_ready

    clock = device.clock
    if simulated:
        wait_until_ready(device, 86_400.0, clock=clock.now)
        return {"time_to_ready_s": clock.now(), "from": "power-on"}
    device.status()
    t0 = clock.now()
    device.reset(wait=False)
    while device.status().state not in (DeviceState.BOOT, DeviceState.WARMUP):
        if clock.now() - t0 > 3.0:
            break  # back already (or BOOT missed): READY is timed from the RESET all the same
        clock.sleep(0.05)
    wait_until_ready(device, 86_400.0, clock=clock.now)
    ticks = device.status().sample_counter + 1  # the first READY status: ticks since the RESET
    return {
        "time_to_ready_s": ticks / float(device.sample_rate_hz),
        "from": "RESET",
        "wall_s": clock.now() - t0,
    }


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text())


class Stages:
    """The stages of one acceptance, each written to the output folder as it ends."""

    def __init__(self, args: argparse.Namespace, ds: Any, out: Path, *, sheet: Any = None,
                 plan: dict[str, Any] | None = None) -> None:  # fmt: skip
        """``ds``: the datasheet the runs follow; ``sheet``: the one given (default ``ds``);
        ``plan``: the runs' plan and its prediction (:func:`choose_plan`)."""
        self.args, self.ds, self.out = args, ds, out
        self.sheet = ds if sheet is None else sheet
        self.plan = plan
        self.device: dict[str, Any] | None = None

    def _done(self, name: str) -> bool:
        return bool(self.args.resume) and (self.out / name).exists()

    def conformance(self) -> None:
        if not self.ds.conformance or self._done("conformance.json"):
            return
        from northfinder.cli import conformance as conf
        from northfinder.driver.conformance import SuiteOptions, select_checks, write_junit

        only = () if tuple(self.ds.conformance) == ("*",) else tuple(self.ds.conformance)
        try:
            select_checks(only)
        except Exception as exc:  # SuiteConfigError: a pattern that names no check
            raise HostConfigError(f"{self.ds.source}: unit.conformance: {exc}") from exc
        options = SuiteOptions(
            node_id=self.args.node_id, only=only, time_scale=self.args.time_scale
        )
        stage_line(self.args, f"conformance ({', '.join(self.ds.conformance)})")
        ns = copy.copy(self.args)
        report = (
            conf.simulated_report(ns, options) if self.args.sim else conf.link_report(ns, options)
        )
        write_junit(report, str(self.out / "conformance.xml"))
        (self.out / "conformance.json").write_text(conf.as_json(report) + "\n")

    def static(self) -> None:
        """The time to READY after a RESET, and the static recording, in one session."""
        ds = self.ds
        allan = _wants_static(ds)
        need_ready = not self._done("ready.json")
        need_static = allan and not self._done("static.npz")
        if not (need_ready or need_static):
            return
        from northfinder.host.procedure import wait_until_ready
        from northfinder.host.recording import RecordedWindow, RecordingWriter
        from northfinder.host.results import device_identity, utc_now

        args = self.args
        with measure.open_device(args) as (device, truth):
            identity = device_identity(
                device.identity,
                simulated=bool(args.sim),
                sensor=None if truth is None else truth.get("sensor"),
            )
            clock = device.clock
            if need_ready:
                ready = {"device": identity, **_time_to_ready(device, bool(args.sim))}
                stage_line(args, f"READY {ready['time_to_ready_s']:.1f} s after {ready['from']}")
                (self.out / "ready.json").write_text(dumps(ready) + "\n")
            else:
                wait_until_ready(device, 86_400.0, clock=clock.now)
            if need_static:
                stage_line(args, f"static recording of {args.static_s:g} s ({args.static_from})")
                angle = float(device.status().angle_deg)
                meta = {
                    "latitude_deg": float(args.latitude),
                    "latitude_source": "--latitude" if not args.sim else "the datasheet",
                    "sample_rate_hz": float(device.sample_rate_hz),
                    "plan": {"positions_deg": [angle], "window_s": args.static_s},
                    "created_utc": utc_now(),
                    "device": identity,
                    "stage": "static",
                }
                if truth is not None:
                    meta["truth"] = truth
                window = device.acquire(args.static_s, on_gap="report")
                device.release_stream()
                # Written once whole: a static.npz in the folder is a finished stage (--resume).
                writer = RecordingWriter(self.out / "static.npz", meta)
                writer.add(RecordedWindow.from_window(window, angle))
                writer.close("complete")

    def _orientation(self, r: int) -> float:
        return (r % self.args.orientations) * 360.0 / self.args.orientations

    def runs(self) -> None:
        ds, args = self.ds, self.args
        if not ds.positions_deg:
            return
        from northfinder.cli.report import angle_error

        for r in range(args.runs):
            name = f"run_{r + 1:02d}"
            if self._done(f"{name}.json"):
                continue
            offset = self._orientation(r)
            a = copy.copy(args)
            a.positions = [p + offset for p in ds.positions_deg]
            a.window, a.settle, a.denoise, a.solver = ds.window_s, ds.settle_s, "none", ds.solver
            a.on_gap, a.can_log, a.can_log_rotate = "remeasure", None, (0, 0.0)
            a.timeout = 600.0  # longest wait for READY, as find
            if args.sim:
                a.seed = args.seed + 1 + r  # a power-on of its own
            a.command = "accept"
            stage_line(args, f"north finding {r + 1}/{args.runs}, orientation {offset:g} deg")
            m = measure.run_plan(a, progress=False, record_to=str(self.out / f"{name}.npz"))
            if m.errors:
                raise m.errors[0]
            res = m.result
            body = {
                "run": r + 1,
                "orientation_deg": offset,
                "azimuth_deg": res.azimuth_deg,
                "sigma_deg": res.sigma_deg,
                "consistent": res.consistent,
                "latitude_deg": m.latitude_deg,
                "recording": f"{name}.npz",
                "device": m.device,
            }
            if m.truth is not None:
                body["truth_azimuth_deg"] = m.truth.azimuth_deg
                body["error_deg"] = angle_error(res.azimuth_deg, m.truth.azimuth_deg)
            (self.out / f"{name}.json").write_text(dumps(body) + "\n")

    def judge(self, wall_s: float) -> dict[str, Any]:
        """Every datasheet line judged, and what the report shows."""
        from northfinder.host import acceptance as acc
        from northfinder.host.results import envelope

        ds, args = self.sheet, self.args
        body: dict[str, Any] = {"stages": {}}
        if self.plan is not None:
            body["plan"] = self.plan
        lines, identity = self._unit_lines(body)
        cal = self._allan(body, lines)
        if self.ds.positions_deg:
            lines += self._run_lines(body, cal)
        ordered = sorted(lines, key=lambda line: _ORDER.index(line.key.split(".")[0]))
        return envelope(
            "accept",
            identity,
            {
                "command_line": "northfinder " + shlex.join(getattr(args, "_argv", sys.argv[1:])),
                "cwd": os.getcwd(),
                "verdict": acc.overall(ordered),
                "datasheet": {
                    "name": ds.name,
                    "source": ds.source,
                    "latitude_deg": ds.latitude_deg,
                    "positions_deg": list(ds.positions_deg),
                    "window_s": ds.window_s,
                },
                "seed": getattr(args, "seed", None) if args.sim else None,
                "wall_s": wall_s,
                "lines": [line.to_dict() for line in ordered],
                **body,
            },
        )

    def _unit_lines(self, body: dict[str, Any]) -> tuple[list[Any], dict[str, Any] | None]:
        """The conformance, protocol version and time to READY lines, and the unit's identity."""
        from northfinder.host import acceptance as acc

        ds, out = self.ds, self.out
        lines: list[Any] = []
        identity = None
        if ds.conformance:
            conf = _read_json(out / "conformance.json")
            lines += acc.conformance_lines(ds.conformance, conf["checks"])
            identity = conf.get("device")
            body["stages"]["conformance"] = {
                "file": "conformance.json",
                "junit": "conformance.xml",
                "counts": conf["counts"],
                "duration_s": conf["duration_s"],
            }
        ready = _read_json(out / "ready.json")
        identity = ready["device"] or identity
        body["stages"]["ready"] = {
            "file": "ready.json",
            "time_to_ready_s": ready["time_to_ready_s"],
        }
        if ds.protocol_version:
            reported = identity.get("protocol_version") if identity else None
            lines.append(acc.equal_line("unit.protocol_version", "protocol version",
                                        ds.protocol_version, reported))  # fmt: skip
        if "unit.time_to_ready_s" in ds.limits:
            lines.append(
                acc.value_line(
                    "unit.time_to_ready_s",
                    ds.limits["unit.time_to_ready_s"],
                    float(ready["time_to_ready_s"]),
                    f"from {ready['from']}, on the device's clock",
                )
            )
        return lines, identity

    def _allan(self, body: dict[str, Any], lines: list[Any]) -> Any:
        """The Allan lines from the static recording (added to ``lines``); its calibration."""
        from northfinder.host import acceptance as acc

        out = self.out
        if not ((out / "static.npz").exists() and _wants_static(self.ds)):
            return None
        from northfinder.host.calibrate import calibrate, read_runs

        stage_line(self.args, "Allan deviation and IEEE 952 fit of the static recording")
        cal = calibrate(read_runs([out / "static.npz"]))
        record_s = cal.hours * 3600.0
        lines += acc.allan_lines(self.ds, cal, record_s)
        body["stages"]["static"] = {
            "file": "static.npz",
            "seconds": record_s,
            "length_from": getattr(self.args, "static_from", "--static-s"),
        }
        body["allan"] = {
            axis: {"taus_s": c.taus_s.tolist(), "adev": c.adev.tolist()}
            for axis, c in cal.curves.items()
        }
        body["fits"] = {
            triad: {
                "coefficients": {k: _finite(v) for k, v in fit.coefficients.items()},
                "resolved": fit.resolved,
            }
            for triad, fit in cal.triad_fits.items()
        }
        return cal

    def _run_lines(self, body: dict[str, Any], cal: Any) -> list[Any]:
        """The repeatability line and the bias repeatability lines from the runs."""
        from northfinder.host import acceptance as acc
        from northfinder.host.recording import Recording

        ds, args, out = self.ds, self.args, self.out
        runs = [_read_json(out / f"run_{r + 1:02d}.json") for r in range(args.runs)]
        body["stages"]["runs"] = runs
        lines = []
        if "north_finding.sigma_deg" in ds.limits:
            site = runs[0]["latitude_deg"]
            lines.append(acc.repeatability_line(ds, [r["azimuth_deg"] for r in runs], site))
            if cal is not None:
                body["prediction"] = _prediction(args, ds, cal)
        if acc.REPEAT_KEY in ds.limits:
            means = []
            for r in runs:
                windows = Recording.load(out / r["recording"]).windows
                means.append([w.gyro_dph.mean(axis=0).tolist() for w in windows])
            lines += acc.bias_repeatability_lines(ds, means)
        return lines


def _wants_static(ds: Any) -> bool:
    """Whether the datasheet has a line the static recording judges."""
    from northfinder.host.acceptance import ALLAN_KEYS

    return any(k in ds.limits for k in ALLAN_KEYS)


_ORDER = ("unit", "gyro", "accel", "north_finding")


def _prediction(args: argparse.Namespace, ds: Any, cal: Any) -> dict[str, Any]:
    """The planner's repeatability of the datasheet's plan at its latitude from the noise terms
    the static record resolved (a term it does not resolve counted as 0: optimistic), on the
    simulated sensor's other figures (``--sim``) or ``paper-rlg``'s."""
    import dataclasses

    from northfinder.host.accuracy import predict
    from northfinder.host.plan import Plan
    from northfinder.simwindows import error_model

    base_name = (args.sensor or "paper-rlg") if args.sim else "paper-rlg"
    fitted = dataclasses.replace(cal, unresolved="zero").sensor_dict()
    keys = {
        "gyro": ("arw_dpsh", "bias_instability_dph", "rrw_dphpsh"),
        "accel": ("vrw_ug_rthz", "bias_instability_ug"),
    }
    values = {f"{sec}.{k}": fitted[sec][k] for sec, ks in keys.items() for k in ks}
    spec = load_sensor(base_name, values)
    plan = Plan(tuple(ds.positions_deg), ds.window_s, ds.settle_s, "none", ds.solver)
    warmup = measure.SIM_WARMUP_S if args.warmup is None else args.warmup
    sigma = predict(error_model(spec), plan, ds.latitude_deg, warmup_s=warmup).sigma_deg
    return {
        "sigma_deg": sigma,
        "from": f"the noise terms the static record resolved, on {base_name}'s other figures",
    }


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None
