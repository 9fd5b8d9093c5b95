"""The monitor's screen: a Textual application on a :class:`~northfinder.monitor.session.MonitorSession`.

The screen is redrawn from the session a few times a second (``refresh_hz``, default 10; the
traces at most ``plot_hz``), never from the link's thread: the link's reader only queues frames,
so however slow the terminal, the link is read in time. Commands run in worker threads, so a
slow or dead unit never freezes the screen; every error is a line in the log, never a traceback.
"""

from __future__ import annotations

import functools
import importlib.resources
import math
import threading
import time
from pathlib import Path
from typing import Any, ClassVar

from rich.text import Text
from textual import on
from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen, Screen
from textual.widgets import Footer, Input, Label, RichLog, Static
from textual_plotext import PlotextPlot

from northfinder.driver.errors import DriverError
from northfinder.driver.protocol import DBC_NODE, dbc_path
from northfinder.driver.protocol.constants import DeviceState
from northfinder.host.canlog import decode_signals
from northfinder.host.errors import HostError
from northfinder.host.heading import heading_text
from northfinder.host.plan import Plan
from northfinder.monitor.observer import FrameRow, LogEntry, Traces, View
from northfinder.monitor.session import ActiveSession, FindRun, MonitorSession

__all__ = ["MIN_SIZE", "FramesScreen", "MonitorApp"]

#: The smallest terminal the monitor draws in, columns x rows.
MIN_SIZE = (100, 30)
_LEVEL_STYLE = {
    "info": "",
    "ok": "green",
    "refused": "yellow",
    "warn": "yellow",
    "error": "bold red",
}
_AXES = ("x", "y", "z")
_TRACE_TITLES = {"gyro": "gyro, deg/h", "accel": "accelerometer about its means, m/s^2"}


def _num(value: float | None, fmt: str = ".3f", unit: str = "") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "---"
    return f"{value:{fmt}}{unit}"


