"""The acceptance report of ``northfinder accept``: one self-contained HTML page (inline CSS,
plots as inline SVG written here: no network, no plotting library), and JUnit XML with one test
case per datasheet line.

Both take the result dictionary the command writes to ``result.json`` (docs/accept.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from html import escape
from typing import Any
from xml.etree import ElementTree as ET

from northfinder.host.heading import heading_text

__all__ = ["html_report", "junit_xml", "summary_html"]

_COLOURS = {"PASS": "#1b7f3b", "FAIL": "#b3261e", "NOT RESOLVED": "#a15c00"}
#: A batch's unit that could not be tested (``accept --batch``).
_ERROR_COLOUR = "#5b2a86"
_CSS = """
body{font:14px/1.45 system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:72em;color:#1d1d1f;padding:0 1em}
h1{font-size:1.6em;margin:.2em 0}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}
h3{font-size:1.05em}
.verdict{font-size:2em;font-weight:700;padding:.3em .6em;border-radius:.3em;color:#fff;
display:inline-block}
table{border-collapse:collapse;width:100%;margin:.5em 0}
th,td{border:1px solid #ddd;padding:.3em .5em;text-align:left;vertical-align:top}
th{background:#f4f4f6}td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.tag{font-weight:700;white-space:nowrap}code{background:#f4f4f6;padding:0 .2em;word-break:break-all}
.small{color:#555;font-size:.9em}td.small{min-width:12em}td.val{text-align:right}td code{font-size:.85em;word-break:normal}svg{max-width:100%;height:auto;background:#fff}
"""


def _num(v: Any, digits: int = 4) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return "—" if not math.isfinite(v) else f"{v:.{digits}g}"
    return escape(str(v))


def _tag(verdict: str) -> str:
    return f'<span class="tag" style="color:{_COLOURS[verdict]}">{escape(verdict)}</span>'


def _lines_table(lines: Sequence[dict[str, Any]]) -> str:
    rows = [
        "<table><tr><th>line</th><th>limit</th><th>measured</th><th>interval (90 %)</th>"
        "<th>verdict</th><th>how</th></tr>"
    ]
    for line in lines:
        limit = line["limit"]
        lim = f"≤ {_num(limit)}" if isinstance(limit, float) else _num(limit)
        lo, hi = line["low"], line["high"]
        interval = "—" if lo is None or hi is None else f"{_num(lo, 3)} to {_num(hi, 3)}"
        if lo is not None and hi is not None and lo == hi:
            interval = "one measurement"
        rows.append(
            f"<tr><td>{escape(line['title'])}<br><code>{escape(line['key'])}</code></td>"
            f'<td class="num">{lim} {escape(line["unit"])}</td>'
            f'<td class="val">{_num(line["measured"])}</td><td class="num">{interval}</td>'
            f"<td>{_tag(line['verdict'])}</td><td class=small>{escape(line['note'])}</td></tr>"
        )
    rows.append("</table>")
    return "\n".join(rows)


class _Axes:
    """A plot area with linear or log axes, drawn as SVG."""

    def __init__(self, xlim: tuple[float, float], ylim: tuple[float, float], *,
                 log: bool, w: int = 640, h: int = 360) -> None:  # fmt: skip
        self.log, self.w, self.h = log, w, h
        self.left, self.right, self.top, self.bottom = 70, 20, 20, 50
        self.x0, self.x1 = (math.log10(v) for v in xlim) if log else xlim
        self.y0, self.y1 = (math.log10(v) for v in ylim) if log else ylim
        self.parts: list[str] = []

    def px(self, x: float, y: float) -> tuple[float, float]:
        if self.log:
            x, y = math.log10(x), math.log10(y)
        u = self.left + (x - self.x0) / (self.x1 - self.x0) * (self.w - self.left - self.right)
        v = self.top + (self.y1 - y) / (self.y1 - self.y0) * (self.h - self.top - self.bottom)
        return u, v

    def polyline(self, xs: Sequence[float], ys: Sequence[float], colour: str,
                 dash: str = "", width: float = 1.5) -> None:  # fmt: skip
        pts = " ".join(
            "{:.1f},{:.1f}".format(*self.px(x, y))
            for x, y in zip(xs, ys, strict=True)
            if not self.log or (x > 0 and y > 0)
        )
        d = f' stroke-dasharray="{dash}"' if dash else ""
        self.parts.append(
            f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="{width}"{d}/>'
        )

    def dots(self, xs: Sequence[float], ys: Sequence[float], colour: str) -> None:
        for x, y in zip(xs, ys, strict=True):
            u, v = self.px(x, y)
            self.parts.append(f'<circle cx="{u:.1f}" cy="{v:.1f}" r="3.5" fill="{colour}"/>')

    def band(self, y_lo: float, y_hi: float, colour: str, opacity: float = 0.18) -> None:
        x0 = self.x0 if not self.log else 10**self.x0
        x1 = self.x1 if not self.log else 10**self.x1
        u0, v0 = self.px(x0, y_hi)
        u1, v1 = self.px(x1, y_lo)
        self.parts.append(
            f'<rect x="{u0:.1f}" y="{v0:.1f}" width="{u1 - u0:.1f}" height="{v1 - v0:.1f}" '
            f'fill="{colour}" fill-opacity="{opacity}"/>'
        )

    def text(self, x: float, y: float, s: str, colour: str = "#333", anchor: str = "start") -> None:
        u, v = self.px(x, y)
        self.parts.append(
            f'<text x="{u:.1f}" y="{v:.1f}" fill="{colour}" font-size="11" '
            f'text-anchor="{anchor}">{escape(s)}</text>'
        )

    def svg(self, xlabel: str, ylabel: str, title: str) -> str:
        w, h, left, top = self.w, self.h, self.left, self.top
        pw, ph = w - left - self.right, h - top - self.bottom
        axes = [
            f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="#888"/>'
        ]
        for ticks, horizontal in ((self._ticks(self.x0, self.x1), True),
                                  (self._ticks(self.y0, self.y1), False)):  # fmt: skip
            for t in ticks:
                value = 10**t if self.log else t
                label = f"{value:g}"
                if horizontal:
                    u = left + (t - self.x0) / (self.x1 - self.x0) * pw
                    axes.append(
                        f'<line x1="{u:.1f}" y1="{top}" x2="{u:.1f}" y2="{top + ph}" '
                        'stroke="#eee"/>'
                        f'<text x="{u:.1f}" y="{top + ph + 15}" font-size="11" '
                        f'text-anchor="middle">{label}</text>'
                    )
                else:
                    v = top + (self.y1 - t) / (self.y1 - self.y0) * ph
                    axes.append(
                        f'<line x1="{left}" y1="{v:.1f}" x2="{left + pw}" y2="{v:.1f}" '
                        'stroke="#eee"/>'
                        f'<text x="{left - 5}" y="{v + 4:.1f}" font-size="11" '
                        f'text-anchor="end">{label}</text>'
                    )
        axes.append(
            f'<text x="{left + pw / 2}" y="{h - 12}" font-size="12" text-anchor="middle">'
            f"{escape(xlabel)}</text>"
            f'<text x="14" y="{top + ph / 2}" font-size="12" text-anchor="middle" '
            f'transform="rotate(-90 14 {top + ph / 2})">{escape(ylabel)}</text>'
        )
        return (
            f'<svg viewBox="0 0 {w} {h}" width="{w}" '
            f'height="{h}" role="img" aria-label="{escape(title)}"><title>{escape(title)}</title>'
            + "".join(axes)
            + "".join(self.parts)
            + "</svg>"
        )

    def _ticks(self, a: float, b: float) -> list[float]:
        if self.log:
            return [float(k) for k in range(math.ceil(a), math.floor(b) + 1)]
        span = b - a
        step = 10 ** math.floor(math.log10(span / 4)) if span > 0 else 1.0
        for m in (1, 2, 5, 10):
            if span / (step * m) <= 8:
                step *= m
                break
        first = math.ceil(a / step) * step
        return [first + i * step for i in range(int((b - first) / step) + 1)]


_AXIS_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c")
_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)


def _allan_svg(result: dict[str, Any], triad: str) -> str:
    """The Allan deviation of a triad's axes with the datasheet's lines."""
    curves = {k: v for k, v in result["allan"].items() if k.startswith(triad)}
    taus = [t for c in curves.values() for t in c["taus_s"]]
    devs = [d for c in curves.values() for d in c["adev"] if d > 0]
    limits = {line["key"]: line["limit"] for line in result["lines"]}
    t0, t1 = min(taus), max(taus)
    ds_lines: list[tuple[str, list[float]]] = []
    grid = [t0 * (t1 / t0) ** (i / 40) for i in range(41)]
    if triad == "gyro":
        unit = "deg/h"
        if "gyro.arw_dpsh" in limits:
            n = limits["gyro.arw_dpsh"] * 60.0
            ds_lines.append((f"ARW limit {limits['gyro.arw_dpsh']:g} deg/√h",
                             [n / math.sqrt(t) for t in grid]))  # fmt: skip
        if "gyro.bias_instability_dph" in limits:
            b = limits["gyro.bias_instability_dph"] * _FLOOR
            ds_lines.append((f"bias instability limit {limits['gyro.bias_instability_dph']:g} "
                             "deg/h", [b] * len(grid)))  # fmt: skip
        if "gyro.rrw_dphpsh" in limits:
            k = limits["gyro.rrw_dphpsh"] / 60.0
            ds_lines.append((f"RRW limit {limits['gyro.rrw_dphpsh']:g} deg/h/√h",
                             [k * math.sqrt(t / 3.0) for t in grid]))  # fmt: skip
    else:
        unit = "µg"
        if "accel.vrw_ug_rthz" in limits:
            n = limits["accel.vrw_ug_rthz"]
            ds_lines.append((f"noise limit {n:g} µg/√Hz", [n / math.sqrt(t) for t in grid]))
        if "accel.bias_instability_ug" in limits:
            b = limits["accel.bias_instability_ug"] * _FLOOR
            ds_lines.append((f"bias instability limit {limits['accel.bias_instability_ug']:g} µg",
                             [b] * len(grid)))  # fmt: skip
    allv = devs + [v for _, ys in ds_lines for v in ys]
    lo, hi = min(allv) / 1.5, max(allv) * 1.5
    ax = _Axes((t0, t1), (lo, hi), log=True)
    for i, (axis, c) in enumerate(curves.items()):
        ax.polyline(c["taus_s"], c["adev"], _AXIS_COLOURS[i % 3])
        ax.text(c["taus_s"][-1], c["adev"][-1], axis.split("_")[1], _AXIS_COLOURS[i % 3])
    for label, ys in ds_lines:
        ax.polyline(grid, ys, "#b3261e", dash="6 4", width=1.2)
        ax.text(grid[len(grid) // 2], ys[len(grid) // 2] * 1.15, label, "#b3261e", "middle")
    return ax.svg("cluster time τ, s", f"Allan deviation, {unit}",
                  f"{triad} Allan deviation against the datasheet")  # fmt: skip


def _orientation_svg(runs: Sequence[dict[str, Any]], mean: float, limit: float | None,
                     sigma: float) -> str:  # fmt: skip
    """Headings of the runs at one orientation, about the mean of all runs, with bands."""
    d = [((r["azimuth_deg"] - mean + 180.0) % 360.0 - 180.0) * 60.0 for r in runs]
    xs = [float(r["run"]) for r in runs]
    span = max([abs(v) for v in d] + [3.0 * sigma * 60.0, (limit or 0.0) * 60.0 * 1.2, 1e-6])
    ax = _Axes((min(xs) - 1.0, max(xs) + 1.0), (-span * 1.1, span * 1.1), log=False, h=240)
    ax.band(-sigma * 60.0, sigma * 60.0, "#1f77b4")
    if limit is not None:
        ax.band(-limit * 60.0, limit * 60.0, "#1b7f3b", 0.08)
        ax.polyline([min(xs) - 1.0, max(xs) + 1.0], [limit * 60.0] * 2, "#1b7f3b", "6 4", 1.0)
        ax.polyline([min(xs) - 1.0, max(xs) + 1.0], [-limit * 60.0] * 2, "#1b7f3b", "6 4", 1.0)
    ax.polyline([min(xs) - 1.0, max(xs) + 1.0], [0.0, 0.0], "#888", width=1.0)
    ax.dots(xs, d, "#1d1d1f")
    return ax.svg(
        "run", "Δ heading, arcmin", "headings at one orientation, about the mean of all runs"
    )


def _headings(result: dict[str, Any]) -> str:
    runs = result["stages"].get("runs")
    if not runs:
        return ""
    a = [math.radians(r["azimuth_deg"]) for r in runs]
    mean = math.degrees(math.atan2(sum(map(math.sin, a)), sum(map(math.cos, a)))) % 360.0
    line = next((x for x in result["lines"] if x["key"] == "north_finding.sigma_deg"), None)
    limit = line["limit"] if line else None
    plan = result.get("plan") or result["datasheet"]
    how = f", {escape(plan['from'])}" if "from" in plan else ""
    parts = [
        "<h2>North finding</h2>",
        f"<p>{len(runs)} runs of the plan "
        f"{escape(', '.join(f'{p:g}' for p in plan['positions_deg']))} deg "
        f"({plan['window_s']:g} s windows{how}) at {runs[0]['latitude_deg']:g} deg; "
        f"mean heading {heading_text(mean, 4)} deg. Blue band: ±1σ of the runs at that orientation; green "
        "dashed: the datasheet's ±1σ limit.</p>",
    ]
    measured = _num(line["measured"] if line else None)
    if "predicted_sigma_deg" in plan:
        parts.append(
            f"<p>Repeatability, 1σ: predicted {plan['predicted_sigma_deg']:.4g} deg by the "
            f"planner for this plan from {escape(plan['predicted_from'])}; measured "
            f"{measured} deg.</p>"
        )
    pred = result.get("prediction")
    if pred:
        parts.append(
            f"<p>The planner predicts σ {pred['sigma_deg']:.4g} deg for this plan from "
            f"{escape(pred['from'])} (measured: {measured} deg).</p>"
        )
    by: dict[float, list[dict[str, Any]]] = {}
    for r in runs:
        by.setdefault(r["orientation_deg"], []).append(r)
    for offset, group in sorted(by.items()):
        d = [(r["azimuth_deg"] - mean + 180.0) % 360.0 - 180.0 for r in group]
        m = sum(d) / len(d)
        s = math.sqrt(sum((v - m) ** 2 for v in d) / (len(d) - 1)) if len(d) > 1 else 0.0
        parts.append(
            f"<h3>Table orientation {offset:g} deg: {len(group)} runs, mean {m * 60:+.3f} "
            f"arcmin, σ {s * 60:.3f} arcmin</h3>"
        )
        parts.append(_orientation_svg(group, mean, limit, s))
        rows = "".join(
            f"<tr><td>{r['run']}</td><td class=num>{heading_text(r['azimuth_deg'], 4)}</td>"
            f"<td class=num>{_num(r['sigma_deg'])}</td><td>{'yes' if r['consistent'] else 'NO'}"
            f"</td><td class=num>{_num(r.get('error_deg'))}</td>"
            f"<td><code>{escape(r['recording'])}</code></td></tr>"
            for r in group
        )
        parts.append(
            "<table><tr><th>run</th><th>azimuth, deg</th><th>σ of the run, deg</th>"
            "<th>consistent</th><th>error against the simulated truth, deg</th>"
            f"<th>recording</th></tr>{rows}</table>"
        )
    return "\n".join(parts)


def html_report(result: dict[str, Any]) -> str:
    """The report as one self-contained HTML page."""
    verdict = result["verdict"]
    dev = result["device"] or {}
    identity = (
        ", ".join(f"{escape(str(k))} {escape(str(v))}" for k, v in dev.items())
        if dev
        else "not identified"
    )
    counts = {v: sum(x["verdict"] == v for x in result["lines"]) for v in _COLOURS}
    body = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>Acceptance {escape(verdict)}: {escape(result['datasheet']['name'])}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>Acceptance test: {escape(result['datasheet']['name'])}</h1>",
        f'<p><span class="verdict" style="background:{_COLOURS[verdict]}">{escape(verdict)}'
        f"</span> {counts['PASS']} passed, {counts['FAIL']} failed, "
        f"{counts['NOT RESOLVED']} not resolved of {len(result['lines'])} lines</p>",
        "<table>",
        f"<tr><th>unit</th><td>{identity}</td></tr>",
        f"<tr><th>software</th><td>northfinder {escape(result['northfinder_version'])}</td></tr>",
        f"<tr><th>command</th><td><code>{escape(result['command_line'])}</code></td></tr>",
        f"<tr><th>datasheet</th><td><code>{escape(result['datasheet']['source'])}</code></td></tr>",
        f"<tr><th>created</th><td>{escape(result['created_utc'])}</td></tr>",
    ]
    if result.get("seed") is not None:
        body.append(f"<tr><th>simulated, seed</th><td>{result['seed']}</td></tr>")
    body += [
        "</table>",
        "<h2>Datasheet lines</h2>",
        "<p class=small>PASS: the interval's upper end is within the limit; FAIL: its lower end "
        "is beyond it; NOT RESOLVED: the data cannot decide (the line says what would). Each "
        "end of a 90 % interval is a one-sided 95 % bound.</p>",
        _lines_table(result["lines"]),
    ]
    if "allan" in result:
        body.append("<h2>Static recording: Allan deviation</h2>")
        seconds = result["stages"]["static"]["seconds"]
        body.append(
            f"<p>{seconds:g} s still (<code>static.npz</code>; its length "
            f"{escape(str(result['stages']['static'].get('length_from', '--static-s')))}); "
            "overlapping Allan deviation per "
            "axis; dashed red: the datasheet's limits as Allan deviation lines (IEEE 952).</p>"
        )
        body.append(_allan_svg(result, "gyro"))
        body.append(_allan_svg(result, "accel"))
    body.append(_headings(result))
    stages = result["stages"]
    if "conformance" in stages:
        c = stages["conformance"]
        body.append(
            f"<h2>Conformance</h2><p>{_num(c['counts'].get('pass'))} passed, "
            f"{_num(c['counts'].get('fail'))} failed, {_num(c['counts'].get('skip'))} skipped "
            f"(<code>{escape(c['file'])}</code>, <code>{escape(c['junit'])}</code>).</p>"
        )
    body.append(
        f"<p class=small>Time to READY after RESET: {stages['ready']['time_to_ready_s']:.1f} s "
        "(device clock). Every stage's data is in the output folder: <code>northfinder solve "
        "run_01.npz</code>, <code>northfinder calibrate static.npz</code>.</p>"
    )
    body.append("</body></html>")
    return "\n".join(body) + "\n"


def junit_xml(result: dict[str, Any]) -> str:
    """JUnit XML: one test case per datasheet line (FAIL a failure, NOT RESOLVED skipped)."""
    lines = result["lines"]
    suite = ET.Element(
        "testsuite",
        name=f"accept {result['datasheet']['name']}",
        tests=str(len(lines)),
        failures=str(sum(x["verdict"] == "FAIL" for x in lines)),
        skipped=str(sum(x["verdict"] == "NOT RESOLVED" for x in lines)),
        errors="0",
    )
    for line in lines:
        case = ET.SubElement(suite, "testcase", classname="accept", name=line["key"])
        text = (
            f"limit {line['limit']} {line['unit']}, measured {line['measured']}, interval "
            f"{line['low']} to {line['high']}: {line['note']}"
        )
        if line["verdict"] == "FAIL":
            ET.SubElement(case, "failure", message=text)
        elif line["verdict"] == "NOT RESOLVED":
            ET.SubElement(case, "skipped", message=f"NOT RESOLVED: {text}")
        else:
            ET.SubElement(case, "system-out").text = text
    ET.indent(suite)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(suite, "unicode") + "\n"


def summary_html(summary: dict[str, Any]) -> str:
    """The summary page of ``accept --batch``: the worst verdict, and a row per unit with its
    verdict, its counts and a link to its report (one self-contained page, as the report)."""
    colours = {**_COLOURS, "ERROR": _ERROR_COLOUR}
    verdict = summary["verdict"]
    rows = []
    for r in summary["units"]:
        tag = (
            f'<span class="tag" style="color:{colours[r["verdict"]]}">{escape(r["verdict"])}</span>'
        )
        if r["verdict"] == "ERROR":
            what = f"<td colspan=3 class=small>{escape(r['error'])}</td>"
            name = escape(r["name"])
        else:
            counts = ", ".join(f"{n} {escape(v)}" for v, n in r["counts"].items() if n)
            what = (
                f"<td class=small>{counts}</td><td class=num>{_num(r['sigma_deg'])}</td>"
                f"<td class=num>{_num(r['predicted_sigma_deg'])}</td>"
            )
            name = f'<a href="{escape(r["report"])}">{escape(r["name"])}</a>'
        rows.append(
            f"<tr><td>{name}</td><td><code>{escape(r['link'])}</code></td><td>{tag}</td>{what}</tr>"
        )
    done = (
        ""
        if summary["done"] == summary["total"]
        else (f" ({summary['done']} of {summary['total']} units done)")
    )
    counts = ", ".join(f"{n} {escape(v)}" for v, n in summary["counts"].items() if n)
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>Acceptance of a batch {escape(verdict)}: "
            f"{escape(summary['datasheet']['name'])}</title>",
            f"<style>{_CSS}</style></head><body>",
            f"<h1>Acceptance of {summary['total']} units: "
            f"{escape(summary['datasheet']['name'])}</h1>",
            f'<p><span class="verdict" style="background:{colours[verdict]}">{escape(verdict)}'
            f"</span> the worst verdict{done}; units: {counts}</p>",
            f"<p class=small>Datasheet <code>{escape(summary['datasheet']['source'])}</code>, "
            f"units <code>{escape(summary['units_file'])}</code>.</p>",
            "<table><tr><th>unit</th><th>link</th><th>verdict</th><th>lines</th>"
            "<th>repeatability, deg</th><th>predicted, deg</th></tr>",
            *rows,
            "</table></body></html>",
            "",
        ]
    )
