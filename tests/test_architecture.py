"""The import direction of the layers, read from the source (every import statement, also those
inside functions), so that a wrong import fails here before it spreads.

- ``driver`` imports neither ``firmware_sim`` nor ``host``; its wire format ``driver.protocol``
  imports nothing outside itself;
- ``firmware_sim`` imports only the wire format, ``driver.protocol``;
- ``host`` imports the driver and itself: never the simulator, never the application layer;
- the application layer is every module of the top-level ``northfinder/`` folder (the public
  face, the command line, embedding, the pytest plugin): nothing beneath it imports it. The rule
  holds by structure: there is no list of exempted modules;
- no module imports itself through others (no cycles).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("driver", "firmware_sim", "host")
LIBRARY = tuple(f"northfinder.{pkg}" for pkg in PACKAGES)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    if parts[0] == "northfinder":  # the application layer's folder is the package itself
        parts.pop(0)
    return ".".join(["northfinder", *parts])


def modules() -> dict[str, Path]:
    """Every module of the three library packages and of the application layer (``northfinder/``)
    by its installed name."""
    found = {}
    for pkg in (*PACKAGES, "northfinder"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            found[module_name(path)] = path
    return found


MODULES = modules()


def imported(name: str, path: Path) -> Iterator[tuple[str, int]]:
    """``(module, line)`` for each import in the file, relative imports resolved; ``from X import
    Y`` counts X, and X.Y too when that is a module."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            yield target, node.lineno
            for alias in node.names:
                if f"{target}.{alias.name}" in MODULES:
                    yield f"{target}.{alias.name}", node.lineno


def imports_of(prefix: str) -> list[tuple[str, str, int]]:
    """``(importer, imported, line)`` for every project import made by modules under ``prefix``."""
    out = []
    for name, path in MODULES.items():
        if name == prefix or name.startswith(prefix + "."):
            for target, line in imported(name, path):
                if target.startswith("northfinder."):
                    out.append((name, target, line))
    return out


def under(name: str, *prefixes: str) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def show(bad: list[tuple[str, str, int]]) -> str:
    return "\n".join(
        f"{MODULES[a].relative_to(ROOT)}:{line}: {a} imports {b}" for a, b, line in bad
    )


WIRE = "the wire format imports only itself"
DRIVER = "the driver imports neither the simulator nor the host"
SIM = "the simulator imports only the wire format"
HOST = "the host library does not import the simulator"
APP = "nothing in the library imports the application layer"


def broken_rule(importer: str, target: str) -> str | None:
    """The rule that ``importer`` importing ``target`` breaks, or None."""
    if under(importer, "northfinder.driver.protocol") and not under(
        target, "northfinder.driver.protocol"
    ):
        return WIRE
    if under(importer, "northfinder.driver") and under(
        target, "northfinder.firmware_sim", "northfinder.host"
    ):
        return DRIVER
    if under(importer, "northfinder.firmware_sim") and not under(
        target, "northfinder.firmware_sim", "northfinder.driver.protocol"
    ):
        return SIM
    if under(importer, "northfinder.host") and under(target, "northfinder.firmware_sim"):
        return HOST
    if under(importer, *LIBRARY) and not under(target, *LIBRARY):
        return APP
    return None


def breaking(rule: str) -> list[tuple[str, str, int]]:
    return [(a, b, n) for a, b, n in imports_of("northfinder") if broken_rule(a, b) == rule]


def test_the_source_is_found_and_read():
    assert {
        "northfinder",
        "northfinder.cli",
        "northfinder.cli.find",
        "northfinder.driver.device",
        "northfinder.firmware_sim.firmware",
    } <= set(MODULES)
    edges = {(a, b) for a, b, _ in imports_of("northfinder")}
    assert ("northfinder.driver.device", "northfinder.driver.window") in edges
    # an import inside a function counts (the CLI loads the simulator lazily)
    assert ("northfinder.session", "northfinder.embed") in edges


@pytest.mark.parametrize("rule", [DRIVER, WIRE, SIM, HOST, APP])
def test_the_import_direction(rule):
    bad = breaking(rule)
    assert not bad, show(bad)


@pytest.mark.parametrize(
    ("importer", "target", "rule"),
    [
        ("northfinder.driver.device", "northfinder.driver.protocol.can", None),
        ("northfinder.driver.device", "northfinder.host.errors", DRIVER),
        ("northfinder.driver.conformance.runner", "northfinder.firmware_sim.runner", DRIVER),
        ("northfinder.driver.protocol.can", "northfinder.driver.errors", WIRE),
        ("northfinder.driver.protocol.can", "northfinder.driver.protocol.errors", None),
        ("northfinder.firmware_sim.adapters", "northfinder.driver.protocol.serial", None),
        ("northfinder.firmware_sim.adapters", "northfinder.driver.errors", SIM),
        ("northfinder.firmware_sim.control", "northfinder.host.errors", SIM),
        ("northfinder.host.procedure", "northfinder.driver.device", None),
        ("northfinder.host.batch_solve", "northfinder.firmware_sim.batch", HOST),
        ("northfinder.host.batch_solve", "northfinder.simwindows", APP),
        ("northfinder.host.procedure", "northfinder", APP),
        ("northfinder.driver.device", "northfinder.embed", APP),
        ("northfinder.firmware_sim.runner", "northfinder.cli", SIM),
        ("northfinder", "northfinder.firmware_sim.imu", None),
        ("northfinder.simwindows", "northfinder.firmware_sim.batch", None),
        ("northfinder.cli.study", "northfinder.firmware_sim.batch", None),
        ("northfinder.embed", "northfinder.firmware_sim.runner", None),
        ("northfinder.pytest_plugin", "northfinder.firmware_sim.control", None),
    ],
)
def test_the_rules(importer, target, rule):
    assert broken_rule(importer, target) == rule


