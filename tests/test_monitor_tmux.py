"""The monitor as a user first meets it: ``northfinder monitor`` in a real terminal (tmux), on an
SLCAN pseudo-terminal to ``northfinder sim`` in another process. Every key of the screen's
bindings is pressed through tmux and the screen read back after each; ``q`` must end the process
within a few seconds and the terminal with it."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.importorskip("textual")
pytest.importorskip("textual_plotext")

from simprocess import fast_sensor_file, sim_process

from northfinder.monitor.app import MonitorApp

TMUX = shutil.which("tmux")
pytestmark = [
    pytest.mark.realtime,
    pytest.mark.subprocess,
    pytest.mark.skipif(TMUX is None, reason="tmux is not installed"),
]

#: Longest wall time for the screen to show what a key should (a busy shared host is slow).
SHOW_WITHIN_S = 30.0
#: Longest wall time from ``q`` to the process's end.
QUIT_WITHIN_S = 5.0


class Terminal:
    """A detached tmux session of its own server (its own socket, no user configuration)."""

    def __init__(self, command: str, *, width: int = 160, height: int = 50) -> None:
        assert TMUX is not None
        self.base = [TMUX, "-L", f"northfinder-test-{os.getpid()}", "-f", os.devnull]
        self.name = "monitor"
        self.tmux("new-session", "-d", "-s", self.name, "-x", str(width), "-y", str(height),
                  command)  # fmt: skip

    def tmux(self, *args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [*self.base, *args], capture_output=True, text=True, check=check, timeout=10
        )

    def alive(self) -> bool:
        return self.tmux("has-session", "-t", self.name, check=False).returncode == 0

    def screen(self) -> str:
        if not self.alive():
            return "(the terminal is gone)"
        return self.tmux("capture-pane", "-p", "-t", self.name).stdout

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", self.name, *keys)

    def wait(self, what: str, shows: Callable[[str], bool], within: float = SHOW_WITHIN_S) -> str:
        """The screen once ``shows(screen)``; fails naming ``what`` with the last screen."""
        deadline = time.monotonic() + within
        while True:
            screen = self.screen()
            if shows(screen):
                return screen
            if time.monotonic() > deadline:
                size = self.tmux(
                    "display",
                    "-p",
                    "-t",
                    self.name,
                    "#{window_width}x#{window_height}",
                    check=False,
                ).stdout
                pytest.fail(
                    f"the screen ({size.strip()}) did not show {what} within {within} s:\n{screen}"
                )
            time.sleep(0.1)

    def close(self) -> None:
        self.tmux("kill-server", check=False)


def has(*words: str) -> Callable[[str], bool]:
    return lambda screen: all(w in screen for w in words)


def lacks(*words: str) -> Callable[[str], bool]:
    return lambda screen: not any(w in screen for w in words)


def one_line_an_id(screen: str) -> bool:
    """The frame view's rows: each on one line (cut with an ellipsis, never wrapped)."""
    lines = screen.splitlines()
    head = next(i for i, x in enumerate(lines) if x.lstrip().startswith("id       dir"))
    rows = [x for x in lines[head + 1 : -1] if x.strip()]
    return bool(rows) and all(re.match(r"\s*[0-9A-F]{3,8} +(rx|tx) ", x) for x in rows)


def banner(screen: str) -> str:
    return screen.splitlines()[0] if screen else ""


