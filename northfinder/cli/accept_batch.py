"""``northfinder accept --datasheet FILE --batch UNITS.TOML -o DIR``: several units against one
datasheet, one after the other: each unit's acceptance in ``DIR/NAME`` (as ``accept -o``
writes it), and ``DIR/index.html`` (one self-contained page: each unit's verdict and a link to
its report) with ``DIR/summary.json``. The exit status is the worst: a unit that could not be
tested (its link failed: ERROR) before a FAIL, before a NOT RESOLVED, before a PASS.

The units file (docs/accept.md) is a list of ``[[unit]]`` tables, each a ``name`` (its folder)
and its link: ``sensor`` and/or ``seed`` for the embedded simulator, or ``serial`` for a unit
on a serial port. A relative sensor file is read from the units file's folder.
"""

from __future__ import annotations

import argparse
import copy
import re
import sys
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from northfinder.cli.argtypes import MAX_SEED
from northfinder.cli.exits import EXIT_NOT_RESOLVED, EXIT_RUNTIME, exit_status
from northfinder.cli.links import bus_given
from northfinder.cli.output import dumps, say
from northfinder.cli.simulated import load_sensor
from northfinder.firmware_sim.errors import SimConfigError
from northfinder.firmware_sim.sensors import DEFAULT_SENSOR
from northfinder.host.errors import HostConfigError

__all__ = ["UNIT_KEYS", "load_units", "run_batch"]

#: The keys of a ``[[unit]]`` table.
UNIT_KEYS = ("name", "sensor", "seed", "serial")
#: Worst first: the verdict of the batch is the first of these any unit has.
WORST_FIRST = ("ERROR", "FAIL", "NOT RESOLVED", "PASS")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


#: One unit's acceptance (``accept.accept_unit``) and the check of its arguments
#: (``accept.check_unit_arguments``), handed in by the command (it imports this module).
AcceptUnit = Callable[[argparse.Namespace, Any, Path], dict[str, Any]]
CheckUnit = Callable[[argparse.Namespace, Any], Any]


def verdict_status(verdict: str) -> int:
    """The exit status of a verdict: 0 PASS, 1 FAIL, 4 NOT RESOLVED."""
    if verdict == "FAIL":
        return EXIT_RUNTIME
    return EXIT_NOT_RESOLVED if verdict == "NOT RESOLVED" else 0


def stage_line(args: argparse.Namespace, text: str) -> None:
    """One line per stage on stderr (stdout holds the result alone)."""
    print(f"accept: {text}", file=sys.stderr, flush=True)


def _bad(path: Path, text: str) -> HostConfigError:
    return HostConfigError(f"--batch {path}: {text}")