def test_imports_are_read_everywhere_in_a_file(tmp_path):
    path = tmp_path / "__init__.py"
    path.write_text(
        "import northfinder.driver.device\n"
        "from . import adapters\n"
        "from .. import host\n"
        "def f():\n"
        "    from northfinder.driver.protocol import can\n"
    )
    got = {t for t, _ in imported("northfinder.firmware_sim", path)}
    assert got == {
        "northfinder.driver.device",
        "northfinder.firmware_sim",
        "northfinder.firmware_sim.adapters",
        "northfinder",
        "northfinder.host",
        "northfinder.driver.protocol",
        "northfinder.driver.protocol.can",
    }


def test_no_import_cycles():
    graph: dict[str, set[str]] = {name: set() for name in MODULES}
    for name in MODULES:
        for a, b, _ in imports_of(name):
            if a == name and b in MODULES and b != a:
                graph[a].add(b)
    cycles = [c for c in strongly_connected(graph) if len(c) > 1]
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(sorted(c)) for c in cycles)


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components, iteratively."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                out.append(component)
    return out


@pytest.mark.parametrize(
    ("graph", "cyclic"),
    [
        ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
        ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, [["a", "b", "c"]]),
        ({"a": {"b"}, "b": {"a"}, "c": {"d"}, "d": {"c"}}, [["a", "b"], ["c", "d"]]),
    ],
)
def test_the_cycle_finder_finds_cycles(graph, cyclic):
    found = sorted(sorted(c) for c in strongly_connected(graph) if len(c) > 1)
    assert found == cyclic


HEAVY = ("scipy", "pywt", "matplotlib", "cantools", "allantools", "threadpoolctl", "hypothesis")


def _modules_after(code: str, depth: int = 1) -> set[str]:
    """The packages imported by running ``code`` in a fresh interpreter (names cut to ``depth``
    parts: 1, the top-level packages)."""
    done = subprocess.run(
        [sys.executable, "-c", f"{code}\nimport sys; print('\\nMODULES', *sys.modules)"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode in (0, 2), done.stderr
    (line,) = [t for t in done.stdout.splitlines() if t.startswith("MODULES ")]
    return {".".join(name.split(".")[:depth]) for name in line.split()[1:]}


def test_the_cli_imports_heavy_modules_only_where_a_command_needs_them():
    run = "from northfinder.cli import main\ntry:\n    main({})\nexcept SystemExit: pass"
    help_only = _modules_after(run.format("['--help']"))
    assert not help_only & {*HEAVY, "can", "serial", "numpy"}
    code = run.format(
        "['find', '--sim', '--seed', '1', '--warmup', '1', '--window', '0.5', '--json']"
    )
    find_sim = _modules_after(code)
    # The quick start needs no PyWavelets, plotting, scipy.stats or scipy.signal (the check of
    # its redundant windows takes the F distribution from scipy.special).
    assert not find_sim & (set(HEAVY) - {"scipy"})
    assert {"numpy", "can"} <= find_sim
    scipy_parts = {m for m in _modules_after(code, depth=2) if m.startswith("scipy.")}
    assert not scipy_parts & {"scipy.stats", "scipy.signal", "scipy.ndimage", "scipy.optimize"}


def test_the_command_list_summaries_are_the_commands_own():
    """The command list written without importing the commands' modules says of each what the
    parser built from its module does."""
    import argparse

    from northfinder import cli

    def summaries(parser: argparse.ArgumentParser) -> dict[str, str | None]:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        return {a.dest: a.help for a in sub._choices_actions}

    assert summaries(cli.build_parser()) == summaries(cli.build_parser(only="find"))
    assert summaries(cli.build_parser()) == cli.SUMMARIES


def test_the_configuration_is_below_every_other_application_module():
    """``northfinder.config`` is what the command line, the session layer and a script build:
    it reads the lower layers' defaults and imports nothing of the application layer (the
    session, the command line, the simulator's embedding), so any of them can take it."""
    edges = {(a, b) for a, b, _ in imports_of("northfinder")}
    assert ("northfinder.cli.measure", "northfinder.config") in edges  # the edges were read
    above = [
        (a, b)
        for a, b in edges
        if a == "northfinder.config" and not under(b, *LIBRARY) and b != "northfinder.config"
    ]
    assert not above, above


def test_the_session_layer_is_below_the_command_line():
    """``northfinder.session`` opens and runs a unit for the command line, the monitor, the
    pytest plugin and scripts alike: it never imports the command line (what it notes as a run
    ends is in ``northfinder.endings``, the checks of a link's log in ``northfinder.config``)."""
    edges = {(a, b) for a, b, _ in imports_of("northfinder")}
    assert ("northfinder.cli.measure", "northfinder.session") in edges  # the edges were read
    for low in ("northfinder.session", "northfinder.endings", "northfinder.config"):
        up = [(a, b) for a, b in edges if a == low and under(b, "northfinder.cli")]
        assert not up, up
