"""Equal control effort across a run's controllers (step 4 of :func:`~snac_gym.evaluation.runner.run_evaluation`).

The reference controller (``effort_reference``, default ``snac``, at its own settings) is run
first; its effort statistic (:mod:`snac_gym.evaluation.effort.statistics`) is the target, unless
``effort_target`` is given (then every controller is matched to it). Every other (task,
controller) is then matched on its own, all at the same time (:meth:`EffortMatcher.match_all`):
the workers run one controller's full pass while another's knob search is still going.

One match (:meth:`EffortMatcher.match_one`) is a few *rounds*, each a knob search on screening
samples (:meth:`EffortMatcher.search_knob`, an :class:`~snac_gym.evaluation.effort.search.EffortSearch`
over short rollouts) and a full pass that checks the statistic over the whole set. What follows
the full pass depends on the statistic:

* ``max``: the maximum over the set can come from a sample the search did not screen, and
  at a ceiling (a velocity limit) the full pass cannot tell a knob that is more aggressive
  than needed. If each rollout's peak grows with the knob, only the *critical* samples,
  those whose peak reached the search's threshold in the full pass, can reach it at a
  smaller knob; so when some critical sample was not screened, or peaked after the
  search's cut, the search is refined on the critical samples alone (over rollouts that
  cover their peaks), from the value found down, which gives the smallest knob for the
  whole set, and a full pass at it ends the match.
* ``mean-peak``, ``median-peak``, ``peak-ratio``: if the full pass misses the target by more
  than the tolerance although the search matched on the screening samples, the screening
  target is corrected by the observed ratio and the search repeats from the value found.
  ``peak-ratio`` divides each rollout's peak by the reference's on the same sample, from the
  reference's full pass (so it cannot be matched to an ``effort_target``).

At most :data:`MAX_MATCH_ROUNDS` full passes are run. Every search is recorded in
``calibration.json`` and read back on ``--resume``. Without effort matching every controller runs
at its own settings (:func:`controller_passes`).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.controllers import ControllerSpec
from snac_gym.evaluation.effort.activity import MatchActivity
from snac_gym.evaluation.effort.search import EffortMatch, match_effort, within
from snac_gym.evaluation.execution.passes import EvaluationRun
from snac_gym.evaluation.samples import EvaluationSample

#: Most full passes spent matching one controller's effort.
MAX_MATCH_ROUNDS = 3
#: Samples whose full-horizon rollouts locate the effort peak in time before a search.
PEAK_PROBE_SAMPLES = 20
#: A knob search screens at least this many samples (unless the set is smaller).
MIN_SCREENING_SAMPLES = 100

#: The passes of a run, by (task, controller).
Results = dict[tuple[str, str], pd.DataFrame]


@dataclass
class EffortRecord:
    """How one controller's effort was set on one task (a row of the summary's effort table)."""

    task: str
    controller: str
    role: str  # "reference", "matched", "unmatched" or "fixed"
    knob: str | None
    knob_value: float | None
    effort: float
    target: float | None
    passes: int = 1
    note: str = ""
    #: Where the knob came from when it was not matched by this run: the calibration cache's run and time.
    calibrated_by: str = ""


Records = dict[tuple[str, str], EffortRecord]
#: ``EffortRecord.calibrated_by`` of the knobs a run in a physics engine matched on the kinematic model.
MODEL_ORIGIN = "this run, on the kinematic model"


def controller_passes(evaluation: EvaluationRun, specs: Sequence[ControllerSpec]) -> tuple[Results, Records]:
    """Every controller's final full pass on every task, and how its effort was set.

    With ``match_effort``, at equal effort (:class:`EffortMatcher`); otherwise each controller at
    its own settings (role ``fixed``).
    """
    if not specs:
        return {}, {}
    if evaluation.config.match_effort:
        return EffortMatcher(evaluation).match_all(specs)
    config = evaluation.config
    passes = [(task, spec, spec.kwargs) for task in config.tasks for spec in specs]
    started = time.perf_counter()
    rows_of_passes = evaluation.run_passes(passes)
    evaluation.timings["passes"] = time.perf_counter() - started
    results: Results = {(task, spec.name): rows for (task, spec, _), rows in zip(passes, rows_of_passes, strict=True)}
    records: Records = {}
    for task, spec, _ in passes:
        # A paired statistic is relative to the effort reference's rollouts: NaN when it is not run.
        reference = results.get((task, config.effort_reference))
        unmeasurable = config.statistic.paired and reference is None
        effort = math.nan if unmeasurable else config.statistic.of(results[(task, spec.name)], reference)
        records[(task, spec.name)] = EffortRecord(task, spec.name, "fixed", spec.knob, spec.knob_value, effort, None)
    return results, records


class _FewerSamplesNeeded(Exception):
    """A knob search's rollouts grew so long that it should start again on fewer samples."""


