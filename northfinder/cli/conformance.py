"""``northfinder conformance``: check a unit on any link against protocol.md.

One link: python-can bus options, ``--serial PORT``, or ``--sim`` (the simulated instrument in this
process, in virtual time). Exit status: 0 all checks passed (skips allowed), 1 a check failed,
2 bad arguments, 3 no check failed but a timing check was not judged (it failed while the host
could not keep pace: docs/conformance.md). For a simulator at ``--speed S`` give ``--time-scale S``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
from collections.abc import Callable, Iterator
from typing import Any

import can
import can.cli
import serial

from northfinder.cli.argtypes import angle_list, bounded_float
from northfinder.cli.files import check_output_path
from northfinder.cli.links import add_link_arguments, bus_given, open_can_bus, open_serial_option
from northfinder.cli.options import add_sensor_argument
from northfinder.config import LinkConfig, SimConfig, default_of
from northfinder.driver.conformance import (
    CHECKS,
    CanRawLink,
    SerialRawLink,
    SuiteOptions,
    format_header,
    format_result,
    format_summary,
    run_suite,
    select_checks,
    write_junit,
)
from northfinder.driver.conformance.core import OUTCOMES, Report
from northfinder.driver.conformance.errors import SuiteConfigError
from northfinder.host.errors import HostConfigError
from northfinder.host.results import SIMULATOR_MODEL, envelope

_DEFAULTS = SuiteOptions()
#: Exit status when no check failed but a timing check was not judged (the host starved).
NOT_JUDGED = 3

#: The suite's options as flags: (flag, :class:`SuiteOptions` field, type, metavar, help).
_FLAGS: tuple[tuple[str, str, Callable[[str], Any], str | None, str], ...] = (
    ("--time-scale", "time_scale", bounded_float(0.0, 10_000.0, open_lo=True), "S",
     "the unit's seconds per wall second (a simulator's --speed; default 1)"),
    ("--stream-seconds", "stream_seconds", bounded_float(0.0, 3600.0, "s", open_lo=True), None,
     "length of the stream and heartbeat observation, unit seconds (default 30)"),
    ("--angles", "angles_deg", angle_list, "DEG,DEG,...",
     "rotation targets of rotation.accuracy (default 37.5,181.25,300)"),
    ("--accuracy", "accuracy_deg", bounded_float(0.0, 180.0, "deg", open_lo=True), "DEG",
     "largest |encoder - target| after a move (default 0.05 deg)"),
    ("--reply-limit-ms", "reply_limit_ms", bounded_float(0.0, 60_000.0, "ms", open_lo=True), None,
     "largest reply latency measured on the host, unit ms (default 100, the host timeout of "
     "protocol.md 6; replies over the unit's 20 ms deadline are counted in the report)"),
    ("--jitter-margin-ms", "jitter_margin_ms", bounded_float(0.0, 60_000.0, "ms"), None,
     "host timestamp margin added to the 10 %% heartbeat jitter bound, wall ms (default 5)"),
    ("--rate-tolerance", "rate_tolerance", bounded_float(0.0, 1.0, open_lo=True), None,
     "relative tolerance of the sample rate and mean heartbeat period (default 0.01)"),
    ("--settle-margin", "settle_margin_s", bounded_float(0.0, 3600.0, "s"), "SECONDS",
     "added (with 10 %%) to profile + settle time before a move is late (default 0.5)"),
    ("--ready-timeout", "ready_timeout_s", bounded_float(0.0, 86_400.0, "s", open_lo=True), "SECONDS",
     "longest wait for READY after boot or reset, unit seconds (default 180)"),
)  # fmt: skip


def add_arguments(p: argparse.ArgumentParser) -> None:
    group = add_link_arguments(p, "serial link and simulation")
    group.add_argument(
        "--sim",
        action="store_true",
        help="check the simulated instrument in this process, in virtual time",
    )
    add_sensor_argument(group)
    group.add_argument("--seed", type=int, default=None, help="--sim random seed")
    g = p.add_argument_group("what to check and how strictly")
    for flag, field, kind, metavar, text in _FLAGS:
        default = getattr(_DEFAULTS, field)
        g.add_argument(flag, dest=field, type=kind, default=default, metavar=metavar, help=text)
    g.add_argument(
        "--unit-pid",
        type=int,
        default=None,
        metavar="PID",
        help="the unit is this process on this host (a simulator): its waits for a CPU count as "
        "the host's (found by itself for a unit on a pseudo-terminal)",
    )
    g.add_argument(
        "--only",
        metavar="PATTERNS",
        default="",
        help="comma-separated glob patterns of checks to run, e.g. 'stream.*,refusal.busy'",
    )
    p.add_argument("--list", action="store_true", help="list the checks and exit")
    p.add_argument("--junit", metavar="FILE", help="also write JUnit XML to FILE")
    p.add_argument("--json", action="store_true", help="print the result as JSON (no report)")


def _identity(report: Report) -> dict[str, Any] | None:
    """The unit's identity from the identify check's figures (None if it did not run or pass)."""
    try:
        r = report.result("identify")
    except KeyError:
        return None
    f = r.figures
    if r.outcome != "pass" or not {"model", "serial", "firmware", "protocol"} <= set(f):
        return None
    return {
        "model": f["model"],
        "serial_number": int(f["serial"]) if f["serial"].isdigit() else None,
        "firmware_version": f["firmware"],
        "protocol_version": f["protocol"],
        "simulated": f["model"] == SIMULATOR_MODEL,
    }


def as_json(report: Report) -> str:
    """The report as the documented JSON result (:mod:`northfinder.host.results`)."""
    body = {
        "link": report.link,
        "passed": report.passed,
        "counts": {k: report.count(k) for k in OUTCOMES},
        "duration_s": report.duration_s,
        "host_pace": None if report.pace is None else dataclasses.asdict(report.pace),
        "options": dataclasses.asdict(report.options),
        "checks": [
            {
                "name": r.name,
                "outcome": r.outcome,
                "message": r.message,
                "figures": dict(r.figures),
                "duration_s": r.duration_s,
            }
            for r in report.results
        ],
    }
    return json.dumps(envelope("conformance", _identity(report), body), indent=2)


def _options(args: argparse.Namespace) -> SuiteOptions:
    values = {field: getattr(args, field) for _, field, _, _, _ in _FLAGS}
    values["angles_deg"] = tuple(values["angles_deg"])
    only = tuple(p.strip() for p in args.only.split(",") if p.strip())
    return SuiteOptions(node_id=args.node_id, only=only, unit_pid=args.unit_pid, **values)


def run(args: argparse.Namespace) -> int:
    if args.list:
        width = max(len(c.name) for c in CHECKS)
        for c in CHECKS:
            print(f"{c.name:<{width}}  {c.summary}")
        return 0
    try:
        options = _options(args)
        select_checks(options.only)
        if sum((bus_given(args), bool(args.serial), bool(args.sim))) != 1:
            raise HostConfigError(
                "choose exactly one link: -i/-c (python-can), --serial PORT or --sim"
            )
        if args.sim and options.time_scale != 1.0:
            raise HostConfigError("--time-scale: not with --sim (the unit runs in virtual time)")
        if args.junit:
            check_output_path(args.junit, "--junit")
    except (HostConfigError, SuiteConfigError) as exc:
        print(f"northfinder conformance: error: {exc}", file=sys.stderr)
        return 2
    if args.sim:
        return _run_simulated(args, options)
    with _raw_link(args) as link:
        report = _run(args, link, options)
    return _finish(args, report)


def _run(
    args: argparse.Namespace,
    link: CanRawLink | SerialRawLink,
    options: SuiteOptions,
    **kwargs: Any,
) -> Report:
    """Run the suite: the header and each result printed as it comes, or nothing with --json
    (stdout then holds the JSON result alone)."""
    if not args.json:
        print(format_header(link.kind, options), flush=True)
    return run_suite(
        link,
        options,
        progress=None if args.json else lambda r: print(format_result(r), flush=True),
        **kwargs,
    )


def _finish(args: argparse.Namespace, report: Report) -> int:
    """Print the summary (or the JSON result), write --junit, give the exit status."""
    if args.json:
        print(as_json(report), flush=True)
    else:
        print(f"\n{format_summary(report)}", flush=True)
    if args.junit:
        write_junit(report, args.junit)
    if not report.passed:
        return 1
    return 0 if report.judged else NOT_JUDGED


def _run_simulated(args: argparse.Namespace, options: SuiteOptions) -> int:
    """The suite against the simulated instrument on virtual CAN in this process, in virtual time."""
    return _finish(
        args, simulated_report(args, options, lambda link, **kw: _run(args, link, options, **kw))
    )


def sim_link(args: argparse.Namespace) -> LinkConfig:
    """The unit of ``--sim``: the simulated instrument of ``--sensor`` and ``--seed``, level at
    azimuth 0 at the simulation's latitude, ready at once (no warm-up), in virtual time."""
    sensor = args.sensor or default_of(SimConfig, "sensor")
    sim = SimConfig(sensor=sensor, seed=args.seed, warmup_s=0.0, azimuth_deg=0.0)
    return LinkConfig(node_id=args.node_id, sim=sim)


