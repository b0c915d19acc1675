"""The search for the knob value whose effort matches a target: :class:`EffortSearch`.

Each policy class names a scalar constructor argument that scales its effort monotonically
(``effort_parameter``, the *knob*). The search looks for the smallest knob value whose effort
reaches the target (within the tolerance), calling a measure function ``knob → effort`` as few
times as it can (each call is a set of rollouts). It knows nothing of rollouts: the run's
equal-effort step (:mod:`snac_gym.evaluation.effort.matching`) gives it the measure function.

**Bracketing** (:meth:`EffortSearch._bracket_step`): multiply the knob by target/effort, 3 % past
it, at most 16x per step and at least 1.5x after the first step, until one value falls short of
the target and one reaches it.

**Bisection** (:meth:`EffortSearch._split`): split the bracket in log space at the log-log
interpolation (the secant, capped by the crossing that effort ∝ knob predicts from the low end,
which keeps a secant to a saturated high end from creeping: worst case 8 evaluations instead of
16–18 on simulated median and maximum statistics) clamped to the middle 80 % of the bracket, or
at the geometric midpoint after two splits that moved the same end (a safeguarded bisection: the
bracket shrinks at every step).

**Flat efforts** (:meth:`EffortSearch._flat_end`). When bracketing finds the effort flat (a
relative change below the tolerance over two knob steps of at least 1.5x) below the target, the
target is out of reach: the search stops and returns the smallest knob whose effort is within the
tolerance of the best reached, marked unmatched. Flat above the target (the effort does not fall
with the knob), it returns the smallest knob tried, matched only if that effort is within the
tolerance. Flat *at* the target while going down is a ceiling equal to the target (the maximum
|u| at a velocity limit): the search keeps stepping down, by growing steps (1.5x, 2.25x, ...), to
find the ceiling's edge, and only after four such steps (a factor of 58) takes the effort as
independent of the knob (the smallest knob tried, matched).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

#: Most knob evaluations of one search.
MAX_EVALUATIONS = 40
#: Largest factor the knob moves by in one bracketing step.
MAX_BRACKET_STEP = 16.0
#: Knob steps at least this large that change the effort by less than the tolerance count as flat.
FLAT_STEP = 1.5
#: Flat downward steps at the target (a ceiling equal to it; each 1.5x larger than the last) after
#: which the effort is taken not to depend on the knob at all (a factor of 1.5¹⁰ ≈ 58).
CEILING_STEPS = 4

#: One measurement: (knob value, effort).
Evaluation = tuple[float, float]


@dataclass
class EffortMatch:
    """Outcome of an :class:`EffortSearch`.

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
    evaluations: list[Evaluation] = field(default_factory=list)
    reason: str = ""


def within(effort: float, target: float, tolerance: float) -> bool:
    """Whether ``effort`` is within the relative ``tolerance`` of ``target``."""
    return abs(effort / target - 1.0) <= tolerance


