"""Spearman ρ of one sample and of groups, and the bootstrap over groups, against hand-worked values
(issue 36)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from nbv_prob_cnn.basics.rank_stats import bootstrap_interval, finite_mean, mean_rho, pooled_rho, ranking_rho, spearman


def test_spearman_by_hand():
    # ranks (1, 2, 3, 4) against (1, 3, 2, 4): d = (0, -1, 1, 0), rho = 1 - 6 * 2 / (4 * 15) = 0.8
    assert spearman(np.array([1.0, 2, 3, 4]), np.array([10.0, 30, 20, 40])) == pytest.approx(0.8)
    assert spearman(np.array([1.0, 2, 3]), np.array([3.0, 2, 1])) == pytest.approx(-1.0)
    # a tie: (1, 2, 2) has ranks (1, 2.5, 2.5); against (1, 2, 3): Pearson of the ranks is sqrt(3) / 2
    assert spearman(np.array([1.0, 2, 2]), np.array([1.0, 2, 3])) == pytest.approx(math.sqrt(3) / 2)
    assert math.isnan(spearman(np.array([1.0, 1.0]), np.array([1.0, 2.0])))
    assert math.isnan(spearman(np.array([1.0]), np.array([1.0])))


def test_spearman_equals_scipys_with_ties():
    from scipy.stats import spearmanr

    rng = np.random.default_rng(5)
    for _ in range(20):
        a, b = rng.integers(0, 6, 30).astype(float), rng.integers(0, 9, 30).astype(float)
        assert spearman(a, b) == pytest.approx(spearmanr(a, b).statistic, abs=1e-12)


def test_a_constant_prediction_ranks_nothing_and_a_constant_outcome_has_nothing_to_rank():
    assert ranking_rho(np.zeros(4), np.array([1.0, 2, 3, 4])) == 0.0
    assert math.isnan(ranking_rho(np.array([1.0, 2, 3]), np.full(3, 7.0)))
    assert ranking_rho(np.array([1.0, 2, 3, 4]), np.array([10.0, 30, 20, 40])) == pytest.approx(0.8)


def test_pooled_and_within_by_hand():
    a = (np.array([1.0, 2, 3, 4]), np.array([10.0, 30, 20, 40]))  # rho 0.8
    b = (np.array([5.0, 6]), np.array([2.0, 1]))  # rho -1
    c = (np.array([9.0, 9]), np.array([1.0, 2]))  # constant prediction: 0
    d = (np.array([1.0, 2]), np.array([5.0, 5]))  # nothing to rank: left out of the mean
    assert mean_rho([a, b, c, d]) == pytest.approx((0.8 - 1.0 + 0.0) / 3)
    # pooled: predicted (1, 2, 3, 4, 5, 6) against realized (10, 30, 20, 40, 2, 1): ranks (3, 5, 4, 6, 2, 1)
    # d = (-2, -3, -1, -2, 3, 5), sum d^2 = 52, rho = 1 - 6 * 52 / (6 * 35) = -17 / 35
    assert pooled_rho([a, b]) == pytest.approx(1 - 6 * 52 / (6 * 35))
    assert math.isnan(pooled_rho([]))
    assert math.isnan(mean_rho([d]))


def exact_bootstrap(values: list[float], level: float) -> tuple[float, float]:
    """The percentile interval of the mean of a resample, from every resample with its probability."""
    n = len(values)
    means, weights = [], []
    for counts in itertools.product(range(n + 1), repeat=n):
        if sum(counts) != n:
            continue
        ways = math.factorial(n) / math.prod(math.factorial(c) for c in counts)
        means.append(sum(c * v for c, v in zip(counts, values, strict=True)) / n)
        weights.append(ways / n**n)
    order = np.argsort(means)
    cumulative = np.cumsum(np.array(weights)[order])
    sorted_means = np.array(means)[order]
    tail = (1 - level) / 2
    return float(sorted_means[np.searchsorted(cumulative, tail)]), float(
        sorted_means[np.searchsorted(cumulative, 1 - tail)]
    )


def test_the_bootstrap_resamples_whole_groups_against_the_enumerated_distribution():
    # three groups of within-anchor rho 1, -1 and 0.8: the mean of a resample of three takes 10 values
    groups = [
        (np.array([1.0, 2, 3]), np.array([1.0, 2, 3])),
        (np.array([1.0, 2, 3]), np.array([3.0, 2, 1])),
        (np.array([1.0, 2, 3, 4]), np.array([10.0, 30, 20, 40])),
    ]
    low, high = bootstrap_interval(groups, mean_rho, n_resamples=2000, level=0.8, seed=3)
    expected = exact_bootstrap([1.0, -1.0, 0.8], 0.8)
    # by hand: P(mean <= -1) = 1/27, P(mean <= (-1 - 1 + 0.8) / 3) = 4/27, so the 10 % point is -0.4; P(mean <=
    # (1 + 0.8 + 0.8) / 3) = 23/27 and P(mean <= (1 + 1 + 0.8) / 3) = 26/27, so the 90 % point is 14/15
    assert expected == pytest.approx((-0.4, 14 / 15))
    assert (low, high) == pytest.approx(expected, abs=1e-9)  # both ends are atoms of the distribution
    # the per-group values resampled give the same interval as the groups (same draws)
    assert bootstrap_interval([1.0, -1.0, 0.8], finite_mean, n_resamples=2000, level=0.8, seed=3) == (low, high)
    # one group: no interval; a statistic that is never defined: none either
    assert all(math.isnan(v) for v in bootstrap_interval(groups[:1], mean_rho))
    assert all(math.isnan(v) for v in bootstrap_interval(groups, lambda g: float("nan"), n_resamples=10))
    with pytest.raises(ValueError, match="n_resamples"):
        bootstrap_interval(groups, mean_rho, n_resamples=0)
    with pytest.raises(ValueError, match="level"):
        bootstrap_interval(groups, mean_rho, level=1.0)
