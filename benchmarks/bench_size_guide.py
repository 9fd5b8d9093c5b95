"""The size guide: hours of 200 Hz data recorded in virtual time, then recorded, solved, calibrated
and dumped, each command timed and its peak memory measured.

For each length H (hours, ``--hours``) one ``northfinder record --sim`` in virtual time writes
the plan's windows as NPZ and every frame of the session as BLF (``--can-log``): 2 H windows of
1800 s at 0, 90, 180, 270 deg in turn (no warm-up), 200 Hz, so H hours of samples. For the
lengths in ``--text-hours`` the BLF is written again frame by frame as ASC and candump ``.log``
by python-can's :class:`can.Logger` (the same frames). Then, one process at a time:

- the floor: a process that iterates ``can.LogReader(FILE)`` and does nothing else (for NPZ:
  ``numpy.load`` of every array);
- ``northfinder solve FILE --latitude 34``;
- ``northfinder calibrate FILE``;
- ``northfinder dump FILE`` (CAN logs; its lines to /dev/null).

Printed as a Markdown table: the file's size, each command's wall time, CPU time (user +
system), peak resident memory of the whole process (its ``ru_maxrss``, read by a wrapper process
of its own) and CPU time as a multiple of the floor's (the steadier figure on a shared machine).
Files are kept in ``--dir`` and reused when present (with the record's figures, in a
``.json`` beside them).

``--formats`` picks the files measured (default ``npz blf asc log``; the text formats
only for the lengths in ``--text-hours``), so that a day runs as NPZ and BLF alone:
``--hours 24 --text-hours --formats npz blf`` (about 1.1 GB of records, 24 h has no limit of
its own). The disk space free in ``--dir`` and what the records of each length take (measured,
or estimated before they are made from 16 MB of NPZ and 29 MB of BLF an hour, 191 MB of ASC and
142 MB of ``.log``) are printed first, and a length whose records would not fit is refused.
``csv`` (asked for only) adds the recording as CSV, written by a second ``record`` of the same
seed (the same samples; its floor parses every row with :mod:`csv`, 103 MB an hour).

Run: ``.venv/bin/python benchmarks/bench_size_guide.py [--hours 1 6] [--text-hours 1]
[--dir DIR] [--skip dump] [--formats npz blf]``.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can

WINDOW_S = 1800
ANGLES = (0, 90, 180, 270)
_CLI = "import sys\nfrom northfinder.cli import main\nsys.exit(main())\n"
_FLOOR_LOG = "import can, sys\nfor _ in can.LogReader(sys.argv[1]):\n    pass\n"
_FLOOR_CSV = "import csv, sys\nfor _ in csv.reader(open(sys.argv[1])):\n    pass\n"
_FLOOR_NPZ = (
    "import numpy as np, sys\n"
    "with np.load(sys.argv[1]) as d:\n"
    "    arrays = [d[k] for k in d.files]\n"
)


def northfinder(*args: str) -> list[str]:
    return [sys.executable, "-c", _CLI, *args]


def measure(cmd: list[str]) -> tuple[float, float, float, int]:
    """Wall time (s), CPU time (s: user + system), peak resident memory (MB: ``ru_maxrss`` of
    the children, this process's only child) and exit status of the command."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, done.returncode


def isolated(cmd: list[str]) -> tuple[float, float, float, int]:
    """:func:`measure` in a process of its own, so that the peak is this command's alone
    (``RUSAGE_CHILDREN`` keeps the largest peak of any child)."""
    code = (
        "import json, sys\n"
        "sys.path.insert(0, sys.argv[1])\n"
        "from bench_size_guide import measure\n"
        "print(json.dumps(measure(json.loads(sys.argv[2]))))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), json.dumps(cmd)],
        capture_output=True,
        text=True,
        check=True,
    )
    wall, cpu, peak, status = json.loads(out.stdout)
    return float(wall), float(cpu), float(peak), int(status)


def _recorded(
    hours: int, made: list[Path], figures: Path, outputs: list[str], what: str
) -> tuple[float, float, float, int]:
    """The figures of ``record`` of ``hours`` of data to ``outputs`` (run once: the files
    ``made`` and the ``figures`` kept)."""
    if not (all(p.exists() for p in made) and figures.exists()):
        positions = ",".join(str(ANGLES[i % len(ANGLES)]) for i in range(2 * hours))
        cmd = northfinder(
            "record", "--sim", "--seed", "1", "--warmup", "0", "--positions", positions,
            "--window", str(WINDOW_S), *outputs,
        )  # fmt: skip
        measured = isolated(cmd)
        if measured[3] != 0:
            raise SystemExit(f"record of {hours} h{what} failed (exit {measured[3]})")
        figures.write_text(json.dumps(measured))
    wall, cpu, peak, status = json.loads(figures.read_text())
    return float(wall), float(cpu), float(peak), int(status)


def make_csv(hours: int, d: Path) -> tuple[Path, tuple[float, float, float, int]]:
    """The CSV recording of ``hours`` of data (the NPZ's samples), and its record's figures."""
    path = d / f"rec{hours}h.csv"
    return path, _recorded(hours, [path], d / f"rec{hours}h.csv.json", [str(path)], " as CSV")


def make_record(hours: int, d: Path) -> tuple[Path, Path, tuple[float, float, float, int]]:
    """The NPZ and BLF of ``hours`` of data, and the record command's figures."""
    npz, blf = d / f"rec{hours}h.npz", d / f"rec{hours}h.blf"
    outputs = ["--can-log", str(blf), str(npz)]
    return npz, blf, _recorded(hours, [npz, blf], d / f"rec{hours}h.json", outputs, "")


def as_text(blf: Path, suffix: str) -> Path:
    """The BLF's frames written again by python-can in the format of ``suffix``."""
    out = blf.with_suffix(suffix)
    if not out.exists():
        part = out.with_name(out.stem + ".making" + suffix)
        with can.LogReader(str(blf)) as reader, can.Logger(str(part)) as writer:
            for msg in reader:
                writer.on_message_received(msg)
        part.replace(out)
    return out


#: Bytes a record takes per hour of 200 Hz data, by format (the size guide, measured at 1 h).
MB_PER_HOUR = {"npz": 16, "blf": 29, "asc": 191, "log": 142, "csv": 103}


def disk_check(d: Path, hours: list[int], text_hours: list[int], formats: list[str]) -> None:
    """Print the space free in ``d`` and what the records will take; refuse what cannot fit."""
    free = shutil.disk_usage(d).free / 1e6
    need = 0.0
    for h in hours:
        for fmt in MB_PER_HOUR:
            text = fmt in ("asc", "log")
            wanted = fmt in formats and (not text or h in text_hours)
            path = d / f"rec{h}h.{fmt}"
            if (wanted or fmt in ("npz", "blf")) and not path.exists():
                need += MB_PER_HOUR[fmt] * h  # the NPZ and BLF are always made
    used = sum(p.stat().st_size for p in d.glob("rec*h.*")) / 1e6
    print(f"disk: {free:.0f} MB free in {d}; records there {used:.0f} MB; to be made about "
          f"{need:.0f} MB", flush=True)  # fmt: skip
    if need > 0.9 * free:
        raise SystemExit(f"not enough disk in {d} for the records ({need:.0f} MB of {free:.0f})")


def commands(path: Path, skip: set[str]) -> list[tuple[str, list[str]]]:
    """The floor and the commands measured on ``path``."""
    log = path.suffix not in (".npz", ".csv")
    floor = {".npz": _FLOOR_NPZ, ".csv": _FLOOR_CSV}.get(path.suffix, _FLOOR_LOG)
    rows = [("floor", [sys.executable, "-c", floor, str(path)])]
    rows += [
        ("solve", northfinder("solve", str(path), "--latitude", "34")),
        ("calibrate", northfinder("calibrate", str(path))),
    ]
    if log:
        rows.append(("dump", northfinder("dump", str(path))))
    return [(name, cmd) for name, cmd in rows if name not in skip]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=int, nargs="+", default=[1, 6])
    ap.add_argument("--text-hours", type=int, nargs="*", default=[1], help="also ASC and .log")
    ap.add_argument("--dir", type=Path, default=None, help="where records are made and kept")
    ap.add_argument("--skip", nargs="*", default=[], choices=("solve", "calibrate", "dump"))
    ap.add_argument(
        "--formats", nargs="+", default=["npz", "blf", "asc", "log"],
        choices=("npz", "blf", "asc", "log", "csv"), help="the files measured",
    )  # fmt: skip
    args = ap.parse_args()
    d = args.dir or Path(tempfile.gettempdir()) / "northfinder-size-guide"
    d.mkdir(parents=True, exist_ok=True)
    disk_check(d, args.hours, args.text_hours, args.formats)
    print("| record | MB | command | wall s | CPU s | peak MB | x floor (CPU) |")
    print("|---|---|---|---|---|---|---|")
    for hours in args.hours:
        npz, blf, (wall, cpu, peak, _) = make_record(hours, d)
        size = (npz.stat().st_size + blf.stat().st_size) / 1e6
        print(f"| {hours} h: NPZ + BLF | {size:.0f} | record | {wall:.0f} | {cpu:.0f} | "
              f"{peak:.0f} | |", flush=True)  # fmt: skip
        files = [f for f in (npz, blf) if f.suffix[1:] in args.formats]
        if hours in args.text_hours:
            files += [as_text(blf, f".{f}") for f in ("asc", "log") if f in args.formats]
        if "csv" in args.formats:
            csv_path, (wall, cpu, peak, _) = make_csv(hours, d)
            print(f"| {hours} h: CSV | {csv_path.stat().st_size / 1e6:.0f} | record | {wall:.0f} | "
                  f"{cpu:.0f} | {peak:.0f} | |", flush=True)  # fmt: skip
            files.append(csv_path)
        for path in files:
            size = path.stat().st_size / 1e6
            floor = None
            for name, cmd in commands(path, set(args.skip)):
                wall, cpu, peak, status = isolated(cmd)
                floor = floor or cpu
                note = "" if status == 0 else f" (exit {status})"
                ratio = "" if name == "floor" else f"{cpu / floor:.2f}"
                print(f"| {hours} h {path.suffix} | {size:.0f} | {name}{note} | {wall:.1f} | "
                      f"{cpu:.1f} | {peak:.0f} | {ratio} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
