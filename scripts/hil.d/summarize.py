"""Host side of the HIL runner: read the output directory, print a summary, write summary.json.

    python3 summarize.py <out-dir>

Standard library only (runs with the host's python3). Exit status: 0 when the guest wrote
status "pass" and every step's rc is 0; 1 when a step failed; 2 when the run never produced
a status (setup failure, VM did not boot, whole-run timeout); 3 when no step failed but one or
more were not judged (status "not judged: ...", each such step's rc 3, its reasons printed).
"""

from __future__ import annotations

import json
import os
import sys


def read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return None


def read_kv(path: str) -> dict:
    text = read(path) or ""
    return dict(line.split("=", 1) for line in text.splitlines() if "=" in line)


def num(text: str | None) -> float | None:
    try:
        return round(float(text), 3) if text is not None else None
    except ValueError:
        return None


def main(out: str) -> int:
    timings = read_kv(os.path.join(out, "timings.env"))
    guest = read_kv(os.path.join(out, "guest-started"))
    status = read(os.path.join(out, "status"))
    summary = collect(out, timings, guest, status)
    verdict, rc = verdict_of(status, summary["steps"])
    summary["verdict"] = verdict
    summary["exit_status"] = rc
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2)
        f.write("\n")
    print_summary(out, summary, timings)
    return rc


def collect(out: str, timings: dict, guest: dict, status: str | None) -> dict:
    """The summary of a run: its machine, timings and steps with their results."""
    summary: dict = {
        "mode": timings.get("mode"),
        "mode_reason": timings.get("mode_reason"),
        "kernel": guest.get("kernel") or timings.get("kernel"),
        "kernel_image": timings.get("kernel"),
        "guest_cpus": int(guest["cpus"]) if guest.get("cpus", "").isdigit() else None,
        "status": status,
        "runner_rc": num(timings.get("runner_rc")),
        "timings_s": {
            "install": num(timings.get("install_seconds")),
            "project_venv": num(timings.get("venv_seconds")),
            "vm_boot_to_guest_script": num(timings.get("boot_seconds")),
            "guest_uptime_at_script_start": num(guest.get("uptime")),
            "vm_total": num(timings.get("vm_seconds")),
            "total": num(timings.get("total_seconds")),
        },
        "steps": [],
    }
    steps_tsv = read(os.path.join(out, "steps.tsv")) or ""
    for line in steps_tsv.splitlines():
        name, rc, secs = ([*line.split("\t"), "", "", ""])[:3]
        step = {
            "name": name,
            "rc": int(rc) if rc.lstrip("-").isdigit() else None,
            "seconds": num(secs),
        }
        res = read(os.path.join(out, "steps", name, "result.json"))
        if res:
            try:
                step["result"] = json.loads(res)
            except json.JSONDecodeError as e:
                step["result_error"] = f"result.json is not JSON: {e}"
        summary["steps"].append(step)
    results = {s["name"]: s.get("result") or {} for s in summary["steps"]}
    rehearsal = results.get("rehearsal", {})
    # The headline figures, also found in the steps' results.
    summary["sample_arrival_jitter_ms"] = rehearsal.get("sample_arrival_jitter_ms")
    summary["conformance_counted"] = rehearsal.get("conformance_counted")
    summary["report_only"] = rehearsal.get("report_only")

    return summary


def verdict_of(status: str | None, steps: list[dict]) -> tuple[str, int]:
    """The run's verdict and exit status (see the module doc)."""
    # A retried step's first attempt (<name>.attempt1) is in the summary, not in the verdict: the
    # verdict is the last attempt's (guest.sh makes a judged failure followed by "not judged" a
    # failure).
    final = [s for s in steps if not s["name"].endswith(".attempt1")]
    if status is None:
        verdict, rc = "ERROR (no status from the guest: see vm.log / guest.log)", 2
    elif status == "pass" and all(s["rc"] == 0 for s in final):
        verdict, rc = "PASS", 0
    elif status.startswith("not judged") and all(s["rc"] in (0, 3) for s in final):
        verdict, rc = (
            f"NOT JUDGED ({status[len('not judged: ') :]}: the machine could not carry it)",
            3,
        )
    elif status.startswith("fail setup") or status.startswith("fail no"):
        verdict, rc = f"ERROR ({status})", 2
    else:
        verdict, rc = f"FAIL ({status})", 1
    return verdict, rc


