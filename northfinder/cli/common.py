"""What the subcommands share: argument helpers (so every command spells an option the same way)
and the error policy (one line per error and a stated exit status).

Exit status
-----------
- 0: done.
- 1 (:data:`EXIT_RUNTIME`): the work failed: the device or link (refusals, timeouts, a lost link,
  gaps, faults), measured data unusable (quality, tilt), a file that cannot be written.
- 2 (:data:`EXIT_USAGE`): the request is wrong: a command-line argument or option, a combination of
  them, or the content of a file named on the command line (a sensor TOML, a recording). Fix the
  command and run it again. argparse's own errors exit 2 as well.
- 3 (:data:`EXIT_INCONSISTENT`): ``find`` and ``solve`` found a heading, but its windows failed
  their consistency check (they disagree beyond their noise: a bias step, a drift, a table angle
  error, a wrong latitude). The result is printed (JSON, plot, record) with the warning, its
  sigma scaled; NMEA sends it as not valid. A script must not take it as a good heading.
- 4 (:data:`EXIT_NOT_RESOLVED`): ``accept`` failed no datasheet line, but the data could not
  decide at least one (NOT RESOLVED: the record too short); the report says what would decide it.
- 130, 143, 129: interrupted by SIGINT (Ctrl-C), SIGTERM, SIGHUP (128 + the signal's number);
  a device the command opened is left at rest first (:class:`SignalInterrupt`).

:func:`exit_status` maps an exception to its status by :data:`EXIT_STATUS` (the most specific
class of the error's MRO decides); :func:`report_error` prints the one line. An exception of no
listed class is a bug of the program: it is reported as an internal error (exit 1) in one line
that names its type, and ``--debug`` shows its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import sys
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import Executor
from typing import Any, NoReturn, TextIO

from northfinder.driver.errors import ArgumentError, DriverError, LinkError
from northfinder.driver.protocol.constants import (
    NODE_ID_DEFAULT,
    NODE_ID_MAX,
    NODE_ID_MIN,
    SERIAL_BAUD_DEFAULT,
)
from northfinder.firmware_sim.errors import ControlRefused, SimConfigError, SimError
from northfinder.host.errors import (
    DenoiseError,
    GeometryError,
    HostConfigError,
    HostError,
    LatitudeError,
    OutputError,
    RecordingError,
)

EXIT_RUNTIME = 1
EXIT_USAGE = 2
EXIT_INCONSISTENT = 3
EXIT_NOT_RESOLVED = 4
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


class SignalInterrupt(KeyboardInterrupt):
    """SIGTERM, SIGHUP (or SIGINT) turned into the interrupt Ctrl-C raises, so that every
    ending runs the same clean-up; ``signum`` names the signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = int(signum)


def note_ending(exc: BaseException, clause: str) -> None:
    """Remember on ``exc`` a clause of what was done as the command ended (the device left at
    rest, the windows kept), for the one line that reports ``exc``."""
    with contextlib.suppress(AttributeError, TypeError):
        clauses = exc.__dict__.setdefault("northfinder_ending", [])
        clauses.append(clause)


def note_at_rest(exc: BaseException, rest: Any) -> None:
    """:func:`note_ending` with what was done to leave the device at rest (an
    :class:`~northfinder.driver.device_link.AtRest`), if there was anything to undo."""
    if rest.needed:
        note_ending(exc, rest.summary())


def ending_of(exc: BaseException) -> str | None:
    """The clauses :func:`note_ending` remembered on ``exc`` and the errors in its chain, joined
    (``sent STOP; the unit reads SETTLING; kept 3 of 4 windows in run.csv``); None if none."""
    clauses: list[str] = []
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        clauses += getattr(current, "northfinder_ending", [])
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return "; ".join(clauses) if clauses else None


#: Exception class -> exit status. The first class of an error's MRO found here decides, so a
#: subclass listed overrides its base (a HostConfigError is a HostError, and exits 2).
EXIT_STATUS: Mapping[type[BaseException], int] = {
    HostConfigError: EXIT_USAGE,
    LatitudeError: EXIT_USAGE,
    GeometryError: EXIT_USAGE,
    DenoiseError: EXIT_USAGE,
    RecordingError: EXIT_USAGE,
    SimConfigError: EXIT_USAGE,
    ControlRefused: EXIT_USAGE,
    ArgumentError: EXIT_USAGE,
    HostError: EXIT_RUNTIME,
    SimError: EXIT_RUNTIME,
    DriverError: EXIT_RUNTIME,
    OSError: EXIT_RUNTIME,
}


