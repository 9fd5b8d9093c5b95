"""Options, results, the check registry and the context a check works with."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NoReturn

from northfinder.driver.conformance.errors import (
    ConformanceError,
    LinkFault,
    NoReply,
    Skipped,
    SuiteConfigError,
)
from northfinder.driver.conformance.pace import TTY_BUFFER_BYTES, PaceFigures
from northfinder.driver.conformance.session import Answer, Session, describe_result
from northfinder.driver.protocol.constants import (
    NODE_ID_MAX,
    NODE_ID_MIN,
    ConfigKey,
    DeviceState,
    Result,
)

__all__ = [
    "OUTCOMES",
    "REGISTRY",
    "Check",
    "CheckResult",
    "Ctx",
    "Outcome",
    "Report",
    "SuiteOptions",
    "TimingProblem",
    "check",
]

LOSS_WORDS = ("incomplete", "tick(s) missing", "frame(s) lost")
"""Words of the session's gaps that say frames went missing (see :meth:`Ctx.gaps`)."""

Outcome = str
"""``"pass"``, ``"fail"``, ``"not judged"`` (a timing check that failed while the host could not
keep pace: :mod:`northfinder.driver.conformance.pace`) or ``"skip"``."""
OUTCOMES = ("pass", "fail", "not judged", "skip")


@dataclass(frozen=True)
class SuiteOptions:
    """What the suite checks and how strictly.

    Attributes
    ----------
    node_id : int
        The unit's CAN node id (1..15).
    time_scale : float
        The unit's seconds per wall second: 1 for a real instrument, the speed of an accelerated
        simulator. Periods, rates and durations are judged in the unit's time.
    stream_seconds : float
        Length of the stream observation in the unit's seconds (the issue asks for at least 30).
    angles_deg : tuple of float
        Rotation targets of ``rotation.accuracy``, deg.
    accuracy_deg : float
        Largest allowed ``|encoder - target|`` after a move, deg.
    reply_limit_ms : float
        Largest allowed reply latency as the host measures it, ms of the unit's time. The unit's
        own deadline is 20 ms (protocol.md 6); the host measurement adds link and host latency, so
        the limit defaults to the host timeout of protocol.md 6 (100 ms).
    jitter_margin_ms : float
        Host-side timestamp uncertainty added to the 10 % heartbeat jitter bound, wall ms.
    rate_tolerance : float
        Largest relative error of the measured sample rate and of the mean heartbeat period.
    settle_margin_s : float
        Added to the expected move time (profile + settle) before a move counts as late, unit s;
        10 % of the expected time is added as well.
    ready_timeout_s : float
        How long to wait for READY after boot or reset (warm-up), unit s.
    only : tuple of str
        Glob patterns of check names to run (empty: all).
    unit_pid : int or None
        A process on this host that is the unit (a simulator): the time its threads wait for a
        CPU counts as the host's (``docs/conformance.md``). A unit on a pseudo-terminal is found
        by itself (the process holding the other end).
    """

    node_id: int = 1
    time_scale: float = 1.0
    stream_seconds: float = 30.0
    angles_deg: tuple[float, ...] = (37.5, 181.25, 300.0)
    accuracy_deg: float = 0.05
    reply_limit_ms: float = 100.0
    jitter_margin_ms: float = 5.0
    rate_tolerance: float = 0.01
    settle_margin_s: float = 0.5
    ready_timeout_s: float = 180.0
    only: tuple[str, ...] = ()
    unit_pid: int | None = None

    def __post_init__(self) -> None:
        positive = {
            "time_scale": self.time_scale,
            "stream_seconds": self.stream_seconds,
            "accuracy_deg": self.accuracy_deg,
            "reply_limit_ms": self.reply_limit_ms,
            "rate_tolerance": self.rate_tolerance,
            "ready_timeout_s": self.ready_timeout_s,
        }
        for name, value in positive.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise SuiteConfigError(f"{name}: must be a positive number, got {value!r}")
        for name, value in (
            ("jitter_margin_ms", self.jitter_margin_ms),
            ("settle_margin_s", self.settle_margin_s),
        ):
            if not (math.isfinite(value) and value >= 0):
                raise SuiteConfigError(f"{name}: must be >= 0, got {value!r}")
        if not NODE_ID_MIN <= self.node_id <= NODE_ID_MAX:
            raise SuiteConfigError(
                f"node_id: must be {NODE_ID_MIN}..{NODE_ID_MAX}, got {self.node_id}"
            )
        if self.unit_pid is not None and not (isinstance(self.unit_pid, int) and self.unit_pid > 0):
            raise SuiteConfigError(f"unit_pid: must be a process id > 0, got {self.unit_pid!r}")
        if not self.angles_deg or not all(math.isfinite(a) for a in self.angles_deg):
            raise SuiteConfigError("angles: give at least one finite angle in degrees")


