"""Every command line of README.md and docs/*.md runs as written, so the docs cannot drift.

The pages are found in the folder (a new page is covered without a change here). Every
``northfinder ...`` command of a page's ``sh`` and ``console`` blocks (see ``docpages``) is run in
this process, in the order of the page, in one folder a page (a later command reads what an
earlier one wrote), and must exit 0 (or fail as the page shows). Where a ``console`` block shows
output after the command, the printed lines must have its shape (the same words, as many
numbers) and, where the command fixes them with ``--seed`` (or solves what such a command
wrote), its numbers as the page rounds them.

A command that cannot run here is in :data:`NOT_RUN` with its reason, and one that runs beside a
simulator in another process is in :data:`BESIDE_A_SIMULATOR` (run by a ``realtime`` test on the
pseudo-terminal the simulator prints). A command in neither is run: a new command that needs
hardware fails the suite until it is listed, and an entry that matches no command fails too.
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import docpages
import pytest
from clirun import run_cli
from docpages import ROOT, Command, commands, output_mismatch, pages
from simprocess import sim_process

from northfinder.cli.exits import EXIT_INCONSISTENT, EXIT_NOT_RESOLVED
from northfinder.host.consistency import FAILED_MARKER

#: Commands of the pages that are not run, each with its reason: a pattern (matched against the
#: whole command, without its comment) -> why.
NOT_RUN: dict[str, str] = {
    r"northfinder \w+ -i socketcan -c vcan0( .*)?": "needs a CAN bus (SocketCAN vcan0: a kernel "
    "module and root to create it; scripts/hil runs the links on one)",
    r"northfinder \w+( \S+)*? --serial /dev/ttyUSB0( .*)?": "needs a unit on a serial port "
    "(/dev/ttyUSB0)",
    r"northfinder record \S+ \$UNIT .*": "$UNIT is the page's placeholder for a unit (a serial "
    "port or CAN bus); two windows of an hour each",
    r"northfinder calibrate still\.npz run\*\.npz .*": "reads the recordings of a unit ($UNIT) "
    "made just before it on the page",
    r"northfinder find --sim --sensor myunit\.toml": "reads myunit.toml, fitted from a unit's "
    "recordings just before it on the page",
    r"northfinder calibrate still\.blf run1\.blf .*": "reads a unit's logs (still.blf, run1.blf) "
    "that the page does not make",
    r"northfinder (solve bus_#\*\.log bus\.log|dump 'bus\*\.log') .*": "reads the rotated log "
    "of the simulator on vcan0 (sim -i socketcan ... --log bus.log) above it on the page",
    r"northfinder sweep --dask tcp://SCHEDULER-HOST:8786 .*": "SCHEDULER-HOST is a placeholder: "
    "needs a Dask scheduler and its workers",
    r"northfinder sim (--pty|--slcan-pty|-i socketcan) .*": "a simulator that serves until it is "
    "stopped (a process of its own; BESIDE_A_SIMULATOR runs the pages' that a command uses)",
    r"northfinder accept --datasheet rlg\.toml --batch units\.toml .*": "reads units.toml, the "
    "page's example of a units file, whose first unit is on a serial port (/dev/ttyUSB0); "
    "tests/test_accept.py runs batches of simulated units",
    r"northfinder monitor( .*)?": "the terminal UI runs until q: tests/test_monitor.py runs the "
    "page's monitor commands headless and presses every key, tests/test_monitor_tmux.py in tmux",
}

#: Commands run by :func:`test_commands_beside_a_simulator_run_on_its_pty`: a page's simulator
#: in the background and the commands that use its pseudo-terminal, and the second shell's
#: commands on its log. page -> the patterns of its commands that run there, in order.
BESIDE_A_SIMULATOR: dict[str, tuple[str, ...]] = {
    "README.md": (
        r"northfinder sim --pty --warmup 0 --speed 10 --azimuth 42 &",
        r"northfinder find --serial /dev/pts/2 --latitude 34",
    ),
    "docs/walkthrough.md": (
        r"northfinder sim --pty --warmup 0 --speed 5 --azimuth 42 --seed 5 --log sim\.log",
        r"northfinder find --serial /dev/pts/2 .*",
        r"northfinder record run2\.npz --serial /dev/pts/2 .*",
        r"northfinder (solve|dump) sim\.log .*",
    ),
}

#: The simulator with a control channel of docs/instrument.md, and the commands that talk to a
#: simulator's control channel (docs/cli.md's 127.0.0.1:7700), run by
#: :func:`test_simctl_commands_talk_to_a_simulator_s_control_channel` on the address it prints.
CONTROLLED_SIM = "northfinder sim --slcan-pty --control 127.0.0.1:0"
CONTROL_COMMANDS = r"northfinder simctl 127\.0\.0\.1:7700 .*"

#: Pages whose commands include Monte Carlo studies of 1000 runs or more (minutes on one core),
#: marked ``slow`` as tests/test_study.py's studies are.
SLOW_PAGES = {"docs/planner.md", "docs/spin.md", "docs/study.md"}

#: Commands whose shown figures are known to be out of date while the page is being revised:
#: their output is compared in shape, not in numbers. command -> why.
FIGURES_PENDING: dict[str, str] = {}

PAGES = pages()


def _listed(command: Command) -> str | None:
    """Why the command is not run by the page's test (None: it is)."""
    for pattern in BESIDE_A_SIMULATOR.get(command.page, ()):
        if re.fullmatch(pattern, command.text):
            return "runs beside the page's simulator (a realtime test)"
    if command.text == CONTROLLED_SIM or re.fullmatch(CONTROL_COMMANDS, command.text):
        return "runs on a simulator's control channel (a realtime test)"
    for pattern, reason in NOT_RUN.items():
        if re.fullmatch(pattern, command.text):
            return reason
    return None