def result_status(consistent: bool | None) -> int:
    """The exit status of a heading: :data:`EXIT_INCONSISTENT` when its consistency check failed,
    else 0 (passed, or not checked: a two-position plan)."""
    return EXIT_INCONSISTENT if consistent is False else 0


def exit_status(exc: BaseException) -> int | None:
    """The exit status of an error of a known kind (:data:`EXIT_STATUS`), None for a bug."""
    for cls in type(exc).__mro__:
        if cls in EXIT_STATUS:
            return EXIT_STATUS[cls]
    return None


def error_line(command: str, exc: BaseException) -> str:
    """``northfinder COMMAND: error: MESSAGE`` on one line (a multi-line message is joined)."""
    text = "; ".join(part.strip() for part in str(exc).splitlines() if part.strip())
    if isinstance(exc, OSError) and not isinstance(exc, DriverError | HostError | SimError):
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        text = f"{where}{exc.strerror or text or type(exc).__name__}"
    if exit_status(exc) is None:
        return (
            f"northfinder {command}: internal error ({type(exc).__name__}: {text or 'no message'}); "
            "run with --debug for the traceback and report it"
        )
    return f"northfinder {command}: error: {text or type(exc).__name__}"


def report_error(command: str, exc: BaseException, stream: TextIO | None = None) -> int:
    """Print the one line for ``exc`` and return the exit status (internal errors: 1); what was
    done to leave a device at rest (:func:`note_at_rest`) ends the line."""
    line = error_line(command, exc)
    ending = ending_of(exc)
    if ending is not None:
        line += f" ({ending})"
    print(line, file=stream or sys.stderr)
    status = exit_status(exc)
    return EXIT_RUNTIME if status is None else status


#: A number that prints as a negative zero ("-0", "-0.000", "-0.0e+00"): a value that rounds to
#: zero is shown as zero, without a sign that says nothing.
_NEGATIVE_ZERO = re.compile(r"(?<![\w.])-(0(?:\.0*)?(?:[eE][-+]?\d+)?)(?![\d.])")


def plain_numbers(text: str) -> str:
    """``text`` with every printed negative zero written as zero (``-0.0000`` -> ``0.0000``,
    ``+-0.0`` stays a plus-minus sign before ``0.0``)."""
    return _NEGATIVE_ZERO.sub(r"\1", text)


def say(*parts: Any, **options: Any) -> None:
    """``print`` for a command's text: every negative zero written as zero (:func:`plain_numbers`)."""
    print(*(plain_numbers(str(p)) for p in parts), **options)


def warn(command: str, text: str) -> None:
    """``northfinder COMMAND: warning: TEXT`` on stderr: the work goes on, but the user should
    know (lines skipped, windows left out)."""
    print(plain_numbers(f"northfinder {command}: warning: {text}"), file=sys.stderr, flush=True)