class EffortSearch:
    """One search for the smallest positive knob value whose effort reaches ``target`` within ``tolerance``.

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
        tolerance: Relative tolerance on the effort (> 0).
        knob_tolerance: Relative width of the bracket at which the search stops.
        max_evaluations: Most calls of ``measure``.

    Raises:
        ValueError: If ``target`` or ``tolerance`` is not positive.
    """

    def __init__(
        self,
        measure: Callable[[float], float],
        target: float,
        tolerance: float,
        knob_tolerance: float = 1e-3,
        max_evaluations: int = MAX_EVALUATIONS,
    ) -> None:
        if not target > 0 or not tolerance > 0:
            raise ValueError(f"target and tolerance must be positive, got {target}, {tolerance}")
        self.measure, self.target, self.tolerance = measure, target, tolerance
        self.knob_tolerance, self.max_evaluations = knob_tolerance, max_evaluations
        self.threshold = target * (1.0 - tolerance)
        #: Every (knob value, effort) measured, in order.
        self.evaluations: list[Evaluation] = []
        #: Largest knob whose effort is below the threshold, and smallest one reaching it.
        self.low: Evaluation | None = None
        self.high: Evaluation | None = None
        self._flat_steps = 0  # consecutive flat bracketing steps away from the target
        self._ceiling_steps = 0  # consecutive flat downward steps at the target
        self._moved_high: list[bool] = []  # whether each split moved the high end

    def run(self, start: float) -> EffortMatch:
        """Search from the knob value ``start`` (> 0), e.g. the policy's default.

        Raises:
            ValueError: If ``start`` is not positive (a ``ValueError`` of ``measure`` at ``start``
                too: no knob value was measured).
        """
        if not start > 0:
            raise ValueError(f"start must be positive, got {start}")
        self.evaluate(start)
        while self.low is None or self.high is None:
            if len(self.evaluations) >= self.max_evaluations:
                return self._failed(f"no bracket after {len(self.evaluations)} evaluations")
            end = self._bracket_step()
            if end is not None:
                return end
        while True:
            end = self._bisection_end()
            if end is not None:
                return end
            self._moved_high.append(self.evaluate(math.exp(self._split())) >= self.threshold)

    def evaluate(self, value: float) -> float:
        """Measure the effort at ``value``, record it and update the bracket."""
        effort = float(self.measure(value))
        self.evaluations.append((value, effort))
        if effort >= self.threshold:
            if self.high is None or value < self.high[0]:
                self.high = (value, effort)
        elif self.low is None or value > self.low[0]:
            self.low = (value, effort)
        return effort

    # -- bracketing ---------------------------------------------------------------------------
    def _bracket_step(self) -> EffortMatch | None:
        """Move the knob from the end found so far towards the target; the result if the search ends here."""
        upward = self.high is None
        value, effort = self.low if upward else self.high  # type: ignore[misc]
        step = self._bracket_factor(effort, upward)
        try:
            new_effort = self.evaluate(value * step)
        except ValueError as exc:
            return self._failed(f"the policy rejects {value * step:.6g}: {exc}")
        if self._count_flat(step, effort, new_effort, upward):
            return self._flat_end(upward)
        return None

    def _bracket_factor(self, effort: float, upward: bool) -> float:
        """The factor of the next bracketing step: target/effort (effort is roughly proportional to the knob), 3 % past
        the target."""
        step = self.target / effort if effort > 0 else MAX_BRACKET_STEP
        step = min(max(step * (1.03 if upward else 1 / 1.03), 1 / MAX_BRACKET_STEP), MAX_BRACKET_STEP)
        if len(self.evaluations) > 1 or within(effort, self.target, self.tolerance):
            # The proportional guess did not bracket, or says nothing (a start at a ceiling equal
            # to the target): step at least FLAT_STEP.
            step = max(step, FLAT_STEP) if upward else min(step, 1 / FLAT_STEP ** (self._ceiling_steps + 1))
        return step

    def _count_flat(self, step: float, effort: float, new_effort: float, upward: bool) -> bool:
        """Count a flat step; whether the effort is flat for good (out of reach, or independent of the knob)."""
        large = max(step, 1 / step) >= FLAT_STEP
        # Flat below the target (going up) or above the accepted band (going down) means out of
        # reach; flat *at* the target going down is a ceiling equal to it: keep stepping down.
        beyond = upward or new_effort > self.target * (1.0 + self.tolerance)
        flat = large and abs(new_effort / effort - 1.0) < self.tolerance
        self._flat_steps = self._flat_steps + 1 if flat and beyond else 0
        self._ceiling_steps = self._ceiling_steps + 1 if flat and not beyond else 0
        return self._flat_steps >= 2 or self._ceiling_steps >= CEILING_STEPS  # the latter: the effort ignores the knob

    def _flat_end(self, upward: bool) -> EffortMatch:
        """End of a search whose bracketing found the effort flat.

        Upward (the effort stays below the target): the smallest knob whose effort is within
        the tolerance of the highest reached, unmatched. Downward (the effort does not fall as the
        knob does): the smallest knob tried, matched if its effort is within the tolerance of the target.
        """
        target, tolerance, evaluations = self.target, self.tolerance, self.evaluations
        extreme = max(e for _, e in evaluations) if upward else min(e for _, e in evaluations)
        value, effort = min((v, e) for v, e in evaluations if abs(e / extreme - 1.0) <= tolerance)
        if upward:
            reason = f"the effort saturates at about {extreme:.4g} (target {target:.4g}): out of reach"
            return EffortMatch(value, effort, target, False, evaluations, reason)
        matched = within(effort, target, tolerance)
        reason = (
            "" if matched else f"the effort does not fall below about {extreme:.4g} (target {target:.4g}): out of reach"
        )
        return EffortMatch(value, effort, target, matched, evaluations, reason)

    # -- bisection ----------------------------------------------------------------------------
    def _bisection_end(self) -> EffortMatch | None:
        """The result if the bracket is close or narrow enough (or the evaluations are spent), else ``None``."""
        low, high, target, tolerance = self.low, self.high, self.target, self.tolerance
        assert low is not None and high is not None
        close = low[1] >= target * (1.0 - 2 * tolerance) and high[1] <= target * (1.0 + tolerance)
        if close and high[0] / low[0] <= 1.0 + 4 * tolerance:  # narrow too: at a ceiling, near its left edge
            return EffortMatch(high[0], high[1], target, True, self.evaluations)
        if high[0] / low[0] <= 1.0 + self.knob_tolerance:
            if within(high[1], target, tolerance):
                return EffortMatch(high[0], high[1], target, True, self.evaluations)
            return self._failed(f"the effort jumps from {low[1]:.4g} to {high[1]:.4g} across the target {target:.4g}")
        if len(self.evaluations) >= self.max_evaluations:
            return self._failed(f"no match within {self.max_evaluations} evaluations")
        return None

    def _split(self) -> float:
        """Log of the next knob value inside the bracket (the safeguarded secant, or the midpoint)."""
        low, high, target, tolerance = self.low, self.high, self.target, self.tolerance
        assert low is not None and high is not None
        a, b = math.log(low[0]), math.log(high[0])
        moved = self._moved_high
        one_sided = len(moved) >= 2 and moved[-1] == moved[-2]  # interpolation is creeping: bisect
        if not (low[1] > 0 and high[1] > low[1] and not one_sided):
            return 0.5 * (a + b)
        fa, fb = math.log(low[1] / target), math.log(high[1] / target)
        # The secant, but never past the crossing that effort ∝ knob predicts from the low end
        # (when the high end sits on a saturated, flat part, the secant lands next to it),
        # aimed inside the band: aimed at its edge, a linear effort would land on the edge
        # itself, where rounding decides the side.
        estimate = min(a - fa * (b - a) / (fb - fa), a + math.log(target * (1.0 - 0.5 * tolerance) / low[1]))
        return min(max(estimate, a + 0.1 * (b - a)), b - 0.1 * (b - a))

    def _failed(self, reason: str) -> EffortMatch:
        """Unmatched: the evaluated knob whose effort came closest to the target."""
        value, effort = min(self.evaluations, key=lambda ve: abs(ve[1] / self.target - 1.0))
        return EffortMatch(value, effort, self.target, False, self.evaluations, reason)


def match_effort(
    measure: Callable[[float], float],
    target: float,
    start: float,
    tolerance: float,
    knob_tolerance: float = 1e-3,
    max_evaluations: int = MAX_EVALUATIONS,
) -> EffortMatch:
    """The smallest positive knob value whose effort reaches ``target`` within ``tolerance``, from ``start``.

    One :class:`EffortSearch` (its arguments and result), run from ``start``.

    Raises:
        ValueError: If ``target``, ``start`` or ``tolerance`` is not positive.
    """
    if not target > 0 or not start > 0 or not tolerance > 0:
        raise ValueError(f"target, start and tolerance must be positive, got {target}, {start}, {tolerance}")
    return EffortSearch(measure, target, tolerance, knob_tolerance, max_evaluations).run(start)


__all__ = ["EffortMatch", "EffortSearch", "match_effort", "within"]
