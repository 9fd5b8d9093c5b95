"""How a command's parser is built: its summary in the command list, its description from
the module docstring, one-line usage errors (exit 2), and its option groups in a fixed order.
"""

from __future__ import annotations

import argparse
import re
from typing import Any, NoReturn

from northfinder.cli.exits import EXIT_USAGE

#: The one-line help of each command in the command list (:func:`command_parser` takes it from
#: here; the list shows it without importing the command's module).
SUMMARIES: dict[str, str] = {
    "simulate": "one simulated window per position, summarised: physics only, no device or link",
    "sim": "serve the simulated instrument on a link (CAN, serial, pty) for other commands",
    "simctl": "change a running sim through its control channel (truth, sensor, faults)",
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
