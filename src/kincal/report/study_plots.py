"""Plots of a Monte Carlo study (``kincal study --plots``): per quantity, the errors of every variant over the
repeats as histograms with the reported std drawn as a normal density; and the validation error distribution
per variant. Plain arrays in, PNG files out (matplotlib through ``kincal.report.plots``)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from kincal.report.plots import _pyplot

BINS = 40


def write_study_plots(errors: Mapping[str, Mapping[str, np.ndarray]], reported: Mapping[str, Mapping[str, float]],
                      validation: Mapping[str, np.ndarray], units: Mapping[str, str], out_dir) -> list[Path]:
    """``errors[quantity][variant]``: errors over the repeats (in ``units[quantity]``); ``reported``: the reported
    std, same keys; ``validation[variant]``: validation RMS errors (``units["validation"]``). Writes
    ``errors.png`` and ``validation.png`` into ``out_dir``; returns the files."""
    plt = _pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [_errors(plt, errors, reported, units, out / "errors.png"),
             _validation(plt, validation, units.get("validation", ""), out / "validation.png")]
    return files


def _errors(plt, errors, reported, units, path: Path) -> Path:
    names = list(errors)
    cols = min(3, max(1, len(names)))
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, q in zip(axes.ravel(), names):
        every = np.concatenate([np.asarray(e, float).ravel() for e in errors[q].values()] + [np.zeros(1)])
        edges = np.histogram_bin_edges(every, bins=BINS)  # one set of bins for every variant: comparable bars
        x = np.linspace(edges[0], edges[-1], 200)
        for variant, e in errors[q].items():
            e = np.asarray(e)
            if e.size < 2:
                continue
            _, _, patches = ax.hist(e, bins=edges, density=True, alpha=0.45, label=variant)
            s = reported[q][variant]
            if s > 0:
                ax.plot(x, np.exp(-0.5 * (x / s) ** 2) / (s * np.sqrt(2 * np.pi)), color=patches[0].get_facecolor(),
                        alpha=1.0, lw=1.2)
        ax.set_title(q)
        ax.set_xlabel(f"error ({units.get(q, '')})")
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    axes[0, 0].legend(fontsize="small")
    fig.suptitle("errors over the repeats; lines: normal densities with the reported std")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _validation(plt, validation, unit: str, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for variant, v in validation.items():
        v = np.asarray(v)
        if v.size:
            ax.hist(v, bins=BINS, alpha=0.45, label=variant)
    ax.set_xlabel(f"validation RMS position error ({unit})")
    ax.set_ylabel("repeats")
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