def _no_negative_zero(value: Any) -> Any:
    if isinstance(value, float):
        return 0.0 if value == 0.0 else value
    if isinstance(value, str):
        return plain_numbers(value)
    if isinstance(value, Mapping):
        return {k: _no_negative_zero(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_no_negative_zero(v) for v in value]
    return value


def dumps(value: Any, **options: Any) -> str:
    """JSON of a command's result (indented by 2), with no negative zero (``-0.0`` is 0.0, in
    numbers and in the texts of notes)."""
    options.setdefault("indent", 2)
    return json.dumps(_no_negative_zero(value), **options)


#: The one-line help of each command in the command list (:func:`command_parser` takes it from
#: here; the list shows it without importing the command's module).
SUMMARIES: dict[str, str] = {
    "simulate": "summarise simulated windows (physics only)",
    "sim": "run the simulated instrument on a link",
    "simctl": "control a running simulator",
    "conformance": "check a unit on a link against protocol.md",
    "study": "Monte Carlo accuracy of a plan against the physical bound; plan search",
    "sweep": "Monte Carlo studies over presets, latitudes, plans and windows (threads or Dask)",
    "solve": "solve a recording or CAN log offline",
    "find": "find true north",
    "record": "record raw windows to CSV or NPZ",
    "calibrate": "fit sensor terms to recordings and write a sensor TOML",
    "monitor": "live terminal view of a unit (Textual)",
    "dump": "decode a CAN log or a live bus with protocol.dbc",
    "reset": "restart a unit (clears FAULT)",
    "accept": "acceptance test of a unit against its datasheet, with an HTML report",
}


#: Where the command line is described at length (the help texts stay short and point there).
CLI_DOCS = "docs/cli.md"

_ROLE = re.compile(r":[\w:.-]+:`~?([^`]*?)(?:\s*<[^>]*>)?`")
_LITERAL = re.compile(r"``(.+?)``", re.S)


def plain_text(doc: str) -> str:
    """A docstring as a terminal shows it: ``literals`` and :role:`targets` without their markup
    (``~a.b.C`` shown as ``C``), a literal block's ``::`` as ``:``."""
    text = _ROLE.sub(
        lambda m: m.group(1).rsplit(".", 1)[-1] if "~" in m.group(0) else m.group(1), doc
    )
    return _LITERAL.sub(r"\1", text).replace("::\n", ":\n")


class OneLineParser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line, as every other error of the command
    line (``northfinder find: error: argument --window: must be ...; see --help``), exit 2."""

    def error(self, message: str) -> NoReturn:
        text = "; ".join(part.strip() for part in message.splitlines() if part.strip())
        self.exit(EXIT_USAGE, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def command_parser(
    sub: argparse._SubParsersAction, name: str, doc: str | None, **options: Any
) -> argparse.ArgumentParser:
    """A subcommand's parser: its line in the command list is its summary in
    :data:`SUMMARIES` (written there once: the list shows it without importing
    the command's module), the module docstring ``doc`` its description, as plain text printed
    as written (paragraphs and lists kept), with a last line that points to the page of the
    command line's docs."""
    summary = SUMMARIES[name]
    description = None
    if doc:
        description = f'{plain_text(doc).rstrip()}\n\nMore: {CLI_DOCS}, section "{name}".'
    parser: argparse.ArgumentParser = sub.add_parser(
        name,
        help=summary,
        description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        **options,
    )
    return parser


#: Marks an argument group that several commands share (:func:`common_group`).
_COMMON = "_northfinder_common"


def common_group(parser: argparse.ArgumentParser, title: str) -> argparse._ArgumentGroup:
    """An argument group several commands share (the link, the simulated truth, execution,
    logging): :func:`order_groups` shows it after the command's own options."""
    group = parser.add_argument_group(title)
    setattr(group, _COMMON, True)
    return group


def _group_rank(group: argparse._ArgumentGroup) -> int:
    if (group.title or "").startswith("bus arguments"):  # python-can's add_bus_arguments
        return 2
    return 1 if getattr(group, _COMMON, False) else 0


def order_groups(parser: argparse.ArgumentParser) -> None:
    """Order a command's help: its own options and groups first, then the groups commands
    share (:func:`common_group`), python-can's bus options last; the usage line names the
    positionals only (``northfinder record [options] FILE``: the options follow it).

    argparse prints groups and usage in the order of ``_action_groups`` and ``_actions`` and
    has no public way to reorder them. A stable sort keeps the positionals' order, which is
    the only order parsing depends on.
    """
    groups = sorted(parser._action_groups, key=_group_rank)
    rank = {id(a): _group_rank(g) for g in groups for a in g._group_actions}
    parser._action_groups[:] = groups
    parser._actions.sort(key=lambda a: rank.get(id(a), 0))
    formatter = parser._get_formatter()
    formatter.add_usage(None, parser._get_positional_actions(), [], prefix="")
    positionals = formatter.format_help().strip().removeprefix(parser.prog).strip()
    parser.usage = f"%(prog)s [options]{' ' + positionals if positionals else ''}"


def whole_number(text: str) -> int:
    """argparse type: a whole number, with an error that quotes the bad text."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None


def finite_float(text: str) -> float:
    """argparse type: a finite float, with an error that quotes the bad text."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite: {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive: {text!r}")
    return value


def bounded_float(lo: float, hi: float, unit: str = "", *, open_lo: bool = False) -> Any:
    """argparse type: a finite float in [lo, hi] (``(lo, hi]`` with ``open_lo``); the error
    states the bounds."""
    span = f"more than {lo:g} and at most {hi:g}" if open_lo else f"{lo:g} to {hi:g}"

    def parse(text: str) -> float:
        value = finite_float(text)
        if value > hi or value < lo or (open_lo and value == lo):
            raise argparse.ArgumentTypeError(
                f"must be {span}{' ' + unit if unit else ''}, got {text!r}"
            )
        return value

    parse.__name__ = "number"
    return parse


def bounded_int(lo: int, hi: int) -> Any:
    """argparse type: a whole number in [lo, hi]; the error states the bounds."""

    def parse(text: str) -> int:
        value = whole_number(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be {lo} to {hi}, got {value}")
        return value

    parse.__name__ = "whole number"
    return parse


#: Largest random seed accepted (numpy takes any non-negative integer; 2**63 - 1 is plenty).
MAX_SEED = 2**63 - 1
seed_value = bounded_int(0, MAX_SEED)
"""argparse type: a random seed, a whole number 0 .. 2**63 - 1."""


def run_seed(args: argparse.Namespace) -> int:
    """The seed of a simulated run: ``--seed``, or a fresh one drawn now (and kept in ``args``)
    when none was given, so that every run can state its seed and be run again with it."""
    if getattr(args, "seed", None) is None:
        import secrets

        args.seed = secrets.randbelow(2**32)  # short to type; any seed up to MAX_SEED is taken
    seed: int = args.seed
    return seed


def node_id(text: str) -> int:
    """argparse type: a CAN node id, 1..15 (protocol.md 2.1)."""
    value = whole_number(text)
    if not NODE_ID_MIN <= value <= NODE_ID_MAX:
        raise argparse.ArgumentTypeError(f"must be {NODE_ID_MIN}..{NODE_ID_MAX}, got {value}")
    return value


#: Highest serial baud rate accepted, bit/s (fast USB UARTs reach about 12 Mbaud).
MAX_BAUD = 100_000_000


def baud_rate(text: str) -> int:
    """argparse type: a serial baud rate, a whole number of bit/s from 1 to :data:`MAX_BAUD`."""
    value = whole_number(text)
    if not 1 <= value <= MAX_BAUD:
        raise argparse.ArgumentTypeError(f"must be 1..{MAX_BAUD} bit/s, got {value}")
    return value


#: python-can interfaces the commands refuse, and why: their frames leave this machine as network
#: traffic to addresses the user did not name (udp_multicast sends to a multicast group on every
#: interface of the host, not to a bus).
REFUSED_INTERFACES: Mapping[str, str] = {
    "udp_multicast": "it sends every frame as IP multicast off this machine, not onto a CAN bus",
}


def _refuse_interfaces_off_the_machine(parser: argparse.ArgumentParser) -> None:
    """Take the refused interfaces out of ``-i/--interface``'s choices, with a message that says
    why and lists what is accepted."""
    for action in parser._actions:
        if "--interface" not in action.option_strings or not action.choices:
            continue
        accepted = sorted(c for c in action.choices if c not in REFUSED_INTERFACES)

        def interface(text: str, accepted: list[str] = accepted) -> str:
            if text in REFUSED_INTERFACES:
                raise argparse.ArgumentTypeError(
                    f"{text!r} is refused: {REFUSED_INTERFACES[text]}; accepted: {', '.join(accepted)}"
                )
            return text

        action.type = interface
        action.choices = accepted
        action.metavar = "INTERFACE"
        action.help = "python-can interface, e.g. socketcan, slcan, virtual"


#: Shorter help of python-can's bus options, by destination (its own run to 8 lines each).
_BUS_HELP: Mapping[str, str] = {
    "channel": "the bus channel, e.g. vcan0, can0, or /dev/ttyACM0 for SLCAN",
    "timing": "bit timing as KEY=VALUE fields of python-can's BitTiming (see its docs)",
    "bus_kwargs": "KEY=VALUE passed to the python-can bus, e.g. sleep_after_open=0 for SLCAN "
    "on a pseudo-terminal",
}


def _short_bus_help(parser: argparse.ArgumentParser) -> None:
    for action in parser._actions:
        if action.dest in _BUS_HELP:
            action.help = _BUS_HELP[action.dest]


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """python-can's bus options (``-i/-c/-b``, as python-can's own tools spell them), without
    the interfaces that would send off the machine."""
    import can.cli

    can.cli.add_bus_arguments(parser)
    _refuse_interfaces_off_the_machine(parser)
    _short_bus_help(parser)


def add_link_arguments(parser: argparse.ArgumentParser, title: str) -> argparse._ArgumentGroup:
    """The links every command speaks: python-can bus options (``-i/-c/-b``, as python-can's own
    tools spell them), ``--serial PORT``, ``--baud`` and ``--node-id``. Returns the serial group so
    a command can add its own links to it."""
    add_bus_arguments(parser)
    group = common_group(parser, title)
    group.add_argument("--serial", metavar="PORT", help="serial port path or pyserial URL")
    group.add_argument(
        "--baud",
        type=baud_rate,
        default=SERIAL_BAUD_DEFAULT,
        help=f"serial baud rate (default {SERIAL_BAUD_DEFAULT})",
    )
    group.add_argument(
        "--node-id",
        type=node_id,
        default=NODE_ID_DEFAULT,
        help=f"CAN node id {NODE_ID_MIN}..{NODE_ID_MAX} (default {NODE_ID_DEFAULT})",
    )
    return group


def open_can_bus(args: argparse.Namespace) -> Any:
    """The python-can bus of the ``-i/-c/-b`` options.

    Raises
    ------
    HostConfigError
        An interface python-can does not know, or options it refuses (exit status 2).
    LinkError
        The bus exists but cannot be opened (exit status 1).
    """
    import can
    import can.cli

    try:
        return can.cli.create_bus_from_namespace(args)
    except (can.CanError, OSError, argparse.ArgumentError, ValueError, TypeError) as exc:
        # python-can wraps every failure in an argparse.ArgumentError: its cause says which
        # it is, a bus that cannot be opened now (1) or options it refuses (2).
        cause = exc.__cause__ if isinstance(exc, argparse.ArgumentError) and exc.__cause__ else exc
        now = isinstance(cause, can.CanError | OSError) and not isinstance(
            cause, can.CanInterfaceNotImplementedError
        )
        from northfinder.driver.transport import bus_open_hint

        raise (LinkError if now else HostConfigError)(
            f"cannot open the CAN bus: {cause}{bus_open_hint(cause)}"
        ) from exc


def open_serial_port(path: str, baud: int) -> Any:
    """A pyserial port (non-blocking) for ``--serial PATH``.

    Raises
    ------
    HostConfigError
        A URL or setting pyserial refuses (exit status 2).
    LinkError
        The port cannot be opened (missing, busy, not a serial device: exit status 1).
    """
    import serial

    try:
        return serial.serial_for_url(path, baudrate=baud, timeout=0)
    except serial.SerialException as exc:
        raise LinkError(f"--serial {path}: cannot open the port: {exc}") from exc
    except ValueError as exc:
        raise HostConfigError(f"--serial {path}: {exc}") from exc


def bus_given(args: argparse.Namespace) -> bool:
    """Whether python-can bus options were given."""
    return any(getattr(args, k, None) is not None for k in ("interface", "channel"))


#: Largest magnitude of an angle given in degrees (an azimuth, a table position): one turn either
#: way. Beyond it a value is a typo, and 1e20 deg has no meaningful remainder modulo 360.
MAX_ANGLE_DEG = 360.0
#: Largest magnitude of a table angle, deg: two turns either way (a plan may count on past 360).
MAX_TABLE_ANGLE_DEG = 720.0
_table_angle = bounded_float(-MAX_TABLE_ANGLE_DEG, MAX_TABLE_ANGLE_DEG, "deg")

#: Most table positions a plan may hold (and angles a list may hold).
MAX_POSITIONS = 64


def angle_list(text: str) -> list[float]:
    """argparse type: comma-separated angles in degrees, e.g. ``0,60`` or ``0,90,180,270``
    (at most :data:`MAX_POSITIONS`)."""
    parts = [p.strip() for p in text.split(",")]
    if not any(parts):
        raise argparse.ArgumentTypeError("expected comma-separated angles in degrees, e.g. 0,180")
    if not all(parts):
        raise argparse.ArgumentTypeError(
            f"an empty angle in {text!r}: give comma-separated angles in degrees, e.g. 0,180"
        )
    if len(parts) > MAX_POSITIONS:
        raise argparse.ArgumentTypeError(
            f"{len(parts)} angles: at most {MAX_POSITIONS} positions are allowed"
        )
    return [_table_angle(p) for p in parts]


def add_positions_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--positions``: the table angles of a plan, as ``find``, ``record`` and ``simulate``
    spell it."""
    from northfinder.host.plan import DEFAULT_POSITIONS_DEG  # numpy: not for --help

    default = list(DEFAULT_POSITIONS_DEG)
    parser.add_argument(
        "--positions",
        type=angle_list,
        default=default,
        help=f"table angles, deg (default {','.join(f'{a:g}' for a in default)})",
    )


def sim_latitude(args: argparse.Namespace) -> float:
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG  # numpy: not for --help

    return DEFAULT_LATITUDE_DEG if args.latitude is None else args.latitude


def sim_truth(args: argparse.Namespace, rng: Any) -> Any:
    """The simulated truth of :func:`add_truth_arguments` (azimuth drawn from ``rng`` when not
    given); SimConfigError names a field the simulated base cannot take."""
    from northfinder.firmware_sim.imu import Truth

    azimuth = float(rng.uniform(0.0, 360.0)) if args.azimuth is None else args.azimuth
    return Truth(azimuth, sim_latitude(args), args.pitch or 0.0, args.roll or 0.0)


def latitude_source(args: argparse.Namespace, simulated: bool) -> str:
    """Where the latitude of a run comes from, as the result states it."""
    if args.latitude is not None:
        return "--latitude"
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG

    return f"the simulated truth (default, {DEFAULT_LATITUDE_DEG:g} deg)" if simulated else ""


def load_sensor(name_or_path: str, overrides: Mapping[str, Any] | None = None) -> Any:
    """A sensor preset or TOML file, with ``SECTION.FIELD`` overrides, that the simulated
    device can run (table limits it reports, impulses it can compute: ``check_device_spec``).

    Raises
    ------
    SimConfigError
        Naming the field, its value and the bound (exit status 2).
    """
    from northfinder.firmware_sim.firmware import check_device_spec
    from northfinder.firmware_sim.sensors import load_spec

    spec = load_spec(name_or_path)
    if overrides:
        spec = spec.with_values(dict(overrides))
    return check_device_spec(spec)


def check_output_path(path: str, option: str, suffixes: tuple[str, ...] = ()) -> str:
    """Refuse, before any work, an output file that cannot be written: a missing folder, a
    folder in its place, a path under /dev that does not exist, or (with ``suffixes``) a name
    of another kind."""
    if suffixes and not path.endswith(suffixes):
        raise HostConfigError(f"{option} {path}: the file name must end in {' or '.join(suffixes)}")
    if os.path.abspath(path).startswith("/dev/") and not os.path.exists(path):
        # A mistyped port name must not become a regular file under /dev.
        raise HostConfigError(f"{option} {path}: no such device (a path under /dev must exist)")
    if os.path.isdir(path):
        raise HostConfigError(f"{option} {path}: is a folder; give a file name")
    folder = os.path.dirname(path) or "."
    if not os.path.isdir(folder):
        raise HostConfigError(f"{option} {path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise HostConfigError(f"{option} {path}: the folder {folder} is not writable")
    return path


def pyplot() -> Any:
    """matplotlib's ``pyplot`` on the Agg backend (files only, no window).

    Raises
    ------
    HostConfigError
        matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise HostConfigError("--plot needs matplotlib: pip install 'northfinder[plot]'") from exc
    return plt


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 110) -> None:
    """Write ``fig`` to the ``--plot`` file ``path`` and close it.

    Raises
    ------
    OutputError
        The file cannot be written.
    """
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise OutputError(f"--plot {path}: cannot write ({exc.strerror})") from exc
    finally:
        pyplot().close(fig)


def check_plot_path(path: str, option: str = "--plot") -> str:
    """Refuse, before any work, a plot file that cannot be written: as
    :func:`check_output_path`, matplotlib not installed, or a name whose ending is no format
    matplotlib writes (the message lists those it does)."""
    check_output_path(path, option)
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError as exc:
        raise HostConfigError(
            f"{option} needs matplotlib: pip install 'northfinder[plot]'"
        ) from exc
    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    suffix = os.path.splitext(path)[1].lower().lstrip(".")
    if suffix not in formats:
        raise HostConfigError(
            f"{option} {path}: "
            + (f".{suffix} is no plot format" if suffix else "the name has no file ending")
            + f"; it must end in one of: {', '.join('.' + f for f in formats)}"
        )
    return path


def key_value(text: str) -> tuple[str, Any]:
    """argparse type: ``KEY=VALUE``, the value read as JSON when it parses, else as a string."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    return key.strip(), value


def add_key_values(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    flag: str,
    dest: str,
    metavar: str,
    help: str | None = None,
) -> None:
    """A repeatable ``FLAG KEY=VALUE`` option collected as a list of (key, value) pairs."""
    parser.add_argument(
        flag, dest=dest, type=key_value, action="append", default=[], metavar=metavar, help=help
    )


def add_sensor_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    parser.add_argument(
        "--sensor",
        default="paper-rlg",
        metavar="PRESET|FILE",
        help="sensor preset name or TOML file (default: paper-rlg)",
    )


def add_latitude_argument(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, *, device: bool
) -> None:
    """``--latitude``: with ``device`` the site's latitude a real device needs (and the
    simulated truth's with ``--sim``), else the simulated truth's only."""
    from northfinder.driver.protocol.units import DEFAULT_LATITUDE_DEG  # numpy: not for --help

    parser.add_argument(
        "--latitude",
        type=bounded_float(-90.0, 90.0, "deg"),
        default=None,
        help=(
            "site latitude, deg north positive: required with a device "
            f"(--sim: the truth's, default {DEFAULT_LATITUDE_DEG:g})"
            if device
            else f"deg, north positive (default {DEFAULT_LATITUDE_DEG:g})"
        ),
    )


def add_truth_arguments(parser: argparse.ArgumentParser, *, latitude: bool = True) -> None:
    """The simulated truth: where the simulated instrument really stands (``latitude`` False:
    the command takes ``--latitude`` among its own options, as a real device needs it)."""
    g = common_group(parser, "simulated truth")
    g.add_argument(
        "--azimuth",
        type=bounded_float(-MAX_ANGLE_DEG, MAX_ANGLE_DEG, "deg"),
        default=None,
        help="deg clockwise from north, -360 to 360 (default: random)",
    )
    if latitude:
        add_latitude_argument(g, device=False)
    from northfinder.host.kernels import MAX_TILT_DEG  # numpy: only for the commands that take it

    tilt = bounded_float(-MAX_TILT_DEG, MAX_TILT_DEG, "deg (the solvers' tilt limit)")
    g.add_argument("--pitch", type=tilt, default=None, help="deg (default: 0)")
    g.add_argument("--roll", type=tilt, default=None, help="deg (default: 0)")
    g.add_argument(
        "--seed",
        type=seed_value,
        default=None,
        help="random seed (default: a fresh one, reported)",
    )


def add_session_argument(group: argparse._ArgumentGroup, help: str) -> None:
    """``--session N``: one host session of a CAN log, 1-based (each host's IDENTIFY begins
    one), as ``dump`` and ``solve`` spell it."""
    group.add_argument(
        "--session", type=bounded_int(1, 1_000_000), default=None, metavar="N", help=help
    )


def add_duration_argument(
    group: argparse._ArgumentGroup, help: str, metavar: str = "SECONDS"
) -> None:
    """``--duration``: a live command stops after this many wall seconds (``dump``,
    ``monitor``)."""
    group.add_argument(
        "--duration",
        type=bounded_float(0.0, 1e7, "s", open_lo=True),
        default=None,
        metavar=metavar,
        help=help,
    )


def add_solver_argument(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, choices: Sequence[str]
) -> None:
    """``--solver`` as ``find``, ``record``, ``solve`` and ``study`` spell it (``--method``, the
    old spelling of ``find`` and ``solve``, is kept as a hidden alias)."""
    parser.add_argument(
        "--solver", choices=list(choices), default="auto", action=_SolverAction,
        help="heading solver (default auto)",
    )  # fmt: skip
    parser.add_argument(
        "--method", dest="solver", choices=list(choices), action=_SolverAction,
        help=argparse.SUPPRESS,
    )  # fmt: skip


class _SolverAction(argparse.Action):
    """``--solver`` and its alias ``--method``: given twice (either spelling) with different
    values, the command is refused rather than one of them silently winning."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
        option_string: str | None = None,
    ) -> None:  # fmt: skip
        given = getattr(namespace, "_solver_given", None)
        if given is not None and given[1] != values:
            parser.error(
                f"{given[0]} {given[1]} and {option_string} {values} disagree: "
                "give the heading solver once"
            )
        namespace._solver_given = (option_string, values)
        setattr(namespace, self.dest, values)


