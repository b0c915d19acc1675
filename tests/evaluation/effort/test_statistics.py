"""Equal effort as a property of the controller: the effort statistics against independent
computations on hand-made rollouts, and a matched knob that does not move with the sample count."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.effort.statistics import DEFAULT_EFFORT_STATISTIC, EFFORT_STATISTICS, PEAK_FLOOR


def _rows(samples, peaks, max_abs_u=None):
    rows = {"sample": samples, "peak_limit_fraction": peaks, "peak_step": np.zeros(len(samples), dtype=int)}
    if max_abs_u is not None:
        rows["max_abs_u"] = max_abs_u
    return pd.DataFrame(rows)


def test_the_default_is_the_mean_peak():
    assert DEFAULT_EFFORT_STATISTIC == "mean-peak" and not EFFORT_STATISTICS["mean-peak"].paired
    assert {"max", "median-peak", "peak-ratio"} <= set(EFFORT_STATISTICS)  # the others stay selectable


def test_peak_ratio_is_the_geometric_mean_of_per_sample_ratios_to_the_reference():
    # The reference's rows in another order and with an extra sample: pairing goes by sample id.
    reference = _rows([7, 3, 9, 5], [0.5, 0.2, 0.9, 1.0])
    rows = _rows([3, 5, 7], [0.8, 0.25, 1.0])  # ratios 4, 1/4, 2 on samples 3, 5, 7
    statistic = EFFORT_STATISTICS["peak-ratio"]
    assert statistic.of(rows, reference) == pytest.approx((4 * 0.25 * 2) ** (1 / 3), rel=1e-12)
    assert statistic.of(reference, reference) == 1.0  # the reference's own target
    # Symmetric: the reference measured against the controller gives the inverse.
    assert statistic.of(reference[reference["sample"] != 9], rows) == pytest.approx(2 ** (-1 / 3), rel=1e-12)
    assert statistic.largest(np.array([2.16, 3.2])) == math.inf


def test_peak_ratio_floors_a_rollout_that_never_moves_and_refuses_unpaired_rows():
    statistic = EFFORT_STATISTICS["peak-ratio"]
    reference = _rows([0, 1], [0.0, 0.5])
    rows = _rows([0, 1], [0.0, 0.5])
    assert statistic.of(rows, reference) == 1.0  # 0/0 is a ratio of 1, not NaN
    assert statistic.of(_rows([0], [0.1]), reference) == pytest.approx(0.1 / PEAK_FLOOR)
    with pytest.raises(ValueError, match="needs the reference"):
        statistic.of(rows)
    with pytest.raises(ValueError, match=r"no reference rollout of sample\(s\) \[4\]"):
        statistic.of(_rows([1, 4], [0.5, 0.5]), reference)
    with pytest.raises(ValueError, match="no rollouts"):
        statistic.of(rows.iloc[:0], reference)


def test_the_unpaired_statistics_by_hand():
    rows = _rows([0, 1, 2, 3], [0.2, 1.0, 0.5, 0.4], max_abs_u=[0.4, 3.15, 1.0, 0.9])
    assert EFFORT_STATISTICS["mean-peak"].of(rows) == pytest.approx(2.1 / 4)
    assert EFFORT_STATISTICS["mean-peak"].largest(np.array([2.16, 3.2])) == 1.0  # a fraction of the limits
    assert EFFORT_STATISTICS["max"].of(rows) == 3.15
    assert EFFORT_STATISTICS["median-peak"].of(rows) == pytest.approx(0.45)
    assert EFFORT_STATISTICS["max"].of(rows, rows.iloc[:1]) == 3.15  # a reference is ignored


def _matched_knob(tmp_path, statistic: str, samples: int) -> float:
    config = EvaluationConfig(
        out=tmp_path / f"{statistic}-{samples}",
        samples=samples,
        effort_samples=0,  # the statistic on the evaluated samples: what this test measures
        tasks=("reach",),
        horizons={"reach": 0.3},
        controllers=("dls", "rnn"),
        effort_reference="dls",
        effort_statistic=statistic,
        progress=False,
        chunk_size=500,
        plots=False,
    )
    results = run_evaluation(config)
    rnn = results[results["controller"] == "rnn"]
    return float(rnn["effort_value"].iloc[0])


@pytest.mark.parametrize(
    "statistic",
    [
        DEFAULT_EFFORT_STATISTIC,
        # The old rule: the maximum over the set comes from its most demanding sample, and RNN's gain
        # moved by 27 % between these sets; strict, so that the test checks that it still fails.
        pytest.param("max", marks=pytest.mark.xfail(strict=True, reason="the set's maximum moves with the set")),
    ],
)
def test_the_matched_knob_does_not_move_with_the_sample_count(tmp_path, statistic):
    """RNN matched to DLS on 40 and on 120 samples of one seed (the 40 are the first of the 120).

    Both command a multiple of the task-space error through J, so a set that happens to be
    demanding is as demanding for both: mean-peak's knob moved by −1.13 %, −0.28 % and −0.11 % on
    seeds 0, 1 and 2 (peak-ratio's by −0.74 %, 0.03 %, 0.40 %; max's by 27 %, 7 %, 35 %). LQR, whose
    peaks follow DLS's less closely, moved by −7.8 %, 2.5 % and −4.9 % on these small sets, and
    against SNAC the knobs move more: docs/evaluation.md has 200 against 1000 samples.
    """
    few, many = (_matched_knob(tmp_path, statistic, samples) for samples in (40, 120))
    assert abs(few / many - 1) <= 0.02


def test_peak_ratio_without_matching_is_relative_to_the_reference_and_refuses_a_target(tmp_path):
    common = {"samples": 4, "tasks": ("reach",), "horizons": {"reach": 0.2}, "progress": False, "plots": False}
    config = EvaluationConfig(
        out=tmp_path / "fixed", controllers=("snac", "dls"), match_effort=False, effort_statistic="peak-ratio", **common
    )
    results = run_evaluation(config)
    summary = pd.read_csv(tmp_path / "fixed" / "summary.csv").set_index("controller")
    by_controller = {name: rows for name, rows in results.groupby("controller")}
    expected = EFFORT_STATISTICS["peak-ratio"].of(by_controller["dls"], by_controller["snac"])
    assert summary.loc["dls", "reach_effort"] == pytest.approx(expected) and summary.loc["snac", "reach_effort"] == 1.0
    alone = EvaluationConfig(
        out=tmp_path / "alone", controllers=("dls",), match_effort=False, effort_statistic="peak-ratio", **common
    )
    run_evaluation(alone)  # no reference evaluated: the effort is unknown, not an error
    assert np.isnan(pd.read_csv(tmp_path / "alone" / "summary.csv")["reach_effort"].iloc[0])
    with pytest.raises(ValueError, match="--effort-target has no meaning for the peak-ratio statistic"):
        run_evaluation(
            EvaluationConfig(
                out=tmp_path / "target",
                controllers=("dls",),
                effort_target=1.0,
                effort_statistic="peak-ratio",
                **common,
            )
        )
