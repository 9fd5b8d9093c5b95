"""The calibration report's figure: Allan deviation per axis with its intervals and the fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from northfinder.host.allan import TERMS
from northfinder.host.calibrate.core import AXES, Calibration
from northfinder.host.errors import HostConfigError

__all__ = ["plot_calibration"]

_ALPHA = {"quantisation": 2, "arw": 0, "bias_instability": -1, "rrw": -2, "rate_ramp": -2}


def plot_calibration(cal: Calibration, path: str | Path) -> None:
    """Draw the pooled Allan deviation of every axis (68 % intervals), the fitted model and, for
    the x axes, each fitted term; gyros and accelerometers side by side. Needs matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise HostConfigError(
            "plot: matplotlib is not installed (pip install 'northfinder[plot]')"
        ) from exc
    fig, panels = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    for triad, (ax, unit) in enumerate(zip(panels, ("deg/h", "ug"), strict=True)):
        for k, axis in enumerate(AXES[3 * triad : 3 * triad + 3]):
            curve, fit = cal.curves[axis], cal.fits[axis]
            # The noise type of each point: the term that dominates the fitted model there.
            parts = np.stack([fit.term_adev(t, curve.taus_s) ** 2 for t in TERMS])
            alpha = np.array([_ALPHA[TERMS[i]] for i in np.argmax(parts, axis=0)])
            lo, hi = curve.interval(alpha=alpha)
            color = f"C{k}"
            ax.errorbar(
                curve.taus_s, curve.adev, yerr=[curve.adev - lo, hi - curve.adev], fmt="o",
                ms=3, color=color, label=f"{axis} ({curve.segments} stretch(es))",
            )  # fmt: skip
            ax.plot(curve.taus_s, fit.adev(curve.taus_s), "-", color=color, lw=1.5)
            if k == 0:
                for term in TERMS:
                    if fit.resolved[term]:
                        ax.plot(
                            curve.taus_s, fit.term_adev(term, curve.taus_s), ":", color="grey",
                            lw=1,
                        )  # fmt: skip
                        i = int(
                            np.argmax(fit.term_adev(term, curve.taus_s) / fit.adev(curve.taus_s))
                        )
                        ax.annotate(
                            term, (curve.taus_s[i], fit.term_adev(term, curve.taus_s)[i]),
                            fontsize=7, color="grey",
                        )  # fmt: skip
        ax.set_xscale("log")
        ax.set_yscale("log")
        low = min(float(cal.curves[a].adev.min()) for a in AXES[3 * triad : 3 * triad + 3])
        high = max(float(cal.curves[a].adev.max()) for a in AXES[3 * triad : 3 * triad + 3])
        ax.set_ylim(low / 3.0, high * 2.0)
        ax.set_xlabel("cluster time tau, s")
        ax.set_ylabel(f"Allan deviation, {unit}")
        ax.set_title(
            ("gyro" if triad == 0 else "accelerometer") + ": data, fit (line), terms (dotted)"
        )
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(cal.summary())
    fig.savefig(path, dpi=110)
    plt.close(fig)
