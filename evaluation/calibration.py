"""Equal control effort: the effort statistics and the search for the knob value that matches one.

**What "maximum control effort" means.** The paper tunes every controller "to the same
maximum control effort". Two statistics of the per-rollout commands are offered
(``--effort-statistic``):

``max`` (default, the issue's literal rule)
    the maximum of |u| over the whole sample set: max over samples, steps and joints of
    |uₖⱼ|, rad/s. Commands are clipped at the velocity limits ū (UR10: 2.16, 2.16, 3.15, 3.2,
    3.2, 3.2 rad/s), so wherever some rollout of the set drives a joint to its limit the
    maximum *is* that limit; it is a worst case, set by the single most demanding sample.
    Matching it gives each controller the least aggressive knob with which its most
    demanding rollout reaches the reference's maximum.

``median-peak``
    the median over the samples of each rollout's peak of max_j |uₖⱼ|/ūⱼ: the fraction of
    the velocity limits a *typical* rollout uses (1 = at a limit). It grows smoothly with the
    knob until half of the rollouts reach a limit, so it pins down the knob by the bulk of the
    set instead of by one sample.

docs/evaluation.md compares the two with measurements; the summary shows both for every
controller, whichever is matched.

**Search.** Each policy class names a scalar constructor argument that scales its effort
monotonically (``effort_parameter``). :func:`match_effort` looks for the smallest knob value
whose effort reaches the target (within the tolerance): it brackets the target (multiplying
the knob by target/effort, 3 % past it, at most 16x per step and at least 1.5x after the
first step), then bisects the bracket in log space, splitting at the log-log interpolation
(the secant, capped by the crossing that effort ∝ knob predicts from the low end, which keeps a
secant to a saturated high end from creeping: worst case 8 evaluations instead of 16–18 on
simulated median and maximum statistics) clamped to the middle 80 % of the bracket, or at the
geometric midpoint after two splits that moved the same end (a safeguarded bisection: the
bracket shrinks at every step). When
bracketing finds the effort flat (a relative change below the tolerance over two knob steps
of at least 1.5x) below the target, the target is out of reach: the search stops and returns
the smallest knob whose effort is within the tolerance of the best reached, marked unmatched.
Flat above the target (the effort does not fall with the knob), it returns the smallest knob
tried, matched only if that effort is within the tolerance. Flat *at* the target while going
down is a ceiling equal to the target (the maximum |u| at a velocity limit): the search keeps
stepping down, by growing steps (1.5x, 2.25x, ...), to find the ceiling's edge, and only after
four such steps (a factor of 58) takes the effort as independent of the knob (the smallest
knob tried, matched).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

#: Results column holding each rollout's peak max_j |u_j|/ū_j (see :mod:`evaluation.metrics`), and its step.
EFFORT_COLUMN = "peak_limit_fraction"
PEAK_STEP_COLUMN = "peak_step"
#: Most knob evaluations of one search.
MAX_EVALUATIONS = 40
#: Largest factor the knob moves by in one bracketing step.
MAX_BRACKET_STEP = 16.0
#: Knob steps at least this large that change the effort by less than the tolerance count as flat.
FLAT_STEP = 1.5
#: Flat downward steps at the target (a ceiling equal to it; each 1.5x larger than the last) after
#: which the effort is taken not to depend on the knob at all (a factor of 1.5¹⁰ ≈ 58).
CEILING_STEPS = 4


@dataclass(frozen=True)
class EffortStatistic:
    """A control-effort statistic of a set of rollouts: a per-rollout column reduced over the samples.

    Attributes:
        name: The ``--effort-statistic`` value.
        description: What it is, as the reports print it.
        column: The results column with each rollout's value.
        step_column: The results column with the step where that value occurs (the knob search
            cuts its rollouts after it).
        reduce: Reduction over the samples (``np.max``, ``np.median``).
        unit: Unit of the statistic (and of ``--effort-target``).
        is_maximum: A maximum over the set, decided by its few *critical* samples (``max``):
            a knob search cuts its rollouts after the highest peak of its probe and the match
            then checks the critical samples over the full horizon (refining on them if
            needed). Otherwise (``median-peak``: any rollout can move the median) the search
            lengthens its cut rollouts while some rollout peaks near the cut, and the match
            corrects its target when the full pass misses.
        screening_budget: Largest fraction of a full pass's sample-steps one search evaluation
            screens. For a maximum, screening fewer than all samples usually costs a refinement
            (one more full pass), which screening all of them in each of a search's ~6
            evaluations costs less than when its rollouts are shorter than 1/6 of a pass.
        relative_to_limits: Measured in fractions of the velocity limits (at most 1), else in
            rad/s (at most the largest limit).
    """

    name: str
    description: str
    column: str
    step_column: str
    reduce: Callable[[np.ndarray], Any]
    unit: str
    is_maximum: bool
    screening_budget: float
    relative_to_limits: bool = False

    def largest(self, velocity_limits: np.ndarray) -> float:
        """The largest value the statistic can take: commands are clipped at the velocity limits ū."""
        return 1.0 if self.relative_to_limits else float(np.max(velocity_limits))

    def of(self, rows: pd.DataFrame) -> float:
        """The statistic over the rollouts of ``rows`` (a results table)."""
        values = rows[self.column].to_numpy(dtype=float)
        if values.size == 0:
            raise ValueError("no rollouts to measure the effort of")
        return float(self.reduce(values))


EFFORT_STATISTICS: dict[str, EffortStatistic] = {
    "max": EffortStatistic(
        "max",
        "maximum |u| over the sample set (max over samples, steps and joints of |u_j|, rad/s)",
        "max_abs_u",
        "max_abs_u_step",
        np.max,
        "rad/s",
        is_maximum=True,
        screening_budget=1 / 6,
    ),
    "median-peak": EffortStatistic(
        "median-peak",
        "median over samples of each rollout's peak max_j |u_j|/ū_j (fraction of the velocity limits)",
        EFFORT_COLUMN,
        PEAK_STEP_COLUMN,
        np.median,
        "fraction of the velocity limits",
        is_maximum=False,
        screening_budget=0.1,
        relative_to_limits=True,
    ),
}
#: The statistic matched unless ``--effort-statistic`` says otherwise: the issue's literal rule.
DEFAULT_EFFORT_STATISTIC = "max"


def effort_statistic_named(name: str) -> EffortStatistic:
    """The statistic called ``name``.

    Raises:
        ValueError: Naming the choices.
    """
    if name not in EFFORT_STATISTICS:
        raise ValueError(f"--effort-statistic must be one of {', '.join(EFFORT_STATISTICS)}, got {name!r}")
    return EFFORT_STATISTICS[name]


@dataclass
class EffortMatch:
    """Outcome of :func:`match_effort`.

    Attributes:
        value: The knob value found (the best evaluated one if not matched).
        effort: The effort measured at ``value``.
        target: The effort aimed at.
        matched: Whether ``|effort/target − 1| ≤ tolerance``.
        evaluations: Every ``(knob value, effort)`` measured, in order.
        reason: Why the search stopped without a match (empty if matched).
    """

    value: float
    effort: float
    target: float
    matched: bool
    evaluations: list[tuple[float, float]] = field(default_factory=list)
    reason: str = ""


def _flat(evaluations: list[tuple[float, float]], target: float, tolerance: float, upward: bool) -> EffortMatch:
    """End of a search whose bracketing found the effort flat.

    Upward (the effort stays below the target): the smallest knob whose effort is within
    ``tolerance`` of the highest reached, unmatched. Downward (the effort does not fall as the
    knob does): the smallest knob tried, matched if its effort is within ``tolerance`` of the target.
    """
    extreme = max(e for _, e in evaluations) if upward else min(e for _, e in evaluations)
    value, effort = min((v, e) for v, e in evaluations if abs(e / extreme - 1.0) <= tolerance)
    if upward:
        reason = f"the effort saturates at about {extreme:.4g} (target {target:.4g}): out of reach"
        return EffortMatch(value, effort, target, False, evaluations, reason)
    matched = _within(effort, target, tolerance)
    reason = (
        "" if matched else f"the effort does not fall below about {extreme:.4g} (target {target:.4g}): out of reach"
    )
    return EffortMatch(value, effort, target, matched, evaluations, reason)


def match_effort(
    measure: Callable[[float], float],
    target: float,
    start: float,
    tolerance: float,
    knob_tolerance: float = 1e-3,
    max_evaluations: int = MAX_EVALUATIONS,
) -> EffortMatch:
    """The smallest positive knob value whose effort reaches ``target`` within ``tolerance``.

    "Reaches" means ``effort ≥ target·(1 − tolerance)``. The search keeps a bracket
    ``low < high`` (effort below / reaching that threshold) and stops when both ends are
    close to the target (``effort(low) ≥ target·(1 − 2·tolerance)`` and
    ``effort(high) ≤ target·(1 + tolerance)``: ``high`` is returned), or when the bracket is
    narrower than ``knob_tolerance`` (relative). Where the effort is strictly increasing, the
    result lies within ``tolerance`` of the target; where it is flat at the target (a target
    at the ceiling 1, "at a limit"), it is the left edge of the flat part: the least
    aggressive setting that reaches the target, so the result is unique.

    Args:
        measure: Effort at a knob value (non-decreasing in it). May raise ``ValueError`` for
            a value the policy rejects; the search then stops, unmatched.
        target: The effort to match (> 0).
        start: First knob value tried (> 0), e.g. the policy's default.
        tolerance: Relative tolerance on the effort.
        knob_tolerance: Relative width of the bracket at which the search stops.
        max_evaluations: Most calls of ``measure``.
    """
    if not target > 0 or not start > 0 or not tolerance > 0:
        raise ValueError(f"target, start and tolerance must be positive, got {target}, {start}, {tolerance}")
    threshold = target * (1.0 - tolerance)
    evaluations: list[tuple[float, float]] = []
    low: tuple[float, float] | None = None
    high: tuple[float, float] | None = None

    def evaluate(value: float) -> float:
        nonlocal low, high
        effort = float(measure(value))
        evaluations.append((value, effort))
        if effort >= threshold:
            if high is None or value < high[0]:
                high = (value, effort)
        elif low is None or value > low[0]:
            low = (value, effort)
        return effort

    def failed(reason: str) -> EffortMatch:
        value, effort = min(evaluations, key=lambda ve: abs(ve[1] / target - 1.0))
        return EffortMatch(value, effort, target, False, evaluations, reason)

    evaluate(start)
    flat_steps = ceiling_steps = 0
    # Bracket: scale the knob by target/effort (effort is roughly proportional to it), 3 % past the target.
    while low is None or high is None:
        if len(evaluations) >= max_evaluations:
            return failed(f"no bracket after {len(evaluations)} evaluations")
        upward = high is None
        value, effort = low if upward else high  # type: ignore[misc]
        step = target / effort if effort > 0 else MAX_BRACKET_STEP
        step = min(max(step * (1.03 if upward else 1 / 1.03), 1 / MAX_BRACKET_STEP), MAX_BRACKET_STEP)
        if len(evaluations) > 1 or _within(effort, target, tolerance):
            # The proportional guess did not bracket, or says nothing (a start at a ceiling equal
            # to the target): step at least FLAT_STEP.
            step = max(step, FLAT_STEP) if upward else min(step, 1 / FLAT_STEP ** (ceiling_steps + 1))
        try:
            new_effort = evaluate(value * step)
        except ValueError as exc:
            return failed(f"the policy rejects {value * step:.6g}: {exc}")
        large = max(step, 1 / step) >= FLAT_STEP
        # Flat below the target (going up) or above the accepted band (going down) means out of
        # reach; flat *at* the target going down is a ceiling equal to it: keep stepping down.
        beyond = upward or new_effort > target * (1.0 + tolerance)
        flat = large and abs(new_effort / effort - 1.0) < tolerance
        flat_steps = flat_steps + 1 if flat and beyond else 0
        ceiling_steps = ceiling_steps + 1 if flat and not beyond else 0
        if flat_steps >= 2 or ceiling_steps >= CEILING_STEPS:  # the latter: the effort ignores the knob
            return _flat(evaluations, target, tolerance, upward)
    # Safeguarded bisection in log space.
    moved: list[bool] = []  # whether each split moved the high end
    while True:
        assert low is not None and high is not None
        close = low[1] >= target * (1.0 - 2 * tolerance) and high[1] <= target * (1.0 + tolerance)
        if close and high[0] / low[0] <= 1.0 + 4 * tolerance:  # narrow too: at a ceiling, near its left edge
            return EffortMatch(high[0], high[1], target, True, evaluations)
        if high[0] / low[0] <= 1.0 + knob_tolerance:
            if _within(high[1], target, tolerance):
                return EffortMatch(high[0], high[1], target, True, evaluations)
            return failed(f"the effort jumps from {low[1]:.4g} to {high[1]:.4g} across the target {target:.4g}")
        if len(evaluations) >= max_evaluations:
            return failed(f"no match within {max_evaluations} evaluations")
        a, b = math.log(low[0]), math.log(high[0])
        split = 0.5 * (a + b)
        one_sided = len(moved) >= 2 and moved[-1] == moved[-2]  # interpolation is creeping: bisect
        if low[1] > 0 and high[1] > low[1] and not one_sided:
            fa, fb = math.log(low[1] / target), math.log(high[1] / target)
            # The secant, but never past the crossing that effort ∝ knob predicts from the low end
            # (when the high end sits on a saturated, flat part, the secant lands next to it),
            # aimed inside the band: aimed at its edge, a linear effort would land on the edge
            # itself, where rounding decides the side.
            estimate = min(a - fa * (b - a) / (fb - fa), a + math.log(target * (1.0 - 0.5 * tolerance) / low[1]))
            split = min(max(estimate, a + 0.1 * (b - a)), b - 0.1 * (b - a))
        moved.append(evaluate(math.exp(split)) >= threshold)


def _within(effort: float, target: float, tolerance: float) -> bool:
    return abs(effort / target - 1.0) <= tolerance
