"""The readable report (a table) and JUnit XML of a conformance run."""

from __future__ import annotations

import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

from northfinder.driver.conformance.core import CheckResult, Report, SuiteOptions

__all__ = [
    "format_header",
    "format_report",
    "format_result",
    "format_summary",
    "junit_xml",
    "write_junit",
]

_MARK = {"pass": "PASS", "fail": "FAIL", "not judged": "NOT JUDGED", "skip": "skip"}


def _figures(r: CheckResult) -> str:
    return ", ".join(f"{k} {v}" for k, v in r.figures.items())


def format_result(r: CheckResult, name_width: int = 28) -> str:
    """One result as table rows: check, result, figures, then the message indented below."""
    head = f"{r.name:<{name_width}} {_MARK[r.outcome]:<6} {_figures(r)}"
    body = textwrap.fill(
        r.message,
        width=100,
        initial_indent=" " * (name_width + 8),
        subsequent_indent=" " * (name_width + 8),
    )
    return f"{head.rstrip()}\n{body}"


def format_header(link: str, options: SuiteOptions) -> str:
    """The lines above the table: link and the tolerances in force, then the column heads."""
    o = options
    return "\n".join(
        [
            f"northfinder conformance: {link} link, node {o.node_id}, time scale {o.time_scale:g}, "
            f"stream {o.stream_seconds:g} s, accuracy {o.accuracy_deg:g} deg, "
            f"reply limit {o.reply_limit_ms:g} ms",
            "",
            f"{'check':<28} {'result':<6} figures / message",
        ]
    )


def format_summary(report: Report) -> str:
    """One line: counts, duration, the names of the failed checks and of those not judged; above
    it a line with the host's pace over the run when it was measured."""
    failed = [r.name for r in report.results if r.outcome == "fail"]
    unjudged = [r.name for r in report.results if r.outcome == "not judged"]
    line = (
        f"{report.count('pass')} passed, {report.count('fail')} failed, "
        + (f"{len(unjudged)} not judged, " if unjudged else "")
        + f"{report.count('skip')} skipped in {report.duration_s:.1f} s"
        + (f"; failed: {', '.join(failed)}" if failed else "")
        + (
            f"; not judged (the host could not keep pace): {', '.join(unjudged)}"
            if unjudged
            else ""
        )
    )
    if report.pace is not None:
        line = f"host pace over the run: {report.pace.text()}\n{line}"
    return line


def format_report(report: Report) -> str:
    """The whole report: header, one block per check, and a summary line."""
    rows = [format_result(r) for r in report.results]
    return "\n".join(
        [format_header(report.link, report.options), *rows, "", format_summary(report)]
    )


def junit_xml(report: Report) -> ET.ElementTree:
    """JUnit XML: one testsuite, a testcase per check with failure or skipped elements."""
    suite = ET.Element(
        "testsuite",
        name=f"northfinder.conformance.{report.link}",
        tests=str(len(report.results)),
        failures=str(report.count("fail")),
        errors="0",
        skipped=str(report.count("skip") + report.count("not judged")),
        time=f"{report.duration_s:.3f}",
    )
    props = ET.SubElement(suite, "properties")
    o = report.options
    pace = [("host_pace", report.pace.text())] if report.pace is not None else []
    for name, value in (
        *pace,
        ("link", report.link),
        ("node_id", o.node_id),
        ("time_scale", o.time_scale),
        ("stream_seconds", o.stream_seconds),
        ("accuracy_deg", o.accuracy_deg),
        ("reply_limit_ms", o.reply_limit_ms),
    ):
        ET.SubElement(props, "property", name=name, value=str(value))
    for r in report.results:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"conformance.{r.name.split('.')[0]}",
            name=r.name,
            time=f"{r.duration_s:.3f}",
        )
        if r.outcome == "fail":
            el = ET.SubElement(case, "failure", message=r.message)
            el.text = f"{r.message}\n{_figures(r)}"
        elif r.outcome == "skip":
            ET.SubElement(case, "skipped", message=r.message)
        elif r.outcome == "not judged":
            # JUnit has no such verdict: skipped, with a message that says why.
            el = ET.SubElement(case, "skipped", message=f"NOT JUDGED: {r.message}")
            el.set("type", "not judged")
        if r.figures:
            out = ET.SubElement(case, "system-out")
            out.text = _figures(r)
    ET.indent(suite)
    return ET.ElementTree(suite)


def write_junit(report: Report, path: str | Path) -> None:
    """Write the JUnit XML of ``report`` to ``path``."""
    junit_xml(report).write(path, encoding="utf-8", xml_declaration=True)