@dataclass
class _Round:
    """What one round of a match searches for: the screening target, the start, and (refining) the samples."""

    target: float
    start: float
    subset: list[EvaluationSample] | None = None
    horizon: int | None = None


class EffortMatcher:
    """The equal-effort step of one run (see the module docstring).

    Args:
        evaluation: The run's passes.
    """

    def __init__(self, evaluation: EvaluationRun) -> None:
        self.evaluation = evaluation
        self.config = evaluation.config
        #: Screening samples of each (task, controller)'s first knob search.
        self.screening_counts: dict[tuple[str, str], int] = {}
        #: The reference's full pass of each task, which a paired statistic divides by.
        self.reference_rows: dict[str, pd.DataFrame] = {}
        #: What the matches running now are doing, for the progress line (:meth:`match_all` sets it).
        self.activity = MatchActivity(None, 0)

    def match_all(self, specs: Sequence[ControllerSpec]) -> tuple[Results, Records]:
        """Run the reference, then match every other (task, controller) to it, concurrently."""
        evaluation, config = self.evaluation, self.config
        names = [s.name for s in specs]
        reference = None
        if config.effort_target is None:
            reference = config.effort_reference if config.effort_reference in names else names[0]
            results, records = self._reference_passes(specs[names.index(reference)])
            targets = {task: records[(task, reference)].effort for task in config.tasks}
        else:
            results, records = {}, {}
            targets = {task: float(config.effort_target) for task in config.tasks}
        pending = [(task, spec) for task in config.tasks for spec in specs if spec.name != reference]
        evaluation.spread_searches = len(pending) < max(1, config.workers)
        self.activity = MatchActivity(evaluation.progress.status, len(pending))
        started = time.perf_counter()
        outcomes = evaluation.concurrently(
            [functools.partial(self._match_shown, task, spec, targets[task]) for task, spec in pending]
        )
        evaluation.timings["effort matching"] = time.perf_counter() - started
        evaluation.progress.status("")
        for (task, spec), (rows, record) in zip(pending, outcomes, strict=True):
            results[(task, spec.name)] = rows
            records[(task, spec.name)] = record
        return results, records

    def _reference_passes(self, spec: ControllerSpec) -> tuple[Results, Records]:
        """The reference's full passes at its own settings: their statistics are the targets."""
        evaluation, config = self.evaluation, self.config
        note = (
            ""
            if spec.name == config.effort_reference
            else f"{config.effort_reference!r} is not evaluated; {spec.name!r} is the reference"
        )
        started = time.perf_counter()
        evaluation.progress.status(f"reference: {spec.name}")
        passes = evaluation.run_passes([(task, spec, spec.kwargs) for task in config.tasks])
        evaluation.timings["reference passes"] = time.perf_counter() - started
        results: Results = {}
        records: Records = {}
        for task, rows in zip(config.tasks, passes, strict=True):
            results[(task, spec.name)] = rows
            self.reference_rows[task] = rows
            target = config.statistic.of(rows, rows)
            records[(task, spec.name)] = EffortRecord(
                task, spec.name, "reference", spec.knob, spec.knob_value, target, target, 1, note
            )
        return results, records

    # -- one controller on one task -----------------------------------------------------------
    def _match_shown(self, task: str, spec: ControllerSpec, target: float) -> tuple[pd.DataFrame, EffortRecord]:
        with self.activity.running(task, spec.name):
            return self.match_one(task, spec, target)

    def match_one(self, task: str, spec: ControllerSpec, target: float) -> tuple[pd.DataFrame, EffortRecord]:
        """Search one controller's knob for ``target`` on one task, then check it with a full pass (rounds: module
        docstring).

        Returns:
            The last full pass's rows and the record of how the effort was set.
        """
        evaluation = self.evaluation
        plan = _Round(target, float(spec.knob_value))
        for round_number in range(1, MAX_MATCH_ROUNDS + 1):
            if round_number > 1:
                evaluation.progress.add_total(len(evaluation.samples[task]))
            with evaluation.searching():
                match = self.search_knob(task, spec, plan.target, plan.start, round_number, plan.subset, plan.horizon)
            self.activity.full_pass(task, spec.name)
            rows = evaluation.run_passes([(task, spec, {**spec.kwargs, spec.knob: match.value})])[0]
            effort = self.config.statistic.of(rows, self.reference_rows.get(task))
            # A failed search is never "matched", even when the full pass happens to land within the
            # tolerance: the knob it reports is then not one that was searched for.
            matched = match.matched and within(effort, target, self.config.effort_tolerance)
            following = self._next_round(task, spec, plan, match, rows, effort, matched, round_number)
            if following is None:
                return rows, self._record(task, spec, match, effort, target, matched, round_number)
            plan = following
        raise AssertionError("unreachable: the last round returns")

    def _next_round(
        self,
        task: str,
        spec: ControllerSpec,
        plan: _Round,
        match: EffortMatch,
        rows: pd.DataFrame,
        effort: float,
        matched: bool,
        round_number: int,
    ) -> _Round | None:
        """What the next round searches for, or ``None`` when this round's full pass ends the match."""
        if round_number == MAX_MATCH_ROUNDS or not match.matched:
            return None
        if self.config.statistic.is_maximum:
            return self._refinement(task, spec, plan, match, rows, round_number)
        if not matched:
            # The screening samples mis-predict the whole set by effort/match.effort: aim off by as much.
            return _Round(plan.target * match.effort / effort, match.value)
        return None

    def _refinement(
        self, task: str, spec: ControllerSpec, plan: _Round, match: EffortMatch, rows: pd.DataFrame, round_number: int
    ) -> _Round | None:
        """For ``max``: search again on the critical samples if the search missed some of them or their peaks."""
        statistic, samples = self.config.statistic, self.evaluation.samples[task]
        threshold = plan.target * (1.0 - self.config.effort_tolerance / 4)
        critical_rows = rows[rows[statistic.column] >= threshold]
        critical = set(critical_rows["sample"].astype(int))
        searched = self.evaluation.store.calibration[f"{task}/{spec.name}/search{round_number}"]
        screened = (
            set(searched["sample_ids"])
            if searched["sample_ids"] is not None
            else {s.index for s in samples[: searched["screening_samples"]]}
        )
        latest_peak = int(critical_rows[statistic.step_column].max()) if len(critical_rows) else 0
        if critical <= screened and latest_peak < searched["search_steps"]:
            return None
        subset = [s for s in samples if s.index in critical]
        return _Round(plan.target, match.value, subset, min(self.config.steps(task), 2 * latest_peak + 25))

    def _record(
        self,
        task: str,
        spec: ControllerSpec,
        match: EffortMatch,
        effort: float,
        target: float,
        matched: bool,
        round_number: int,
    ) -> EffortRecord:
        """The record of a finished match, with a note saying why it is unmatched."""
        note = ""
        if not match.matched:
            note = f"knob search failed: {match.reason}; the full pass reached {effort:.4g} (target {target:.4g})"
        elif not matched:
            note = f"not within {self.config.effort_tolerance:.0%} after {round_number} passes"
        role = "matched" if matched else "unmatched"
        return EffortRecord(task, spec.name, role, spec.knob, match.value, effort, target, round_number, note)

    # -- the knob search of one round ---------------------------------------------------------
    def screening_count(self, task: str, spec: ControllerSpec, search_steps: int, round_number: int) -> int:
        """How many of the first samples a search runs on (later rounds keep the first round's count).

        ``calibration_samples`` if given; otherwise every sample when the search's rollouts are
        short, fewer when they are long, so that one evaluation costs about the statistic's
        ``screening_budget`` of a full pass (never fewer than :data:`MIN_SCREENING_SAMPLES`).
        """
        if round_number > 1:
            key = (task, spec.name)
            if key not in self.screening_counts:  # resumed after the first round
                self.screening_counts[key] = int(
                    self.evaluation.store.calibration[f"{task}/{spec.name}/search1"]["screening_samples"]
                )
            return self.screening_counts[key]
        config = self.config
        count = len(self.evaluation.samples[task])
        if config.calibration_samples:
            return min(count, config.calibration_samples)
        budget = math.ceil(config.statistic.screening_budget * count * config.steps(task) / search_steps)
        return min(count, max(MIN_SCREENING_SAMPLES, budget))

    def search_knob(
        self,
        task: str,
        spec: ControllerSpec,
        target: float,
        start: float,
        round_number: int,
        subset: Sequence[EvaluationSample] | None = None,
        horizon: int | None = None,
    ) -> EffortMatch:
        """Search ``spec``'s knob so that the screening samples' effort statistic hits ``target``.

        The screening samples are the first ones of the set (:meth:`screening_count`), or
        ``subset`` when given (the critical samples of a ``max`` refinement, with the
        ``horizon`` that covers their peaks). The search's rollouts stop after the steps where
        the effort peaks: a probe of :data:`PEAK_PROBE_SAMPLES` full rollouts at ``start``
        locates the peak, and the search runs twice that step plus 25. For the statistics other than ``max``
        that is the latest peak of the probe, and the horizon doubles whenever some rollout
        peaks in its last quarter (when that calls for fewer screening samples, first round
        only, the search starts again with them). For ``max`` it is the step of the probe's
        highest peak, without doubling: the maximum over a set is almost always the first
        transient of its most demanding sample, and :meth:`match_one` checks the critical
        samples over the full horizon afterwards. (The full pass that follows checks the
        result at full length.) A search recorded by an earlier run of the same inputs
        (``--resume``) is read back instead.
        """
        record_key = f"{task}/{spec.name}/search{round_number}"
        subset_ids = None if subset is None else [int(s.index) for s in subset]
        stored = self._stored_search(record_key, target, start, subset_ids)
        if stored is not None:
            if subset is None:
                self.screening_counts[(task, spec.name)] = int(
                    self.evaluation.store.calibration[record_key]["screening_samples"]
                )
            return stored
        samples = self.evaluation.samples[task] if subset is None else list(subset)
        started = time.perf_counter()
        if horizon is None:
            horizon = self._probe_horizon(task, spec, start, samples)
        while True:
            count = len(samples) if subset is not None else self.screening_count(task, spec, horizon, round_number)
            screened = _ScreenedEffort(self, task, spec, samples[:count], horizon, round_number)
            try:
                match = match_effort(screened.effort_at, target, start, self.config.effort_tolerance / 4)
                break
            except _FewerSamplesNeeded:
                horizon = screened.horizon
        if subset is None:
            self.screening_counts[(task, spec.name)] = count
        record = {"sample_ids": subset_ids, "target": target, "start": start, "screening_samples": count}
        self._save_search(record_key, record, match, screened.horizon, started)
        return match

    def _save_search(self, key: str, record: dict[str, Any], match: EffortMatch, steps: int, started: float) -> None:
        """Record a search in ``calibration.json``: what it searched for, every evaluation, and what it found."""
        record = {
            **record,
            "value": match.value,
            "effort": match.effort,
            "matched": match.matched,
            "evaluations": match.evaluations,
            "reason": match.reason,
            "search_steps": steps,
            "seconds": round(time.perf_counter() - started, 3),
        }
        self.evaluation.store.save_calibration(key, record)

    def _stored_search(self, key: str, target: float, start: float, subset_ids: list[int] | None) -> EffortMatch | None:
        """The search recorded under ``key`` in ``calibration.json`` if it searched for the same thing."""
        stored = self.evaluation.store.calibration.get(key)
        if not (
            stored
            and stored.get("target") == target
            and stored.get("start") == start
            and stored.get("sample_ids") == subset_ids
        ):
            return None
        evaluations = [tuple(e) for e in stored["evaluations"]]
        return EffortMatch(stored["value"], stored["effort"], target, stored["matched"], evaluations, stored["reason"])

    def _probe_horizon(self, task: str, spec: ControllerSpec, start: float, samples: Sequence[EvaluationSample]) -> int:
        """Steps of the search's rollouts: twice the step where a probe at ``start`` peaks, plus 25."""
        statistic, full_steps = self.config.statistic, self.config.steps(task)
        kwargs = {**spec.kwargs, spec.knob: start}
        probe = self.evaluation.measure(task, spec, kwargs, samples[:PEAK_PROBE_SAMPLES], full_steps)
        if statistic.is_maximum:
            peak_step = int(probe[statistic.step_column].iloc[int(np.argmax(probe[statistic.column].to_numpy()))])
        else:
            peak_step = int(probe[statistic.step_column].max())
        return min(full_steps, 2 * peak_step + 25)


