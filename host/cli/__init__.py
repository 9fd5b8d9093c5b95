"""The ``northfinder`` command line: one module per subcommand, each with ``add_parser`` and ``run``.

Every subcommand's errors derive from the packages' root exceptions (``HostError``, ``DriverError``,
``SimError``); they are printed as one line naming what is wrong, with the exit status of
:mod:`northfinder.host.cli.common` (2: the request is wrong, 1: the work failed). ``--debug``
shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from northfinder.driver.errors import DriverError
from northfinder.firmware_sim.errors import SimError
from northfinder.host.cli.common import EXIT_INTERRUPTED, EXIT_USAGE, report_error
from northfinder.host.errors import HostError

#: Subcommand name -> module in this package. Modules are imported lazily so that a broken optional
#: dependency of one command does not break the others.
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


#: The packages' root exceptions (``common.EXIT_STATUS`` gives each kind its exit status).
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
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2, its line printed)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except Exception as exc:  # one line and a stated status for every error (common.py)
        if args.debug:
            raise
        return report_error(args.command, exc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
