"""``--plot`` files: matplotlib on the Agg backend, the file's format checked before any work."""

from __future__ import annotations

import os
from typing import Any

from northfinder.cli.files import check_output_path
from northfinder.host.errors import (
    HostConfigError,
    OutputError,
)


def pyplot() -> Any:
    """matplotlib's ``pyplot`` on the Agg backend (files only, no window).

    Raises
    ------
    HostConfigError
        matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise HostConfigError("--plot needs matplotlib: pip install 'northfinder[plot]'") from exc
    return plt


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 110) -> None:
    """Write ``fig`` to the ``--plot`` file ``path`` and close it.

    Raises
    ------
    OutputError
        The file cannot be written.
    """
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise OutputError(f"--plot {path}: cannot write ({exc.strerror})") from exc
    finally:
        pyplot().close(fig)


def check_plot_path(path: str, option: str = "--plot") -> str:
    """Refuse, before any work, a plot file that cannot be written: as
    :func:`check_output_path`, matplotlib not installed, or a name whose ending is no format
    matplotlib writes (the message lists those it does)."""
    check_output_path(path, option)
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError as exc:
        raise HostConfigError(
            f"{option} needs matplotlib: pip install 'northfinder[plot]'"
        ) from exc
    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    suffix = os.path.splitext(path)[1].lower().lstrip(".")
    if suffix not in formats:
        raise HostConfigError(
            f"{option} {path}: "
            + (f".{suffix} is no plot format" if suffix else "the name has no file ending")
            + f"; it must end in one of: {', '.join('.' + f for f in formats)}"
        )
    return path
