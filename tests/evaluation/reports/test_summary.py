"""V/N's interval (evaluation/reports/summary.py): a seeded bootstrap percentile interval of the mean, inside the
data's range whatever the tails, and close to the t interval where the normal approximation holds."""

import math

import numpy as np
import pytest
from snac_gym.evaluation.reports.summary import mean_confidence_interval


def test_a_heavy_tail_never_takes_the_interval_below_the_smallest_cost():
    """The case the normal approximation got wrong: 999 costs near 3000 and one near 2·10⁵."""
    rng = np.random.default_rng(5)
    costs = np.append(rng.lognormal(np.log(3000), 0.5, 999), 2.0e5)
    mean, std, low, high = mean_confidence_interval(costs)
    assert costs.min() <= low < mean < high <= costs.max()
    # One extreme sample among 20: the t interval goes below zero, the bootstrap's stays above the minimum.
    few = np.append(np.full(19, 10.0), 5.0e4)
    mean, std, low, high = mean_confidence_interval(few)
    assert mean - 2.093 * std / math.sqrt(few.size) < 0 < few.min() <= low <= high <= few.max()


def test_the_interval_is_inside_the_data_for_any_sample():
    """200 samples of 2 to 300 costs from light and heavy tails, ties, and two-point sets."""
    rng = np.random.default_rng(11)
    draws = [
        lambda n: rng.uniform(0, 1e6, n),
        lambda n: rng.pareto(0.8, n) * 100,  # no finite mean
        lambda n: np.round(rng.exponential(5, n)),  # ties
        lambda n: rng.choice([1.0, 1e5], n, p=[0.99, 0.01]),
        lambda n: np.full(n, 7.25),
    ]
    for case in range(200):
        values = draws[case % len(draws)](int(rng.integers(2, 301)))
        mean, _, low, high = mean_confidence_interval(values)
        assert values.min() <= low <= high <= values.max(), (case, values.min(), low, high, values.max())


def test_seeded_and_close_to_the_t_interval_for_a_normal_sample():
    values = np.random.default_rng(1).normal(100.0, 10.0, 1000)
    first, second = mean_confidence_interval(values), mean_confidence_interval(values)
    assert first == second  # the same rows, the same interval
    mean, std, low, high = first
    half = 1.9623 * std / math.sqrt(values.size)
    assert low == pytest.approx(mean - half, abs=0.1 * half) and high == pytest.approx(mean + half, abs=0.1 * half)


def test_too_few_or_non_finite_costs_have_no_interval():
    assert math.isnan(mean_confidence_interval(np.array([3.0]))[2])
    assert math.isnan(mean_confidence_interval(np.array([1.0, math.inf]))[3])