@dataclass
class CheckResult:
    """Outcome of one check.

    Attributes
    ----------
    name : str
    outcome : str
        ``"pass"``, ``"fail"``, ``"not judged"`` or ``"skip"``.
    message : str
        Why it failed, was not judged or was skipped; for a pass, what was verified.
    figures : dict
        Measured figures, name -> text with unit.
    duration_s : float
        Wall seconds spent.
    """

    name: str
    outcome: Outcome
    message: str
    figures: dict[str, str] = field(default_factory=dict)
    duration_s: float = 0.0


@dataclass
class Report:
    """All results of one run, in order, and the host's pace over the run."""

    results: list[CheckResult]
    link: str
    options: SuiteOptions
    duration_s: float = 0.0
    pace: PaceFigures | None = None
    """The host's pace over the whole run (None in virtual time)."""

    @property
    def passed(self) -> bool:
        """No check failed (checks not judged or skipped do not fail a run)."""
        return not any(r.outcome == "fail" for r in self.results)

    @property
    def judged(self) -> bool:
        """Every check that ran was judged (none ``"not judged"``)."""
        return not any(r.outcome == "not judged" for r in self.results)

    def count(self, outcome: Outcome) -> int:
        return sum(r.outcome == outcome for r in self.results)

    def result(self, name: str) -> CheckResult:
        for r in self.results:
            if r.name == name:
                return r
        raise KeyError(name)


@dataclass(frozen=True)
class TimingProblem:
    """A failure about time, judged over ``[t0, t1]`` (session clock seconds).

    ``excess_s``: how late the unit was beyond its limit, wall s; None for a check over the
    observation window whose unit counters showed nothing wrong. The runner asks the host's pace
    over the interval whether it excuses the failure (:func:`~.pace.excused`). For frames lost on
    the link, ``behind_s`` is how far the reader was behind and ``excess_s`` what the link holds.
    """

    text: str
    t0: float
    t1: float
    excess_s: float | None = None
    behind_s: float | None = None
    """Frames lost: how far the reader was behind the unit's stream, wall s (``excess_s`` is then
    what the link holds, wall s)."""


@dataclass(frozen=True)
class Check:
    """A named check: ``fn(ctx)`` records figures and problems on the context."""

    name: str
    summary: str
    fn: Callable[[Ctx], None]


REGISTRY: dict[str, Check] = {}
"""Every check by name, as the modules of :mod:`northfinder.driver.conformance.checks` define them;
that package puts them in the order the suite runs them (``CHECKS``)."""


def check(
    name: str, summary: str | None = None
) -> Callable[[Callable[[Ctx], None]], Callable[[Ctx], None]]:
    """Register a check function under ``name``. ``summary`` says what a pass means, with the
    sections of protocol.md; by default it is the function's docstring, folded onto one line."""

    def register(fn: Callable[[Ctx], None]) -> Callable[[Ctx], None]:
        if name in REGISTRY:
            raise ConformanceError(f"check {name!r} registered twice")
        text = summary if summary is not None else " ".join((fn.__doc__ or "").split())
        if not text:
            raise ConformanceError(f"check {name!r} has no summary (nor a docstring)")
        REGISTRY[name] = Check(name, text, fn)
        return fn

    return register


