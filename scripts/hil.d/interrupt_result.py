"""The interrupt step's result: the JUnit report of tests/test_interrupt.py and the figures of
``bench_robustness.py --sections interrupt`` (its ``--json``), judged.

    python interrupt_result.py <step-out-dir>

Writes ``result.json`` (tests, failures; runs and runs at rest in all; one row per link and
signal: runs, caught moving, exit status as stated, at rest, ROTATING, streaming, median exit
seconds, errors) and exits 0 when every test passed and every run of every row left the unit at
rest (READY or SETTLING, the stream off) with no run in error (a host that did not exit after
the signal, or a simulator that died), else 1.
"""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROW_KEYS = ("link", "mode", "signal", "runs", "caught_moving", "status_ok", "at_rest", "rotating",
            "streaming", "exit_s_median", "states")  # fmt: skip


def judge(junit: Path, bench: Path) -> tuple[dict, list[str]]:
    """(result, what failed)."""
    failed: list[str] = []
    try:
        suite = ET.parse(junit).getroot().find("testsuite")
        if suite is None:
            raise AttributeError("no testsuite element")
        res: dict = {k: int(suite.get(k, 0)) for k in ("tests", "failures", "errors", "skipped")}
        if res["failures"] or res["errors"]:
            failed.append(f"tests: {res['failures']} failed, {res['errors']} errors")
    except (OSError, ET.ParseError, AttributeError) as exc:
        res = {"error": f"no JUnit report: {exc}"}
        failed.append(res["error"])
    try:
        rows = json.loads(bench.read_text())["interrupt"]["rows"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        res["bench_error"] = repr(exc)
        failed.append(f"no figures from the bench: {exc!r}")
        return res, failed
    res["runs"] = sum(r["runs"] for r in rows)
    res["at_rest"] = sum(r["at_rest"] for r in rows)
    res["rows"] = [{k: r.get(k) for k in ROW_KEYS} | {"errors": len(r["errors"])} for r in rows]
    for r in rows:
        where = f"{r['link']} {r.get('mode', 'move')} {r['signal']}"
        if r["at_rest"] < r["runs"]:
            failed.append(f"{where}: {r['runs'] - r['at_rest']} of {r['runs']} runs not at rest")
        if r["errors"]:
            failed.append(f"{where}: {len(r['errors'])} runs in error: {r['errors'][0][:300]}")
    if not rows:
        failed.append("the bench ran no link")
    return res, failed


def main(out: str) -> int:
    folder = Path(out)
    res, failed = judge(folder / "junit.xml", folder / "bench.json")
    res["failed"] = failed
    (folder / "result.json").write_text(json.dumps(res))
    for line in failed:
        print(f"interrupt: FAIL: {line}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
