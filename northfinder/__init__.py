"""northfinder: a workbench for gyro north finders.

What a user needs is named here, as python-can names ``can.Bus`` and ``can.Message``. A run is
configured by the same typed objects the command line builds (:mod:`northfinder.config`) and
run through the session layer (:mod:`northfinder.session`)::

    import northfinder

    config = northfinder.FindConfig(
        northfinder.LinkConfig(sim=northfinder.SimConfig(seed=1)),  # find --sim --seed 1
        plan=northfinder.Plan((0.0, 180.0, 180.0, 0.0), 10.0),
    )
    measured = northfinder.find(config)

or, a step lower, with a device in hand::

    import northfinder

    truth = northfinder.Truth(azimuth_deg=42.0)
    with northfinder.SimulatedInstrument("paper-rlg", truth, seed=1, clock="virtual") as sim:
        with sim.open_device() as device:
            plan = northfinder.Plan((0.0, 180.0, 180.0, 0.0), 10.0)
            result, _ = northfinder.find_north(device, plan, latitude_deg=34.0)
    print(result.azimuth_deg, result.sigma_deg)

The names are loaded when first used, so ``import northfinder`` stays light (the command line
and the codec do not pay for the simulator or SciPy). The modules they come from keep working
under their own paths (``northfinder.driver.device.Device`` is ``northfinder.Device``).

The package is laid out in layers, imports going one way only:

- :mod:`northfinder.driver`: the host-side driver and the wire codec (imports neither other package);
- :mod:`northfinder.firmware_sim`: the simulated instrument (imports only the wire codec);
- :mod:`northfinder.host`: north finding (imports the driver, never the simulator);
- this package's own modules, the application layer: the configuration of a run
  (:mod:`northfinder.config`) and the session that opens a unit and runs it
  (:mod:`northfinder.session`), the command line (:mod:`northfinder.cli`),
  the embedded simulator (:mod:`northfinder.embed`), the pytest plugin
  (:mod:`northfinder.pytest_plugin`) and the study's simulated windows
  (:mod:`northfinder.simwindows`). Only they import all three.
"""

import importlib as _importlib
import importlib.abc as _abc
import importlib.machinery as _machinery
import sys as _sys
import warnings as _warnings
from types import ModuleType as _ModuleType
from typing import TYPE_CHECKING as _TYPE_CHECKING
from typing import Any as _Any

__version__ = "0.2.0"

#: Public name -> the module that defines it: the one list of the public names (``__all__`` is
#: made from it; the imports for static tools below are checked against it by tests/test_api.py).
_PUBLIC: dict[str, str] = {
    # the device and what it reports
    "Device": "northfinder.driver.device",
    "DeviceStatus": "northfinder.driver.device_link",
    "LinkStats": "northfinder.driver.device_link",
    "Window": "northfinder.driver.window",
    "VirtualClock": "northfinder.driver.clock",
    "WallClock": "northfinder.driver.clock",
    # the simulated instrument
    "SimulatedInstrument": "northfinder.embed",
    "SensorSpec": "northfinder.firmware_sim.sensors",
    "Truth": "northfinder.firmware_sim.imu",
    "load_spec": "northfinder.firmware_sim.sensors",
    "preset_names": "northfinder.firmware_sim.sensors",
    # finding north
    "Plan": "northfinder.host.plan",
    "TableModel": "northfinder.host.plan",
    "SpinPlan": "northfinder.host.plan",
    "find_north": "northfinder.host.procedure",
    "FindResult": "northfinder.host.procedure",
    "find_north_spin": "northfinder.host.procedure",
    "SpinFind": "northfinder.host.procedure",
    "SpinSolution": "northfinder.host.spin",
    "solve_windows": "northfinder.host.procedure",
    "Recording": "northfinder.host.recording",
    "RecordedWindow": "northfinder.host.recording",
    # configuring and running a session (the command line builds the same objects)
    "FindConfig": "northfinder.config",
    "LinkConfig": "northfinder.config",
    "SimConfig": "northfinder.config",
    "SpinConfig": "northfinder.config",
    "OutputConfig": "northfinder.config",
    "NmeaConfig": "northfinder.config",
    "find": "northfinder.session",
    "find_spin": "northfinder.session",
    "open_unit": "northfinder.session",
    "Unit": "northfinder.session",
    "Measured": "northfinder.session",
    "SimTruth": "northfinder.session",
    "SpinMeasured": "northfinder.session",
    # the errors: one root per package, and what a host handles by kind
    "DriverError": "northfinder.driver.errors",
    "ArgumentError": "northfinder.driver.errors",
    "ProtocolError": "northfinder.driver.errors",
    "DeviceRefused": "northfinder.driver.errors",
    "DriverTimeout": "northfinder.driver.errors",
    "ReplyTimeout": "northfinder.driver.errors",
    "MoveTimeout": "northfinder.driver.errors",
    "NodeConflict": "northfinder.driver.errors",
    "StreamTimeout": "northfinder.driver.errors",
    "LinkError": "northfinder.driver.errors",
    "LinkLost": "northfinder.driver.errors",
    "StreamGap": "northfinder.driver.errors",
    "DeviceReset": "northfinder.driver.errors",
    "DeviceFault": "northfinder.driver.errors",
    "EmptyWindow": "northfinder.driver.errors",
    "HostError": "northfinder.host.errors",
    "HostConfigError": "northfinder.host.errors",
    "QualityError": "northfinder.host.errors",
    "RecordingError": "northfinder.host.errors",
    "SimError": "northfinder.firmware_sim.errors",
    "SimConfigError": "northfinder.firmware_sim.errors",
}

