"""Running the checks in order, restoring the unit after a failure, and reporting."""

from __future__ import annotations

import traceback
from collections.abc import Callable
from typing import Any

import can
import serial

from northfinder.driver.clock import Clock
from northfinder.driver.conformance.checks import select_checks
from northfinder.driver.conformance.core import CheckResult, Ctx, Report, SuiteOptions
from northfinder.driver.conformance.errors import LinkFault, NoReply, Skipped
from northfinder.driver.conformance.pace import excused, pty_peer_pids
from northfinder.driver.conformance.session import LAG_LOOKBACK_S, Session
from northfinder.driver.conformance.wire import RawLink
from northfinder.driver.errors import DriverError
from northfinder.driver.protocol.constants import ConfigKey, DeviceState
from northfinder.driver.protocol.messages import Reset, SetConfig, Stop

__all__ = ["restore", "run_suite"]

_NO_RECOVERY = "the unit did not recover"
#: Seconds of the unit's time the suite listens, at least, before it calls a unit it never heard
#: silent: two heartbeats at the slowest period the protocol allows (HEARTBEAT_PERIOD_MS 5000).
SILENCE_S = 10.5

_LINK_ERRORS = (
    LinkFault,
    DriverError,
    can.CanError,
    serial.SerialException,
    OSError,
)


def run_suite(
    link: RawLink,
    options: SuiteOptions,
    progress: Callable[[CheckResult], None] | None = None,
    clock: Clock | None = None,
) -> Report:
    """Run the selected checks against the unit on ``link``; never stops at a failure.

    After a failed check the unit is restored (STOP, wait for rest, RESET if it is in FAULT or
    does not answer, configuration written back) so that the next check starts from READY.

    Parameters
    ----------
    link : RawLink
        The suite's end of the link (a :class:`~northfinder.driver.conformance.wire.CanRawLink` or
        :class:`~northfinder.driver.conformance.wire.SerialRawLink`).
    options : SuiteOptions
    progress : callable, optional
        Called with each result as soon as it is known.
    clock : Clock, optional
        The host's clock: the wall clock by default, or a
        :class:`~northfinder.driver.clock.VirtualClock` shared with an in-process simulated unit
        (then the suite runs in virtual time, its durations are the clock's, and ``time_scale``
        must be 1).

    Returns
    -------
    Report
    """
    checks = select_checks(options.only)
    reply_wait = max(1.0, 2 * options.reply_limit_ms / 1000.0)
    session = Session(link, options.time_scale, reply_wait, clock)
    if options.unit_pid is not None:
        session.pace.unit_pids = (options.unit_pid,)
    elif (path := _link_path(link)) is not None:
        session.pace.unit_pids = pty_peer_pids(path)
    try:
        with session.pace:
            return _run(session, checks, options, progress)
    finally:
        session.close()


def _run(
    session: Session,
    checks: list[Any],
    options: SuiteOptions,
    progress: Callable[[CheckResult], None] | None,
) -> Report:
    session.drain(0.2)
    shared: dict[str, Any] = {}
    results: list[CheckResult] = []
    start = session.now()
    dead: str | None = None
    for chk in checks:
        if dead is not None:
            # Every further check would wait out its timeouts against a unit that does not answer.
            results.append(CheckResult(chk.name, "fail", f"not run: {dead}"))
            if progress is not None:
                progress(results[-1])
            continue
        ctx = Ctx(session, options, shared)
        t0 = session.now()
        late_before = len(session.late_answers)
        outcome, message = "pass", ""
        try:
            chk.fn(ctx)
        except Skipped as exc:
            outcome, message = "skip", str(exc)
        except NoReply as exc:
            ctx.no_reply(exc)
        except _LINK_ERRORS as exc:
            ctx.fail(f"{type(exc).__name__}: {exc}" if not isinstance(exc, LinkFault) else str(exc))
        except Exception as exc:  # a bug in a check must not hide the remaining checks
            ctx.fail(f"internal error: {type(exc).__name__}: {exc} ({_where(exc)})")
        ctx.late_replies(late_before)
        if ctx.problems or ctx.timing_problems:
            outcome, message = judge(session, ctx)
        elif outcome == "pass":
            message = chk.summary
            if ctx.notes:
                message += " [" + "; ".join(ctx.notes) + "]"
        if outcome == "fail" and session.arrived == 0:
            # Listened SILENCE_S at least (a heartbeat would have come), and still not a frame
            # of any kind since the suite started: restoring (a RESET, then waiting up to
            # --ready-timeout for READY) would only wait out its timeouts.
            session.drain(max(0.0, session.wall(SILENCE_S) - (session.now() - start)))
            if session.arrived == 0:
                dead = silent_link(session, session.unit(session.now() - start))
                message += f" ({dead})"
        result = CheckResult(chk.name, outcome, message, ctx.figures, session.now() - t0)
        results.append(result)
        if progress is not None:
            progress(result)
        if dead is not None:
            continue
        if outcome in ("fail", "not judged"):
            note = restore(session, options, shared)
            if note:
                result.message += f" (restore: {note})"
            if note.startswith(_NO_RECOVERY):
                dead = f"the unit stopped answering after {chk.name}"
    end = session.now()
    pace = session.pace.during(start, end) if session.pace.measuring else None
    return Report(results, session.link.kind, options, end - start, pace)


