"""The documentation site is wired: every public name has its entry in the API reference, every
page is in a table of contents, and the README's Quick start is the command CI runs.

The site itself is built by ``.ci/run`` (``sphinx-build -W``, the ``docs`` extra); these checks
need no Sphinx.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

import northfinder

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _toctree_entries() -> set[str]:
    """Every document named in a MyST or reStructuredText toctree of the site."""
    entries: set[str] = set()
    for page in [*DOCS.rglob("*.md"), *DOCS.rglob("*.rst")]:
        text = page.read_text(encoding="utf-8")
        blocks = re.findall(r"```\{toctree\}\n(.*?)```", text, flags=re.S)
        blocks += re.findall(r"\.\. toctree::\n((?:[ \t]+.*\n|\n)+)", text)
        for block in blocks:
            for line in block.splitlines():
                line = line.strip()
                if line and not line.startswith(":"):
                    entries.add(str((page.parent / line).relative_to(DOCS)))
    return entries


@pytest.mark.parametrize("name", [n for n in northfinder.__all__ if n != "__version__"])
def test_every_public_name_has_an_entry_in_the_api_reference(name):
    api = (DOCS / "api.rst").read_text(encoding="utf-8")
    assert re.search(rf"^\.\. auto\w+:: northfinder\.{name}$", api, flags=re.M), name


def test_every_page_is_in_a_table_of_contents_and_every_entry_exists():
    pages = {
        str(p.relative_to(DOCS).with_suffix(""))
        for p in [*DOCS.rglob("*.md"), *DOCS.rglob("*.rst")]
        if p.stem != "index"
    }
    entries = _toctree_entries()
    assert pages - entries == set(), "pages in no toctree"
    assert entries - pages == set(), "toctree entries without a page"


def test_the_readme_quick_start_test_command_is_the_one_ci_runs():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && .venv/bin/python -m pytest -q"
    assert f"```sh\n{command}\n```" in readme
    assert f"\n{command}\n" in ci


def test_the_docs_extra_and_the_ci_build_use_warnings_as_errors():
    pyproject = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    docs_extra = re.search(r"^docs = \[(.*?)\]", pyproject, flags=re.M | re.S)
    assert docs_extra is not None
    for package in ("sphinx", "myst-parser", "furo", "sphinx-copybutton"):
        assert f'"{package}' in docs_extra.group(1)
    assert "sphinx-build -W --keep-going -b html docs build/docs" in ci


@pytest.mark.slow
def test_the_site_builds_without_warnings(tmp_path):
    """The build of ``.ci/run`` (warnings as errors) without writing HTML, where the ``docs``
    extra is installed (``dev`` includes it), so that a docstring or page that makes Sphinx warn
    fails here before CI."""
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    pytest.importorskip("sphinx_copybutton")
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-W",
            "--keep-going",
            "-q",
            "-b",
            "dummy",
            "-d",
            str(tmp_path / "doctrees"),
            str(DOCS),
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert build.returncode == 0, build.stderr


def test_the_readme_python_example_prints_what_the_readme_says(capsys):
    """The tour's Python example runs as written and prints the figures in its last comment
    (virtual time and a seed: the same digits on any machine)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert len(blocks) == 1
    expected = re.search(r"# (.*)$", blocks[0].strip().splitlines()[-1])
    assert expected is not None
    exec(compile(blocks[0], "README.md", "exec"), {})
    assert capsys.readouterr().out.strip() == expected.group(1).strip()