#: What ``from northfinder import *`` gives: the public names, once, from :data:`_PUBLIC`.
__all__ = sorted(["__version__", *_PUBLIC])

if _TYPE_CHECKING:  # what static tools see: the names of _PUBLIC, re-exported
    from northfinder.config import FindConfig as FindConfig
    from northfinder.config import LinkConfig as LinkConfig
    from northfinder.config import NmeaConfig as NmeaConfig
    from northfinder.config import OutputConfig as OutputConfig
    from northfinder.config import SimConfig as SimConfig
    from northfinder.config import SpinConfig as SpinConfig
    from northfinder.driver.clock import VirtualClock as VirtualClock
    from northfinder.driver.clock import WallClock as WallClock
    from northfinder.driver.device import Device as Device
    from northfinder.driver.device_link import DeviceStatus as DeviceStatus
    from northfinder.driver.device_link import LinkStats as LinkStats
    from northfinder.driver.errors import ArgumentError as ArgumentError
    from northfinder.driver.errors import DeviceFault as DeviceFault
    from northfinder.driver.errors import DeviceRefused as DeviceRefused
    from northfinder.driver.errors import DeviceReset as DeviceReset
    from northfinder.driver.errors import DriverError as DriverError
    from northfinder.driver.errors import DriverTimeout as DriverTimeout
    from northfinder.driver.errors import EmptyWindow as EmptyWindow
    from northfinder.driver.errors import LinkError as LinkError
    from northfinder.driver.errors import LinkLost as LinkLost
    from northfinder.driver.errors import MoveTimeout as MoveTimeout
    from northfinder.driver.errors import NodeConflict as NodeConflict
    from northfinder.driver.errors import ProtocolError as ProtocolError
    from northfinder.driver.errors import ReplyTimeout as ReplyTimeout
    from northfinder.driver.errors import StreamGap as StreamGap
    from northfinder.driver.errors import StreamTimeout as StreamTimeout
    from northfinder.driver.window import Window as Window
    from northfinder.embed import SimulatedInstrument as SimulatedInstrument
    from northfinder.firmware_sim.errors import SimConfigError as SimConfigError
    from northfinder.firmware_sim.errors import SimError as SimError
    from northfinder.firmware_sim.imu import Truth as Truth
    from northfinder.firmware_sim.sensors import SensorSpec as SensorSpec
    from northfinder.firmware_sim.sensors import load_spec as load_spec
    from northfinder.firmware_sim.sensors import preset_names as preset_names
    from northfinder.host.errors import HostConfigError as HostConfigError
    from northfinder.host.errors import HostError as HostError
    from northfinder.host.errors import QualityError as QualityError
    from northfinder.host.errors import RecordingError as RecordingError
    from northfinder.host.plan import Plan as Plan
    from northfinder.host.plan import SpinPlan as SpinPlan
    from northfinder.host.plan import TableModel as TableModel
    from northfinder.host.procedure import FindResult as FindResult
    from northfinder.host.procedure import SpinFind as SpinFind
    from northfinder.host.procedure import find_north as find_north
    from northfinder.host.procedure import find_north_spin as find_north_spin
    from northfinder.host.procedure import solve_windows as solve_windows
    from northfinder.host.recording import RecordedWindow as RecordedWindow
    from northfinder.host.recording import Recording as Recording
    from northfinder.host.spin import SpinSolution as SpinSolution
    from northfinder.session import Measured as Measured
    from northfinder.session import SimTruth as SimTruth
    from northfinder.session import SpinMeasured as SpinMeasured
    from northfinder.session import Unit as Unit
    from northfinder.session import find as find
    from northfinder.session import find_spin as find_spin
    from northfinder.session import open_unit as open_unit