def print_summary(out: str, summary: dict, timings: dict) -> None:
    t = summary["timings_s"]
    fmt = lambda v: "-" if v is None else f"{v:.1f} s"  # noqa: E731
    print(
        f"hil: mode {summary['mode']} ({summary['mode_reason']}), kernel {summary['kernel']}, "
        f"{summary['guest_cpus']} CPU(s)"
    )
    print(
        f"hil: install {fmt(t['install'])}, project venv {fmt(t['project_venv'])}, "
        f"boot to guest script {fmt(t['vm_boot_to_guest_script'])}, "
        f"VM total {fmt(t['vm_total'])}, run total {fmt(t['total'])}"
    )
    for s in summary["steps"]:
        r = s.get("result") or {}
        print(step_line(s, r, fmt))
        if r.get("not_judged_because"):
            print(f"hil:   NOT JUDGED: {r['not_judged_because']}")
        elif r.get("why_judged"):
            print(f"hil:   {r['why_judged']}")
        if s["rc"] != 0:
            # A failed or timed-out step: its last words, so a CI log says what happened.
            tail = (read(os.path.join(out, "steps", s["name"], "log")) or "").splitlines()[-25:]
            for text in tail:
                print(f"hil:   | {text[:300]}")
        for name, item in (
            (r.get("report_only") or {}) if s["name"] == "rehearsal" else {}
        ).items():
            print(f"hil:   reported, not counted: {name}: {item.get('result')}")
    j = summary["sample_arrival_jitter_ms"]
    if j:
        print(
            f"hil: sample arrival jitter on {timings.get('can_if', 'vcan0')}: p50 {j.get('p50')} ms, p99 {j.get('p99')} ms"
        )
    print(f"hil: {summary['verdict']}  (summary: {os.path.join(out, 'summary.json')})")


def step_line(s: dict, r: dict, fmt) -> str:
    """The one line of a step: its status and time, and the figures of its result."""
    line = f"hil: step {s['name']}: rc {s['rc']} in {fmt(s['seconds'])}"
    if s["name"] == "smoke" and r:
        rx = r.get("receiver", {})
        line += (
            f"; sent {r.get('frames_sent')} received {r.get('frames_received')} "
            f"lost {r.get('frames_lost')} candump {r.get('candump_data_frames')} "
            f"at {r.get('achieved_rate_hz')} Hz; inter-arrival p50 "
            f"{rx.get('interarrival', {}).get('p50_us')} us p99 "
            f"{rx.get('interarrival', {}).get('p99_us')} us; jitter p50 "
            f"{rx.get('jitter', {}).get('p50_us')} us p99 {rx.get('jitter', {}).get('p99_us')} us"
        )
    if s["name"] == "probe" and r:
        line += (
            f"; 2e6-iteration loop {r.get('python_loop_2e6_s')} s, time.monotonic "
            f"{r.get('monotonic_call_us')} us, SocketCAN send {r.get('socketcan_send_ms')} ms"
        )
    if s["name"] == "driver" and r:
        line += (
            f"; driver tests on SocketCAN: {r.get('tests')} run, {r.get('failures')} failed, "
            f"{r.get('errors')} errors, {r.get('skipped')} skipped"
        )
    if s["name"] == "interrupt" and r:
        if "tests" in r:
            line += f"; tests {r.get('tests')} run, {r.get('failures')} failed"
        for row in r.get("rows") or []:
            line += (
                f"; {row['link']} {row['signal']}: {row['at_rest']}/{row['runs']} at rest, "
                f"{row['caught_moving']}/{row['runs']} caught moving, {row['rotating']} "
                f"left ROTATING, exit {row['exit_s_median']:.2f} s (median)"
            )
    if s["name"] == "rehearsal" and r:
        line += rehearsal_figures(r)
    return line


def rehearsal_figures(r: dict) -> str:
    """The rehearsal's figures: the find, the spin, the candump, the conformance, the machine."""
    line = ""
    err, sigma = r.get("azimuth_error_deg"), r.get("sigma_deg")
    if err is not None and sigma is not None:
        line += f"; azimuth error {err:+.3f} deg, sigma {sigma:.3f} deg"
    spin = r.get("spin") or {}
    if spin:
        line += (
            f"; spin {spin.get('rate_dps', 0):+.2f} deg/s, {spin.get('turns')} turns: "
            f"azimuth error {spin['azimuth_error_deg']:+.3f} deg, sigma "
            f"{spin['sigma_deg']:.3f} deg = {spin['sigma_over_bound']:.2f} x the "
            f"white-noise bound {spin['bound_deg']:.3f} deg"
        )
    checks = r.get("spin_conformance") or {}
    if checks:
        line += "; " + ", ".join(f"{n} {st}" for n, st in sorted(checks.items()))
    line += (
        f"; candump {r.get('frames')} frames, {r.get('unknown_frames')} unknown, "
        f"{r.get('undecodable_frames')} undecodable, {r.get('ticks_lost')} ticks lost"
    )
    c = r.get("conformance_counted") or {}
    if c:
        line += f"; conformance counted {c.get('passed')}/{c.get('checks')} passed"
        if c.get("failed"):
            line += f" (failed: {', '.join(c['failed'])})"
    if r.get("machine_cpu_busy_percent") is not None:
        line += f"; guest CPU {r['machine_cpu_busy_percent']} % busy"
    stalls = r.get("machine_stalls")  # a message instead when the monitor failed
    clock = stalls.get("clock_call_us") if isinstance(stalls, dict) else None
    if clock and clock.get("p50") is not None:
        line += f"; clock read {clock['p50']} us (p90 {clock['p90']})"
    return line


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