def _check_output(command: Command, code: int, out: str, err: str, fixed: bool) -> None:
    """The command ended as the page shows: exit 0 and the shown output, or the shown error
    (with its numbers where they are ``fixed``)."""
    argv = shlex.split(command.text)
    seeded = fixed and command.text not in FIGURES_PENDING
    if command.shown and re.match(r"northfinder \w+: error: ", command.shown[0]):
        assert code != 0, f"{command}: exit 0, the page shows an error\n{out}"
        mismatch = output_mismatch(command.shown, err, seeded)
        assert mismatch is None, f"{command}: {mismatch}"
        return
    if code == EXIT_NOT_RESOLVED and argv[1:2] == ["accept"]:
        # A datasheet line the record was too short to decide: the documented outcome (exit 4),
        # said so in the report, with the length that would decide it.
        assert "NOT RESOLVED" in out + err, f"{command}\n{out}\n{err[-2000:]}"
        return
    if code == EXIT_INCONSISTENT and not fixed:
        # Unseeded, a correct instrument fails its consistency check at its stated
        # false-alarm rate (find's windows 1 %, a spin's halves 0.3 %): the documented outcome,
        # said so on the result.
        # In its text or its JSON's notes (--json): find's and a spin's alike.
        assert FAILED_MARKER in out, f"{command}\n{out}"
        return
    assert code == 0, f"{command}: exit status {code}\n{err[-2000:]}"
    mismatch = output_mismatch(command.shown, out, seeded)
    if mismatch is not None and err:
        # Log lines (-v) go to stderr, before the result on stdout.
        mismatch = output_mismatch(command.shown, err + "\n" + out, seeded)
    assert mismatch is None, f"{command}: {mismatch}"


def _run(command: Command, text: str | None = None, fixed: bool | None = None) -> None:
    """Run the command (or ``text``, its form here); its numbers are fixed by ``--seed``."""
    argv = shlex.split(text or command.text)
    code, out, err = run_cli(*argv[1:])
    _check_output(command, code, out, err, "--seed" in argv if fixed is None else fixed)


def _files(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}


def test_every_page_is_found_and_the_pages_have_commands():
    assert "README.md" in PAGES and "docs/walkthrough.md" in PAGES
    assert len(PAGES) == 1 + len(list((ROOT / "docs").glob("*.md")))
    all_commands = [c for page in PAGES for c in commands(page)]
    assert any(c.text == "northfinder find --sim --seed 1" for c in commands("README.md"))
    assert sum(_listed(c) is None for c in all_commands) >= 40
    assert sum(bool(c.shown) for c in all_commands) >= 15