def judge(session: Session, ctx: Ctx) -> tuple[str, str]:
    """The outcome and message of a check with problems: ``"fail"`` if any problem is not about
    time or the host kept pace through a timing problem; ``"not judged"`` if every problem is
    about time and the host's pace excuses each (:func:`~.pace.excused`). The host's figures
    over the problems' span go into the check's figures, and into the message."""
    texts = ctx.problems + [p.text for p in ctx.timing_problems if p.text]
    message = "; ".join(texts)
    if not ctx.timing_problems:
        return "fail", message
    pace = session.pace
    if not pace.measuring:
        return "fail", message
    span = (
        min(p.t0 for p in ctx.timing_problems),
        max(p.t1 for p in ctx.timing_problems),
    )
    ctx.fig("host pace", pace.during(*span).text())
    lags = {
        p: session.lag(p.t0, p.t1)
        for p in ctx.timing_problems
        if p.excess_s is not None and p.behind_s is None
    }
    unexcused = [
        p
        for p in ctx.timing_problems
        if not excused(
            pace.during(p.t0, p.t1),
            p.excess_s,
            p.behind_s,
            lags.get(p),
            pace.during(p.t0 - LAG_LOOKBACK_S, p.t1),
        )
    ]
    if ctx.problems or unexcused:
        if not ctx.problems:
            p = unexcused[0]
            figures = pace.during(p.t0, p.t1).text()
            if p.behind_s is not None:
                message += f" (not the host's doing: {figures})"
            elif p.excess_s is None:
                message += f" (the host kept pace: {figures})"
            else:
                message += (
                    f" (more than the host explains: {p.excess_s:.2f} s beyond the limit, the "
                    f"unit's messages {lags.get(p, 0.0) * 1e3:.0f} ms late by its own clock, "
                    f"{figures})"
                )
        return "fail", message
    worst = max(
        (pace.during(p.t0, p.t1) for p in ctx.timing_problems),
        key=lambda f: max(f.lost_fraction, f.wait_fraction),
    )
    lag = max(lags.values(), default=0.0)
    late = f", the unit's messages up to {lag * 1e3:.0f} ms late by its own clock" if lag else ""
    if all(p.behind_s is not None for p in ctx.timing_problems) and worst.kept_pace:
        # The reader itself stood still longer than the link holds (the scheduler's figures over
        # the window did not show it): the link was full, the loss is the suite's.
        return (
            "not judged",
            f"{message}; not judged: the suite's reader fell behind more than the link holds "
            f"({worst.text()})",
        )
    return (
        "not judged",
        f"{message}; not judged: the host could not keep pace ({worst.text()}{late})",
    )


def silent_link(session: Session, seconds: float) -> str:
    """Why the remaining checks are not run when the unit was never heard."""
    link = session.link
    other = getattr(link, "other", 0)
    hint = (
        f"; {other} frame(s) of other nodes or equipment were heard: is the node id right?"
        if other
        else "; check the interface and channel, the node id, the bitrate or baud rate, and "
        "that the unit is powered"
    )
    return f"nothing heard from the unit in {seconds:.1f} s (no reply, no heartbeat){hint}"


def _link_path(link: RawLink) -> str | None:
    """The device path of a link on a serial port or an SLCAN adapter, else None."""
    port = getattr(link, "port", None) or getattr(
        getattr(link, "bus", None), "serialPortOrig", None
    )
    name = getattr(port, "port", None)
    return name if isinstance(name, str) else None


def _where(exc: BaseException) -> str:
    tb = traceback.extract_tb(exc.__traceback__)
    return f"{tb[-1].filename.rsplit('/', 1)[-1]}:{tb[-1].lineno}" if tb else "?"


def restore(session: Session, options: SuiteOptions, shared: dict[str, Any]) -> str:
    """Bring the unit back to READY with the configuration the suite found; return what it took."""
    s = session
    done: list[str] = []
    try:
        s.request(Stop(0))
        st = s.get_status()
        if st.state in (DeviceState.ROTATING, DeviceState.SETTLING):
            s.wait_state({DeviceState.READY, DeviceState.FAULT}, options.ready_timeout_s)
            st = s.get_status()
        if st.state == DeviceState.FAULT:
            raise LinkFault("FAULT")
    except _LINK_ERRORS:
        done.append("RESET")
        try:
            s.expect_restart()
            s.request(Reset(0))
            s.streaming = False
            s.begin_segment()
            if s.wait_state({DeviceState.READY}, options.ready_timeout_s) is None:
                return f"{_NO_RECOVERY}: no READY within {options.ready_timeout_s:g} s of RESET"
        except _LINK_ERRORS as exc:
            return f"{_NO_RECOVERY}: {exc}"
    config = shared.get("config")
    if config:
        try:
            for key in (
                ConfigKey.HEARTBEAT_PERIOD_MS,
                ConfigKey.SAMPLE_RATE_HZ,
                ConfigKey.TABLE_MAX_RATE_MDPS,
                ConfigKey.TABLE_MAX_ACCEL_MDPS2,
                ConfigKey.SETTLE_TIME_MS,
            ):
                if s.get_config(key) != config[key]:
                    s.request(SetConfig(0, key, config[key]))
                    done.append(f"{key.name}={config[key]}")
        except _LINK_ERRORS as exc:
            done.append(f"configuration not restored: {exc}")
    try:
        s.idle(0.1)
    except _LINK_ERRORS as exc:
        done.append(f"link failed: {exc}")
    return ", ".join(done)
