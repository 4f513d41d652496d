"""Rank agreement between a prediction and what happened: Spearman ρ of one sample, of groups of
samples (pooled, or averaged over the groups), and a bootstrap interval that resamples whole groups
(e.g. the anchors of ``nbv gain-study``, whose poses are not independent of each other)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

#: A group of paired samples: ``(predicted, realized)``, two 1-D arrays of one length.
Group = tuple[np.ndarray, np.ndarray]
T = TypeVar("T")


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman ρ of two samples (ties get their mean rank); NaN when either is constant or shorter than 2."""
    a, b = np.asarray(a), np.asarray(b)
    if a.size < 2 or np.all(a == a[0]) or np.all(b == b[0]):
        return float("nan")
    from scipy.stats import rankdata  # here: scipy.stats takes 0.3-2.4 s to import (every completion_server start)

    ra, rb = rankdata(a), rankdata(b)  # Pearson's r of the ranks (as scipy's spearmanr, a tenth of its time)
    ra, rb = ra - ra.mean(), rb - rb.mean()
    return float(np.clip((ra @ rb) / np.sqrt((ra @ ra) * (rb @ rb)), -1.0, 1.0))


def ranking_rho(predicted: np.ndarray, realized: np.ndarray) -> float:
    """ρ of a prediction that has to rank ``realized``: NaN when ``realized`` is constant or shorter than
    2 (nothing to rank), 0 when only the prediction is constant (it ranks nothing: a choice among
    equal predictions is a random one), else :func:`spearman`."""
    predicted, realized = np.asarray(predicted), np.asarray(realized)
    if realized.size < 2 or np.all(realized == realized[0]):
        return float("nan")
    if np.all(predicted == predicted[0]):
        return 0.0
    return spearman(predicted, realized)


def pooled_rho(groups: Sequence[Group]) -> float:
    """:func:`ranking_rho` of all groups' samples together (NaN without samples)."""
    if not groups:
        return float("nan")
    return ranking_rho(np.concatenate([g[0] for g in groups]), np.concatenate([g[1] for g in groups]))


def finite_mean(values: Sequence[float]) -> float:
    """Mean of the finite values (NaN if there is none)."""
    array = np.asarray(values, dtype=np.float64)
    array = array[np.isfinite(array)]
    return float(array.mean()) if array.size else float("nan")


def mean_rho(groups: Sequence[Group]) -> float:
    """Mean of the groups' :func:`ranking_rho` over the groups where it is defined (NaN if none is)."""
    return finite_mean([ranking_rho(p, r) for p, r in groups])


def bootstrap_interval(
    items: Sequence[T],
    statistic: Callable[[Sequence[T]], float],
    n_resamples: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap interval of ``statistic`` over ``items`` (groups, or one value per group):
    each resample draws as many items as there are, with replacement, each kept whole. Resamples whose
    statistic is NaN are left out; ``(nan, nan)`` when fewer than 2 items or no resample gives a value.

    Raises:
        ValueError: ``n_resamples`` < 1 or ``level`` outside (0, 1).
    """
    if n_resamples < 1:
        raise ValueError(f"n_resamples: expected at least 1, got {n_resamples}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: expected a probability in (0, 1), got {level}")
    if len(items) < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(items), size=(n_resamples, len(items)))
    values = np.array([statistic([items[i] for i in row]) for row in picks], dtype=np.float64)
    values = values[np.isfinite(values)]
    if not values.size:
        return float("nan"), float("nan")
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(values, [tail, 100.0 - tail])
    return float(low), float(high)
