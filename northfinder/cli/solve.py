"""``northfinder solve FILE [FILE ...]``: solve a recording or a CAN log offline.

FILE is a recording of ``northfinder record`` (.csv, .npz) or a CAN log in a format python-can
reads; several files (or a quoted glob) are the parts of one rotated log, read in order. A log
carries no latitude: give ``--latitude``. From a log, damaged lines are skipped and
windows with samples missing left out, each with a warning (``--strict`` refuses such a log,
naming its first damaged line; ``--on-gap report`` solves a window with sample ticks missing
from the samples it holds, each gap in the result's notes);
``--session N`` and ``--windows 1,2`` pick what to solve. Exit status 3: the windows failed their
consistency check.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from northfinder.cli import report, spinfind
from northfinder.cli.argtypes import bounded_float, node_id, positive_float
from northfinder.cli.exits import result_status
from northfinder.cli.logprogress import LogProgress
from northfinder.cli.options import add_session_argument, add_solver_argument
from northfinder.cli.output import say, warn
from northfinder.cli.plots import check_plot_path
from northfinder.driver.framelog import expand_log_names
from northfinder.host.canlog import LogSet, is_can_log, read_can_log
from northfinder.host.denoise import METHODS
from northfinder.host.errors import HostConfigError, HostError, QualityError
from northfinder.host.procedure import (
    METHOD_CHOICES,
    FindResult,
    Plan,
    PositionWindow,
    result_from_windows,
    summarise_window,
)
from northfinder.host.recording import RecordedWindow, Recording, summarise_recording


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "file", nargs="+", metavar="FILE",
        help="recording (.csv, .npz) or CAN log (.log, .asc, .blf, ...); several files or a "
        "glob: the parts of a rotated log",
    )  # fmt: skip
    p.add_argument(
        "--latitude",
        type=bounded_float(-90.0, 90.0, "deg"),
        default=None,
        help="deg (default: from the recording)",
    )
    p.add_argument(
        "--denoise", default="none", choices=list(METHODS), help="denoising method (default none)"
    )
    add_solver_argument(p, METHOD_CHOICES)
    g = p.add_argument_group("CAN logs")
    g.add_argument(
        "--window", type=positive_float, default=None, metavar="SECONDS",
        help="keep the first SECONDS of each window (default: all samples at the position)",
    )  # fmt: skip
    g.add_argument(
        "--node-id", type=node_id, default=None,
        help="the device's node id (default: the only node in the log)",
    )  # fmt: skip
    add_session_argument(
        g, "the host session to solve, 1-based (required when the log holds several)"
    )
    g.add_argument(
        "--windows", type=_window_list, default=None, metavar="I,J,...",
        help="solve only these windows of the session, 1-based (e.g. 1,2)",
    )  # fmt: skip
    g.add_argument(
        "--strict", action="store_true",
        help="refuse a log with a damaged line, a gap or a cut (default: skip and warn)",
    )  # fmt: skip
    p.add_argument(
        "--on-gap", choices=ON_GAP_CHOICES, default="leave-out",
        help="a window with sample ticks missing: leave-out (default: solve the complete "
        "windows) or report (solve it from the samples it holds, each gap in the notes)",
    )  # fmt: skip
    p.add_argument(
        "--spin-drift", action="store_true",
        help="spin recordings: also fit a linear drift of each gyro (default: as recorded)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument(
        "--plot", metavar="FILE", help="plot the windows, or the spin's fit (matplotlib)"
    )


#: ``--on-gap``: what a window with sample ticks missing does (``leave-out``: the default).
ON_GAP_CHOICES = ("leave-out", "report")


def _window_list(text: str) -> list[int]:
    """argparse type: 1-based window numbers, comma-separated (``1,2``)."""
    parts = [part.strip() for part in text.split(",")]
    try:
        numbers = [int(part) for part in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected window numbers such as 1,2, got {text!r}"
        ) from None
    if any(n < 1 for n in numbers) or len(set(numbers)) != len(numbers):
        raise argparse.ArgumentTypeError(
            f"window numbers are 1, 2, ... each at most once, got {text!r}"
        )
    return numbers


def solve_recording(
    rec: Recording,
    latitude: float | None,
    denoise: str,
    method: str,
    *,
    allow_gaps: bool = False,
) -> FindResult:
    """Solve a recording's windows (``allow_gaps``: a window with ticks missing is solved from
    the samples it holds, the gap in its notes; else it is an error)."""
    lat, source = _latitude(rec.meta, latitude)
    plan = Plan(
        positions_deg=tuple(w.commanded_deg for w in rec.windows),
        window_s=max(len(w.counter) for w in rec.windows) / float(rec.meta["sample_rate_hz"]),
        denoise=denoise,
        method=method,
    )
    windows = [
        summarise_window(w, w.commanded_deg, denoise, allow_gaps=allow_gaps) for w in rec.windows
    ]
    return result_from_windows(windows, lat, plan, latitude_source=source)


def _latitude(meta: dict[str, Any], latitude: float | None) -> tuple[float, str]:
    """The latitude to solve with, deg, and where it came from."""
    if latitude is None and "latitude_deg" not in meta:
        raise HostConfigError("--latitude: the recording has no latitude_deg; give --latitude")
    lat = float(meta["latitude_deg"] if latitude is None else latitude)
    recorded = meta.get("latitude_source")
    if latitude is not None:
        return lat, "--latitude"
    return lat, f"the recording (from {recorded})" if recorded else "the recording"


@dataclass(frozen=True)
class WindowSummary:
    """What solving needs of one window (:func:`summarise_window`), its samples dropped; the
    error summarising raised, kept to be raised where solving the window would have."""

    commanded_deg: float
    samples: int
    window: PositionWindow | None
    error: HostError | None = None


def summariser(denoise: str, allow_gaps: bool) -> Callable[[RecordedWindow, float], WindowSummary]:
    """The function that reduces each window as it is read (for ``read_can_log``'s
    ``summarise``), as :func:`solve_recording` reduces it."""

    def summarise(w: RecordedWindow, sample_rate_hz: float) -> WindowSummary:
        try:
            window = summarise_window(w, w.commanded_deg, denoise, allow_gaps=allow_gaps)
        except HostError as exc:
            return WindowSummary(w.commanded_deg, len(w.counter), None, exc)
        return WindowSummary(w.commanded_deg, len(w.counter), window)

    return summarise


@dataclass(frozen=True)
class Summarised:
    """A recording read window by window, each window summarised as it was read."""

    windows: tuple[WindowSummary, ...]
    meta: dict[str, Any]


def solve_summaries(
    summaries: Sequence[WindowSummary], meta: dict[str, Any], latitude: float | None,
    denoise: str, method: str,
) -> FindResult:  # fmt: skip
    """:func:`solve_recording` of windows summarised as they were read: the same result."""
    lat, source = _latitude(meta, latitude)
    plan = Plan(
        positions_deg=tuple(s.commanded_deg for s in summaries),
        window_s=max(s.samples for s in summaries) / float(meta["sample_rate_hz"]),
        denoise=denoise,
        method=method,
    )
    windows = []
    for s in summaries:
        if s.error is not None:
            raise s.error
        assert s.window is not None
        windows.append(s.window)
    return result_from_windows(windows, lat, plan, latitude_source=source)


def load(args: argparse.Namespace) -> tuple[Recording | Summarised, dict[str, Any]]:
    """The recording named by the arguments (read from a CAN log if it is one, from its parts
    if several) and where it came from."""
    names = expand_log_names(args.file)
    path = Path(names[0])
    if len(names) > 1 and not all(is_can_log(n) for n in names):
        other = next(n for n in names if not is_can_log(n))
        raise HostConfigError(
            f"{other}: several files are the parts of one CAN log; a recording is solved alone"
        )
    report_gaps = args.on_gap == "report"
    if args.strict and report_gaps:
        raise HostConfigError("--on-gap report: --strict refuses a log with a gap; choose one")
    if is_can_log(path):
        return _load_can_log(args, names)
    given = [
        name for name in ("window", "node_id", "session", "windows")
        if getattr(args, name) is not None
    ]  # fmt: skip
    if given or args.strict:
        option = "--" + (given[0] if given else "strict").replace("_", "-")
        raise HostConfigError(f"{option} applies to CAN logs only")
    if not args.plot:
        summaries = summarise_recording(path, summariser(args.denoise, report_gaps))
        if summaries is not None:
            windows, meta, partial = summaries
            if len(windows) < 2:
                Recording.load(path)  # the stop-and-go reader's own error: a heading needs two
            return Summarised(tuple(windows), meta), _recording_source(path, partial, False)
    rec = Recording.load(path, min_windows=1)
    if "spin" not in rec.meta and len(rec.windows) < 2:
        rec = Recording.load(path)  # the stop-and-go reader's own error: a heading needs two
    return rec, _recording_source(path, rec.partial, "spin" in rec.meta)


def _recording_source(path: Path, partial: str | None, spin: bool) -> dict[str, Any]:
    """Where a recording's windows came from, and what a partial one holds."""
    source: dict[str, Any] = {"file": str(path), "format": f"recording{path.suffix}"}
    if partial is not None:
        held = "samples" if spin else "windows"
        source["partial"] = partial
        source["notes"] = [f"partial recording ({partial}): solved from the {held} it holds"]
    return source


