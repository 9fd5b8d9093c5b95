"""The public face: ``import northfinder`` names what a user needs, documented, and nothing else."""

from __future__ import annotations

import importlib
import inspect
import os
import subprocess
import sys
import warnings

import pytest

import northfinder

# What a user of the instrument needs, by kind (the list: the device, the simulated
# instrument, the find procedure, plans, results, the errors, the version).
NEEDED = {
    "Device",
    "SimulatedInstrument",
    "find_north",
    "Plan",
    "FindResult",
    "Recording",
    "Truth",
    "DriverError",
    "HostError",
    "SimError",
    "LinkLost",
    "DeviceFault",
    "__version__",
}


def test_the_needed_names_are_public():
    assert NEEDED <= set(northfinder.__all__)


@pytest.mark.parametrize("name", [n for n in northfinder.__all__ if n != "__version__"])
def test_every_public_name_resolves_to_a_documented_object_of_its_own_module(name):
    obj = getattr(northfinder, name)
    doc = inspect.getdoc(obj)
    assert doc and len(doc.split()) >= 3, f"{name} has no docstring"
    # the deep path keeps working and is the very same object
    module = importlib.import_module(obj.__module__)
    assert getattr(module, name) is obj
    assert obj.__module__.startswith("northfinder.")


def test_nothing_private_leaks():
    assert not [n for n in northfinder.__all__ if n.startswith("_") and n != "__version__"]
    assert sorted(set(northfinder.__all__)) == sorted(northfinder.__all__)
    public = {n for n in [*dir(northfinder), *vars(northfinder)] if not n.startswith(("_", "@"))}
    # besides __all__, only the subpackages and modules a user may import by path
    extra = public - set(northfinder.__all__)
    assert all(inspect.ismodule(getattr(northfinder, n)) for n in extra), extra
    with pytest.raises(AttributeError, match="no attribute 'Devise'"):
        northfinder.Devise  # noqa: B018


def test_the_version_is_the_installed_distributions():
    from importlib.metadata import version

    assert northfinder.__version__ == version("northfinder")
    assert northfinder.__version__.count(".") == 2


def test_import_northfinder_is_light():
    code = "import northfinder, sys; print(*sorted(sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = set(out.stdout.split())
    assert not loaded & {"numpy", "can", "serial", "scipy", "northfinder.driver.device"}


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("northfinder.host.embed", "northfinder.embed"),
        ("northfinder.host.cli", "northfinder.cli"),
        ("northfinder.host.cli.find", "northfinder.cli.find"),
        ("northfinder.host.cli.simulated", "northfinder.simwindows"),
        ("northfinder.host.pytest_plugin", "northfinder.pytest_plugin"),
        ("northfinder.driver.link", "northfinder.driver.device_link"),
        ("northfinder.driver.conformance.links", "northfinder.driver.conformance.wire"),
        ("northfinder.firmware_sim.links", "northfinder.firmware_sim.adapters"),
        ("northfinder.firmware_sim.sendloop", "northfinder.firmware_sim.sender_child"),
        ("northfinder.host.planner", "northfinder.host.plan_search"),
        ("northfinder.host.study", "northfinder.host.batch_solve"),
    ],
)
def test_the_paths_of_version_0_1_still_import_with_a_warning(old, new):
    code = (
        "import warnings, importlib, sys\n"
        "warnings.simplefilter('always')\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        f"    old = importlib.import_module({old!r})\n"
        f"new = importlib.import_module({new!r})\n"
        "assert old is new, (old, new)\n"
        "assert any(issubclass(x.category, DeprecationWarning) and 'moved to' in str(x.message)"
        " for x in w), [str(x.message) for x in w]\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_a_renamed_module_keeps_its_names_under_the_old_path():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from northfinder.driver.link import DeviceLink
        from northfinder.host.study import chunk_errors
    from northfinder.driver.device_link import DeviceLink as new_link
    from northfinder.host.batch_solve import chunk_errors as new_errors

    assert DeviceLink is new_link and chunk_errors is new_errors


def test_no_old_path_is_a_module_of_its_own():
    """A moved path is only an alias: no file is left behind to shadow it (and drift from it)."""
    for old in northfinder._MOVED:
        parent, _, leaf = old.rpartition(".")
        if parent in northfinder._MOVED:
            continue  # inside a moved package: nothing of it is left
        for folder in importlib.import_module(parent).__path__:
            assert not os.path.exists(os.path.join(folder, leaf + ".py")), old
            assert not os.path.isdir(os.path.join(folder, leaf)), old


def test_an_unknown_old_path_is_still_an_import_error():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module("northfinder.host.cli.no_such_command")


def test_the_readme_example_finds_north_through_the_public_names():
    truth = northfinder.Truth(azimuth_deg=42.0)
    sensor = northfinder.load_spec("ideal")
    with northfinder.SimulatedInstrument(sensor, truth, seed=1, clock="virtual") as sim:
        with sim.open_device() as device:
            plan = northfinder.Plan((0.0, 180.0), 2.0)
            result, _ = northfinder.find_north(device, plan, latitude_deg=34.0)
    assert isinstance(result, northfinder.FindResult)
    assert result.azimuth_deg == pytest.approx(42.0, abs=1e-6)


def test_a_spin_finds_north_through_the_public_names():
    truth = northfinder.Truth(azimuth_deg=123.0)
    sensor = northfinder.load_spec("ideal")
    with northfinder.SimulatedInstrument(sensor, truth, seed=1, clock="virtual") as sim:
        with sim.open_device() as device:
            found = northfinder.find_north_spin(device, 10.0, 36.0, latitude_deg=34.0)
    assert isinstance(found, northfinder.SpinFind)
    assert isinstance(found.solution, northfinder.SpinSolution)
    assert found.solution.azimuth_deg == pytest.approx(123.0, abs=1e-6)
    plan = northfinder.SpinPlan(10.0, 36.0)
    assert plan.rate_dps == 10.0


def test_the_imports_static_tools_see_are_the_public_names():
    import ast

    tree = ast.parse(inspect.getsource(northfinder))
    block = next(
        node
        for node in tree.body
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "_TYPE_CHECKING"
    )
    imported = {
        alias.name: node.module
        for node in block.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert imported == northfinder._PUBLIC
    assert set(northfinder.__all__) == {"__version__", *northfinder._PUBLIC}
