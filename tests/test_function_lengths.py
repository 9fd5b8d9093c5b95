"""scripts/function_lengths: no function over 120 lines outside tests, and a stated reason for
every one over 80."""

from __future__ import annotations

import importlib.machinery
import importlib.util
import textwrap
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "function_lengths"


def _script():
    loader = importlib.machinery.SourceFileLoader("function_lengths", str(SCRIPT))
    spec = importlib.util.spec_from_loader("function_lengths", loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def _body(n: int) -> str:
    return "".join(f"    x{k} = {k}\n" for k in range(n - 2)) + "    return 0\n"


def test_the_repository_keeps_its_function_lengths():
    _, problems = _script().check()
    assert problems == [], "\n".join(problems)


def test_a_long_function_is_listed_and_a_too_long_or_unexplained_one_refused(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text(
        "class C:\n    def ok(self):\n" + textwrap.indent(_body(80), "    ")
        + "def long_one():\n" + _body(100) + "def explained():\n" + _body(90)
        + "def too_long():\n" + _body(121)
    )  # fmt: skip
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_a.py").write_text("def test_long():\n" + _body(200))
    reasons = {"pkg/a.py::explained": "a table", "pkg/a.py::gone": "was long once"}
    lines, problems = _script().check(tmp_path, reasons)
    assert [line.split()[1] for line in lines] == [
        "tests/test_a.py::test_long",
        "pkg/a.py::too_long",
        "pkg/a.py::long_one",
        "pkg/a.py::explained",
    ]
    assert problems == [
        "pkg/a.py::too_long: 121 lines, more than 120",
        "pkg/a.py::long_one: 100 lines and no reason in REASONS",
        "pkg/a.py::gone: in REASONS but not over 80 lines",
    ]