def test_every_key_in_tmux_against_a_simulator_process(tmp_path: Path):
    bound = {b.key for b in MonitorApp.BINDINGS}  # type: ignore[union-attr]
    pressed: set[str] = set()
    record = tmp_path / "monitor.asc"
    status = tmp_path / "status"
    # The fast table: a move and its settling take a second, not ten.
    sensor = fast_sensor_file(tmp_path)
    sim = ["--slcan-pty", "--warmup", "0", "--sensor", str(sensor), "--control", "127.0.0.1:0"]
    with sim_process(*sim) as facts:
        monitor = [
            sys.executable, "-c", "from northfinder.cli import main; raise SystemExit(main())",
            "monitor", "-i", "slcan", "-c", facts["pty"], "-b", "500000",
            "--bus-kwargs", "sleep_after_open=0", "--latitude", "34", "--window", "2",
            "--record", str(record),
        ]  # fmt: skip
        # Its exit status to a file; on a failure the terminal stays a minute to be read.
        line = shlex.join(monitor)
        command = f"{line}; s=$?; echo $s > {shlex.quote(str(status))}; [ $s = 0 ] || sleep 60"
        # The terminal's own size, not one a parent process left in COLUMNS and LINES.
        term = Terminal(f"unset COLUMNS LINES; cd {shlex.quote(str(tmp_path))} && {command}")
        try:

            def key(k: str, *then: str) -> None:
                pressed.add(k)
                term.keys(k, *then)

            term.wait("the unit READY with its stream on",
                      lambda s: banner(s).strip().startswith("READY")
                      and "stream    on" in s and "commands and events" in s,
                      within=60.0)  # fmt: skip

            # t: a question for the angle; 90 and Enter rotate the table, its target shown
            key("t")
            term.wait("the rotate-to question", has("Rotate the table to (deg, encoder):"))
            term.keys("9", "0", "Enter")
            term.wait("the rotation's command and target",
                      has("ROTATE_TO 90.000 deg -> OK", "target     90.0000 deg"))  # fmt: skip
            # s: the table stops
            key("s")
            term.wait("the stop", has("STOP -> OK"))
            term.wait("the table settled", lambda s: banner(s).strip().startswith("READY"))
            # b: a question; a bad angle is refused in it, Escape cancels and nothing is sent
            key("b")
            term.wait("the rotate-by question", has("Rotate the table by (deg, + counter-"))
            term.keys("x", "Enter")
            term.wait("the refusal of a bad angle", has("not an angle from -720 to 720 deg"))
            term.keys("Escape")
            screen = term.wait("the question gone", lacks("Rotate the table by"))
            assert "ROTATE_BY" not in screen
            # h: home
            key("h")
            term.wait("the homing", has("HOME -> OK"))
            term.wait("the table home", lambda s: banner(s).strip().startswith("READY"))
            # o: the stream off, o again on
            key("o")
            term.wait("the stream off", has("stream    off", "STREAM_STOP -> OK"))
            term.keys("o")
            term.wait("the stream on again", has("stream    on"))
            # p: the traces paused, p again resumes them
            key("p")
            term.wait("the traces paused", has("PAUSED (p resumes)"))
            term.keys("p")
            term.wait("the traces running", lacks("PAUSED"))
            # a: the traces' y scale fixed, a again automatic
            key("a")
            term.wait("a fixed scale", has("gyro, deg/h, y fixed (a)"))
            term.keys("a")
            term.wait("an automatic scale", has("gyro, deg/h, y auto (a)"))
            # m: the frame view, decoded rows; Escape returns to the panels
            key("m")
            term.wait("the frame view",
                      has("frames of the link: all frames", "SAMPLE", "STATUS"))  # fmt: skip
            # its own keys: / asks for a filter (the rows of one message), p pauses the view
            term.keys("/")
            term.wait("the filter question", has("Show the frames whose name or id has:"))
            term.keys("S", "T", "A", "T", "U", "S", "Enter")
            term.wait("the filtered view",
                      lambda s: "filter 'STATUS', 2 ids" in s and " SAMPLE " not in s
                      and one_line_an_id(s))  # fmt: skip
            term.keys("p")
            term.wait("the frame view paused", has("2 ids  PAUSED (p resumes)"))
            term.keys("Escape")
            term.wait("the panels again", has("commands and events", "─ unit "))
            # w: every frame recorded to --record, w again stops (the file then holds them)
            key("w")
            term.wait("the recording", has("recording every frame to"))
            key("w")
            term.wait("the recording stopped", has("recording stopped:"))
            assert record.stat().st_size > 0
            # r: the unit resets and comes back READY
            key("r")
            term.wait("the reset", has("RESET -> OK"))
            term.wait("the unit READY again", lambda s: "READY" in banner(s), within=60.0)
            # f: a find starts on the plan of the command line (2 s windows, 4 positions)
            key("f")
            term.wait("the find under way", lambda s: re.search(r"position \d/4", s) is not None)
            # q: quits at once, even with a find running
            assert bound - {"q"} <= pressed, f"keys without a case: {sorted(bound - pressed)}"
            key("q")
            t0 = time.monotonic()
            while term.alive() and time.monotonic() - t0 < QUIT_WITHIN_S:
                time.sleep(0.05)
            waited = time.monotonic() - t0
            assert not term.alive(), f"q not answered in {waited:.1f} s:\n{term.screen()}"
            assert status.read_text().strip() == "0"
        finally:
            term.close()
    assert pressed == bound
