"""The ``northfinder`` command line: one module per subcommand, each with ``add_parser`` and ``run``.

Every subcommand's errors derive from the packages' root exceptions (``HostError``, ``DriverError``,
``SimError``); they are printed as one line naming what is wrong and the exit status is 2 for bad
arguments, 1 for anything else. ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from northfinder.driver.errors import DriverError
from northfinder.firmware_sim.errors import SimError
from northfinder.host.errors import HostError

#: Subcommand name -> module in this package. A command's module (and what it imports: scipy,
#: PyWavelets, python-can, the simulator) is imported only when that command runs, so that
#: ``northfinder --help`` and each command start quickly and a broken optional dependency of one
#: command does not break the others.
COMMANDS: dict[str, str] = {
    "simulate": "northfinder.host.cli.simulate",
    "sim": "northfinder.host.cli.sim",
    "simctl": "northfinder.host.cli.simctl",
    "conformance": "northfinder.host.cli.conformance",
    "study": "northfinder.host.cli.study",
    "solve": "northfinder.host.cli.solve",
    "find": "northfinder.host.cli.find",
    "record": "northfinder.host.cli.record",
    "calibrate": "northfinder.host.cli.calibrate",
}

#: The one-line help of each command, for the command list (the same text as each module's).
SUMMARIES: dict[str, str] = {
    "simulate": "summarise simulated windows (physics only)",
    "sim": "run the simulated instrument on a link",
    "simctl": "control a running simulator",
    "conformance": "check a unit on a link against protocol.md",
    "study": "Monte Carlo accuracy of a plan against the physical bound; plan search",
    "solve": "solve a recording offline",
    "find": "find true north",
    "record": "record raw windows to CSV or NPZ",
    "calibrate": "fit sensor terms to recordings and write a sensor TOML",
}


#: The packages' root exceptions: one line on stderr and exit status 1 (``--debug``: traceback).
ROOT_ERRORS: tuple[type[Exception], ...] = (HostError, SimError, DriverError)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line. With ``only`` a command's name, only that command's module is imported
    (the others are listed by name and summary); otherwise every command's."""
    parser = argparse.ArgumentParser(
        prog="northfinder", description="Workbench for gyro north finders."
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=SUMMARIES[name], add_help=False)
            continue
        module = importlib.import_module(module_name)
        p = module.add_parser(sub)
        p.set_defaults(_run=module.run)
    return parser


def _command_of(argv: Sequence[str]) -> str:
    """The command named on the command line ("" if none: then no command module is needed)."""
    for arg in argv:
        if not arg.startswith("-"):
            return arg if arg in COMMANDS else ""
    return ""


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(only=_command_of(argv))
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except ROOT_ERRORS as exc:
        if args.debug:
            raise
        print(f"northfinder {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
