"""PNG plots of the empirical models (matplotlib, Agg). Every title names the data shown."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from host.learning.empirical.scoring import thermal_pairs

if TYPE_CHECKING:
    from host.data.runs import Run


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_curves(model: Any, run: Run, path: str, title: str, window: tuple[float | None, float | None] | None = None, max_sweeps: int = 12) -> str:
    """Measured vs predicted thermal error: per sweep over position (poly_slope) or over time (linear_direct)."""
    plt = _plt()
    t, P, m, p = thermal_pairs(model, run, window)
    fig, ax = plt.subplots(figsize=(8, 4.8))
    if model.target == "slope":
        times = np.unique(t)
        pick = times[np.linspace(0, times.size - 1, min(max_sweeps, times.size)).round().astype(int)]
        cmap = plt.get_cmap("viridis")
        for i, ts in enumerate(pick):
            k = t == ts
            order = np.argsort(P[k])
            c = cmap(i / max(1, pick.size - 1))
            ax.plot(P[k][order], m[k][order], "o-", color=c, ms=3, lw=1, label="%.1f h" % (ts / 3600))
            ax.plot(P[k][order], p[k][order], "--", color=c, lw=1)
        ax.set_xlabel("position (mm)")
        ax.legend(fontsize=7, ncol=2, title="sweep (solid measured, dashed predicted)", title_fontsize=7)
    else:
        ax.plot(t / 3600, m, lw=1, label="measured")
        ax.plot(t / 3600, p, lw=1, label="predicted")
        ax.set_xlabel("time (h)")
        ax.legend(fontsize=8)
    ax.set_ylabel("thermal error (µm)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_residuals(models: Mapping[str, Any], run: Run, path: str, title: str, window: tuple[float | None, float | None] | None = None) -> str:
    """Residual (measured − predicted) over time of several models on one run: {label: model}."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for label, model in models.items():
        t, _, m, p = thermal_pairs(model, run, window)
        order = np.argsort(t, kind="stable")
        ax.plot(t[order] / 3600, (m - p)[order], ".", ms=2 if t.size > 500 else 4, label=label)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("time (h)")
    ax.set_ylabel("residual, measured − predicted (µm)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, markerscale=3)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_scree(pcr: Any, path: str, title: str) -> str:
    """Eigenvalues and cumulative explained variance of a fitted PCR, kept components marked."""
    plt = _plt()
    k = np.arange(1, pcr.eigenvalues_.size + 1)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.bar(k, pcr.eigenvalues_, color=["C0" if i < pcr.n_components_ else "0.7" for i in range(k.size)])
    ax.set_xlabel("principal component")
    ax.set_ylabel("eigenvalue of the correlation matrix")
    ax2 = ax.twinx()
    ax2.plot(k, 100 * pcr.cumulative_variance_ratio_, "o-", color="C3")
    ax2.axhline(100 * pcr.variance_threshold, color="C3", ls=":", lw=0.8)
    ax2.set_ylabel("cumulative explained variance (%)", color="C3")
    ax2.set_ylim(0, 105)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_summary(rows: Sequence[Mapping[str, Any]], path: str, title: str) -> str:
    """Bars of mean held-out RMSE, clean and disturbed, per method. rows: dicts from compare."""
    plt = _plt()
    rows = [r for r in rows if r.get("mean_test_rmse_um") is not None]
    labels = ["%s (%d)" % (r["method"], r["n_sensors"]) for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(rows) + 2), 4.5))
    ax.bar(x - 0.2, [r["mean_test_rmse_um"] for r in rows], 0.4, label="held-out RMSE")
    ax.bar(x + 0.2, [r.get("mean_disturbed_rmse_um") or 0 for r in rows], 0.4, label="with disturbed temperatures")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("RMSE (µm)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