class AskAngle(ModalScreen[float | None]):
    """A one-line question for an angle in degrees (Enter: go, Escape: cancel)."""

    DEFAULT_CSS = """
    AskAngle { align: center middle; }
    AskAngle > Vertical { width: 50; height: auto; border: round $accent; padding: 0 1;
                          background: $surface; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "cancel", "cancel")]

    def __init__(self, question: str) -> None:
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(self.question)
            yield Input(placeholder="degrees, e.g. 90", id="angle")
            yield Label("", id="problem")

    @on(Input.Submitted)
    def submitted(self, event: Input.Submitted) -> None:
        try:
            value = float(event.value)
            if not math.isfinite(value) or abs(value) > 720.0:
                raise ValueError
        except ValueError:
            self.query_one("#problem", Label).update(
                Text(f"not an angle from -720 to 720 deg: {event.value!r}", style="red")
            )
            return
        self.dismiss(value)

    def action_cancel(self) -> None:
        self.dismiss(None)


class MonitorApp(App[int]):
    """A live view of one unit on one link.

    Parameters
    ----------
    session : MonitorSession
        The link (active or passive), opened; closed when the app ends.
    plan : Plan
        What a find started with ``f`` measures.
    refresh_hz : float
        Screen updates per second (0: only when :meth:`refresh_view` is called, for tests).
    plot_hz : float
        Trace redraws per second, at most ``refresh_hz``.
    record_path : str
        The CAN log ``w`` writes (its ending picks the format).
    duration_s : float, optional
        Quit after this many wall seconds (a measurement run).
    on_gap : {"remeasure", "report", "fail"}
        What a find does with a window that lost ticks (as ``find --on-gap``).
    """

    TITLE = "northfinder monitor"
    # The footer lists every key at 120 columns; the command palette would take their room.
    ENABLE_COMMAND_PALETTE = False
    CSS = """
    Screen { layout: vertical; }
    #banner { height: 1; padding: 0 1; background: $primary-background; }
    #banner.alarm { background: darkred; color: white; text-style: bold; }
    #banner.warn { background: darkorange; color: black; text-style: bold; }
    #top { height: 13; }
    .panel { border: round $primary; padding: 0 1; height: 100%; }
    #unit { width: 38; }
    #stream { width: 34; }
    #link { width: 1fr; }
    #traces { height: 1fr; min-height: 8; }
    #traces PlotextPlot { width: 1fr; border: round $primary; }
    #bottom { height: 12; }
    #find { width: 50%; }
    #log { width: 1fr; border: round $primary; }
    #toosmall { display: none; width: 100%; height: 100%; content-align: center middle;
                text-style: bold; }
    Screen.toosmall #toosmall { display: block; }
    Screen.toosmall #banner, Screen.toosmall #top, Screen.toosmall #traces,
    Screen.toosmall #bottom { display: none; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("t", "rotate_to", "rotate to"),
        Binding("b", "rotate_by", "rotate by"),
        Binding("s", "stop", "stop"),
        Binding("h", "home", "home"),
        Binding("o", "stream", "stream"),
        Binding("f", "find", "find"),
        Binding("w", "record", "record"),
        Binding("r", "reset", "reset"),
        Binding("m", "frames", "frames"),
        Binding("p", "pause_traces", "pause"),
        Binding("a", "trace_scale", "scale"),
        Binding("q", "quit", "quit"),
    ]

    def __init__(
        self,
        session: MonitorSession,
        *,
        plan: Plan | None = None,
        refresh_hz: float = 10.0,
        plot_hz: float = 2.0,
        record_path: str = "monitor.asc",
        duration_s: float | None = None,
        on_gap: str = "remeasure",
    ) -> None:
        super().__init__()
        self.session = session
        self.on_gap = on_gap
        self.plan = plan or Plan((0.0, 180.0, 180.0, 0.0), 10.0)
        self.refresh_hz = float(refresh_hz)
        self.plot_hz = min(float(plot_hz), self.refresh_hz) if self.refresh_hz else 0.0
        self.record_path = record_path
        self.duration_s = duration_s
        self.find_run: FindRun | None = None
        self.ticks = 0
        self.tick_seconds = 0.0  # CPU seconds spent in refresh_view (this thread)
        self._last_plot = -math.inf
        self._shown: dict[str, str] = {}
        self._log_shown = 0
        self._log_last: LogEntry | None = None
        self._started = time.monotonic()
        self.traces_paused = False
        # y limits of each trace while the scale is fixed (None: each redraw scales to its data)
        self.trace_limits: dict[str, tuple[float, float]] | None = None
        self._trace_ranges: dict[str, tuple[float, float]] = {}

    @property
    def _main(self) -> Any:
        """The screen of the panels (the first): a question or the frame view on top of it
        does not hide them from the redraw."""
        return self.screen_stack[0]

    # -- layout -------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static("", id="banner")
        with Horizontal(id="top"):
            yield Static("", id="unit", classes="panel")
            yield Static("", id="stream", classes="panel")
            yield Static("", id="link", classes="panel")
        with Horizontal(id="traces"):
            yield PlotextPlot(id="gyro")
            yield PlotextPlot(id="accel")
        with Horizontal(id="bottom"):
            yield Static("", id="find", classes="panel")
            yield RichLog(id="log", max_lines=500, wrap=True, markup=False, min_width=20)
        yield Static("", id="toosmall")
        yield Footer()

    def on_mount(self) -> None:
        self._main.query_one("#unit").border_title = "unit"
        self._main.query_one("#stream").border_title = "stream"
        self._main.query_one("#link").border_title = "link"
        self._main.query_one("#find").border_title = "find"
        self._main.query_one("#log").border_title = "commands and events"
        self._trace_titles()
        self._check_size()
        self.refresh_view()
        if self.refresh_hz > 0:
            self.set_interval(1.0 / self.refresh_hz, self.refresh_view)
        if self.duration_s is not None:
            self.set_timer(self.duration_s, self.action_quit)

    def on_resize(self) -> None:
        self._check_size()

    def _check_size(self) -> None:
        w, h = self.size
        small = w < MIN_SIZE[0] or h < MIN_SIZE[1]
        self._main.set_class(small, "toosmall")
        if small:
            self._main.query_one("#toosmall", Static).update(
                f"The terminal is {w} x {h}: the monitor needs at least "
                f"{MIN_SIZE[0]} x {MIN_SIZE[1]}.\nEnlarge the window (q quits)."
            )

    # -- the periodic redraw ------------------------------------------------------------------
    def refresh_view(self) -> None:
        """Decode what the link brought and redraw the panels (the traces at most at
        ``plot_hz``). Never raises: a failure is a line in the log."""
        t0 = time.thread_time()
        try:
            self.session.poll()
            frames = self.screen if isinstance(self.screen, FramesScreen) else None
            if frames is not None:
                frames.show(self.session.observer)
            else:
                self._draw(self.session.observer.view())
        except Exception as exc:  # the screen must stay up whatever a panel trips on
            self.session.observer.note(f"display error: {exc!r}", "error")
        self.ticks += 1
        self.tick_seconds += time.thread_time() - t0

    def _set(self, wid: str, content: Any) -> None:
        key = content.plain if isinstance(content, Text) else str(content)
        if self._shown.get(wid) == key + str(getattr(content, "spans", "")):
            return
        self._shown[wid] = key + str(getattr(content, "spans", ""))
        self._main.query_one(f"#{wid}", Static).update(content)

    def _draw(self, v: View) -> None:
        self._set("banner", self._banner(v))
        self._set("unit", self._unit(v))
        self._set("stream", self._stream(v))
        self._set("link", self._link(v))
        self._set("find", self._find())
        self._draw_log(v)
        now = time.monotonic() if self.refresh_hz else v.now_s
        if self.traces_paused:
            return
        if self.plot_hz == 0 or now - self._last_plot >= 1.0 / self.plot_hz:
            self._last_plot = now
            self._draw_traces(self.session.observer.traces())

    def _banner(self, v: View) -> Text:
        s = self.session
        mode = "PASSIVE (listening only)" if s.passive else "active"
        where = f"{s.description}  {mode}"
        banner = self._main.query_one("#banner")
        if not s.connected:
            banner.set_classes("alarm")
            return Text(f"LINK LOST: {s.lost_reason or 'no link'}; reopening every 2 s ({where})")
        if v.status is None:
            banner.set_classes("alarm" if v.frames == 0 else "warn")
            what = "nothing received" if v.frames == 0 else "frames, but no status yet"
            return Text(
                f"NO STATUS from node {s.observer.node_id}: {what} (is the unit on, the node id "
                f"right, the bus up?)  {where}"
            )
        if v.silent:
            banner.set_classes("alarm")
            return Text(
                f"SILENT: no status for {v.status_age_s:.1f} s (the unit is off, restarting, or "
                f"the link is down); last state {v.state}  {where}"
            )
        if v.status.state == DeviceState.FAULT:
            banner.set_classes("alarm")
            return Text(f"FAULT: {v.faults}; r resets the unit  {where}")
        banner.set_classes("")
        rec = f"  recording {s.record_path}" if s.record_path else ""
        turning = "" if v.table_rate_dps is None else f" {v.table_rate_dps:+.3f} deg/s"
        return Text(f"{v.state}{turning}  {where}{rec}")

    def _unit(self, v: View) -> Text:
        t = Text()
        ident = v.identity
        if ident is None:
            t.append("identity: not seen yet\n", style="dim")
        else:
            fw = ".".join(map(str, ident.firmware_version))
            t.append(f"{ident.model} #{ident.serial_number}\n", style="bold")
            t.append(f"fw {fw}  protocol {ident.protocol_version[0]}."
                     f"{ident.protocol_version[1]}\n")  # fmt: skip
        style = "bold red" if v.state == "FAULT" else "bold"
        t.append("state    ")
        t.append(f"{v.state}\n", style=style)
        if v.state == "WARMUP":
            t.append(f"warm-up  {self._warmup_left(self.session.observer, short=True)}\n",
                     style="yellow")  # fmt: skip
        t.append(
            f"faults   {v.faults or '---'}\n", style="red" if v.faults not in ("", "none") else ""
        )
        t.append(f"table    {_num(v.angle_deg, '9.4f')} deg\n")
        if v.target_deg is not None:
            t.append(f"target   {v.target_deg:9.4f} deg\n", style="cyan")
        else:
            t.append("target   ---\n", style="dim")
        if v.table_rate_dps is not None:
            # measured / the rate SPIN asked for, as the stream's rate reads
            spin = "" if v.spin_rate_dps is None else f" / {v.spin_rate_dps:+.3f}"
            t.append(f"rate     {v.table_rate_dps:+.3f}{spin} deg/s\n", style="cyan")
        else:
            t.append("rate     ---\n", style="dim")
        t.append(f"temp     {_num(v.temperature_c, '7.2f')} degC\n")
        age = "---" if v.status_age_s is None else f"{v.status_age_s:.2f} s ago"
        t.append(f"status   {age}\n", style="dim")
        s = self.session
        if s.truth is not None:
            t.append(f"truth    azimuth {heading_text(s.truth.get('azimuth_deg', math.nan), 3)} deg\n",
                     style="magenta")  # fmt: skip
        return t

    def _stream(self, v: View) -> Text:
        t = Text()
        on = "on" if v.streaming else "off"
        t.append(f"stream    {on}\n", style="bold" if v.streaming else "dim")
        conf = "" if v.configured_rate_hz is None else f" / {v.configured_rate_hz} Hz"
        t.append(f"rate      {_num(v.rate_hz, '.1f')}{conf}\n")
        t.append(f"counter   {v.sample_counter if v.sample_counter is not None else '---'}\n")
        t.append(f"samples   {v.samples}\n")
        bad = "red" if v.gaps or v.ticks_lost else ""
        t.append(f"gaps      {v.gaps}  lost {v.ticks_lost}\n", style=bad)
        t.append(f"partial   {v.ticks_incomplete}  late {v.late}\n",
                 style="yellow" if v.ticks_incomplete or v.late else "")  # fmt: skip
        t.append(f"commands  {v.commands}  replies {v.replies}\n")
        t.append(f"refused   {v.refused}  unanswered {v.unanswered}\n",
                 style="yellow" if v.refused or v.unanswered else "")  # fmt: skip
        dev = "---" if v.device_rejected is None else str(v.device_rejected)
        t.append(f"unit: rejected {dev}  dropped "
                 f"{'---' if v.device_tx_dropped is None else v.device_tx_dropped}\n")  # fmt: skip
        return t

    def _link(self, v: View) -> Text:
        t = Text()
        stats = self.session.link_stats()
        t.append(f"frames seen  {v.frames}\n")
        t.append(f"not protocol {v.frames_unknown}  malformed {v.frames_malformed}\n")
        t.append(f"other nodes  {v.frames_other_node}\n")
        if stats is None:
            t.append("driver: none (passive)\n", style="dim")
            return t
        names = (
            ("received", "frames_received"), ("rejected", "frames_rejected"),
            ("lost", "frames_lost"), ("ticks lost", "ticks_lost"),
            ("incomplete", "ticks_incomplete"), ("retries", "retries"),
            ("timeouts", "reply_timeouts"), ("stray", "stray_replies"),
            ("resets", "resets_detected"),
        )  # fmt: skip
        t.append("driver\n", style="bold")
        for i, (label, key) in enumerate(names):
            value = stats.get(key, 0)
            style = "red" if value and key not in ("frames_received",) else ""
            t.append(f" {label:<10} {value:>7}", style=style)
            t.append("\n" if i % 2 else " ")
        return t

    def _find(self) -> Text:
        run = self.find_run
        t = Text()
        s = self.session
        if run is None:
            if s.passive:
                t.append("passive: a find run by another host shows in the log and the traces\n",
                         style="dim")  # fmt: skip
            else:
                positions = ", ".join(f"{p:g}" for p in self.plan.positions_deg)
                t.append(f"f starts a find: positions {positions} deg, "
                         f"{self.plan.window_s:g} s windows\n", style="dim")  # fmt: skip
                if s.latitude_deg is None:
                    t.append("(needs --latitude)\n", style="yellow")
            return t
        p = run.progress
        if p is not None and not run.finished:
            obs = s.observer
            if p.phase == "warm-up":
                t.append(f"warm-up: {self._warmup_left(obs)}\n", style="bold")
            else:
                left = run.seconds_left(s.clock.now(), obs.pace())
                more = "" if left is None else f", ~{left:.0f} s left"
                t.append(f"{p.phase} position {p.position}/{p.positions}{more}\n", style="bold")
        for line in run.gaps:
            t.append(f"{line}\n", style="yellow")
        for i, w in enumerate(run.windows):
            t.append(f"w{i + 1} {w.encoder_deg:8.3f} deg  gx {w.gyro_dph[0]:+9.4f}  "
                     f"gy {w.gyro_dph[1]:+9.4f} deg/h\n")  # fmt: skip
        truth = run.truth_deg
        for sol in run.solutions[-3:]:
            sig = "---" if sol.sigma_deg is None else f"{sol.sigma_deg:.3f}"
            t.append(f"{sol.windows} windows: {heading_text(sol.azimuth_deg, 3):>8} +- {sig} deg")
            if truth is not None:
                err = (sol.azimuth_deg - truth + 180.0) % 360.0 - 180.0
                t.append(f"  error {err:+.3f}", style="magenta")
            t.append("\n")
        r = run.result
        if r is not None:
            sig = "---" if r.sigma_deg is None else f"{r.sigma_deg:.3f}"
            t.append(f"azimuth {heading_text(r.azimuth_deg, 3)} +- {sig} deg", style="bold green")
            check = {True: "consistent", False: "INCONSISTENT", None: "not checked"}[r.consistent]
            t.append(f"  {check}\n", style="green" if r.consistent else "yellow")
        if truth is not None:
            t.append(f"truth   {heading_text(truth, 3)} deg (simulated)\n", style="magenta")
        if run.error:
            t.append(f"failed: {run.error}\n", style="bold red")
        return t

    def _warmup_left(self, obs: Any, *, short: bool = False) -> str:
        """The warm-up's time left where it is known (a simulated unit says how long it warms
        up), else how long the unit has been warming up."""
        since = obs.unit_seconds()
        truth = self.session.truth or {}
        total = truth.get("warmup_s")
        if since is None:
            return "time left not known yet" if short else "the unit's time is not known yet"
        if total is None:
            if short:
                return f"{since:.0f} s so far"
            return (
                f"the unit has run {since:.0f} s; it does not say how long its warm-up lasts "
                "(a few minutes)"
            )
        pace = obs.pace() or 1.0
        left = max(0.0, float(total) - since) / max(pace, 1e-9)
        if short:
            return f"~{left:.0f} s left"
        return f"~{left:.0f} s left (warm-up {float(total):g} s, the unit has run {since:.0f} s)"

    def _draw_log(self, v: View) -> None:
        log = self._main.query_one("#log", RichLog)
        entries = v.log
        if not entries:
            return
        # Write only the entries after the last one written.
        start = 0
        if self._log_last is not None:
            for i in range(len(entries) - 1, -1, -1):
                if entries[i] is self._log_last:
                    start = i + 1
                    break
        for e in entries[start:]:
            line = Text(f"{e.time_s - v.t0_s:9.3f}  ", style="dim")
            line.append(e.text, style=_LEVEL_STYLE.get(e.level, ""))
            log.write(line)
        self._log_last = entries[-1]

    def _draw_traces(self, tr: Traces | None) -> None:
        for name, attr in (("gyro", "gyro_dph"), ("accel", "accel_mps2")):
            plot = self._main.query_one(f"#{name}", PlotextPlot)
            plt = plot.plt
            plt.clear_data()
            if tr is None or tr.samples < 2:
                plt.title("no samples (o starts the stream)")
                plot.refresh()
                continue
            data = getattr(tr, attr)
            means = tr.mean_gyro_dph if name == "gyro" else tr.mean_accel_mps2
            x = tr.time_s.tolist()
            lo, hi = math.inf, -math.inf
            for k, axis in enumerate(_AXES):
                # The accelerometers read about 0, 0 and g: on one scale x and y would be flat
                # lines, so each is drawn about its mean (which the label gives).
                y = data[:, k] - (means[k] if name == "accel" else 0.0)
                lo, hi = min(lo, float(y.min())), max(hi, float(y.max()))
                plt.plot(x, y.tolist(), label=f"{axis} mean {means[k]:+.4g}", marker="braille")
            self._trace_ranges[name] = (lo, hi)
            limits = None if self.trace_limits is None else self.trace_limits.get(name)
            if limits is not None:
                plt.ylim(*limits)
            plt.title(f"last {tr.seconds:.1f} s, {tr.samples} samples")
            plt.xlabel("s")
            plot.refresh()

    # -- keys ---------------------------------------------------------------------------------
    def _active(self) -> ActiveSession | None:
        s = self.session
        if isinstance(s, ActiveSession):
            return s
        self.session.observer.note("passive mode: the monitor sends nothing", "warn")
        self.refresh_view()
        return None

    def _command(self, label: str, call: Any) -> None:
        """Run a device call in a worker thread; its error is a line in the log."""
        s = self._active()
        if s is None:
            return

        def work() -> None:
            try:
                call(s.require())
            except Exception as exc:  # a line in the log, never a traceback on the screen
                s.report(label, exc)

        self.run_worker(work, thread=True, group="commands", name=label)

    def _move_asked(self, prompt: str, label: str, move: Any) -> None:
        """Ask for an angle (``prompt``), then run ``move(device, angle)`` as :meth:`_command`."""
        if self._active() is None:
            return

        def go(angle: float | None) -> None:
            if angle is not None:
                self._command(label, lambda d: move(d, angle))

        self.push_screen(AskAngle(prompt), go)

    def action_rotate_to(self) -> None:
        self._move_asked(
            "Rotate the table to (deg, encoder):",
            "rotate to",
            lambda d, angle: d.rotate_to(angle, wait=False),
        )

    def action_rotate_by(self) -> None:
        self._move_asked(
            "Rotate the table by (deg, + counter-clockwise):",
            "rotate by",
            lambda d, delta: d.rotate_by(delta, wait=False),
        )

    def action_stop(self) -> None:
        self._command("stop", lambda d: d.stop())

    def action_home(self) -> None:
        self._command("home", lambda d: d.home(wait=False))

    def action_reset(self) -> None:
        self._command("reset", lambda d: d.reset(wait=False))

    def action_stream(self) -> None:
        def toggle(d: Any) -> None:
            on = not d.streaming
            if isinstance(self.session, ActiveSession):
                self.session.stream_on_ready(on)  # kept as chosen after a find or a reset
            if on:
                d.start_streaming()
            else:
                d.stop_streaming()

        self._command("stream", toggle)

    def action_record(self) -> None:
        s = self.session
        if s.record_path:

            def stop() -> None:  # closing a log flushes it (an SQLite log drains its queue)
                try:
                    path = s.stop_recording()
                except (DriverError, HostError, OSError) as exc:
                    s.observer.note(f"record: {exc}", "error")
                else:
                    if path is not None:
                        s.observer.note(f"recording stopped: {path}", "ok")

            self.run_worker(stop, thread=True, group="record", name="record")
        else:
            path = self.record_path
            try:
                s.start_recording(path)
            except (DriverError, HostError, OSError) as exc:
                s.observer.note(f"record: {exc}", "error")
            else:
                s.observer.note(f"recording every frame to {Path(path).resolve()}", "ok")
        self.refresh_view()

    def action_find(self) -> None:
        s = self._active()
        if s is None:
            return
        if self.find_run is not None and not self.find_run.finished:
            s.observer.note("a find is running", "warn")
            return
        if s.latitude_deg is None:
            s.observer.note("find: give the site's latitude (--latitude)", "error")
            return
        truth = None if s.truth is None else s.truth.get("azimuth_deg")
        run = FindRun(self.plan, float(s.latitude_deg), truth_deg=truth, on_gap=self.on_gap)
        self.find_run = run

        def work() -> None:
            try:
                run.run(s)
            except (DriverError, HostError):
                pass  # FindRun put it in the log and on the panel
            except Exception as exc:
                run.error = f"internal error {exc!r}"
                s.observer.note(f"find: internal error {exc!r}", "error")

        self.run_worker(work, thread=True, group="find", name="find")

    def action_frames(self) -> None:
        """The frame view: one row per CAN id of the link."""
        self.push_screen(FramesScreen())
        self.refresh_view()

    def action_pause_traces(self) -> None:
        """Freeze the traces (the link is read on; p again resumes them)."""
        self.traces_paused = not self.traces_paused
        self._trace_titles()
        if not self.traces_paused:
            self._last_plot = -math.inf
            self.refresh_view()

    def action_trace_scale(self) -> None:
        """The traces' y scale: fixed at the range they show now, or each redraw's own."""
        if self.trace_limits is None:
            self.trace_limits = {
                name: (lo, hi) if hi > lo else (lo - 1.0, hi + 1.0)
                for name, (lo, hi) in self._trace_ranges.items()
            }
        else:
            self.trace_limits = None
        self._trace_titles()
        self._last_plot = -math.inf
        self.refresh_view()

    def _trace_titles(self) -> None:
        for name, title in _TRACE_TITLES.items():
            scale = "auto" if self.trace_limits is None else "fixed"
            paused = "  PAUSED (p resumes)" if self.traces_paused else ""
            plot = self._main.query_one(f"#{name}", PlotextPlot)
            plot.border_title = f"{title}, y {scale} (a){paused}"

    async def action_quit(self) -> None:
        run, s = self.find_run, self.session
        device = getattr(s, "device", None)
        if run is not None and not run.finished and device is not None:
            # The find's worker thread would hold the process until its plan ends (the app
            # waits for its workers as it ends): closing the device leaves the unit at rest
            # (STOP, STREAM_STOP) and ends the find with a LinkError. In a thread of its own,
            # so that the screen goes at once whatever the reply takes.
            s.observer.note("find: stopped on quitting", "warn")
            threading.Thread(
                target=device.close, name="northfinder-monitor-quit", daemon=True
            ).start()
        self.exit(0)


