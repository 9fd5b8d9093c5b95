"""Refusals (protocol.md 4.3): every command the unit must refuse, with the result it must answer.

Each check is a table of :class:`Case` rows (what is sent, the result expected) run by one routine,
:func:`send_cases`, which sends the rows, matches the replies and judges them. A row whose
expectation holds only in the state the check sets up (BUSY while the table turns, NOT_READY in
BOOT) is marked ``in_state``: a reply that came after the unit left that state is noted, not judged.

The checks at rest (:data:`AT_REST`) also compare the unit's ``cmd_rejected`` counter before and
after with the refusals sent, then check what must not have changed. Three checks set up a state
first: ``refusal.busy`` and ``refusal.check_order`` during a move, ``refusal.not_ready`` after a
RESET.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from northfinder.driver.conformance.checks.common import (
    BOOT_MAX_S,
    ONE_DEG_COUNTS,
    SELF_TEST_MAX_S,
    allowed_move_s,
    config_unchanged,
    malformed_delta,
    reset_to_boot,
    undisturbed,
)
from northfinder.driver.conformance.checks.moves import begin_long_move, finish_move
from northfinder.driver.conformance.core import Ctx, check
from northfinder.driver.protocol.budget import rate_fits
from northfinder.driver.protocol.constants import (
    ANGLE_FULL_TURN,
    CONFIG_LIMITS,
    INT32_MIN,
    ROTATE_BY_LIMIT,
    SAMPLE_RATES_HZ,
    ConfigKey,
    DeviceState,
    Direction,
    Opcode,
    Result,
)
from northfinder.driver.protocol.messages import (
    Command,
    GetConfig,
    GetStatus,
    Home,
    RequestIdentify,
    RotateBy,
    RotateTo,
    SelfTest,
    SetConfig,
    Status,
    StreamStart,
)


@dataclass(frozen=True)
class Raw:
    """A command payload the codec would not build: any opcode and argument bytes (the seq is
    added when it is sent)."""

    opcode: int
    args: bytes = b""


Sendable = Command | Raw
"""What a row sends: a command (its seq is replaced) or a raw payload."""


@dataclass(frozen=True)
class Case:
    """One row of a refusal table.

    Attributes
    ----------
    what : str
        How the report names it.
    send : Command, Raw or callable
        What to send, or ``send(ctx)`` building it when it depends on the unit (its configuration).
    expected : Result
        The result the unit must answer.
    in_state : bool
        The expectation holds only in the state the check set up.
    """

    what: str
    send: Sendable | Callable[[Ctx], Sendable]
    expected: Result
    in_state: bool = False


@dataclass
class Tally:
    """What :func:`send_cases` saw."""

    refused: int = 0
    """Replies other than OK."""
    judged: int = 0
    """Rows judged (the others were answered after the state had ended)."""
    answered_in_state: int = 0
    """Rows not answered outside the state (answered in it, or not answered at all)."""


def _payload(c: Ctx, send: Sendable | Callable[[Ctx], Sendable]) -> Command | bytes:
    if not isinstance(send, Command | Raw):
        send = send(c)
    return c.s.raw(send.opcode, send.args) if isinstance(send, Raw) else send


def same_value(key: ConfigKey) -> Callable[[Ctx], SetConfig]:
    """SET_CONFIG of ``key`` to the value the suite found (changes nothing if accepted)."""
    return lambda c: SetConfig(0, key, c.config()[key])


def send_cases(
    c: Ctx,
    cases: Sequence[Case],
    *,
    state: DeviceState | None = None,
    wait: float | None = None,
    pipelined: bool = False,
    ended: str = "the move had ended",
) -> Tally:
    """Send every row, then judge each reply against its expected result.

    Parameters
    ----------
    state : DeviceState, optional
        The state the check set up; rows marked ``in_state`` answered in another state with another
        result are noted with ``ended`` instead of judged.
    wait : float, optional
        Wall seconds to wait for each reply (default the session's).
    pipelined : bool
        Send all rows at once, then wait for the replies (to fit them into a short state).
    """
    s = c.s
    if pipelined:
        sent = [(case, s.send(_payload(c, case.send))) for case in cases]
        s.wait_until(lambda: all(a.reply is not None for _, a in sent), wait or s.reply_wait_s)
    else:
        sent = [(case, s.request(_payload(c, case.send), wait=wait)) for case in cases]
    if any(a.reply is None for _, a in sent):
        # Late is not missing: listen as long again before counting and judging the replies.
        s.wait_until(lambda: all(a.reply is not None for _, a in sent), s.reply_wait_s)
    tally = Tally()
    for case, a in sent:
        reply = a.reply
        if reply is not None and reply.result != Result.OK:
            tally.refused += 1
        outside = state is not None and reply is not None and s.state_when_answered(a) != state
        if not outside:
            tally.answered_in_state += 1
        if outside and case.in_state and reply is not None and reply.result != case.expected:
            c.note(f"{case.what}: {ended}")
            continue
        tally.judged += 1
        c.expect(a, case.expected, case.what)
    return tally


# -- the checks at rest ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Before:
    """What a check at rest saw before sending its rows."""

    t0: float
    """Host time, s."""
    status: Status


@dataclass(frozen=True)
class FromReady:
    """A refusal check run from READY: its rows and what must hold afterwards."""

    name: str
    summary: str
    cases: Sequence[Case] | Callable[[Ctx], Sequence[Case]]
    then: tuple[Callable[[Ctx, Before], None], ...] = ()
    stream: bool = False
    """Switch the stream on first (for checks that also judge the stream)."""
    in_fault: bool = False
    """Run only if the unit is in FAULT (the protocol gives the host no way to cause one)."""


def run_at_rest(spec: FromReady, c: Ctx) -> None:
    """The routine of every :class:`FromReady` check."""
    s = c.s
    if spec.in_fault:
        if s.get_status().state != DeviceState.FAULT:
            c.skip("the unit is not in FAULT, and the protocol gives the host no way to cause one")
    else:
        c.ready()
        if spec.stream:
            c.stream_on()
    cases = spec.cases(c) if callable(spec.cases) else spec.cases
    before = Before(s.now(), s.get_status())
    tally = send_cases(c, cases)
    after = s.get_status()
    delta = (after.cmd_rejected - before.status.cmd_rejected) & 0xFF
    c.fig("cases", len(cases))
    c.fig("cmd_rejected delta", delta)
    if delta != tally.refused:
        c.fail(f"commands rejected rose by {delta}, {tally.refused} refusal(s) were sent")
    for then in spec.then:
        then(c, before)


def _still_at_rest(c: Ctx, before: Before) -> None:
    st = c.s.get_status()
    if st.state != DeviceState.READY or st.angle != before.status.angle:
        c.fail(
            f"after the refusals the state is {st.state.name} and the angle moved from {before.status.angle} to {st.angle}"
        )


def _config_unchanged(c: Ctx, before: Before) -> None:
    config_unchanged(c)


def _read_only_unchanged(c: Ctx, before: Before) -> None:
    cfg = c.config()
    for key in (k for k in ConfigKey if k.read_only):
        now = c.s.get_config(key)
        if now != cfg[key]:
            c.fail(f"{key.name} changed from {cfg[key]} to {now}")


def _each_counted_malformed(c: Ctx, before: Before) -> None:
    n = len(WRONG_LENGTH)
    malformed_delta(c, before.status, n, f"{n} commands of the wrong length")


def _stream_undisturbed(c: Ctx, before: Before) -> None:
    undisturbed(c, before.t0)


UNDEFINED_OPCODES = (0x00, 0x03, 0x15, 0x22, 0x42, 0x7F, 0xFF)
"""Opcodes protocol.md leaves undefined (a sample of the range)."""
ARG_BYTES = {Opcode.ROTATE_TO: 5, Opcode.ROTATE_BY: 4, Opcode.GET_CONFIG: 1, Opcode.SET_CONFIG: 5}
"""Argument bytes of each opcode that has arguments (protocol.md 4.1)."""
_DIRECTION_BYTE = (1000).to_bytes(4, "little")  # ROTATE_TO 0.001 deg, then the direction byte

UNKNOWN_COMMAND = (
    *(Case(f"opcode 0x{op:02X}", Raw(op), Result.UNKNOWN_COMMAND) for op in UNDEFINED_OPCODES),
    Case("opcode 0x7F with 6 argument bytes", Raw(0x7F, bytes(6)), Result.UNKNOWN_COMMAND),
)

WRONG_LENGTH = tuple(
    Case(f"{op.name} with {n} argument bytes", Raw(op, bytes(n)), Result.BAD_ARGUMENT)
    for op in Opcode
    for n in (ARG_BYTES.get(op, 0) - 1, ARG_BYTES.get(op, 0) + 1)
    if 0 <= n <= 6
)

BAD_ARGUMENT = (
    *(
        Case(
            f"ROTATE_TO direction {d}",
            Raw(Opcode.ROTATE_TO, _DIRECTION_BYTE + bytes((d,))),
            Result.BAD_ARGUMENT,
        )
        for d in (3, 0x80, 0xFF)
    ),
    Case(
        "ROTATE_TO angle 360e6 and direction 3",
        Raw(Opcode.ROTATE_TO, ANGLE_FULL_TURN.to_bytes(4, "little") + b"\x03"),
        Result.BAD_ARGUMENT,
    ),
)

OUT_OF_RANGE = (
    Case("ROTATE_TO 360e6", RotateTo(0, ANGLE_FULL_TURN), Result.OUT_OF_RANGE),
    Case("ROTATE_TO 0xFFFFFFFF", RotateTo(0, 0xFFFFFFFF, Direction.POSITIVE), Result.OUT_OF_RANGE),
    Case("ROTATE_BY +720e6+1", RotateBy(0, ROTATE_BY_LIMIT + 1), Result.OUT_OF_RANGE),
    Case("ROTATE_BY -720e6-1", RotateBy(0, -ROTATE_BY_LIMIT - 1), Result.OUT_OF_RANGE),
    Case("ROTATE_BY INT32_MIN", RotateBy(0, INT32_MIN), Result.OUT_OF_RANGE),
    *(
        Case(f"SAMPLE_RATE_HZ {r}", SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, r), Result.OUT_OF_RANGE)
        for r in (150, 0, 800)
    ),
    *(
        Case(f"{key.name} {v}", SetConfig(0, key, v), Result.OUT_OF_RANGE)
        for key, (lo, hi) in CONFIG_LIMITS.items()
        if key != ConfigKey.SAMPLE_RATE_HZ
        for v in (lo - 1, hi + 1)
        if v >= 0
    ),
)

UNKNOWN_KEY = (
    *(
        Case(f"GET_CONFIG key 0x{key:02X}", GetConfig(0, key), Result.UNKNOWN_KEY)
        for key in (0x00, 0x07, 0x0F, 0x13, 0x7F, 0xFF)
    ),
    *(
        Case(f"SET_CONFIG key 0x{key:02X}", SetConfig(0, key, 1), Result.UNKNOWN_KEY)
        for key in (0x00, 0x07, 0x0F)
    ),
)

READ_ONLY = tuple(
    case
    for key in ConfigKey
    if key.read_only
    for case in (
        Case(f"SET_CONFIG {key.name} (same value)", same_value(key), Result.READ_ONLY),
        Case(f"SET_CONFIG {key.name} 1", SetConfig(0, key, 1), Result.READ_ONLY),
    )
)


def rate_exceeds_link(c: Ctx) -> list[Case]:
    """Every sample rate, and the shortest heartbeat, that does not fit this link (protocol.md 7)."""
    cfg = c.config()
    kind, bitrate = c.link_kind, cfg[ConfigKey.LINK_BITRATE]
    rate, hb = cfg[ConfigKey.SAMPLE_RATE_HZ], cfg[ConfigKey.HEARTBEAT_PERIOD_MS]
    cases = [
        Case(
            f"SAMPLE_RATE_HZ {r}",
            SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, r),
            Result.RATE_EXCEEDS_LINK,
        )
        for r in SAMPLE_RATES_HZ
        if not rate_fits(kind, bitrate, r, hb)
    ]
    lo = CONFIG_LIMITS[ConfigKey.HEARTBEAT_PERIOD_MS][0]
    if not rate_fits(kind, bitrate, rate, lo):
        cases.append(
            Case(
                f"HEARTBEAT_PERIOD_MS {lo}",
                SetConfig(0, ConfigKey.HEARTBEAT_PERIOD_MS, lo),
                Result.RATE_EXCEEDS_LINK,
            )
        )
    if not cases:
        c.skip(
            f"every sample rate and heartbeat period fits a {kind} link of {bitrate} bit/s: nothing to refuse"
        )
    return cases


IN_FAULT = (
    Case("ROTATE_BY in FAULT", RotateBy(0, ONE_DEG_COUNTS), Result.FAULT),
    Case("HOME in FAULT", Home(0), Result.FAULT),
    Case("SET_CONFIG in FAULT", same_value(ConfigKey.SETTLE_TIME_MS), Result.FAULT),
)

AT_REST = (
    FromReady(
        "refusal.unknown_command",
        "undefined opcodes answered UNKNOWN_COMMAND, echoing seq and opcode, before the length check (4.3)",
        UNKNOWN_COMMAND,
    ),
    FromReady(
        "bad_input.wrong_length",
        "every opcode with one argument byte too few or too many: BAD_ARGUMENT, counted in rx malformed, stream undisturbed (4.3, 9)",
        WRONG_LENGTH,
        then=(_each_counted_malformed, _stream_undisturbed),
        stream=True,
    ),
    FromReady(
        "refusal.bad_argument",
        "ROTATE_TO with an undefined direction: BAD_ARGUMENT, also before the range check (4.3)",
        BAD_ARGUMENT,
        then=(_still_at_rest,),
    ),
    FromReady(
        "refusal.out_of_range",
        "arguments outside their range answered OUT_OF_RANGE and nothing changes (4.3, 4.4)",
        OUT_OF_RANGE,
        then=(_config_unchanged, _still_at_rest),
    ),
    FromReady(
        "refusal.unknown_key",
        "GET_CONFIG and SET_CONFIG of undefined keys below 0x10 answered UNKNOWN_KEY (4.3)",
        UNKNOWN_KEY,
        then=(_config_unchanged,),
    ),
    FromReady(
        "refusal.read_only",
        "SET_CONFIG of keys 0x10..0x12 answered READ_ONLY; values unchanged (4.3, 4.4)",
        READ_ONLY,
        then=(_read_only_unchanged,),
    ),
    FromReady(
        "refusal.rate_exceeds_link",
        "a sample rate or heartbeat that does not fit the link: RATE_EXCEEDS_LINK, nothing changed (4.3, 7)",
        rate_exceeds_link,
        then=(_config_unchanged,),
    ),
    FromReady(
        "refusal.fault",
        "in FAULT moves and SET_CONFIG are refused with FAULT (4.3) — only if the unit is in FAULT",
        IN_FAULT,
        in_fault=True,
    ),
)

for _spec in AT_REST:
    check(_spec.name, _spec.summary)(functools.partial(run_at_rest, _spec))


# -- refusals in a state the check sets up -----------------------------------------------------------
BUSY_WHILE_ROTATING = (
    Case(
        "ROTATE_TO while rotating",
        lambda c: RotateTo(0, c.s.get_status().angle),
        Result.BUSY,
        in_state=True,
    ),
    Case("ROTATE_BY while rotating", RotateBy(0, ONE_DEG_COUNTS), Result.BUSY, in_state=True),
    Case("HOME while rotating", Home(0), Result.BUSY, in_state=True),
    Case("SELF_TEST while rotating", SelfTest(0), Result.BUSY, in_state=True),
    *(
        Case(f"SET_CONFIG {key.name} while rotating", same_value(key), Result.BUSY, in_state=True)
        for key in (
            ConfigKey.TABLE_MAX_RATE_MDPS,
            ConfigKey.TABLE_MAX_ACCEL_MDPS2,
            ConfigKey.SETTLE_TIME_MS,
        )
    ),
)

BUSY_WHILE_SETTLING = (
    Case("ROTATE_BY while settling", RotateBy(0, ONE_DEG_COUNTS), Result.BUSY, in_state=True),
    Case("HOME while settling", Home(0), Result.BUSY, in_state=True),
    Case("SELF_TEST while settling", SelfTest(0), Result.BUSY, in_state=True),
    Case(
        "SET_CONFIG SETTLE_TIME_MS while settling",
        same_value(ConfigKey.SETTLE_TIME_MS),
        Result.BUSY,
        in_state=True,
    ),
)

CHECK_ORDER = (
    Case(
        "undefined opcode 0x7F with 6 argument bytes", Raw(0x7F, bytes(6)), Result.UNKNOWN_COMMAND
    ),
    Case("ROTATE_TO with 3 argument bytes", Raw(Opcode.ROTATE_TO, bytes(3)), Result.BAD_ARGUMENT),
    Case(
        "ROTATE_TO with direction 3", Raw(Opcode.ROTATE_TO, bytes(4) + b"\x03"), Result.BAD_ARGUMENT
    ),
    Case("ROTATE_TO 360e6", RotateTo(0, ANGLE_FULL_TURN), Result.BUSY, in_state=True),
    Case(
        "ROTATE_BY 721 deg",
        RotateBy(0, ROTATE_BY_LIMIT + ONE_DEG_COUNTS),
        Result.BUSY,
        in_state=True,
    ),
    Case(
        "SET_CONFIG TABLE_MAX_RATE_MDPS 0",
        SetConfig(0, ConfigKey.TABLE_MAX_RATE_MDPS, 0),
        Result.BUSY,
        in_state=True,
    ),
    Case(
        "SET_CONFIG SAMPLE_RATE_HZ 150 (not a motion key)",
        SetConfig(0, ConfigKey.SAMPLE_RATE_HZ, 150),
        Result.OUT_OF_RANGE,
    ),
)

IN_BOOT = (
    Case("ROTATE_BY in BOOT", RotateBy(0, ONE_DEG_COUNTS), Result.NOT_READY, in_state=True),
    Case("HOME in BOOT", Home(0), Result.NOT_READY, in_state=True),
    Case("SELF_TEST in BOOT", SelfTest(0), Result.NOT_READY, in_state=True),
    Case("STREAM_START in BOOT", StreamStart(0), Result.NOT_READY, in_state=True),
    Case(
        "SET_CONFIG in BOOT", same_value(ConfigKey.SETTLE_TIME_MS), Result.NOT_READY, in_state=True
    ),
    Case(
        "SET_CONFIG key 0x07 in BOOT (state before key)",
        SetConfig(0, 0x07, 1),
        Result.NOT_READY,
        in_state=True,
    ),
    Case(
        "ROTATE_TO 360e6 in BOOT (state before range)",
        RotateTo(0, ANGLE_FULL_TURN),
        Result.NOT_READY,
        in_state=True,
    ),
    Case("GET_STATUS in BOOT", GetStatus(0), Result.OK),
    Case("GET_CONFIG in BOOT", GetConfig(0, ConfigKey.SAMPLE_RATE_HZ), Result.OK),
    Case("IDENTIFY in BOOT", RequestIdentify(0), Result.OK),
)

IN_WARMUP = (
    Case("ROTATE_BY in WARMUP", RotateBy(0, ONE_DEG_COUNTS), Result.NOT_READY, in_state=True),
    Case("HOME in WARMUP", Home(0), Result.NOT_READY, in_state=True),
)


@check("refusal.busy")
def refusal_busy(c: Ctx) -> None:
    """moves, SELF_TEST and motion keys refused with BUSY while ROTATING and while SETTLING (4.3, 5)"""
    s = c.s
    c.config()
    m = begin_long_move(c)
    if m is None:
        return
    wait = s.wall(SELF_TEST_MAX_S) + s.reply_wait_s
    judged = send_cases(c, BUSY_WHILE_ROTATING, state=DeviceState.ROTATING, wait=wait).judged
    # SETTLING: wait for it, then try again.
    allowed = allowed_move_s(c, abs(m.turn_deg or 0.0))[1]
    if s.wait_state({DeviceState.SETTLING}, allowed, start=m.first_index):
        judged += send_cases(
            c,
            BUSY_WHILE_SETTLING,
            state=DeviceState.SETTLING,
            wait=wait,
            ended="settling had ended",
        ).judged
    finish_move(c, m)
    c.fig("refusals judged", judged)


@check("refusal.check_order")
def refusal_check_order(c: Ctx) -> None:
    """while ROTATING the checks run in the order of table 4.3: opcode, length, state, range (4.3)"""
    m = begin_long_move(c)
    if m is None:
        return
    send_cases(c, CHECK_ORDER, state=DeviceState.ROTATING)
    finish_move(c, m)


@check("refusal.not_ready")
def refusal_not_ready(c: Ctx) -> None:
    """in BOOT only IDENTIFY, GET_STATUS, GET_CONFIG are served, the rest NOT_READY (before the
    range and key checks); in WARMUP moves are NOT_READY (4.3, 5)"""
    s = c.s
    c.ready()
    c.config()  # read before the reset: BOOT is short
    _, i_boot = reset_to_boot(c)
    if i_boot is None:
        return
    s.seq_restart_pending = False
    tally = send_cases(
        c,
        IN_BOOT,
        state=DeviceState.BOOT,
        wait=s.reply_wait_s + s.wall(0.5),
        pipelined=True,
        ended="answered after BOOT ended",
    )
    i_left = s.wait_state(
        {DeviceState.WARMUP, DeviceState.READY, DeviceState.FAULT}, BOOT_MAX_S + 2.0, start=i_boot
    )
    c.fig("judged in BOOT", f"{tally.answered_in_state} of {len(IN_BOOT)}")
    if tally.answered_in_state == 0:
        c.skip("BOOT ended before any reply: too short to test from this host")
    if i_left is not None and s.state == DeviceState.WARMUP:
        send_cases(c, IN_WARMUP, state=DeviceState.WARMUP, ended="warm-up had ended")
    else:
        c.note("the unit went from BOOT straight to READY: WARMUP refusals not tried")
    s.streaming = False
    s.begin_segment()
    c.ready()
