"""Protocol conformance suite: checks a unit on any link against ``protocol.md``.

The suite talks to the unit at the wire level with the shared codec (it must be able to send
malformed input), on a raw link of its own: a python-can bus (:class:`CanRawLink`) or a serial
port (:class:`SerialRawLink`). It runs a list of named checks in order (:data:`CHECKS`): identity,
configuration, stream and heartbeat timing, every command's reply and every refusal, bad input,
rotations. Each check passes, fails or is skipped with a message and measured figures; a failure
does not stop the run, and the unit is restored (STOP, RESET if needed) before the next check.

It validates the protocol, so it lives beside the driver and imports only the driver's codec,
transport helpers and errors (never the host or the simulator). Modules: :mod:`.wire` (raw links),
:mod:`.session` (requests, replies and the record of what the unit sent), :mod:`.core` (options,
results, the check context), :mod:`.checks` (the checks, one module per protocol section),
:mod:`.runner` (running and restoring), :mod:`.report` (text and JUnit XML), :mod:`.errors`.

Time: the suite runs on the host's wall clock. A simulator running accelerated is judged in its own
time by giving ``time_scale`` (the unit's seconds per wall second). Reply latencies are measured on
the host and so include link and host latency; they are judged against ``reply_limit_ms`` (default
the host timeout of protocol.md 6, 100 ms) and the count above the unit's 20 ms deadline is reported.

Example::

    with can.Bus(interface="socketcan", channel="vcan0") as bus:
        report = run_suite(CanRawLink(bus, node_id=1), SuiteOptions())
    print(format_report(report))
"""

from northfinder.driver.conformance.checks import CHECKS, select_checks
from northfinder.driver.conformance.core import Check, CheckResult, Report, SuiteOptions
from northfinder.driver.conformance.errors import (
    ConformanceError,
    LinkFault,
    Skipped,
    SuiteConfigError,
)
from northfinder.driver.conformance.report import (
    format_header,
    format_report,
    format_result,
    format_summary,
    junit_xml,
    write_junit,
)
from northfinder.driver.conformance.runner import restore, run_suite
from northfinder.driver.conformance.wire import CanRawLink, RawLink, SerialRawLink

__all__ = [
    "CHECKS",
    "CanRawLink",
    "Check",
    "CheckResult",
    "ConformanceError",
    "LinkFault",
    "RawLink",
    "Report",
    "SerialRawLink",
    "Skipped",
    "SuiteConfigError",
    "SuiteOptions",
    "format_header",
    "format_report",
    "format_result",
    "format_summary",
    "junit_xml",
    "restore",
    "run_suite",
    "select_checks",
    "write_junit",
]
