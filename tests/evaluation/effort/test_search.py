"""The knob search on synthetic effort functions (evaluation/effort/search.py): no rollouts involved."""

from __future__ import annotations

import math

import numpy as np
import pytest
from snac_gym.evaluation.effort.search import EffortMatch, EffortSearch, match_effort, within

TOLERANCE = 0.005


class Counted:
    """An effort function that records every knob value it is asked for."""

    def __init__(self, effort):
        self.effort, self.calls = effort, []

    def __call__(self, knob: float) -> float:
        self.calls.append(knob)
        return self.effort(knob)


def _crossing(effort, level: float, low: float = 1e-6, high: float = 1e6) -> float:
    """The smallest knob whose (non-decreasing) effort reaches ``level``, by plain bisection."""
    for _ in range(200):
        middle = math.sqrt(low * high)
        low, high = (low, middle) if effort(middle) >= level else (middle, high)
    return high


@pytest.mark.parametrize("power", [0.5, 1.0, 1.1, 2.0])
@pytest.mark.parametrize("target", [0.2, 1.7, 30.0])
@pytest.mark.parametrize("start_factor", [0.1, 0.5, 1.0, 3.0, 10.0])
def test_a_power_law_is_matched_within_the_tolerance_in_few_evaluations(power, target, start_factor):
    measure = Counted(lambda knob: 0.3 * knob**power)
    answer = (target / 0.3) ** (1 / power)
    result = EffortSearch(measure, target, TOLERANCE).run(answer * start_factor)
    assert result.matched and result.reason == ""
    assert within(result.effort, target, TOLERANCE)
    assert result.effort == measure.effort(result.value)  # the effort reported is the one measured there
    # Within the band of knobs whose effort lies in [target·(1 − tol), target·(1 + tol)].
    assert _crossing(measure.effort, target * (1 - TOLERANCE)) <= result.value * (1 + 1e-12)
    assert result.value <= _crossing(measure.effort, target * (1 + TOLERANCE)) * (1 + 1e-12)
    # The bracketing assumes effort ∝ knob: a square root takes a few more steps.
    assert len(measure.calls) <= (8 if power >= 1 else 12)
    assert [v for v, _ in result.evaluations] == measure.calls  # every call is recorded, in order


def test_the_bracket_ends_on_both_sides_of_the_threshold():
    search = EffortSearch(lambda knob: 0.3 * knob**1.1, 1.7, TOLERANCE)
    result = search.run(2.0)
    threshold = 1.7 * (1 - TOLERANCE)
    assert search.low is not None and search.high is not None
    assert search.low[0] < search.high[0] and search.low[1] < threshold <= search.high[1]
    assert (result.value, result.effort) == search.high  # the least aggressive knob reaching the target


def test_evaluate_keeps_the_largest_low_and_smallest_high_end():
    search = EffortSearch(lambda knob: knob, target=1.0, tolerance=0.1)  # threshold 0.9
    for value in (0.5, 2.0, 0.8, 3.0, 0.6, 1.2):
        search.evaluate(value)
    assert search.low == (0.8, 0.8) and search.high == (1.2, 1.2)
    assert len(search.evaluations) == 6


def test_a_saturating_effort_is_matched_below_its_plateau():
    def effort(knob: float) -> float:
        return 3.15 * (1.0 - math.exp(-knob))

    for fraction in (0.3, 0.9, 0.99):
        measure = Counted(effort)
        result = match_effort(measure, target=fraction * 3.15, start=2.0, tolerance=TOLERANCE)
        assert result.matched and within(result.effort, fraction * 3.15, TOLERANCE)
        assert len(measure.calls) <= 14


@pytest.mark.parametrize("exponent", [0.5, 1.0])
@pytest.mark.parametrize("target", [0.2, 0.6, 0.95])
def test_the_mean_of_clipped_per_rollout_peaks_is_matched(exponent, target):
    """The default statistic's shape: mean over rollouts of min(1, a_s·knob^p), each rollout's peak
    clipped at a limit at its own knob (p = 1/2: lqr's √q_scale), continuous but with a kink per rollout."""
    scales = np.random.default_rng(0).lognormal(mean=-1.0, sigma=0.8, size=200)

    def effort(knob: float) -> float:
        return float(np.mean(np.minimum(1.0, scales * knob**exponent)))

    measure = Counted(effort)
    result = match_effort(measure, target=target, start=1.0, tolerance=TOLERANCE)
    assert result.matched and within(result.effort, target, TOLERANCE)
    assert _crossing(effort, target * (1 - TOLERANCE)) <= result.value * (1 + 1e-12)
    assert result.value <= _crossing(effort, target * (1 + TOLERANCE)) * (1 + 1e-12)
    # Measured: 6–11 calls up to 0.6 (SNAC's mean peak at its defaults is about 0.6); near the
    # plateau the mean creeps up as the last rollouts saturate one by one: 15 (p = 1) and 18 (p = 1/2).
    assert len(measure.calls) <= (12 if target <= 0.6 else 18)