def load_units(path: str | Path) -> list[dict[str, Any]]:
    """The units of a units file, each checked: a unique folder name and one link.

    Raises
    ------
    HostConfigError
        One line naming the file, the unit and what is wrong.
    """
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise _bad(p, f"cannot read ({exc})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise _bad(p, f"not a TOML file ({exc})") from exc
    units = data.get("unit")
    if set(data) - {"unit"} or not isinstance(units, list) or not units:
        raise _bad(p, 'give the units as [[unit]] tables, each with name = "..." and its link')
    seen: set[str] = set()
    for i, unit in enumerate(units, 1):
        name = unit.get("name")
        where = f"unit {i}" if not isinstance(name, str) else f"unit {name!r}"
        unknown = sorted(set(unit) - set(UNIT_KEYS))
        if unknown:
            raise _bad(
                p, f"{where}: unknown key {unknown[0]!r}; a unit takes {', '.join(UNIT_KEYS)}"
            )
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise _bad(p, f"{where}: name must be a folder name (letters, digits, . _ -)")
        if name in seen:
            raise _bad(p, f"{where}: named twice (each unit has a folder of its own)")
        seen.add(name)
        _check_link(p, where, unit)
    return units


def _check_link(path: Path, where: str, unit: dict[str, Any]) -> None:
    sim = "sensor" in unit or "seed" in unit
    if sim == ("serial" in unit):
        raise _bad(
            path,
            f"{where}: give its link: sensor and/or seed (the embedded simulator) or serial "
            "(a port), not both",
        )
    seed = unit.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise _bad(path, f"{where}: seed = {seed!r} must be a whole number 0 to {MAX_SEED}")
    for key in ("sensor", "serial"):
        if key in unit and not (isinstance(unit[key], str) and unit[key].strip()):
            raise _bad(path, f"{where}: {key} = {unit[key]!r} must be a non-empty string")


def _refuse_links(args: argparse.Namespace) -> None:
    """The links are the units file's: a link (or --junit) on the command line is refused."""
    for flag, given in (
        ("--sim", args.sim), ("--serial", args.serial), ("--sensor", args.sensor),
        ("--seed", args.seed is not None), ("-i/-c", bus_given(args)), ("--junit", args.junit),
    ):  # fmt: skip
        if given:
            raise HostConfigError(
                f"{flag}: not with --batch (each unit's link is in {args.batch}; each unit's "
                "JUnit file is its folder's)"
                if flag == "--junit"
                else f"{flag}: not with --batch (each unit's link is in {args.batch})"
            )


def _unit_args(args: argparse.Namespace, unit: dict[str, Any], out: Path) -> argparse.Namespace:
    a = copy.copy(args)
    a.batch, a.json, a.output = None, False, str(out / unit["name"])
    sensor = unit.get("sensor")
    if sensor is not None and sensor.endswith(".toml") and not Path(sensor).is_absolute():
        sensor = str(Path(args.batch).parent / sensor)
    if "serial" in unit:
        a.serial = unit["serial"]
    else:
        a.sim, a.sensor, a.seed = True, sensor, unit.get("seed")
    return a


def _link_text(unit: dict[str, Any]) -> str:
    if "serial" in unit:
        return f"serial {unit['serial']}"
    return ", ".join(f"{k} {unit[k]}" for k in ("sensor", "seed") if k in unit)


def run_batch(
    args: argparse.Namespace,
    ds: Any,
    out: Path,
    *,
    accept_unit: AcceptUnit,
    check_unit_arguments: CheckUnit,
) -> int:
    """Every unit of ``--batch`` checked first, then accepted in turn; the summary written
    after each (a stopped batch keeps the summary so far)."""
    _refuse_links(args)
    units = load_units(args.batch)
    prepared = []
    for unit in units:
        a = _unit_args(args, unit, out)
        if Path(a.output).is_file():
            raise HostConfigError(f"-o {a.output}: is a file; give a folder")
        try:
            if a.sim:  # the sensor read now, not when the unit's turn comes
                load_sensor(a.sensor or DEFAULT_SENSOR)
            check_unit_arguments(copy.copy(a), ds)
        except (HostConfigError, SimConfigError) as exc:
            raise _bad(Path(args.batch), f"unit {unit['name']!r}: {exc}") from exc
        prepared.append((unit, a))
    out.mkdir(exist_ok=True)
    rows: list[dict[str, Any]] = []
    for i, (unit, a) in enumerate(prepared, 1):
        stage_line(args, f"unit {unit['name']} ({i}/{len(prepared)}): {_link_text(unit)}")
        rows.append(_accept_one(a, ds, unit, accept_unit))
        summary = _summary(args, ds, rows, len(prepared))
        _write_summary(out, summary)
    say(dumps(summary) if args.json else _summary_text(summary, out))
    return summary["status"]


def _accept_one(
    a: argparse.Namespace, ds: Any, unit: dict[str, Any], accept_unit: AcceptUnit
) -> dict[str, Any]:
    """One unit's row of the summary; a unit whose link or run failed is an ERROR row."""
    row: dict[str, Any] = {"name": unit["name"], "link": _link_text(unit)}
    try:
        result = accept_unit(a, ds, Path(a.output))
    except Exception as exc:
        status = exit_status(exc)
        if status is None:
            raise  # a bug of the program: not a unit's verdict
        text = "; ".join(s.strip() for s in str(exc).splitlines() if s.strip())
        stage_line(a, f"unit {unit['name']}: error: {text}")
        return {**row, "verdict": "ERROR", "status": status, "error": text or type(exc).__name__}
    counts = {v: sum(x["verdict"] == v for x in result["lines"]) for v in WORST_FIRST[1:]}
    plan = result.get("plan") or {}
    sigma = next((x for x in result["lines"] if x["key"] == "north_finding.sigma_deg"), None)
    return {
        **row,
        "verdict": result["verdict"],
        "status": verdict_status(result["verdict"]),
        "report": f"{unit['name']}/report.html",
        "counts": counts,
        "device": result.get("device"),
        "seed": result.get("seed"),
        "sigma_deg": None if sigma is None else sigma["measured"],
        "predicted_sigma_deg": plan.get("predicted_sigma_deg"),
        "wall_s": result["wall_s"],
    }


def _summary(
    args: argparse.Namespace, ds: Any, rows: list[dict[str, Any]], total: int
) -> dict[str, Any]:
    worst = min(rows, key=lambda r: WORST_FIRST.index(r["verdict"]))
    status = worst["status"] if worst["verdict"] == "ERROR" else verdict_status(worst["verdict"])
    return {
        "kind": "accept-batch",
        "verdict": worst["verdict"],
        "status": status,
        "datasheet": {"name": ds.name, "source": ds.source},
        "units_file": str(args.batch),
        "units": rows,
        "done": len(rows),
        "total": total,
        "counts": {v: sum(r["verdict"] == v for r in rows) for v in WORST_FIRST},
    }


def _write_summary(out: Path, summary: dict[str, Any]) -> None:
    from northfinder.host.acceptance_report import summary_html

    (out / "summary.json").write_text(dumps(summary) + "\n")
    (out / "index.html").write_text(summary_html(summary))


def _summary_text(summary: dict[str, Any], out: Path) -> str:
    rows = [
        f"northfinder accept --batch: {summary['verdict']} ({summary['datasheet']['name']}, "
        f"{summary['total']} unit{'' if summary['total'] == 1 else 's'})"
    ]
    for r in summary["units"]:
        what = r.get("error") or r["report"]
        rows.append(f"  {r['verdict']:<12} {r['name']:<16} {r['link']:<40} {what}")
    rows.append(f"summary: {out / 'index.html'}")
    return "\n".join(rows)
