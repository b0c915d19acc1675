"""Equal control effort: what "equal" equalises, the effort statistics of a set of rollouts.

**What "maximum control effort" means.** The paper tunes every controller "to the same
maximum control effort". Four statistics of the per-rollout commands are offered
(``--effort-statistic``); each rollout's *peak* is max over steps and joints of |uₖⱼ|/ūⱼ
(1 = a joint at its velocity limit ū; UR10: 2.16, 2.16, 3.15, 3.2, 3.2, 3.2 rad/s):

``mean-peak`` (default)
    the mean over the samples of each rollout's peak: the share of the velocity limits the
    controller uses on an average sample. Every sample counts, each with a bounded weight (a
    peak is at most 1), so the mean is the statistic whose estimate moves least with the
    sample set: the matched knob is a property of the controller, not of which samples were
    drawn. Of the four statistics measured on random 200-sample subsets of 1000 it moved the
    matched knobs least (docs/evaluation.md, "Equal effort: the statistic").

``max`` (the rule as first specified: the peak command)
    the maximum of |u| over the whole sample set: max over samples, steps and joints of
    |uₖⱼ|, rad/s. Commands are clipped at the velocity limits, so wherever some rollout of the
    set drives a joint to its limit the maximum *is* that limit; it is a worst case, set by
    the single most demanding sample, and so moves with the sample count. Matching it gives
    each controller the least aggressive knob with which its most demanding rollout reaches
    the reference's maximum.

``median-peak``
    the median over the samples of each rollout's peak: the fraction of the velocity limits a
    *typical* rollout uses. It pins down the knob by the bulk of the set instead of by one
    sample, but where the reference's peaks are spread thin around their median (SNAC's, in
    reach) the median of 200 samples is a poor estimate of the median of 1000.

``peak-ratio``
    the geometric mean over the samples of each rollout's peak divided by the reference
    controller's peak *on the same sample* (1 = as hard as the reference). Pairing cancels what
    makes a sample demanding when the two controllers' peaks are nearly proportional sample by
    sample (RNN against DLS); against SNAC, whose small peaks scatter, the log-ratios of those
    samples make it noisier than ``mean-peak``. Needs the reference's rollouts (no
    ``--effort-target``).

docs/evaluation.md compares them with measurements; the summary shows the maximum and the
median peak for every controller, whichever is matched. The search for the knob value that
matches a statistic is :mod:`snac_gym.evaluation.effort.search`; the equal-effort step of a run,
:mod:`snac_gym.evaluation.effort.matching`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

#: Results column holding each rollout's peak max_j |u_j|/ū_j (see :mod:`snac_gym.metrics`), and its step.
EFFORT_COLUMN = "peak_limit_fraction"
PEAK_STEP_COLUMN = "peak_step"
#: Smallest peak a paired statistic divides by or takes the log of: a rollout that never moves
#: (peak 0) would otherwise give an infinite ratio that outweighs every other sample.
PEAK_FLOOR = 1e-6


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
            needed). Otherwise (a mean, median or ratio: any rollout can move it) the search
            lengthens its cut rollouts while some rollout peaks near the cut, and the match
            corrects its target when the full pass misses.
        screening_budget: Largest fraction of a full pass's sample-steps one search evaluation
            screens. For a maximum, screening fewer than all samples usually costs a refinement
            (one more full pass), which screening all of them in each of a search's ~6
            evaluations costs less than when its rollouts are shorter than 1/6 of a pass.
        relative_to_limits: Measured in fractions of the velocity limits (at most 1), else in
            rad/s (at most the largest limit).
        paired: A statistic of each rollout's value *relative to the reference's on the same
            sample* (``reduce`` then receives the per-sample ratios): it needs the reference's
            rows, is 1 for the reference itself and has no upper bound.
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
    paired: bool = False

    def largest(self, velocity_limits: np.ndarray) -> float:
        """The largest value the statistic can take: commands are clipped at the velocity limits ū."""
        if self.paired:
            return math.inf
        return 1.0 if self.relative_to_limits else float(np.max(velocity_limits))

    def of(self, rows: pd.DataFrame, reference: pd.DataFrame | None = None) -> float:
        """The statistic over the rollouts of ``rows`` (a results table).

        Args:
            rows: The rollouts, one row per sample (column ``sample``).
            reference: The reference controller's rollouts of (at least) the same samples; needed
                by a :attr:`paired` statistic, ignored by the others.

        Raises:
            ValueError: With no rollouts, or for a paired statistic without the reference's
                rollout of every sample in ``rows``.
        """
        values = rows[self.column].to_numpy(dtype=float)
        if values.size == 0:
            raise ValueError("no rollouts to measure the effort of")
        if not self.paired:
            return float(self.reduce(values))
        if reference is None:
            raise ValueError(f"the {self.name} statistic needs the reference controller's rollouts")
        by_sample = reference.drop_duplicates("sample").set_index("sample")[self.column]
        missing = ~rows["sample"].isin(by_sample.index)
        if missing.any():
            raise ValueError(f"no reference rollout of sample(s) {rows.loc[missing, 'sample'].tolist()[:5]}")
        reference_values = by_sample.reindex(rows["sample"]).to_numpy(dtype=float)
        return float(self.reduce(np.maximum(values, PEAK_FLOOR) / np.maximum(reference_values, PEAK_FLOOR)))


def geometric_mean(values: np.ndarray) -> float:
    """exp(mean(log values)): the typical ratio, symmetric in which controller is the reference."""
    return float(np.exp(np.mean(np.log(values))))


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
    "mean-peak": EffortStatistic(
        "mean-peak",
        "mean over samples of each rollout's peak max_j |u_j|/ū_j (fraction of the velocity limits)",
        EFFORT_COLUMN,
        PEAK_STEP_COLUMN,
        np.mean,
        "fraction of the velocity limits",
        is_maximum=False,
        screening_budget=0.1,
        relative_to_limits=True,
    ),
    "peak-ratio": EffortStatistic(
        "peak-ratio",
        "geometric mean over samples of each rollout's peak max_j |u_j|/ū_j over the reference's on the same sample",
        EFFORT_COLUMN,
        PEAK_STEP_COLUMN,
        geometric_mean,
        "ratio to the reference's peak",
        is_maximum=False,
        screening_budget=0.1,
        paired=True,
    ),
}
#: The statistic matched unless ``--effort-statistic`` says otherwise: the stable one (module docstring).
DEFAULT_EFFORT_STATISTIC = "mean-peak"


def effort_statistic_named(name: str) -> EffortStatistic:
    """The statistic called ``name``.

    Raises:
        ValueError: Naming the choices.
    """
    if name not in EFFORT_STATISTICS:
        raise ValueError(f"--effort-statistic must be one of {', '.join(EFFORT_STATISTICS)}, got {name!r}")
    return EFFORT_STATISTICS[name]