def _load_can_log(
    args: argparse.Namespace, names: list[str]
) -> tuple[Recording | Summarised, dict[str, Any]]:
    """The complete windows of a CAN log (or of its parts) and where they came from; the
    windows left out warned of. Each window is summarised as it is read and its samples
    dropped, unless they are plotted."""
    report_gaps = args.on_gap == "report"
    logs = LogSet(names)
    path = Path(logs.name)
    summarise = None if args.plot else summariser(args.denoise, report_gaps)
    # Damaged lines are read past even with --strict, so that it names the first one.
    with LogProgress("solve", logs.files, enabled=not args.json) as progress:
        session = read_can_log(
            logs.files, node_id=args.node_id, window_s=args.window, skip_damaged=True,
            session=args.session, windows=args.windows, min_windows=1, progress=progress,
            summarise=summarise,
        )  # fmt: skip
    if args.strict and session.first_damaged:
        raise QualityError(
            f"{session.first_damaged}; --strict refuses a log with a damaged line "
            f"({session.skipped_lines} in all)"
        )
    if args.strict and (session.incomplete or session.part_gaps):
        raise QualityError(f"{path}: " + "; ".join(session.incomplete or session.part_gaps))
    complete = session.complete(keep_gaps=report_gaps)
    kept = {session.window_numbers[i] for i in session.gap_windows} if report_gaps else set()
    reported = [
        n for n in session.incomplete if any(n.startswith(f"window {k} (") for k in kept)
    ]  # in the result's notes instead: solved from the samples the window holds
    warned = [
        n for n in session.notes
        if (n in session.incomplete and n not in reported) or n in session.part_gaps
        or n.startswith("skipped ")
    ]  # fmt: skip
    for note in warned:
        warn("solve", f"{path}: {note}")
    held, solved = len(session.window_numbers), len(complete.window_numbers)
    if solved < held:
        left = ", ".join(str(n) for n in complete.window_numbers)
        gaps_only = len(session.gap_windows) and not report_gaps
        warn(
            "solve",
            f"{path}: {held - solved} window(s) with samples "
            f"missing left out; solving the complete windows {left or '(none)'}"
            + (
                f" (--on-gap report solves the {len(session.gap_windows)} with sample "
                "ticks missing from the samples they hold)"
                if gaps_only
                else ""
            ),
        )
    if solved < 2:
        raise QualityError(
            f"{path}: {solved} complete window(s); a heading needs two"
            + ("" if args.strict else " (windows with samples missing are left out")
            + (
                "; --on-gap report solves those with sample ticks missing)"
                if session.gap_windows and not (args.strict or report_gaps)
                else ")"
                if not args.strict
                else ""
            )
        )
    source = {
        "file": str(path), "format": "can-log", "node_id": session.node_id,
        **({"parts": [str(f) for f in logs.files]} if len(logs.files) > 1 else {}),
        "frames": session.frames, "sample_rate_hz": session.sample_rate_hz,
        "window_s": args.window, "notes": list(session.notes),
        "session": session.session, "sessions": [list(s) for s in session.sessions],
        "windows": list(complete.window_numbers), "skipped_lines": session.skipped_lines,
        "warnings": warned, "reported": reported,
    }  # fmt: skip
    if summarise is not None:
        return Summarised(complete.summaries, complete.recording().meta), source
    return complete.recording(), source


