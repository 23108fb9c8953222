"""Figures of a comparison (PNG, with matplotlib when installed).
"""

import math
import os

import numpy as np

from noise.fitsio import atomic_path

__all__ = ['plot_report']


def _savefig(fig, path):
    with atomic_path(path, overwrite=True) as tmp:   # checked by check_plot_dir
        fig.savefig(tmp, format="png", dpi=100)
    return path


def plot_report(directory, fit, rate, var_opt, use, rows, notes):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        notes.append("plots skipped: matplotlib is not importable")
        return []
    written = []
    slope = fit["slope"]
    fig, ax = plt.subplots(figsize=(6, 5))
    finite = slope[use]
    lo, hi = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
    im = ax.imshow(slope, origin="lower", vmin=lo, vmax=hi, cmap="gray")
    fig.colorbar(im, ax=ax, label="slope (e-/s)")
    ax.set_title("Fitted slope")
    written.append(_savefig(fig, os.path.join(directory, "slope.png")))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    z = (slope - rate)[use] / np.sqrt(fit["var"][use])
    z = z[np.isfinite(z)]
    grid = np.linspace(-5, 5, 201)
    ax.hist(np.clip(z, -5, 5), bins=100, range=(-5, 5), density=True, histtype="step",
            label="(fit - truth) / sqrt(reported var)")
    ax.plot(grid, np.exp(-0.5 * grid ** 2) / math.sqrt(2 * math.pi), label="N(0, 1)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    written.append(_savefig(fig, os.path.join(directory, "residuals.png")))
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    ok = [r for r in rows if r["n"] > 1]
    centre = [math.sqrt(max(r["lo"], 1e-3) * r["hi"]) if np.isfinite(r["hi"])
              else 2 * max(r["lo"], 1e-3) for r in ok]
    ax.errorbar(centre, [r["std_opt"] for r in ok],
                yerr=[r["std_opt"] / math.sqrt(2 * r["n"]) for r in ok], fmt="o",
                label="measured std / sqrt(V_opt)")
    ax.plot(centre, [r["ols_ratio"] for r in ok], "s--", label="equal weights (OLS)")
    ax.axhline(1.0, color="k", lw=0.8, label="optimal")
    ax.set_xscale("log")
    ax.set_xlabel("true rate (e-/s)")
    ax.set_ylabel("std / sqrt(V_opt)")
    ax.legend(fontsize=8)
    written.append(_savefig(fig, os.path.join(directory, "noise_vs_flux.png")))
    plt.close(fig)
    return written
