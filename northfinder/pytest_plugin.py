"""The pytest plugin: the simulated instrument as a fixture for your own tests.

Installed with northfinder and registered through the ``pytest11`` entry point, so a project that
depends on northfinder has it without a conftest: ask for the fixture by name.

``northfinder_sim``
    A started :class:`~northfinder.embed.SimulatedInstrument` (python-can ``virtual`` bus,
    the ``paper-rlg`` sensor, level at azimuth 0 deg and 34 deg N, seed 0, no warm-up, a control
    channel on a free loopback port). On the ``virtual`` bus it runs in virtual time unless the
    test asks for a ``speed``: the instrument and a :class:`~northfinder.driver.device.Device`
    from ``open_device()`` share its clock, which jumps to the next event whenever both wait, so
    the test runs as fast as the CPU allows and gives the same result on a busy machine. A host
    that sends on ``open_bus()`` itself calls ``northfinder_sim.clock.notify()`` after sending.
    On a pty (another process's host) it is paced, at ``speed`` times real time (default 1). It gives what a host needs:
    ``open_bus()`` / ``open_device()`` (``virtual`` and ``slcan-pty``), ``path`` (the pty of
    ``serial-pty`` and ``slcan-pty``, for a host in another process), ``truth``, ``control``
    (fault injection), ``check()``. It is closed after the test.

``northfinder_device``
    A :class:`~northfinder.driver.device.Device` on ``northfinder_sim``, READY, closed after the
    test.

Choose the instrument with the ``northfinder_sim`` marker (keywords of
:class:`~northfinder.embed.SimulatedInstrument`; ``azimuth_deg``, ``latitude_deg``,
``pitch_deg`` and ``roll_deg`` build the truth), or parametrise the fixture indirectly with dicts
of the same keywords::

    import pytest

    @pytest.mark.northfinder_sim(sensor="nav-fog", azimuth_deg=42.0, seed=1)
    def test_my_host_finds_north(northfinder_device):
        ...

    @pytest.mark.parametrize(
        "northfinder_sim", [{"link": "virtual"}, {"link": "serial-pty"}], indirect=True
    )
    def test_on_every_link(northfinder_sim):
        ...
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from northfinder.embed import SimulatedInstrument
from northfinder.firmware_sim.imu import Truth
from northfinder.firmware_sim.sensors import DEFAULT_SENSOR
from northfinder.session import relaxed_device

__all__ = ["DEFAULTS", "northfinder_device", "northfinder_sim", "simulator_options"]

DEFAULTS: dict[str, Any] = {
    "sensor": DEFAULT_SENSOR,
    "seed": 0,
    "warmup_s": 0.0,
    "link": "virtual",
    "control": "127.0.0.1:0",
}
"""What ``northfinder_sim`` starts when the test asks for nothing else (and: virtual time on the
``virtual`` link, real time on a pty, unless ``speed`` or ``clock`` is given)."""

_TRUTH_KEYS = ("azimuth_deg", "latitude_deg", "pitch_deg", "roll_deg")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "northfinder_sim(**options): the simulated instrument of the northfinder_sim fixture "
        "(sensor, truth or azimuth_deg/latitude_deg/pitch_deg/roll_deg, seed, speed or clock, "
        "warmup_s, link, node_id, control, log)",
    )


def simulator_options(request: pytest.FixtureRequest) -> dict[str, Any]:
    """The keywords for :class:`SimulatedInstrument`: the defaults, then the marker's (closest
    first), then the indirect parameter's."""
    options = dict(DEFAULTS)
    for marker in reversed(list(request.node.iter_markers("northfinder_sim"))):
        options.update(marker.kwargs)
    param = getattr(request, "param", None)
    if param is not None:
        if not isinstance(param, dict):
            raise pytest.UsageError(
                f"northfinder_sim: an indirect parameter must be a dict of options, got {param!r}"
            )
        options.update(param)
    if "speed" not in options and "clock" not in options:
        if options["link"] == "virtual":
            options["clock"] = "virtual"
        else:
            options["speed"] = 1.0
    truth_fields = {k: options.pop(k) for k in _TRUTH_KEYS if k in options}
    if truth_fields:
        if "truth" in options:
            raise pytest.UsageError(
                "northfinder_sim: give truth= or azimuth_deg/latitude_deg/..., not both"
            )
        options["truth"] = Truth(**truth_fields)
    return options


@pytest.fixture
def northfinder_sim(request: pytest.FixtureRequest) -> Iterator[SimulatedInstrument]:
    """A started simulated instrument (see the module docstring); closed after the test."""
    options = simulator_options(request)
    sensor = options.pop("sensor")
    with SimulatedInstrument(sensor, **options) as sim:
        yield sim
        sim.check()


@pytest.fixture
def northfinder_device(northfinder_sim: SimulatedInstrument) -> Iterator[Any]:
    """A READY :class:`~northfinder.driver.device.Device` on ``northfinder_sim``."""
    with relaxed_device(northfinder_sim) as device:
        device.wait_ready(timeout=10.0)
        yield device
