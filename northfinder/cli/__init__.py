"""The ``northfinder`` command line: one module per subcommand, each with ``add_parser`` and ``run``.

Every subcommand's errors derive from the packages' root exceptions (``HostError``, ``DriverError``,
``SimError``); they are printed as one line naming what is wrong, with the exit status of
:mod:`northfinder.cli.exits` (2: the request is wrong, 1: the work failed). ``--debug``
shows the traceback instead.

SIGINT (Ctrl-C), SIGTERM and SIGHUP end a command the same way: the work stops, a device the
command opened is left at rest (STOP for a move it commanded, STREAM_STOP for a stream it started),
logs are closed, one line says what was done, and the exit status is 128 + the signal's number
(130, 143, 129).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import signal
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from typing import Any

from northfinder.cli.exits import (
    EXIT_INTERRUPTED,
    EXIT_RUNTIME,
    EXIT_USAGE,
    SignalInterrupt,
    ending_of,
    report_error,
)
from northfinder.cli.parsers import (
    SUMMARIES,
    OneLineParser,
    command_parser,
    common_group,
    order_groups,
)
from northfinder.driver.errors import DriverError
from northfinder.firmware_sim.errors import SimError
from northfinder.host.errors import HostError

#: Subcommand name -> module in this package. A command's module (and what it imports: scipy,
#: PyWavelets, python-can, the simulator) is imported only when that command runs, so that
#: ``northfinder --help`` and each command start quickly and a broken optional dependency of one
#: command does not break the others.
COMMANDS: dict[str, str] = {
    "simulate": "northfinder.cli.simulate",
    "sim": "northfinder.cli.sim",
    "simctl": "northfinder.cli.simctl",
    "conformance": "northfinder.cli.conformance",
    "study": "northfinder.cli.study",
    "sweep": "northfinder.cli.sweep",
    "solve": "northfinder.cli.solve",
    "find": "northfinder.cli.find",
    "record": "northfinder.cli.record",
    "calibrate": "northfinder.cli.calibrate",
    "monitor": "northfinder.cli.monitor",
    "dump": "northfinder.cli.dump",
    "reset": "northfinder.cli.reset",
    "accept": "northfinder.cli.accept",
}


#: The packages' root exceptions (``exits.EXIT_STATUS`` gives each kind its exit status).
ROOT_ERRORS: tuple[type[Exception], ...] = (HostError, SimError, DriverError)


LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")


def _log_level(text: str) -> str:
    name = text.upper()
    if name not in LOG_LEVELS:
        raise argparse.ArgumentTypeError(f"choose one of {', '.join(LOG_LEVELS)}, got {text!r}")
    return name


def add_global_options(parser: argparse.ArgumentParser, *, sub: bool = False) -> None:
    """``--debug``, ``-v`` and ``--log-level`` (and ``--version``), before or after the
    subcommand. On a
    subcommand their defaults are left out, so that an option given before it stays."""
    default: dict[str, Any] = {"default": argparse.SUPPRESS} if sub else {}
    g = common_group(parser, "logging and debugging") if sub else parser
    if sub:  # the top-level parser has its own --version
        from northfinder.host.results import package_version

        g.add_argument(
            "--version", action="version", version=f"northfinder {package_version()}",
            help="print the version and exit",
        )  # fmt: skip
    g.add_argument(
        "--debug", action="store_true", help="show tracebacks on errors", **default
    )  # fmt: skip
    g.add_argument(
        "-v", "--verbose", action="count", dest="verbose",
        help="log more on stderr: -v info, -vv debug", **({"default": 0} if not sub else default),
    )  # fmt: skip
    g.add_argument(
        "--log-level", type=_log_level, metavar="LEVEL", dest="log_level",
        help=f"log level on stderr: {', '.join(LOG_LEVELS)} (default WARNING; sim: INFO)",
        **({"default": None} if not sub else default),
    )  # fmt: skip


def _configure_logging(args: argparse.Namespace) -> None:
    """Set the log level when one was asked for (a subcommand may set its own default)."""
    level = args.log_level
    if level is None and args.verbose:
        level = "INFO" if args.verbose == 1 else "DEBUG"
    if level is None:
        return
    logging.basicConfig(
        level=getattr(logging, level),
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger().setLevel(getattr(logging, level))


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line. With ``only`` a command's name, only that command's module is imported
    (the others are listed by name and summary); otherwise every command's."""
    from northfinder.host.results import package_version

    parser = OneLineParser(prog="northfinder", description="Workbench for gyro north finders.")
    parser.add_argument("--version", action="version", version=f"northfinder {package_version()}")
    add_global_options(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=SUMMARIES[name], add_help=False)
            continue
        module = importlib.import_module(module_name)
        p = command_parser(sub, name, module.__doc__)
        module.add_arguments(p)
        add_global_options(p, sub=True)
        order_groups(p)
        p.set_defaults(_run=module.run)
    return parser


