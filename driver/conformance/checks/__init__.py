"""The checks of the conformance suite, one module per protocol section, and the order they run in.

- :mod:`.identity`: IDENTIFY, READY, GET_STATUS, GET_CONFIG;
- :mod:`.stream`: STREAM_START/STOP, then one observation window judged for heartbeat period and
  jitter, sample rate, counters and validity bits;
- :mod:`.commands`: STOP at rest, SELF_TEST, SET_CONFIG, RESET;
- :mod:`.refusals`: every refusal as a table of cases run by one routine;
- :mod:`.bad_input`: input the unit must drop and count without disturbing the stream;
- :mod:`.rotations`: every move, STOP during a move, commands while turning, accuracy and settling;
- :mod:`.spin`: SPIN (protocol 1.1): rate reached and held, angle monotonic, STOP, refusals;
- :mod:`.whole_run`: reply latencies and link integrity over the whole run.

:data:`ORDER` is the run order. Checks share what they measured (the configuration, the
observation window, the rotations) and leave the unit as the next one expects it, so the order is
part of the suite: it is stated here once, not left to import order.
"""

from __future__ import annotations

import fnmatch

from northfinder.driver.conformance.checks import (  # noqa: F401  (each registers its checks)
    bad_input,
    commands,
    identity,
    refusals,
    rotations,
    spin,
    stream,
    whole_run,
)
from northfinder.driver.conformance.core import REGISTRY, Check
from northfinder.driver.conformance.errors import ConformanceError, SuiteConfigError

__all__ = ["CHECKS", "ORDER", "select_checks"]

ORDER = (
    "identify",
    "state.ready",
    "command.get_status",
    "command.get_config",
    "command.stream_stop",
    "command.stream_start",
    "heartbeat.period",
    "heartbeat.jitter",
    "stream.rate",
    "stream.counters",
    "stream.validity",
    "command.stop_at_rest",
    "command.self_test",
    "command.set_config",
    "refusal.unknown_command",
    "bad_input.wrong_length",
    "refusal.bad_argument",
    "refusal.out_of_range",
    "refusal.unknown_key",
    "refusal.read_only",
    "refusal.rate_exceeds_link",
    "bad_input.short_command",
    "bad_input.unknown_id",
    "bad_input.unknown_type",
    "bad_input.bad_crc",
    "bad_input.resync",
    "command.rotate_to",
    "command.rotate_to_direction",
    "command.rotate_by",
    "command.home",
    "command.rotate_to_present",
    "command.stop_while_rotating",
    "refusal.busy",
    "command.while_rotating",
    "refusal.check_order",
    "rotation.accuracy",
    "rotation.settle_time",
    "rotation.validity",
    "spin.refusals",
    "spin.steady",
    "command.reset",
    "refusal.not_ready",
    "refusal.fault",
    "timing.reply",
    "link.integrity",
)
"""Names of every check in the order the suite runs them."""

if sorted(ORDER) != sorted(REGISTRY):
    raise ConformanceError(
        f"the suite's order and its checks differ: {sorted(set(ORDER) ^ set(REGISTRY))}"
    )

CHECKS: list[Check] = [REGISTRY[name] for name in ORDER]
"""Every check in the order the suite runs them."""


def select_checks(patterns: tuple[str, ...]) -> list[Check]:
    """The checks matching any glob pattern (all when none), in suite order.

    Raises
    ------
    SuiteConfigError
        A pattern that matches no check (the message lists the checks).
    """
    if not patterns:
        return list(CHECKS)
    for p in patterns:
        if not any(fnmatch.fnmatchcase(c.name, p) for c in CHECKS):
            names = ", ".join(c.name for c in CHECKS)
            raise SuiteConfigError(f"no check matches {p!r}; checks are {names}")
    return [c for c in CHECKS if any(fnmatch.fnmatchcase(c.name, p) for p in patterns)]