def can_log_path(text: str) -> str:
    """argparse type: a CAN log file name whose ending names one of python-can's formats."""
    from northfinder.driver.errors import ArgumentError
    from northfinder.driver.framelog import log_suffix

    try:
        log_suffix(text)
        check_output_path(text, "--can-log")
    except (ArgumentError, HostConfigError) as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--can-log ")) from None
    return text


_SIZE_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "d": 86_400.0}


def rotation_limits(text: str) -> tuple[int, float]:
    """argparse type: when a rotated log begins a new part, as ``(max_bytes, max_seconds)`` (0:
    not by that): a size with K, M, G or T (1024-based: ``10M`` is 10 MiB, a trailing B
    allowed), an age of log time with s, min, h or d (``90s``, ``1h``), or one of each
    (``10M,1h``: whichever comes first)."""
    from northfinder.driver.framelog import MAX_BYTES_RANGE, MAX_SECONDS_RANGE

    max_bytes, max_seconds = 0, 0.0
    for item in (part.strip() for part in text.split(",")):
        size = re.fullmatch(r"(\d+)\s*([KMGT])(?:i?B)?|(\d+)\s*B", item)
        age = re.fullmatch(r"(\d+(?:\.\d+)?)\s*(s|min|h|d)", item)
        if size is not None and not max_bytes:
            number, unit = (size.group(1), size.group(2)) if size.group(1) else (size.group(3), "")
            max_bytes = int(number) * _SIZE_UNITS[unit]
            lo, hi = MAX_BYTES_RANGE
            if not lo <= max_bytes <= hi:
                raise argparse.ArgumentTypeError(f"a size must be 4K to 1T, got {item!r}")
        elif age is not None and not max_seconds:
            max_seconds = float(age.group(1)) * _TIME_UNITS[age.group(2)]
            lo_s, hi_s = MAX_SECONDS_RANGE
            if not lo_s <= max_seconds <= hi_s:
                raise argparse.ArgumentTypeError(f"an age must be 1s to 366d, got {item!r}")
        else:
            raise argparse.ArgumentTypeError(
                f"expected a size (10M, 1G), an age (90s, 15min, 1h) or one of each (10M,1h), "
                f"got {text!r}"
            )
    return max_bytes, max_seconds


