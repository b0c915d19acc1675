"""Paired statistics of two controllers on the same samples, against independent computations."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.reports.paired import compare, fraction_better, median_ratio_ci, wilcoxon_p


def test_the_bootstrap_interval_is_the_percentiles_of_resampled_medians():
    rng = np.random.default_rng(1)
    a, b = rng.lognormal(0.2, 1.0, 60), rng.lognormal(0.0, 1.0, 60)
    median, low, high = median_ratio_ci(a, b, resamples=500, seed=7)
    draws = np.random.default_rng(7).integers(0, 60, size=(500, 60))
    slow = [np.median([a[i] / b[i] for i in row]) for row in draws]  # one resample at a time
    assert median == pytest.approx(np.median(a / b))
    assert (low, high) == pytest.approx(tuple(np.percentile(slow, [2.5, 97.5])))
    assert median_ratio_ci(a, b, resamples=500, seed=7) == (median, low, high)  # seeded: reproducible


@pytest.mark.parametrize("n", [1, 2, 7, 60, 1000, 1001])
def test_the_resampled_medians_are_numpys_bit_for_bit(n):
    """Read off counted draws, the bootstrap medians are ``np.median`` of the resampled values exactly,
    ties (a third of the values equal) and odd and even sizes included."""
    from snac_gym.evaluation.reports.paired import _resampled_medians

    values = np.random.default_rng(n).lognormal(0.0, 1.0, n)
    values[::3] = values[0]
    draws = np.random.default_rng(11).integers(0, n, size=(300, n))
    np.testing.assert_array_equal(_resampled_medians(values, 300, 11), np.median(values[draws], axis=1))


def test_the_interval_covers_the_true_median_ratio_about_95_percent_of_the_time():
    rng = np.random.default_rng(3)
    covered = 0
    for _ in range(200):
        b = rng.lognormal(0.0, 1.5, 80)
        a = b * rng.lognormal(np.log(1.3), 0.3, 80)  # true median ratio 1.3
        _, low, high = median_ratio_ci(a, b, resamples=400, seed=int(rng.integers(1 << 30)))
        covered += low <= 1.3 <= high
    assert covered >= 180


def test_wilcoxon_and_fraction_better_on_a_hand_case():
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 9.0])
    b = np.array([1.5, 2.5, 2.0, 5.0, 6.5, 5.0, 8.0, 10.0])
    assert wilcoxon_p(a, b) == pytest.approx(stats.wilcoxon(a - b).pvalue)
    assert fraction_better(a, b) == pytest.approx(6 / 8)


def test_edge_cases_give_nan_not_a_crash():
    same = np.array([1.0, 2.0, 3.0])
    assert math.isnan(wilcoxon_p(same, same))  # no difference at all
    assert math.isnan(wilcoxon_p(np.array([1.0]), np.array([2.0])))  # one pair
    result = compare(np.array([1.0, np.nan, 3.0]), np.array([2.0, 2.0, np.nan]))  # NaN pairs are left out
    assert result.samples == 1 and result.median_ratio == 0.5 and result.fraction_better == 1.0
    empty = compare(np.array([np.nan]), np.array([1.0]))
    assert empty.samples == 0 and math.isnan(empty.median_ratio) and math.isnan(empty.fraction_better)
    with pytest.raises(ValueError, match="same length"):
        compare(np.ones(3), np.ones(4))


def test_the_summary_reports_paired_statistics_against_the_best_and_the_optimum(tmp_path):
    config = EvaluationConfig(
        out=tmp_path, samples=5, seed=4, controllers=("dls", "rnn", "optimal"), horizons={"reach": 2.0, "track": 2.0},
        match_effort=False, progress=False, success_threshold=0.0, plots=False,
    )  # fmt: skip
    results = run_evaluation(config)
    summary = pd.read_csv(tmp_path / "summary.csv").set_index("controller")
    for task in ("reach", "track"):
        costs = results[results.task == task].pivot_table(index="sample", columns="controller", values="cost")
        best = summary.loc[summary[f"{task}_rank"] == 1].index[0]
        other = "rnn" if best == "dls" else "dls"
        assert summary.loc[other, f"{task}_vs_best"] == best
        assert summary.loc[other, f"{task}_vs_best_median_ratio"] == pytest.approx(
            np.median(costs[other] / costs[best])
        )
        assert summary.loc[other, f"{task}_vs_optimal_fraction_better"] == 0.0  # nobody beats the optimum
        assert np.isnan(summary.loc[best, f"{task}_vs_best_median_ratio"])
    text = (tmp_path / "summary.md").read_text()
    assert "## Paired comparison" in text and "vs the optimum: median ratio [95 % CI]" in text