def simulated_report(
    args: argparse.Namespace,
    options: SuiteOptions,
    run: Callable[..., Report] | None = None,
) -> Report:
    """The suite's report on the simulated instrument of ``--sensor`` and ``--seed``, on virtual
    CAN in this process, in virtual time (``run(link, clock=...)`` runs it; default
    :func:`~northfinder.driver.conformance.run_suite` without progress)."""
    from northfinder import session
    from northfinder.driver.clock import VirtualClock

    link_config = sim_link(args)
    assert link_config.sim is not None
    sim, _ = session.simulated_instrument(link_config, link_config.sim)
    with sim, sim.open_bus() as bus:
        assert isinstance(sim.clock, VirtualClock)
        link = CanRawLink(bus, args.node_id)
        if run is None:
            report = run_suite(link, options, clock=sim.clock)
        else:
            report = run(link, clock=sim.clock)
        sim.check()
    return report


def _open_raw_link(args: argparse.Namespace, closers: list[Any]) -> CanRawLink | SerialRawLink:
    """The suite's link to the unit of ``--serial`` or the python-can options; what closes it
    goes to ``closers``."""
    if args.serial:
        port = open_serial_option(args.serial, args.baud)
        closers.append(port.close)
        return SerialRawLink(port)
    bus = open_can_bus(args)
    closers.append(bus.shutdown)
    return CanRawLink(bus, args.node_id)


def link_report(args: argparse.Namespace, options: SuiteOptions) -> Report:
    """The suite's report on the unit of ``--serial`` or the python-can options (no progress)."""
    with _raw_link(args) as link:
        return run_suite(link, options)


@contextlib.contextmanager
def _raw_link(args: argparse.Namespace) -> Iterator[Any]:
    """The unit's link of ``--serial`` or the python-can options, closed on leaving (what was
    opened of it, when opening failed half-way)."""
    closers: list[Any] = []
    try:
        yield _open_raw_link(args, closers)
    finally:
        for close in reversed(closers):
            try:
                close()
            except (can.CanError, serial.SerialException, OSError):
                pass  # the link is already gone; the report says what failed