def _command_of(argv: Sequence[str]) -> str:
    """The command named on the command line ("" if none: then no command module is needed)."""
    takes_value = False
    for arg in argv:
        if takes_value:
            takes_value = False
        elif arg == "--log-level":
            takes_value = True  # its value is no command
        elif not arg.startswith("-"):
            return arg if arg in COMMANDS else ""
    return ""


#: Signals that end a command as Ctrl-C does (SIGINT is Ctrl-C itself).
ENDING_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Seconds after the first ending signal during which more are ignored: the clean-up (STOP,
#: STREAM_STOP, a few replies) runs to its end; a signal after that interrupts it.
CLEANUP_GRACE_S = 3.0


@contextlib.contextmanager
def ending_signals() -> Iterator[None]:
    """SIGINT, SIGTERM and SIGHUP raise :class:`~northfinder.cli.exits.SignalInterrupt` (a
    KeyboardInterrupt) in the main thread, so that every ending runs the same clean-up; the
    previous handlers come back afterwards. Outside the main thread nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    first: list[float] = []

    def handler(signum: int, frame: Any) -> None:
        now = time.monotonic()
        if first and now - first[0] < CLEANUP_GRACE_S:
            return  # leaving already: let the clean-up finish
        first[:] = [now]
        raise SignalInterrupt(signum)

    previous = {}
    for sig in ENDING_SIGNALS:
        with contextlib.suppress(OSError, ValueError):
            previous[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            with contextlib.suppress(OSError, ValueError, TypeError):
                signal.signal(sig, old)


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    with ending_signals():
        try:
            return _main(argv)
        except KeyboardInterrupt as exc:  # while a module loads, or while an error is reported
            return _interrupted(_command_of(argv) or "", exc)


def _main(argv: list[str]) -> int:
    parser = build_parser(only=_command_of(argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2, its line printed)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    _configure_logging(args)
    args._argv = list(argv)  # the command as given, for reports that state it
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt as exc:
        return _interrupted(args.command, exc)
    except BrokenPipeError:
        # The reader of stdout went away (``northfinder find --json | head``): nothing left to
        # say to it. Further writes to the closed pipe would fail again at exit.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_RUNTIME
    except Exception as exc:  # one line and a stated status for every error (exits.py)
        if _caused_by_interrupt(exc):
            # Ctrl-C stopped the work, and the clean-up that followed failed because of it
            # (a device left mid-command, an embedded simulator no longer stepped): the
            # interrupt is what happened, not the clean-up's error.
            if args.debug:
                raise
            return _interrupted(args.command, exc)
        if args.debug:
            raise
        return report_error(args.command, exc)


def _interrupt_in(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt in the error's chain of causes and contexts, if any."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


def _caused_by_interrupt(exc: BaseException) -> bool:
    """Whether a KeyboardInterrupt is in the error's chain of causes and contexts."""
    return _interrupt_in(exc) is not None


def _interrupted(command: str, exc: BaseException | None = None) -> int:
    """The one line of an ending signal (``interrupted: sent STOP and STREAM_STOP; the unit
    reads READY``), and its status: 128 + the signal's number (130 for Ctrl-C)."""
    interrupt = _interrupt_in(exc) if exc is not None else None
    signum = getattr(interrupt, "signum", signal.SIGINT)
    what = (
        "interrupted" if signum == signal.SIGINT else f"interrupted ({signal.Signals(signum).name})"
    )
    ending = ending_of(exc) if exc is not None else None
    if ending is not None:
        what += f": {ending}"
    try:
        print(f"northfinder{' ' + command if command else ''}: {what}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
    return EXIT_INTERRUPTED if signum == signal.SIGINT else 128 + int(signum)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