def __getattr__(name: str) -> _Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'northfinder' has no attribute {name!r}")
    value = getattr(_importlib.import_module(module), name)
    globals()[name] = value  # later look-ups do not come here again
    return value


def __dir__() -> list[str]:
    """The public names and the subpackages imported so far."""
    modules = [k for k, v in globals().items() if isinstance(v, _ModuleType) and k[0] != "_"]
    return sorted({*__all__, *modules})


# ---------------------------------------------------------------------------------------------
# Paths of version 0.1. The application layer lived under northfinder.host, and a few modules had
# names easy to confuse (four "link" modules, plan/planner, study/montecarlo/cli.study,
# sender/sendloop). Importing an old path gives the module at its new path (the same module
# object) with a DeprecationWarning, so code and entry points written for 0.1 keep working while
# the host library itself never imports the layer above it.
# ---------------------------------------------------------------------------------------------

_MOVED: dict[str, str] = {
    # the application layer, out of the host library
    "northfinder.host.cli.simulated": "northfinder.simwindows",
    "northfinder.host.cli": "northfinder.cli",
    "northfinder.host.embed": "northfinder.embed",
    "northfinder.host.pytest_plugin": "northfinder.pytest_plugin",
    # clearer names
    "northfinder.driver.link": "northfinder.driver.device_link",
    "northfinder.driver.conformance.links": "northfinder.driver.conformance.wire",
    "northfinder.firmware_sim.links": "northfinder.firmware_sim.adapters",
    "northfinder.firmware_sim.sendloop": "northfinder.firmware_sim.sender_child",
    "northfinder.host.planner": "northfinder.host.plan_search",
    "northfinder.host.study": "northfinder.host.batch_solve",
}


def _new_name(old: str) -> str | None:
    for prefix, new in _MOVED.items():
        if old == prefix or old.startswith(prefix + "."):
            return new + old[len(prefix) :]
    return None


class _MovedModuleLoader(_abc.Loader):
    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: _machinery.ModuleSpec) -> _ModuleType:
        _warnings.warn(
            f"{spec.name} moved to {self.new} in northfinder 0.2; import it from there",
            DeprecationWarning,
            stacklevel=2,
        )
        module = _importlib.import_module(self.new)
        _sys.modules[spec.name] = module
        return module

    def exec_module(self, module: _ModuleType) -> None:
        """The module was executed under its new name."""


class _MovedModuleFinder(_abc.MetaPathFinder):
    def find_spec(
        self, fullname: str, path: _Any = None, target: _Any = None
    ) -> _machinery.ModuleSpec | None:
        new = _new_name(fullname)
        if new is None:
            return None
        return _machinery.ModuleSpec(fullname, _MovedModuleLoader(new))


if not any(isinstance(f, _MovedModuleFinder) for f in _sys.meta_path):
    _sys.meta_path.insert(0, _MovedModuleFinder())
