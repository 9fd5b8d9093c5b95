"""The conformance suite judges the unit's states by the unit's own order (the sample counter each
status carries, protocol.md 4.6), not by when a loaded host read its frames. Lockstep: a session
fed by hand, nothing waits on time."""

from __future__ import annotations

from sessions import idle_session

from northfinder.driver.conformance.checks.common import judge_validity
from northfinder.driver.conformance.core import Ctx, SuiteOptions
from northfinder.driver.conformance.session import Session
from northfinder.driver.conformance.wire import Arrival
from northfinder.driver.protocol.constants import ConfigKey, DeviceState, Fault, Validity
from northfinder.driver.protocol.messages import Sample, Status

GOOD = Validity.GYRO_VALID | Validity.ACCEL_VALID
MOVING = GOOD | Validity.TABLE_MOVING
SETTLING = GOOD | Validity.TABLE_SETTLING


def _session() -> tuple[Session, Ctx]:
    s = idle_session()
    ctx = Ctx(s, SuiteOptions(), {"config": {ConfigKey.SAMPLE_RATE_HZ: 200}})
    return s, ctx


def _status(s: Session, t: float, state: DeviceState, counter: int) -> None:
    s._record(Arrival(t, Status(state, 0, 2500, Fault(0), counter, 0, 0, 0)))


def _sample(s: Session, t: float, counter: int, validity: Validity) -> None:
    s._record(Arrival(t, Sample(counter, (0, 0, 0), (0, 0, 0), 0, 2000, validity)))


def test_samples_read_after_the_change_they_preceded_are_judged_in_their_own_state():
    """The unit sent ticks 100..199 in ROTATING and its SETTLING status after tick 199; a loaded
    host read the status at 1.50 s and ticks 190..199 only 0.1 s later (longer than any guard by
    time): those ticks are still the move's, by their counters. A tick after the change that
    still says TABLE_MOVING is wrong, and named."""
    s, ctx = _session()
    _status(s, 0.0, DeviceState.READY, 90)
    for k in range(91, 100):
        _sample(s, 0.005 * (k - 90), k, GOOD)
    _status(s, 0.05, DeviceState.ROTATING, 99)
    for k in range(100, 190):
        _sample(s, 0.05 + 0.005 * (k - 99), k, MOVING)
    _status(s, 1.50, DeviceState.SETTLING, 199)
    for k in range(190, 200):
        _sample(s, 1.60, k, MOVING)  # read late, behind the status in time
    for k in range(200, 260):
        _sample(s, 1.60 + 0.005 * (k - 199), k, SETTLING if k != 240 else MOVING)
    judged, bad, problems = judge_validity(ctx, s.samples)
    assert bad == 1, problems
    assert problems == ["sample 240 validity 0x07: SETTLING needs TABLE_SETTLING"]
    # Three ticks either side of each change are not judged (a status follows within 5 ms): 7 at
    # each change, 3 after the first status (none came before it).
    assert judged == len(s.samples) - 2 * 7 - 3


def test_the_state_of_a_sample_starts_afresh_after_a_reset():
    """Counters restart at a reset: a tick of the new boot is judged by its changes only."""
    s, _ = _session()
    _status(s, 0.0, DeviceState.READY, 5000)
    _sample(s, 0.05, 5010, GOOD)
    _status(s, 1.0, DeviceState.BOOT, 0)
    _status(s, 1.2, DeviceState.WARMUP, 40)
    _sample(s, 1.3, 60, Validity.WARMING_UP)
    assert s.state_of(s.samples[0]) == DeviceState.READY
    assert s.state_of(s.samples[1]) == DeviceState.WARMUP
