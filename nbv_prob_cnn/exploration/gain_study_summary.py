"""The rank agreement of ``nbv gain-study`` (:mod:`~nbv_prob_cnn.exploration.gain_study`) and its files.

Per method and scoring variant, and per realized target (``revealed``: the cells unknown at the anchor
that a pose's frame labels; ``surface``: those it sees occupied, :data:`TARGETS`):

* **per anchor**: Spearman ρ between the predicted and the realized gains of the anchor's next poses
  (0 when the prediction is constant and the realized gains are not: it ranks nothing; undefined
  when the realized gains are all equal);
* **pooled**: ρ of every (anchor, pose) pair together (undefined, NaN, when the prediction is one value
  everywhere: ``RhoRow.constant_gain``, printed as "undefined"). It also counts how well the gains tell the
  anchors apart (an early anchor, with most of the room unknown, has larger gains on both sides);
* **within**: the mean of the per-anchor ρ, the ranking a planner needs when it picks one of the
  poses open to it at one moment.

The baseline (:data:`~nbv_prob_cnn.exploration.gain_study.BASELINE`, frames since the anchor) gets the
same three.

Both come with a percentile bootstrap interval over the anchors (whole anchors resampled:
:func:`~nbv_prob_cnn.basics.rank_stats.bootstrap_interval`).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.rank_stats import Group, bootstrap_interval, finite_mean, pooled_rho, ranking_rho
from nbv_prob_cnn.exploration.gain_study import BASELINE, GainStudy, PoseRow

SCOPES = ("anchor", "pooled", "within")
#: What the predictions are ranked against: the cells a frame revealed, or the surface it saw.
TARGETS = ("revealed", "surface")


@dataclass(frozen=True)
class RhoRow:
    """One ρ: per anchor (``anchor`` its frame index), pooled or within (``anchor`` -1)."""

    method: str
    variant: str
    scope: str
    anchor: int
    rho: float
    low: float
    high: float
    anchors: int  # anchors that count (realized gains not all equal)
    poses: int
    mean_rays_in_frustum: float
    constant_gain: bool = False  # the predicted gain is one value (per anchor; pooled/within: at every anchor)
    target: str = "revealed"  # what the realized side counts (TARGETS)

    def text(self) -> str:
        """``0.86 [0.71, 0.93]``, or why ρ is undefined (a constant prediction; realized gains all equal)."""
        if self.constant_gain:
            return "undefined (constant predicted gain: it ranks nothing; a probabilistic method such as prob_ig ranks)"
        if not np.isfinite(self.rho):
            return "undefined (the realized gains are all equal)"
        return f"{self.rho:.2f} [{self.low:.2f}, {self.high:.2f}]"


def anchor_groups(rows: Sequence[PoseRow], method: str, variant: str, target: str = "revealed") -> dict[int, Group]:
    """Per anchor: (predicted, realized) gains of one method and variant, in pose order; ``target``:
    the realized cells (``revealed``) or the realized surface (``surface``)."""
    if target not in TARGETS:
        raise ValueError(f"target: expected one of {TARGETS}, got {target!r}")
    groups: dict[int, tuple[list[float], list[float]]] = {}
    for row in rows:
        if row.method == method and row.variant == variant:
            predicted, realized = groups.setdefault(row.anchor, ([], []))
            predicted.append(row.predicted)
            realized.append(row.realized if target == "revealed" else row.realized_surface)
    return {a: (np.array(p, dtype=np.float64), np.array(r, dtype=np.float64)) for a, (p, r) in groups.items()}


def summarise(study: GainStudy, n_resamples: int = 2000, level: float = 0.95, seed: int = 0) -> list[RhoRow]:
    """Every ρ of the study: per target, (method, variant) the anchors', the pooled one and the within one."""
    pairs = list(dict.fromkeys((r.method, r.variant) for r in study.rows))
    out = []
    for target, (method, variant) in ((t, p) for t in TARGETS for p in pairs):
        groups = anchor_groups(study.rows, method, variant, target)
        rays = [r.rays_in_frustum for r in study.rows if r.method == method and r.variant == variant]
        mean_rays = float(np.mean(rays))
        rhos = {anchor: ranking_rho(*group) for anchor, group in groups.items()}
        counting = int(np.count_nonzero(np.isfinite(list(rhos.values()))))
        n_poses = sum(len(g[0]) for g in groups.values())
        constant = {anchor: bool(np.all(g[0] == g[0][0])) for anchor, g in groups.items()}
        for anchor, rho in rhos.items():
            out.append(RhoRow(method, variant, "anchor", anchor, rho, rho, rho, int(np.isfinite(rho)),
                              len(groups[anchor][0]), mean_rays, constant[anchor], target))  # fmt: skip
        all_groups = list(groups.values())
        predicted = np.concatenate([g[0] for g in all_groups])
        if np.all(predicted == predicted[0]):  # no ranking at all: rho is undefined, not 0
            nan = float("nan")
            for scope in ("pooled", "within"):
                out.append(RhoRow(method, variant, scope, -1, nan, nan, nan, counting, n_poses, mean_rays, True,
                                  target))  # fmt: skip
            continue
        low, high = bootstrap_interval(all_groups, pooled_rho, n_resamples, level, seed)
        out.append(RhoRow(method, variant, "pooled", -1, pooled_rho(all_groups), low, high, counting, n_poses,
                          mean_rays, False, target))  # fmt: skip
        low, high = bootstrap_interval(list(rhos.values()), finite_mean, n_resamples, level, seed)
        out.append(RhoRow(method, variant, "within", -1, finite_mean(list(rhos.values())), low, high, counting,
                          n_poses, mean_rays, all(constant.values()), target))  # fmt: skip
    return out


def write_csv(path: Path, rows: Sequence[PoseRow] | Sequence[RhoRow]) -> None:
    """One dataclass row per line, the field names as the header (floats to 6 significant digits)."""
    if not rows:
        raise ValueError(f"{path}: no rows to write")
    names = [f.name for f in fields(rows[0])]  # type: ignore[arg-type]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for row in rows:
            values = asdict(row)  # type: ignore[call-overload]
            writer.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in (values[n] for n in names)])


def rho_line(summary: Sequence[RhoRow], variant: str, scope: str = "pooled", target: str = "revealed") -> str:
    """``rho: METHOD X [lo, hi], ... (K anchors)`` of one variant, scope and target, methods in study order
    (the surface target's line says so)."""
    chosen = [r for r in summary if r.variant == variant and r.scope == scope and r.target == target]
    if not chosen:
        raise ValueError(f"variant: no {scope} rho for {variant!r}")
    parts = [f"{r.method} {r.text()}" for r in chosen]
    anchors = max(r.anchors for r in chosen)
    label = ("rho" if scope == "pooled" else f"rho {scope} anchors") + (" (baseline)" if variant == BASELINE[1] else "")
    label += " against the surface seen" if target == "surface" else ""
    return f"{label}: {', '.join(parts)} ({anchors} anchors)"