@functools.cache
def _protocol_dbc() -> Any:
    import cantools

    with importlib.resources.as_file(dbc_path()) as path:
        return cantools.database.load_file(str(path))


def decoded(row: FrameRow) -> tuple[str, str]:
    """A frame's message name and its signals, decoded by cantools with the protocol's DBC
    (``cantools monitor`` style); the name says what is not the protocol's."""
    if row.is_extended_id:
        return "not protocol", row.data.hex(" ").upper()
    try:
        name, node, fields = decode_signals(_protocol_dbc(), row.arbitration_id, row.data)
    except Exception:  # cantools raises its own, KeyError and ValueError
        return "not protocol", row.data.hex(" ").upper()
    if node != DBC_NODE:
        name = f"{name} node {node}"
    return name, ", ".join(fields)


class AskText(ModalScreen[str | None]):
    """A one-line question for text (Enter: take it, an empty line clears; Escape: cancel)."""

    DEFAULT_CSS = AskAngle.DEFAULT_CSS.replace("AskAngle", "AskText")
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "cancel", "cancel")]

    def __init__(self, question: str, value: str = "") -> None:
        super().__init__()
        self.question = question
        self.value = value

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(self.question)
            yield Input(value=self.value, placeholder="e.g. SAMPLE, STATUS, 201", id="text")

    @on(Input.Submitted)
    def submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value.strip())

    def action_cancel(self) -> None:
        self.dismiss(None)


