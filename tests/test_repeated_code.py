"""scripts/repeated_code: the pairs of places that share six or more lines (pylint's symilar)."""

from __future__ import annotations

import importlib.machinery
import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("pylint")

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "repeated_code"


def _script():
    loader = importlib.machinery.SourceFileLoader("repeated_code", str(SCRIPT))
    spec = importlib.util.spec_from_loader("repeated_code", loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


BLOCK = "".join(f"    total = total * {k} + value_{k}\n" for k in range(8))


def test_a_shared_block_is_a_pair_and_a_shorter_one_is_none(tmp_path):
    files = []
    for name, block in (("a", BLOCK), ("b", BLOCK), ("c", "".join(BLOCK.splitlines(True)[:5]))):
        (tmp_path / f"{name}.py").write_text(f"def {name}(total):\n{block}    return -total\n")
        files.append(str(tmp_path / f"{name}.py"))
    pairs = _script().repeated_pairs(files, min_lines=6)
    assert pairs == [(9, f"{files[0]}:2-10", f"{files[1]}:2-10")]
    assert _script().repeated_pairs(files, min_lines=10) == []


def test_imports_and_comments_are_no_repeated_code(tmp_path):
    imports = "".join(f"import module_{k}  # why {k}\n" for k in range(10))
    for name in ("a.py", "b.py"):
        (tmp_path / name).write_text(imports + f"X_{name[0]} = 1\n")
    files = [str(tmp_path / "a.py"), str(tmp_path / "b.py")]
    assert _script().repeated_pairs(files) == []


@pytest.mark.slow
def test_the_repository_has_at_most_15_repeated_pairs(monkeypatch):
    script = _script()
    monkeypatch.chdir(script.ROOT)  # the files are named relative to the repository's root
    pairs = script.repeated_pairs(script.python_files())
    assert len(pairs) <= 15, "\n".join(f"{n} lines: {a} ~ {b}" for n, a, b in pairs)
