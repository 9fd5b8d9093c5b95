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

#: Subcommand name -> module in this package. Modules are imported lazily so that a broken optional
#: dependency of one command does not break the others.
COMMANDS: dict[str, str] = {
    "simulate": "northfinder.host.cli.simulate",
    "sim": "northfinder.host.cli.sim",
    "simctl": "northfinder.host.cli.simctl",
    "conformance": "northfinder.host.cli.conformance",
    "study": "northfinder.host.cli.study",
    "sweep": "northfinder.host.cli.sweep",
    "solve": "northfinder.host.cli.solve",
    "find": "northfinder.host.cli.find",
    "record": "northfinder.host.cli.record",
    "calibrate": "northfinder.host.cli.calibrate",
}


#: The packages' root exceptions: one line on stderr and exit status 1 (``--debug``: traceback).
ROOT_ERRORS: tuple[type[Exception], ...] = (HostError, SimError, DriverError)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="northfinder", description="Workbench for gyro north finders."
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in COMMANDS.values():
        module = importlib.import_module(module_name)
        p = module.add_parser(sub)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
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
