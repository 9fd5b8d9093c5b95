"""The help texts a terminal shows: plain text, the command's own options first, python-can's
bus options last."""

from __future__ import annotations

import io
import re
from contextlib import redirect_stdout

import pytest

from northfinder.cli import COMMANDS, main
from northfinder.cli.parsers import plain_text

#: Group titles several commands share (their own groups come before these).
COMMON_TITLES = {
    "serial link and simulation",
    "serial and pseudo-terminal links",
    "embedded simulator (--sim only)",
    "simulated truth",
    "execution (results for a seed are the same everywhere)",
    "logging and debugging",
}
BUS_TITLE = "bus arguments"


def help_text(command: str) -> str:
    buf = io.StringIO()
    with redirect_stdout(buf):
        assert main([command, "--help"]) == 0
    return buf.getvalue()


def section_titles(text: str) -> list[str]:
    """The group headings of a help text (``options``, ``plan``, ``bus arguments``, ...)."""
    return re.findall(r"^(\S[^\n]*):$", text, re.M)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_help_is_plain_text(command):
    text = help_text(command)
    assert "``" not in text, command
    assert not re.search(r":[a-z]+:`", text), command
    assert "More: docs/cli.md" in text


@pytest.mark.parametrize("command", list(COMMANDS))
def test_own_options_come_first_and_the_bus_options_last(command):
    titles = section_titles(help_text(command))
    shared = [i for i, t in enumerate(titles) if t in COMMON_TITLES]
    own = [i for i, t in enumerate(titles) if t not in COMMON_TITLES and t != BUS_TITLE]
    assert shared and own, titles  # every command has --debug and some option of its own
    if command != "simctl":  # its epilog (the operations) follows the option groups
        assert max(own) < min(shared), titles
    else:
        assert titles.index("options") < min(shared), titles
    if BUS_TITLE in titles:
        assert titles[-1] == BUS_TITLE and titles.count(BUS_TITLE) == 1, titles


def test_commands_with_a_link_show_the_bus_options_last_and_their_own_first():
    titles = section_titles(help_text("find"))
    assert titles[:3] == ["options", "plan", "NMEA 0183 output"]
    assert titles[-1] == BUS_TITLE


@pytest.mark.parametrize("command", ["find", "record", "sim", "conformance", "study"])
def test_the_long_help_texts_are_short(command):
    assert len(help_text(command).splitlines()) <= 95, command


def test_plain_text_drops_the_markup():
    doc = "``northfinder find``: see :class:`~northfinder.embed.SimulatedInstrument` and :mod:`a.b`.\n\nE::\n"
    assert plain_text(doc) == "northfinder find: see SimulatedInstrument and a.b.\n\nE:\n"