def test_a_target_above_the_plateau_is_out_of_reach():
    measure = Counted(lambda knob: min(0.8, 0.25 * knob))
    result = EffortSearch(measure, 1.0, TOLERANCE).run(2.0)
    assert not result.matched and "out of reach" in result.reason and "saturates at about 0.8" in result.reason
    # The least aggressive knob that already gives the plateau (within the tolerance), not a larger one.
    assert result.effort == pytest.approx(0.8, rel=TOLERANCE)
    assert result.value == min(v for v, e in result.evaluations if abs(e / 0.8 - 1) <= TOLERANCE)
    assert len(measure.calls) <= 6


def test_a_ceiling_equal_to_the_target_gives_its_left_edge():
    result = EffortSearch(lambda knob: min(1.0, 0.25 * knob), 1.0, TOLERANCE).run(20.0)  # start deep in the ceiling
    assert result.matched
    assert 4.0 * (1 - TOLERANCE) <= result.value <= 4.0 * (1 + 4 * TOLERANCE)  # the ceiling's edge is 4


def test_an_effort_that_ignores_the_knob():
    at_target = EffortSearch(lambda knob: 1.0, 1.0, TOLERANCE).run(2.0)
    assert at_target.matched and at_target.value == min(v for v, _ in at_target.evaluations)
    assert len(at_target.evaluations) == 1 + 4  # the start, then four growing steps down the "ceiling"
    above = EffortSearch(lambda knob: 2.0, 1.0, TOLERANCE).run(2.0)
    assert not above.matched and "does not fall below about 2" in above.reason
    below = EffortSearch(lambda knob: 0.5, 1.0, TOLERANCE).run(2.0)
    assert not below.matched and "out of reach" in below.reason


def test_a_jump_across_the_target_is_reported():
    result = EffortSearch(lambda knob: 0.1 if knob < 3.0 else 1.0, 0.5, TOLERANCE).run(1.0)
    assert not result.matched and "jumps from 0.1 to 1 across the target 0.5" in result.reason
    assert 3.0 <= result.value <= 3.0 * (1 + 1e-3) or result.value < 3.0  # the closest evaluated knob


def test_a_knob_value_the_policy_rejects_ends_the_search():
    def picky(knob: float) -> float:
        if knob > 3.0:
            raise ValueError("too large")
        return 0.25 * knob

    result = EffortSearch(picky, 1.0, TOLERANCE).run(2.0)
    assert not result.matched and "rejects" in result.reason and "too large" in result.reason
    assert result.value == 2.0  # the closest of what was measured


def test_the_evaluation_budget_is_kept():
    measure = Counted(lambda knob: 1e-9 * knob)  # the target is 16x per step away
    result = EffortSearch(measure, 1.0, TOLERANCE, max_evaluations=4).run(1.0)
    assert not result.matched and "no bracket after 4 evaluations" in result.reason
    assert len(measure.calls) == 4


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="target and tolerance must be positive"):
        EffortSearch(lambda knob: knob, 0.0, TOLERANCE)
    with pytest.raises(ValueError, match="start must be positive"):
        EffortSearch(lambda knob: knob, 1.0, TOLERANCE).run(0.0)
    with pytest.raises(ValueError, match="target, start and tolerance must be positive"):
        match_effort(lambda knob: knob, 1.0, -1.0, TOLERANCE)


def test_match_effort_is_one_search():
    def effort(knob: float) -> float:
        return 0.3 * knob**1.1

    assert match_effort(effort, 1.7, 2.0, TOLERANCE) == EffortSearch(effort, 1.7, TOLERANCE).run(2.0)
    assert isinstance(match_effort(effort, 1.7, 2.0, TOLERANCE), EffortMatch)