def add_log_rotation(group: Any, option: str) -> None:
    """``OPTION-rotate LIMIT``: rotation of the CAN log of ``OPTION`` (``--log``,
    ``--can-log``) by size or age, as python-can's rotating loggers rotate."""
    group.add_argument(
        f"{option}-rotate", type=rotation_limits, default=(0, 0.0), metavar="AT",
        help="new part at a size or an age: 10M, 1h or 10M,1h",
    )  # fmt: skip


def check_log_rotation(path: str | None, limits: tuple[int, float], option: str) -> None:
    """Refuse, before any work, a rotation the log cannot have: no log, a format python-can
    does not rotate, parts of an earlier rotated log in the way (they would be mixed with the
    new ones)."""
    from northfinder.driver.framelog import check_rotation, log_parts

    max_bytes, max_seconds = limits
    if not (max_bytes or max_seconds):
        return
    if path is None:
        raise HostConfigError(f"{option}-rotate: rotates a log; give {option} FILE")
    try:
        check_rotation(path, max_bytes, max_seconds)
    except ArgumentError as exc:
        raise HostConfigError(f"{option} {exc}") from None
    old = log_parts(path)
    if old:
        raise HostConfigError(
            f"{option} {path}: {len(old)} part(s) of an earlier rotated log are in the way "
            f"({old[0].name} ...); move them or choose another name"
        )