def test_every_listed_command_is_on_a_page():
    """An entry of the lists that matches no command of the pages is stale."""
    texts = [c.text for page in PAGES for c in commands(page)]
    for pattern in NOT_RUN:
        assert any(re.fullmatch(pattern, t) for t in texts), f"NOT_RUN: {pattern}"
    for page, patterns in BESIDE_A_SIMULATOR.items():
        for pattern in patterns:
            assert any(re.fullmatch(pattern, c.text) for c in commands(page)), (page, pattern)
    assert CONTROLLED_SIM in texts
    assert any(re.fullmatch(CONTROL_COMMANDS, t) for t in texts)
    for text in FIGURES_PENDING:
        assert text in texts, text
    assert SLOW_PAGES <= set(PAGES)


def test_the_commands_not_run_here_and_why():
    """The list, as a reader of the test report sees it (``-rA``): every command of the pages
    that the page tests leave out has a reason."""
    lines = [f"{c}  -- {_listed(c)}" for page in PAGES for c in commands(page) if _listed(c)]
    print("\n".join(lines))
    assert all(" -- " in line and not line.endswith("-- ") for line in lines)


@pytest.mark.parametrize(
    "page",
    [pytest.param(p, marks=pytest.mark.slow) if p in SLOW_PAGES else p for p in PAGES],
)
def test_a_page_s_commands_run_in_order(page, tmp_path, monkeypatch):
    """The page's commands one after the other, as a reader types them, in one folder: a later
    command reads what an earlier one wrote (record before solve). One test a page, so that no
    scheduler can run a page's commands apart; the first that fails is named with its place."""
    monkeypatch.chdir(tmp_path)
    seeded: set[str] = set()  # files last written by a command with --seed
    for command in commands(page):
        if _listed(command) is not None:
            continue
        argv = shlex.split(command.text)
        before = _files(tmp_path)
        reads = [a for a in argv[2:] if a in before]
        # A solve of what seeded commands wrote is as fixed as they are (not a dump: a log's
        # timestamps are the wall clock's).
        fixed = "--seed" in argv or (argv[1] == "solve" and bool(reads) and set(reads) <= seeded)
        _run(command, fixed=fixed)
        after = _files(tmp_path)
        written = {name for name, t in after.items() if before.get(name) != t}
        seeded = (seeded - written) | (written if "--seed" in argv else set())


@pytest.mark.realtime
@pytest.mark.parametrize("page", sorted(BESIDE_A_SIMULATOR))
def test_commands_beside_a_simulator_run_on_its_pty(page, tmp_path, monkeypatch):
    """The page's ``northfinder sim --pty`` in another process, and the commands after it on the
    pty it prints (the page's ``/dev/pts/2``), in this one; the second shell's commands on the
    simulator's log while it still runs."""
    monkeypatch.chdir(tmp_path)
    selected = [
        c for c in commands(page) if any(re.fullmatch(p, c.text) for p in BESIDE_A_SIMULATOR[page])
    ]
    sim, rest = selected[0], selected[1:]
    args = shlex.split(sim.text.removesuffix("&"))[2:]
    with sim_process(*args, wanted=("pty", "truth")) as facts:
        pty = facts["pty"]
        printed = f"pty {pty}\ntruth {facts['truth']}\n"
        shown = tuple(line.replace("/dev/pts/2", pty) for line in sim.shown)
        mismatch = output_mismatch(shown, printed, "--seed" in sim.text)
        assert mismatch is None, f"{sim}: {mismatch}"
        for command in rest:
            _run(command, command.text.replace("/dev/pts/2", pty))


@pytest.mark.realtime
def test_simctl_commands_talk_to_a_simulator_s_control_channel(tmp_path, monkeypatch):
    """docs/instrument.md's simulator with a control channel, and every ``simctl`` command of
    the pages on the address it prints (the pages' 127.0.0.1:7700)."""
    monkeypatch.chdir(tmp_path)
    control = [c for p in PAGES for c in commands(p) if re.fullmatch(CONTROL_COMMANDS, c.text)]
    args = shlex.split(CONTROLLED_SIM)[2:]
    with sim_process(*args, wanted=("pty", "control", "truth")) as facts:
        for command in control:
            _run(command, command.text.replace("127.0.0.1:7700", facts["control"]))


