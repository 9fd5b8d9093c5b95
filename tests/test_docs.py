"""The documentation site is wired: every public name has its entry in the API reference, every
page is in a table of contents, and the README's Quick start is the command CI runs.

The site itself is built by ``.ci/run`` (``sphinx-build -n -W``, the ``docs`` extra); the checks
marked slow build it too (nitpicky, warnings as errors) and follow every internal link of its
HTML; the others need no Sphinx.
"""

from __future__ import annotations

import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

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
    assert "sphinx-build -n -W --keep-going -b html docs build/docs" in ci


def _prose(page: Path) -> str:
    """A Markdown page without its fenced blocks (directives, code, output)."""
    return re.sub(r"^(```|~~~|:::).*?^\1", "", page.read_text(encoding="utf-8"), flags=re.M | re.S)


@pytest.mark.parametrize("page", sorted(DOCS.glob("*.md")), ids=lambda p: p.name)
def test_a_page_reads_on_a_code_host_with_markdown_links_and_full_alt_texts(page):
    """A code host renders Markdown, not MyST: a role such as {doc}`cli` shows as its source
    there, where the link ``[the command line](cli.md)`` works on both. An image's alt text is
    plain words: Sphinx drops a code span from it (the figure of find.md read "The figure of")."""
    prose = _prose(page)
    roles = re.findall(r"\{[a-z:]+\}`[^`]*`", prose)
    assert not roles, f"{page.name}: MyST roles, not Markdown links: {roles}"
    for alt in re.findall(r"!\[([^\]]*)\]\(", prose):
        assert len(alt.split()) >= 5, f"{page.name}: an image without a full alt text: {alt!r}"
        assert "`" not in alt, f"{page.name}: a code span in an alt text is dropped: {alt!r}"


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    """The build of ``.ci/run`` (nitpicky, every reference checked; warnings as errors, kept
    going to report them all) into a temporary folder: the process and the HTML folder."""
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    pytest.importorskip("sphinx_copybutton")
    where = tmp_path_factory.mktemp("site")
    build = subprocess.run(
        [sys.executable, "-m", "sphinx", "-n", "-W", "--keep-going", "-q", "-b", "html",
         "-d", str(where / "doctrees"), str(DOCS), str(where / "html")],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )  # fmt: skip
    return build, where / "html"


@pytest.mark.slow
def test_the_site_builds_without_warnings(site):
    """Where the ``docs`` extra is installed (``dev`` includes it): a docstring or page that
    makes Sphinx warn, a reference it cannot resolve included, fails here before CI."""
    build, _ = site
    assert build.returncode == 0, build.stderr


class _Links(HTMLParser):
    """The ids of an HTML page and its links (``href`` of ``a`` and ``link``, ``src``)."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.ids: set[str] = set()
        self.hrefs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        for key in ("id", "name") if tag == "a" else ("id",):
            if a.get(key):
                self.ids.add(a[key])  # type: ignore[arg-type]
        for key in ("href", "src"):
            if a.get(key):
                self.hrefs.append(a[key])  # type: ignore[arg-type]


@pytest.mark.slow
def test_every_internal_link_of_the_site_leads_to_a_page_and_anchor_that_exist(site):
    """Relative links and #anchors of every built page (the source pages of viewcode and their
    back-links included) name a file of the build and, where they have one, an id in it."""
    build, html = site
    assert build.returncode == 0, build.stderr
    pages: dict[Path, _Links] = {}
    for page in html.rglob("*.html"):
        parser = _Links()
        parser.feed(page.read_text(encoding="utf-8"))
        pages[page.resolve()] = parser
    assert len(pages) > 20
    dead: list[str] = []
    checked = 0
    for page, parser in sorted(pages.items()):
        for href in parser.hrefs:
            parts = urlsplit(href)
            if parts.scheme or parts.netloc or href.startswith(("mailto:", "data:", "javascript:")):
                continue  # another site: not checked here (no network)
            target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            if target.is_dir():
                target = target / "index.html"
            checked += 1
            where = f"{page.relative_to(html.resolve())}: {href}"
            if not target.is_file():
                dead.append(f"{where} (no file)")
            elif parts.fragment and target.suffix == ".html":
                if unquote(parts.fragment) not in pages[target].ids:
                    dead.append(f"{where} (no such anchor)")
    assert checked > 1000
    assert not dead, f"{len(dead)} dead links:\n" + "\n".join(dead[:40])


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
