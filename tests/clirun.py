"""Running the command line in this process, for the tests: its exit status and what it printed."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stderr, redirect_stdout
from typing import Any

from northfinder.cli import main


def run_cli(*argv: str) -> tuple[int, str, str]:
    """``northfinder ARGV...``: exit status, stdout and stderr."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def run_json(*argv: str) -> dict[str, Any]:
    """The JSON result of ``northfinder ARGV... --json`` (which must succeed)."""
    code, out, err = run_cli(*argv, "--json")
    assert code == 0, err
    doc: dict[str, Any] = json.loads(out)
    return doc