def test_the_comparison_tells_a_changed_label_a_lost_field_and_a_seeded_figure():
    shown = ("azimuth 184.1778 deg +- 0.0579 (1 sigma), clockwise from true north", "...")
    printed = "azimuth 184.17779 deg +- 0.0579 (1 sigma), clockwise from true north\nmore\n"
    assert output_mismatch(shown, printed, numbers=True) is None  # the page's rounding
    assert output_mismatch(shown, printed.replace("184.17779", "184.1790"), True) is not None
    assert output_mismatch(shown, printed.replace("184.17779", "184.1790"), False) is None
    assert output_mismatch(shown, printed.replace("azimuth", "heading"), False) is not None
    assert output_mismatch(shown, printed.replace("+- 0.0579 ", ""), False) is not None
    # Without an elision at the end the shown lines are the last printed ones.
    assert output_mismatch(shown[:1], printed, False) is not None
    # A line that ends in "..." shows the start of its line.
    assert output_mismatch(("azimuth 1.0 deg ...",), "azimuth 2.5 deg and more\n", False) is None
    assert output_mismatch(("azimuth 1.0 deg ...",), "azimuth 2.5 rad and more\n", False)


def test_a_page_s_blocks_give_its_commands_and_what_they_show(tmp_path, monkeypatch):
    page = tmp_path / "page.md"
    page.write_text(
        "```sh\npython3 -m venv .venv && .venv/bin/northfinder find --sim  # first\n"
        "northfinder sweep --sensors a \\\n    --runs 3\n```\n"
        "```console\n$ northfinder find --sim --seed 1\nazimuth 1 deg\n...\n$ ls\n```\n"
        "```console\nnorthfinder simctl HOST status\n```\n"
        "```text\nnorthfinder find: error: not a command\n```\n"
    )
    monkeypatch.setattr(docpages, "ROOT", tmp_path)
    found = commands("page.md")
    assert [c.text for c in found] == [
        "northfinder find --sim",
        "northfinder sweep --sensors a --runs 3",
        "northfinder find --sim --seed 1",
        "northfinder simctl HOST status",
    ]
    assert found[0].comment == "first"
    assert found[2].shown == ("azimuth 1 deg", "...")


def test_an_unseeded_command_s_exit_3_passes_only_where_its_result_says_so():
    """Unseeded, exit 3 is the documented false alarm when the printed result says it: the
    marker in its text, or in its JSON's notes where the page asks for ``--json``. Where the
    numbers are fixed (``--seed``, or a solve of what a seeded command wrote), exit 3 is a
    failure."""
    spin = next(c for c in commands("docs/spin.md") if c.text.endswith(" --json"))
    assert "--seed" not in spin.text
    marker = "CONSISTENCY CHECK FAILED: the two halves disagree beyond their noise"
    failed = json.dumps({"solver": "spin", "consistent": False, "notes": [marker]}, indent=2)
    _check_output(spin, EXIT_INCONSISTENT, failed, "", False)
    _check_output(spin, EXIT_INCONSISTENT, marker, "", False)
    silent = json.dumps({"solver": "spin", "consistent": False, "notes": []}, indent=2)
    for out in (silent, failed.replace(marker, "fine"), "{", ""):
        with pytest.raises(AssertionError):
            _check_output(spin, EXIT_INCONSISTENT, out, "", False)
    seeded = Command(spin.page, spin.index, spin.text + " --seed 1")
    with pytest.raises(AssertionError):
        _check_output(seeded, EXIT_INCONSISTENT, failed, "", True)
    # A solve of a seeded command's recording: no --seed of its own, but its numbers are fixed.
    solve = next(c for c in commands("README.md") if c.text.startswith("northfinder solve "))
    assert "--seed" not in solve.text
    with pytest.raises(AssertionError):
        _check_output(solve, EXIT_INCONSISTENT, marker, "", True)
