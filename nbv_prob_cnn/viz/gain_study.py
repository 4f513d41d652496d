"""The picture of ``nbv gain-study`` (matplotlib, Agg backend, no pyplot state kept): the pooled and
within-anchor Spearman ρ of every method and scoring variant with their bootstrap intervals, ρ against
the rays a pose's score sums, and ρ per anchor of the service's defaults."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from nbv_prob_cnn.exploration.gain_study import BASELINE, GainStudy
from nbv_prob_cnn.exploration.gain_study_summary import RhoRow

RHO_LABEL = "Spearman ρ, predicted vs realized gain"


def _interval_panel(ax: Axes, summary: Sequence[RhoRow], scope: str, methods: list[str], variants: list[str]) -> None:
    """ρ with its interval per variant (rows) and method (markers); the baseline's ρ as a dotted line."""
    for row in summary:
        if row.variant == BASELINE[1] and row.scope == scope:
            ax.axvline(row.rho, color="black", lw=1.0, ls=":", label=f"baseline: {row.method}")
    step = 0.8 / max(1, len(methods))
    for m, method in enumerate(methods):
        rows = {r.variant: r for r in summary if r.method == method and r.scope == scope}
        y = np.arange(len(variants)) - 0.4 + step * (m + 0.5)
        rho = np.array([rows[v].rho for v in variants])
        low, high = np.array([rows[v].low for v in variants]), np.array([rows[v].high for v in variants])
        err = np.vstack([np.nan_to_num(rho - low), np.nan_to_num(high - rho)])
        undefined = any(rows[v].constant_gain for v in variants)  # not drawn (NaN)
        label = method + (" (ρ undefined where its gain is constant)" if undefined else "")
        ax.errorbar(rho, y, xerr=err, fmt="o", ms=4, capsize=2, label=label)
    ax.set_yticks(np.arange(len(variants)), variants, fontsize=7)
    ax.invert_yaxis()
    ax.axvline(0.0, color="grey", lw=0.6)
    ax.axvline(0.8, color="grey", lw=0.6, ls="--")
    ax.set_xlim(-1.0, 1.0)
    ax.set_xlabel(f"{RHO_LABEL} (1)")
    ax.set_title(
        "pooled over every anchor's poses" if scope == "pooled" else "within anchors (mean of per-anchor ρ)",
        fontsize=9,
    )


def plot_gain_study(study: GainStudy, summary: Sequence[RhoRow], default_variant: str, path: Path) -> None:
    """Write the study's picture to ``path`` (PNG)."""
    methods = list(dict.fromkeys(r.method for r in summary if r.variant != BASELINE[1]))
    variants = list(dict.fromkeys(r.variant for r in summary if r.variant != BASELINE[1]))
    fig = Figure(figsize=(13.0, 4.0 + 0.28 * len(variants) * 2))
    axes = fig.subplots(2, 2)
    _interval_panel(axes[0, 0], summary, "pooled", methods, variants)
    _interval_panel(axes[0, 1], summary, "within", methods, variants)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    ax = axes[1, 0]
    for method in methods:
        rows = [r for r in summary if r.method == method and r.scope == "within"]
        ax.scatter([r.mean_rays_in_frustum for r in rows], [r.rho for r in rows], s=14, label=method)
    ax.set_xscale("log")
    ax.set_ylim(-1.0, 1.0)
    ax.set_xlabel("rays a pose's score sums (mean over poses, count)")
    ax.set_ylabel("within-anchor ρ (1)")
    ax.set_title("ρ against the rays inside the frustum (every variant)", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1, 1]
    for method in methods:
        mine = [r for r in summary if r.method == method and r.variant == default_variant and r.scope == "anchor"]
        rows = sorted(mine, key=lambda r: r.anchor)
        ax.plot([r.anchor for r in rows], [r.rho for r in rows], "o-", ms=4, label=method)
    baseline = sorted((r for r in summary if r.variant == BASELINE[1] and r.scope == "anchor"), key=lambda r: r.anchor)
    ax.plot([r.anchor for r in baseline], [r.rho for r in baseline], "k:", lw=1.0, label=f"baseline: {BASELINE[0]}")
    ax.axhline(0.0, color="grey", lw=0.6)
    ax.set_ylim(-1.05, 1.05)
    ax.set_xlabel("anchor (frame index of the recording)")
    ax.set_ylabel("per-anchor ρ (1)")
    ax.set_title(f"per anchor, the service's defaults ({default_variant})", fontsize=9)
    ax.legend(fontsize=7)
    g = study.geometry
    fig.suptitle(
        f"Predicted (/nbv/evaluate_views) vs realized gain: {len(study.anchors)} anchors, "
        f"{g.resolution * 100:g} cm cells, box {' x '.join(f'{n * g.resolution:.2f}' for n in g.shape)} m",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
