"""Equal control effort: what "equal" equalises, the effort statistics of a set of rollouts.

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
controller, whichever is matched. The search for the knob value that matches a statistic is
:mod:`evaluation.effort_search`; the equal-effort step of a run, :mod:`evaluation.effort_matching`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

#: Results column holding each rollout's peak max_j |u_j|/ū_j (see :mod:`snac_gym.metrics`), and its step.
EFFORT_COLUMN = "peak_limit_fraction"
PEAK_STEP_COLUMN = "peak_step"


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