class FramesScreen(Screen[None]):
    """The frames of the link, one row per CAN id as ``cantools monitor`` shows them: id,
    direction, message name, count, rate, time since last seen and the last frame's signals.
    ``/`` filters the rows (by name or hexadecimal id), ``p`` pauses the view, Escape returns."""

    DEFAULT_CSS = """
    FramesScreen { layout: vertical; }
    #frames_head { height: 1; padding: 0 1; background: $primary-background; }
    #frames { height: 1fr; padding: 0 1; text-wrap: nowrap; text-overflow: ellipsis; }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("slash", "filter", "filter"),
        Binding("p", "pause", "pause"),
        Binding("escape", "back", "back"),
    ]

    def __init__(self) -> None:
        super().__init__()
        self.paused = False
        self.filter = ""
        self.shown: list[FrameRow] = []

    def compose(self) -> ComposeResult:
        yield Static("", id="frames_head")
        yield Static("", id="frames")
        yield Footer()

    def show(self, observer: Any) -> None:
        """Redraw from the observer (called by the app's redraw; nothing while paused)."""
        if self.paused or not self.query("#frames"):
            return  # paused, or not composed yet
        now = observer.clock()
        rows = []
        for row in observer.frame_rows():
            name, signals = decoded(row)
            ident = (
                f"{row.arbitration_id:08X}" if row.is_extended_id else f"{row.arbitration_id:03X}"
            )
            f = self.filter.lower()
            if f and f not in name.lower() and f not in ident.lower():
                continue
            rows.append((row, name, signals, ident))
        self.shown = [r[0] for r in rows]
        t = Text(no_wrap=True, overflow="ellipsis")  # one line an id, as cantools monitor
        t.append(f"{'id':<8} {'dir':<3} {'message':<18} {'count':>9} {'rate Hz':>8} "
                 f"{'ago s':>7}  signals\n", style="bold")  # fmt: skip
        for row, name, signals, ident in rows:
            rate = "---" if row.rate_hz is None else f"{row.rate_hz:.1f}"
            t.append(f"{ident:<8} {'rx' if row.is_rx else 'tx':<3} {name:<18} {row.count:>9} "
                     f"{rate:>8} {now - row.last_s:>7.2f}  {signals}\n")  # fmt: skip
        self.query_one("#frames", Static).update(t)
        self._head()

    def _head(self) -> None:
        what = f"filter {self.filter!r}" if self.filter else "all frames"
        paused = "  PAUSED (p resumes)" if self.paused else ""
        self.query_one("#frames_head", Static).update(
            Text(f"frames of the link: {what}, {len(self.shown)} ids{paused}  (Escape: back)")
        )

    def action_pause(self) -> None:
        self.paused = not self.paused
        self._head()

    def action_filter(self) -> None:
        def take(text: str | None) -> None:
            if text is not None:
                self.filter = text
                self.paused = False
                self.app.refresh_view()  # type: ignore[attr-defined]

        self.app.push_screen(AskText("Show the frames whose name or id has:", self.filter), take)

    def action_back(self) -> None:
        self.app.pop_screen()
