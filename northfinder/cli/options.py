"""Options several commands share, spelled once: ``--positions``, ``--sensor``, ``--latitude``,
the simulated truth, ``--session``, ``--duration``, ``--solver``, ``KEY=VALUE`` lists.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from northfinder.cli.argtypes import (
    MAX_ANGLE_DEG,
    angle_list,
    bounded_float,
    bounded_int,
    key_value,
    seed_value,
)
from northfinder.cli.parsers import common_group


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
    from northfinder.host.kernels import (
        MAX_SOLVER_TILT_DEG,  # numpy: only for the commands that take it
    )

    tilt = bounded_float(-MAX_SOLVER_TILT_DEG, MAX_SOLVER_TILT_DEG, "deg (the solvers' tilt limit)")
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