class Ctx:
    """What a check works with: the session, the options, state shared between checks, and the
    figures and problems it records."""

    def __init__(self, session: Session, options: SuiteOptions, shared: dict[str, Any]) -> None:
        self.s = session
        self.opt = options
        self.shared = shared
        self.figures: dict[str, str] = {}
        self.problems: list[str] = []
        self.timing_problems: list[TimingProblem] = []
        self.notes: list[str] = []

    # -- recording --------------------------------------------------------------------------------
    def fig(self, name: str, value: object) -> None:
        self.figures[name] = str(value)

    def fail(self, problem: str) -> None:
        self.problems.append(problem)

    def late(self, text: str, t0: float, t1: float, excess_s: float | None = None) -> None:
        """Record a failure about time, judged over ``[t0, t1]`` (see :class:`TimingProblem`):
        not judged if the host could not keep pace then, a failure otherwise."""
        self.timing_problems.append(TimingProblem(text, t0, t1, excess_s))

    def lost(self, text: str, t: float) -> None:
        """Frames from the unit lost or broken, found at ``t``: a timing problem judged by how far
        the reader was behind the unit's stream then (:meth:`Session.behind`) against what the
        link holds (:data:`~.pace.TTY_BUFFER_BYTES` of the stream at its configured rate); a FAIL
        if the reader kept up or the host kept pace."""
        rate = self.config()[ConfigKey.SAMPLE_RATE_HZ]
        behind = self.s.behind(t, rate)
        holds = self.s.wall(TTY_BUFFER_BYTES / (self.s.link.tick_bytes * rate))
        text += (
            ""
            if not text
            else (
                f" (the reader {behind * 1e3:.0f} ms behind the unit's stream then; the link holds "
                f"{holds * 1e3:.0f} ms)"
            )
        )
        self.timing_problems.append(TimingProblem(text, t - behind, t, holds, behind))

    def gaps(self, found: list[tuple[float, str]], head: str) -> None:
        """Judge the session's gaps ``found`` ((time, text) pairs), the message starting with
        ``head``: frames missing (an incomplete tick, ticks or serial frames lost) are judged as
        frames lost on the link (:meth:`lost`); a counter repeated or going back is the unit's
        whatever the host did, and fails them all."""
        if not found:
            return
        texts = [text for _, text in found]
        summary = (
            head + "; ".join(texts[:3]) + (f" (+{len(texts) - 3} more)" if len(texts) > 3 else "")
        )
        if all(any(k in text for k in LOSS_WORDS) for text in texts):
            for i, (t, _) in enumerate(found):
                self.lost(summary if i == 0 else "", t)
        else:
            self.fail(summary)

    def note(self, text: str) -> None:
        self.notes.append(text)

    @staticmethod
    def skip(reason: str) -> NoReturn:
        raise Skipped(reason)

    # -- units ------------------------------------------------------------------------------------
    def ms(self, wall_s: float) -> float:
        """A wall duration as ms of the unit's time."""
        return self.s.unit(wall_s) * 1000.0

    @property
    def link_kind(self) -> str:
        return self.s.link.kind

    # -- replies ----------------------------------------------------------------------------------
    def expect(self, a: Answer, result: Result, what: str | None = None) -> bool:
        """Record a problem unless ``a`` got a reply with ``result`` (and no data if refused).

        A reply that did not come within the wait is listened for as long again: if it comes,
        it is late (a timing problem with its delay), not wrong; if not, it is missing (a timing
        problem too: a host that stood still that long excuses it)."""
        what = what or a.name
        if a.reply is None:
            self.s.await_late(a, self.s.reply_wait_s)
        if a.reply is None:
            wrong = [
                r for t, r in self.s.unsolicited if t >= a.sent and r.seq == a.seq
            ]  # the same seq, another opcode: a wrong echo
            if wrong:
                r = wrong[0]
                self.fail(
                    f"{what}: the reply echoed seq {r.seq} opcode 0x{int(r.opcode):02X} "
                    f"instead of seq {a.seq} opcode 0x{a.opcode:02X}"
                )
            else:
                self.missing(a, what)
            return False
        self.judge_latency(a, what)
        got = a.reply.result
        if got != result:
            self.fail(
                f"{what}: answered {describe_result(got)}, expected {describe_result(result)}"
            )
            return False
        if result != Result.OK and a.reply.data:
            self.fail(f"{what}: a refusal must carry no data, got {a.reply.data.hex(' ')}")
            return False
        return True

    @property
    def reply_limit_wall(self) -> float:
        """The reply limit in wall seconds."""
        return self.s.wall(self.opt.reply_limit_ms / 1000.0)

    def missing(self, a: Answer, what: str) -> None:
        """No reply to ``a`` so far: a timing problem over the time since it was sent."""
        now = self.s.now()
        self.late(
            f"{what}: no reply in {now - a.sent:.1f} s (wall)",
            a.sent,
            now,
            now - a.sent - self.reply_limit_wall,
        )

    def judge_latency(self, a: Answer, what: str) -> None:
        """A reply that came after the wait is late: a timing problem with its delay."""
        if a.latency is not None and a.received is not None and a.latency > self.s.reply_wait_s:
            self.late(
                f"{what}: the reply came late, {self.ms(a.latency):.0f} ms after the command "
                f"(waited {self.s.reply_wait_s:g} s, limit {self.opt.reply_limit_ms:g} ms)",
                a.sent,
                a.received,
                a.latency - self.reply_limit_wall,
            )

    def no_reply(self, exc: NoReply) -> None:
        """A command the check needed got no reply within twice the wait (:class:`NoReply`)."""
        a = exc.answer
        assert isinstance(a, Answer)
        self.missing(a, exc.what)

    def late_replies(self, since: int) -> None:
        """Judge the replies :meth:`Session.ok` got late since ``session.late_answers[since]``."""
        for a, what in self.s.late_answers[since:]:
            self.judge_latency(a, what)

    # -- shared helpers ---------------------------------------------------------------------------
    def config(self) -> dict[ConfigKey, int]:
        """Every configuration value, read once and kept as the values to restore."""
        if "config" not in self.shared:
            self.shared["config"] = {k: self.s.get_config(k) for k in ConfigKey}
        return self.shared["config"]

    def ready(self) -> None:
        """Make sure the unit is READY (wait for warm-up or a move to end).

        Raises
        ------
        LinkFault
            The unit is in FAULT or does not become READY within the ready timeout.
        """
        st = self.s.get_status()
        if st.state == DeviceState.READY:
            return
        if st.state == DeviceState.FAULT:
            raise LinkFault(f"the unit is in FAULT (fault flags 0x{int(st.faults):02X})")
        if self.s.wait_state({DeviceState.READY}, self.opt.ready_timeout_s) is None:
            raise LinkFault(
                f"the unit did not become READY within {self.opt.ready_timeout_s:g} s "
                f"(state {self.s.state.name if self.s.state is not None else 'unknown'})"
            )

    def stream_on(self) -> None:
        """Switch the sample stream on (if the suite does not know it to be on)."""
        if not self.s.streaming:
            self.s.start_stream()
            rate = self.config()[ConfigKey.SAMPLE_RATE_HZ]
            self.s.idle(3.0 / rate)
