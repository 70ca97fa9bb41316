"""Plots of a calibration ``Result`` as PNG files: residuals before and after per data set, the singular value
spectrum behind the identifiability report, the standard deviations of the identifiable estimates and derived
quantities (axis geometry, tool pose at the nominal zero), and predicted against
actual accuracy on validation sets. matplotlib (``pip install "kincal[plot]"``) is imported here only, with the
file-only Agg backend."""

from __future__ import annotations

import math
from pathlib import Path
import numpy as np

from kincal.errors import DataFormatError, KincalError

DEG = 180.0 / math.pi


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        raise KincalError('plots need matplotlib: pip install "kincal[plot]"') from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_plots(result, out_dir) -> list[Path]:
    """Write the plots of ``result`` into ``out_dir``; returns the files. Existing files are never replaced."""
    plt = _pyplot()
    out = Path(out_dir)
    names = ["residuals.png", "identifiability.png", "uncertainty.png"]
    if result.predictions:
        names.append("prediction.png")
    existing = [str(out / n) for n in names if (out / n).exists()]
    if existing:
        raise DataFormatError(f"{', '.join(existing)}: file exists; not overwritten (choose another output directory)")
    out.mkdir(parents=True, exist_ok=True)
    figures = [_residuals(plt, result), _spectrum(plt, result), _uncertainty(plt, result)]
    if result.predictions:
        figures.append(_prediction(plt, result))
    paths = []
    for name, fig in zip(names, figures):
        fig.savefig(out / name, dpi=110, bbox_inches="tight")
        plt.close(fig)
        paths.append(out / name)
    return paths


def per_sample_errors(result) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(data set, position error per sample before, after) in m: the norm of each sample's position part
    (per point where a sample has several), at the nominal model (frames at their first guesses) and at the
    result, for every data set of the calibration (``result.problem``)."""
    problem = result.problem
    out = []
    for exp in problem.experiments:
        pos = np.array([c.length for c in exp.components()])
        if not pos.any():
            continue
        errs = []
        for state in (problem.nominal, result.state):
            r = exp.residual(state, want=set(), jq=False).r[:, pos]
            errs.append(np.linalg.norm(r.reshape(len(r), -1, 3), axis=-1).ravel() if pos.sum() % 3 == 0
                        else np.abs(r).ravel())
        out.append((exp.name, *errs))
    return out


def _residuals(plt, result):
    rows = per_sample_errors(result)
    fig, axes = plt.subplots(1, max(len(rows), 1), figsize=(4.5 * max(len(rows), 1), 3.6), squeeze=False)
    for ax, (name, before, after) in zip(axes[0], rows):
        for e, label in ((before, "nominal"), (after, "calibrated")):
            e = np.sort(e) * 1e3
            ax.plot(np.maximum(e, 1e-9), np.linspace(0, 100, len(e)), label=label)
        ax.set_xscale("log")
        ax.set_xlabel("position error per sample [mm]")
        ax.set_ylabel("samples below [%]")
        ax.set_title(name)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle("residuals before and after calibration", y=1.02)
    return fig


def _spectrum(plt, result):
    ana = result.identifiability
    s = np.asarray(ana.singular_values, float)
    rel = s / s[0] if len(s) and s[0] > 0 else s
    idx = np.arange(1, len(s) + 1)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    kept = idx <= ana.rank
    ax.semilogy(idx[kept], np.maximum(rel[kept], 1e-17), "o", label=f"identifiable ({ana.rank})")
    ax.semilogy(idx[~kept], np.maximum(rel[~kept], 1e-17), "x", color="gray",
                label=f"unidentifiable or held ({len(s) - ana.rank})")
    ax.axhline(ana.rtol, color="red", lw=0.8, ls="--", label=f"rank_rtol {ana.rtol:g}")
    ax.set_xlabel("direction")
    ax.set_ylabel("singular value / largest")
    ax.set_title(f"identifiability: rank {ana.rank} of {len(ana.names)} free coordinates"
                 + (f", {len(ana.weak)} weak" if ana.weak else ""))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def _uncertainty_rows(result) -> list[tuple[str, float, str, bool]]:
    """(name, std in deg or mm, unit, derived) of every identifiable estimate and identifiable (gauge-invariant)
    derived quantity: what the data determine whatever the gauge."""
    rows = []
    items = [(e, False) for e in result.estimates] + [(d, True) for d in result.derived]
    for x, is_derived in items:
        if x.identifiable and np.isfinite(x.std):
            scale, unit = {"rad": (DEG, "deg"), "m": (1e3, "mm")}.get(x.unit, (1.0, x.unit))
            rows.append((x.name, x.std * scale, unit, is_derived))
    return rows


def _uncertainty(plt, result, limit: int = 40):
    rows = _uncertainty_rows(result)
    fig, axes = plt.subplots(1, 2, figsize=(11, max(3.0, 0.22 * min(len(rows), limit) + 1)))
    for ax, unit in zip(axes, ("deg", "mm")):
        sel = sorted((r for r in rows if r[2] == unit), key=lambda r: -r[1])[:limit][::-1]
        ax.barh([r[0] for r in sel], [r[1] for r in sel],
                color=["tab:orange" if r[3] else "tab:blue" for r in sel])
        ax.set_xlabel(f"standard deviation [{unit}]")
        ax.set_title(f"angles ({unit})" if unit == "deg" else f"lengths ({unit})")
        ax.tick_params(axis="y", labelsize=7)
        ax.tick_params(axis="x", labelrotation=30)
        if not sel:
            ax.set_xticks([])
            ax.set_yticks([])
            ax.text(0.5, 0.5, "no parameter or derived quantity of this kind is identifiable:\neach trades off "
                    "against others (identifiability.png,\nresult.yaml); only combinations are determined",
                    transform=ax.transAxes, ha="center", va="center", fontsize=8)
    fig.suptitle("standard deviations of what the data determine in every gauge (largest first): identifiable "
                 "estimates (blue),\naxis geometry and tool pose at the nominal zero (orange, result.yaml 'derived')",
                 y=1.08)
    return fig


def _prediction(plt, result):
    actual = {v.experiment: v.after.position_rms for v in result.validation}
    labels, predicted, measured, trusted = [], [], [], []
    for name, p in result.predictions:
        labels.append(f"{name}\n{p.arm}")
        predicted.append(float(np.sqrt(np.mean(p.position_std**2))) * 1e3)
        measured.append((actual.get(name) or np.nan) * 1e3)
        trusted.append(p.trusted)
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(5, 1.6 * len(labels)), 3.6))
    ax.bar(x - 0.2, predicted, 0.4, label="predicted std (RMS)")
    ax.bar(x + 0.2, measured, 0.4, label="actual error (RMS)")
    for xi, ok in zip(x, trusted):
        if not ok:  # x in data, y in axes coordinates: readable whatever the log scale's range
            ax.text(xi, 0.92, "not trusted", transform=ax.get_xaxis_transform(), ha="center", color="red",
                    fontsize=9)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_yscale("log")
    values = [v for v in predicted + measured if np.isfinite(v) and v > 0]
    if values:  # bars start well below the smallest, so every height reads on the log scale
        ax.set_ylim(min(values) / 5, max(values) * 2)
    ax.set_ylabel("tool position [mm]")
    ax.set_title("predicted against actual accuracy on held-out configurations")
    ax.legend(fontsize=8, loc="lower right")
    return fig