class _ScreenedEffort:
    """The effort of one knob value on the screening samples, over rollouts cut after the peak."""

    def __init__(
        self,
        matcher: EffortMatcher,
        task: str,
        spec: ControllerSpec,
        screening: Sequence[EvaluationSample],
        horizon: int,
        round_number: int,
    ) -> None:
        self.matcher, self.task, self.spec, self.screening = matcher, task, spec, screening
        self.horizon, self.round_number = horizon, round_number
        self.full_steps = matcher.config.steps(task)

    def effort_at(self, value: float) -> float:
        """The effort statistic at knob ``value`` (for a median, lengthening the rollouts while peaks come late)."""
        spec, statistic = self.spec, self.matcher.config.statistic
        self.matcher.activity.tried(self.task, spec.name)
        while True:
            rows = self.matcher.evaluation.measure(
                self.task, spec, {**spec.kwargs, spec.knob: value}, self.screening, self.horizon
            )
            late = rows[statistic.step_column] >= self.horizon - max(10, self.horizon // 4)
            if statistic.is_maximum or self.horizon >= self.full_steps or not late.any():
                return statistic.of(rows, self.matcher.reference_rows.get(self.task))
            self.horizon = min(self.full_steps, 2 * self.horizon)
            if self.matcher.screening_count(self.task, spec, self.horizon, self.round_number) < len(self.screening):
                raise _FewerSamplesNeeded


__all__ = [
    "MAX_MATCH_ROUNDS",
    "MIN_SCREENING_SAMPLES",
    "PEAK_PROBE_SAMPLES",
    "MODEL_ORIGIN",
    "EffortMatcher",
    "EffortRecord",
    "controller_passes",
]