def _workers(text: str) -> int:
    value = whole_number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1: {text!r}")
    return value


def _dask_address(text: str) -> str:
    from northfinder.host.distributed import parse_dask_address
    from northfinder.host.errors import HostConfigError

    try:
        parse_dask_address(text)
    except HostConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("dask: ")) from None
    return text


def add_execution_arguments(parser: argparse.ArgumentParser) -> None:
    """Where a Monte Carlo study runs: threads on this machine, or a Dask cluster."""
    g = common_group(parser, "execution (results for a seed are the same everywhere)")
    x = g.add_mutually_exclusive_group()
    x.add_argument(
        "--workers",
        type=_workers,
        default=None,
        metavar="N",
        help="threads on this machine (default: one per core)",
    )
    x.add_argument(
        "--dask",
        type=_dask_address,
        default=None,
        metavar="ADDRESS",
        help="run on the Dask cluster whose scheduler is at tcp://HOST:PORT, or on local:N "
        "(a local cluster of N worker processes); needs the dask extra",
    )


@contextlib.contextmanager
def study_executor(args: argparse.Namespace) -> Iterator[Executor | None]:
    """The executor of :func:`add_execution_arguments`' choice (None: run in this thread)."""
    from northfinder.host.montecarlo import local_executor

    if args.dask is not None:
        from northfinder.host.distributed import dask_executor

        with dask_executor(args.dask) as ex:
            yield ex
        return
    workers = args.workers or os.cpu_count() or 1
    if workers == 1:
        yield None
        return
    with local_executor(workers) as ex:
        yield ex