def run(args: argparse.Namespace) -> int:
    if args.plot:
        check_plot_path(args.plot)
    rec, source = load(args)
    if "spin" in rec.meta:
        assert isinstance(rec, Recording)
        return _solve_spin(args, rec, source)
    if args.spin_drift:
        raise HostConfigError("--spin-drift: applies to spin recordings only")
    if isinstance(rec, Summarised):
        result = solve_summaries(rec.windows, rec.meta, args.latitude, args.denoise, args.solver)
    else:
        result = solve_recording(
            rec, args.latitude, args.denoise, args.solver, allow_gaps=args.on_gap == "report"
        )
    truth = rec.meta.get("truth")
    if args.plot:
        assert isinstance(rec, Recording)
        report.plot(args.plot, result, list(rec.windows), args.denoise, truth)
    device = rec.meta.get("device")
    if args.json:
        say(report.as_json("solve", result, truth, device, source=source))
    else:
        say(report.text(result, truth))
        shown = [*source.get("warnings", []), *source.get("reported", [])]
        for note in source.get("notes", []):
            if note not in shown:
                say(f"note: {note}")
    return result_status(result.consistent)


def _solve_spin(args: argparse.Namespace, rec: Recording, source: dict[str, Any]) -> int:
    """A spin recording (``record --spin``): the spin solution; the stop-and-go options are
    refused, not ignored."""
    if args.denoise not in (None, "none"):
        raise HostConfigError("--denoise: not available for a spin recording")
    if args.solver not in (None, "auto"):
        raise HostConfigError("--solver: a spin recording has its own solver")
    found = spinfind.solve_recording(rec, args.latitude, True if args.spin_drift else None)
    truth = rec.meta.get("truth")
    if args.plot:
        spinfind.plot(args.plot, found, truth, float(rec.meta["sample_rate_hz"]))
    if args.json:
        say(spinfind.as_json(found, truth, rec.meta.get("device"), "solve", source=source))
    else:
        say(spinfind.text(found, truth))
        for note in source.get("notes", []):
            say(f"note: {note}")
    return result_status(found.solution.consistent)
