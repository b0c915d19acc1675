"""The evaluation from options to reports: ``run_evaluation(EvaluationConfig(...))``.

Steps (each documented in docs/evaluation.md):

1. **Samples**: read ``samples_file`` or draw ``samples`` per task from ``seed``
   (:mod:`snac_gym.evaluation.samples`), spread over the workers in chunks; written to
   ``DIR/samples.csv`` (and ``export_samples``).
2. **Controllers** (:mod:`snac_gym.evaluation.controllers`): ``controllers`` or every registered policy
   that can be built from a :class:`~snac_gym.policies.base.PolicyContext` (and, with effort
   matching, declares an ``effort_parameter``); those left out are listed in the summary.
3. **Passes** (:mod:`snac_gym.evaluation.execution.passes`): a *pass* rolls one controller with one knob value over
   every sample of a task, in jobs of ``chunk_size`` samples (:mod:`snac_gym.evaluation.execution.jobs`) run by the
   executor (:mod:`snac_gym.evaluation.execution.executors`); each finished job is stored at once
   (:mod:`snac_gym.evaluation.store`).
4. **Equal effort** (``match_effort``, :mod:`snac_gym.evaluation.effort.matching`): the reference controller
   (``effort_reference``, default ``snac``, at its own settings) is run first; its effort statistic
   (:mod:`snac_gym.evaluation.effort.statistics`) is the target, unless ``effort_target`` is given (then
   every controller is matched to it). Every other controller's knob is searched on the
   screening samples (:mod:`snac_gym.evaluation.effort.search`), then a full pass checks the statistic over
   the whole set; if it misses the tolerance, the screening target is corrected by the observed
   ratio and the search repeats (at most ``MAX_MATCH_ROUNDS`` passes).
5. **Optimal reference** (``optimal`` among ``controllers``): every sample's numerical optimum of
   the same cost (:mod:`snac_gym.evaluation.reference.optimum`, docs/optimal.md), an open-loop row with no effort
   knob; every row gains ``ratio_to_optimal`` and ``below_optimal``.
6. **Reports**: ``results.csv``/``.parquet`` (one row per task, controller and sample),
   ``summary.csv`` (:mod:`snac_gym.evaluation.reports.summary`), ``summary.md`` and box plots
   (:mod:`snac_gym.evaluation.reports.writer`).

The options and their checks are :mod:`snac_gym.evaluation.run_config`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd
from snac_gym.evaluation import sample_cache
from snac_gym.evaluation.controllers import ControllerSpec, resolve_controllers
from snac_gym.evaluation.effort.cache import (
    SWITCH_ENV,
    cache_enabled,
    calibration_folder,
    calibration_identity,
    check_record,
    read_records,
    write_records,
)
from snac_gym.evaluation.effort.matching import (
    MAX_MATCH_ROUNDS,
    MODEL_ORIGIN,
    EffortRecord,
    Records,
    Results,
    controller_passes,
)
from snac_gym.evaluation.effort.search import MAX_EVALUATIONS
from snac_gym.evaluation.effort.shipped import read_shipped
from snac_gym.evaluation.execution.executors import open_executor
from snac_gym.evaluation.execution.passes import SIDE_BY_SIDE, EvaluationRun, step_costs
from snac_gym.evaluation.execution.progress import Progress
from snac_gym.evaluation.reference.cache import CACHE_ENV, DISTRIBUTIONS, cache_folder, installed_versions
from snac_gym.evaluation.reference.optimum import OPTIMAL, add_optimality
from snac_gym.evaluation.reports.writer import prefetch_report_modules, write_reports
from snac_gym.evaluation.run_config import EvaluationConfig
from snac_gym.evaluation.samples import EvaluationSample, generate_samples, read_samples_csv, write_samples_csv
from snac_gym.evaluation.store import RESULTS_FILE, RunDirectoryError, RunStore

from snac_gym.common.machine import describe_machine, machine_info
from snac_gym.common.outputs import write_whole
from snac_gym.kernels.compiled import EVALUATOR_KERNEL_MODULES, evaluator_kernel_modules
from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace

#: Samples drawn per sample-generation job.
GENERATION_CHUNK = 25


def run_evaluation(config: EvaluationConfig) -> pd.DataFrame:
    """Run the evaluation described by ``config`` and write its outputs to ``config.out``.

    Returns:
        The results table (one row per task, controller and sample), as written to
        ``results.parquet``.

    Raises:
        ValueError: On a bad option, controller or samples file (the message says which).
        snac_gym.evaluation.store.RunDirectoryError: If ``out`` holds another run (see ``resume``).
    """
    started = time.perf_counter()
    machine = machine_info()  # the load the run meets, before it makes its own
    kinematics, space = _checked_setting(config)
    config, store_knobs = _writable_caches(config)
    # 2. Controllers first: the run's manifest, which locks the output folder to it, names them.
    specs, skipped = resolve_controllers(config)
    kernel_modules = evaluator_kernel_modules(reference=config.wants_optimal)  # only the kernels the run calls
    with RunStore(config.out, config.manifest(space, specs), resume=config.resume) as store:
        if config.progress:  # once the folder is taken: a run refused there compiles nothing
            announce_compiles(sys.stderr.write, kernel_modules)
        with open_executor(config.workers, config.ray_address, kernel_modules) as executor:
            samples, timings = _sample_set(config, kinematics, space, executor, store)  # 1. Samples
            model = _knob_config(config)  # the settings the knobs are matched at: the kinematic model's
            identities = _calibration_identities(model, space, specs)
            cached = _run_knobs(model, space, specs, identities, store)
            # A physics engine's run that matches effort does so on the model first. The effort set is only matched
            # on: a run at cached knobs, or of the reference alone, does not draw it.
            matching = cached is None and bool(specs)
            on_model = config.match_effort and matching and model is not config
            effort_set = _effort_set(config, kinematics, space, executor, samples) if matching else samples
            if matching and config.match_effort and config.progress and not config.resume:
                costs = step_costs(config, executor, specs, effort_set)
                workers = getattr(executor, "workers", config.workers)  # Ray's: the run's --workers
                announce_matching(sys.stderr.write, config, samples, effort_set, bool(identities), costs, workers)
            matched_on = samples if on_model else effort_set
            rollouts = len(specs) * sum(map(len, matched_on.values())) + config.wants_optimal * sum(
                map(len, samples.values())
            )
            rollouts += len(specs) * sum(map(len, effort_set.values())) if on_model else 0
            progress = Progress(rollouts, config.progress)
            evaluation = EvaluationRun(config, store, executor, matched_on, progress)  # 3. Passes
            if matched_on is not samples:
                evaluation.reported = {task: {s.index for s in samples[task]} for task in config.tasks}
            try:
                store_matched = identities if store_knobs else {}  # where this run's matched knobs are cached
                if on_model:  # 4a. Equal effort on the kinematic model, the knobs kept for 4b and a resume
                    cached = _match_on_the_model(model, store, executor, effort_set, samples, progress, specs, timings)
                    _store_matched(store_matched, cached[0], config)
                if cached is not None:  # 4. Equal effort, at the knobs an earlier run (or 4a) matched, and 5.
                    # The last phase: the main process mostly waits for the workers now. Not earlier, where a run
                    # stopped before its reports (an interrupt, an error) would only have paid for them.
                    prefetch_report_modules(config.plots)
                    # Side by side: the passes and the optimal reference share no input, and their jobs share the
                    # workers, the reference's long ones first (lower priority number), the passes' short ones
                    # filling the last gaps instead of one long job running alone at the end.
                    side_by_side = time.perf_counter()
                    (results, records), optimal = evaluation.concurrently(
                        [lambda: _passes_at_cached_knobs(evaluation, specs, *cached), lambda: _optimal_rows(evaluation)]
                    )
                    results.update(optimal)
                    if config.wants_optimal:
                        evaluation.timings[SIDE_BY_SIDE] = time.perf_counter() - side_by_side
                else:  # 4. Equal effort
                    results, records = controller_passes(evaluation, specs)
                    _store_matched(store_matched, records, config)
                    if matched_on is not samples:  # the rows of the evaluated samples only
                        results = {key: _reported_rows(rows, samples[key[0]]) for key, rows in results.items()}
                        evaluation.samples = samples
                    prefetch_report_modules(config.plots)
                    results.update(_optimal_rows(evaluation))  # 5. Optimal reference
            finally:
                progress.close()
                timings.update(evaluation.timings)
        order = _row_order(config, specs)
        table = _results_table(config, order, results)
        efforts = [records[key] for key in order if key in records]
        executor_text = getattr(executor, "description", "serial")
        _write_outputs(store, config, table, efforts, skipped, timings, started, executor_text, machine)  # 6. Reports
    return table


#: What a run that compiles the kernels says first (:func:`announce_compiles`).
COMPILING = (
    "evaluate: compiling the numerical kernels for this machine first (numba's cache has none for this code yet: "
    "the first run after an install or an update; up to about 20 s on 2 cores)"
)


def announce_compiles(write: Any, modules: tuple[str, ...] = EVALUATOR_KERNEL_MODULES) -> None:
    """Write :data:`COMPILING` (one line) where the kernels of ``modules`` (default: every evaluator kernel's) are not
    in numba's cache.

    They compile when the workers start, before the first progress line: a first run would otherwise be silent
    for its first seconds (10-40 s of CPU by machine, shared by the workers: docs/benchmarks-log.md).
    """
    from snac_gym.kernels.compiled import cached_on_disk  # imports numba: a run needs it

    if not cached_on_disk(modules):
        write(COMPILING + "\n")


#: A match whose one pass over the effort set is estimated to take this long or longer (s) says how long, and how long
#: a pass of the evaluated samples alone would take instead.
LONG_MATCH_S = 60.0


def announce_matching(
    write: Any,
    config: EvaluationConfig,
    samples: dict[str, list[EvaluationSample]],
    effort_set: dict[str, list[EvaluationSample]],
    cache_on: bool,
    costs: dict[tuple[str, str], float] | None = None,
    workers: int = 1,
) -> None:
    """Say (one line) that the run matches equal effort before its evaluated samples, on how many samples, why no
    knobs were read, and the options that make it shorter or skip it.

    A run at the default settings reads the shipped knobs and matches nothing; any other run (another arm, cost or
    controller) searches every controller's knob on the effort set first, 1000 samples a task whatever ``--samples``:
    seconds for most controllers, but most of an hour for one as slow as ``mpc``, for what may be a 10-sample
    question. So where ``costs`` (each (task, controller)'s seconds per sample and step on one worker:
    :func:`~snac_gym.evaluation.execution.passes.step_costs`) put one pass of the controllers over the effort set at
    :data:`LONG_MATCH_S` or more on ``workers``, the line says how long that pass takes, which controller's steps
    cost most, and how long a pass of the evaluated samples alone would take.
    """
    if config.recalibrate:
        why = "--recalibrate"
    elif not cache_on:
        why = "the calibration cache is off"
    else:
        why = "no knobs cached or shipped for these controllers at these settings"
    size = max(map(len, effort_set.values()), default=0)
    larger = size > max(map(len, samples.values()), default=0)
    shorter = ", --effort-samples 0 matches on the evaluated samples" if larger else ""
    duration = ""
    if costs:
        pass_s = _pass_seconds(config, effort_set, costs, workers)
        if pass_s >= LONG_MATCH_S:
            (_, slowest), cost = max(costs.items(), key=lambda item: item[1])
            duration = (
                f"; one pass of these controllers over them takes {_about(pass_s)} here ({workers} "
                f"worker{'s' * (workers != 1)}; {slowest}: {_step_text(cost)} a step), and matching takes several "
                f"times that (a knob search of up to {MAX_EVALUATIONS} tries on them, then one to {MAX_MATCH_ROUNDS} "
                "passes)"
            )
            if larger:
                shorter += f" (a pass of them: {_about(_pass_seconds(config, samples, costs, workers))})"
    write(
        f"evaluate: matching equal effort first, on {size} samples a task ({why}){duration}; "
        f"--no-match-effort skips it{shorter}\n"
    )


def _pass_seconds(
    config: EvaluationConfig,
    sample_set: dict[str, list[EvaluationSample]],
    costs: dict[tuple[str, str], float],
    workers: int,
) -> float:
    """Seconds of one pass of every controller of ``costs`` over ``sample_set`` on ``workers`` workers."""
    total = sum(len(sample_set.get(task, ())) * config.steps(task) * cost for (task, _), cost in costs.items())
    return total / max(workers, 1)


def _step_text(seconds: float) -> str:
    """A step's cost in ms, or µs below one."""
    return f"{seconds * 1e3:.1f} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.0f} µs"


def _about(seconds: float) -> str:
    """``seconds`` as "about …" in the unit a reader thinks of them in."""
    if seconds < 0.5:
        return "under a second"
    if seconds < 90:
        return f"about {seconds:.0f} s"
    if seconds < 90 * 60:
        return f"about {seconds / 60:.0f} min"
    return f"about {seconds / 3600:.1f} h"


def _writable_caches(config: EvaluationConfig) -> tuple[EvaluationConfig, bool]:
    """``config`` and whether the matched knobs can be stored, after one check, here, that the cache folder can be
    written. Where it cannot (a read-only folder, a file in the way, no home), one line on stderr says so and how
    to run without the caches, and the run goes on without storing anything: the reference is solved, the knobs
    matched (or the shipped ones read), with the same rows. Checked once, in this process, so that no worker or
    late phase meets the fault alone."""
    wants_knobs = config.match_effort and config.calibration_cache and cache_enabled()
    if not (config.reference_cache or wants_knobs):
        return config, True
    folders = [
        folder
        for folder, used in ((cache_folder(), config.reference_cache), (calibration_folder(), wants_knobs))
        if used
    ]
    try:
        for folder in folders:
            folder.mkdir(parents=True, exist_ok=True)
            probe = folder / f".write-probe.{os.getpid()}"
            probe.write_text("")
            probe.unlink()
    except OSError as exc:
        sys.stderr.write(
            f"warning: the cache folder {folder} cannot be written ({exc.strerror or exc}): this run goes on without "
            f"storing its reference rows and knobs ({CACHE_ENV} names another folder; --no-reference-cache and "
            f"{SWITCH_ENV}=0 turn the caches off)\n"
        )
        return dataclasses.replace(config, reference_cache=False), False
    return config, True


def export_sample_set(config: EvaluationConfig) -> Path:
    """Only draw (or read and check) the sample set of ``config`` and write it to ``config.export_samples``."""
    if config.export_samples is None:
        raise ValueError("export_samples (--export-samples FILE) is needed to export the samples")
    config.validate()
    kinematics = Kinematics(config.robot)
    space = config.space if config.space is not None else SampleSpace.for_robot(kinematics)
    with open_executor(config.workers, config.ray_address) as executor:
        samples = load_samples(config, kinematics, space, executor)
    return write_samples_csv(
        [s for task in config.tasks for s in samples[task]], config.export_samples, kinematics.n_joints
    )


def _checked_setting(config: EvaluationConfig) -> tuple[Kinematics, SampleSpace]:
    """Validate ``config`` (with its robot) and return the robot's model and the sample space."""
    config.validate()
    kinematics = Kinematics(config.robot)
    config.validate_for(kinematics)
    space = config.space if config.space is not None else SampleSpace.for_robot(kinematics)
    return kinematics, space


# -- 1. samples ---------------------------------------------------------------------------------
def _generate_chunk(args: tuple[str, SampleSpace, int, str, list[int]]) -> list[EvaluationSample]:
    robot, space, seed, task, indices = args
    return generate_samples(Kinematics(robot), space, seed, task, indices)


def load_samples(
    config: EvaluationConfig, kinematics: Kinematics, space: SampleSpace, executor: Any
) -> dict[str, list[EvaluationSample]]:
    """The sample set of every task of ``config`` (from the file, or drawn in parallel chunks)."""
    if config.samples_file is not None:
        from_file = read_samples_csv(config.samples_file, kinematics, space)
        for task in config.tasks:
            if not from_file[task]:
                raise ValueError(f"{config.samples_file} has no {task!r} rows; choose --task accordingly")
        return {task: from_file[task] for task in config.tasks}
    return _draw(config, kinematics, space, executor, 0, config.samples)


def _draw(
    config: EvaluationConfig, kinematics: Kinematics, space: SampleSpace, executor: Any, first: int, end: int
) -> dict[str, list[EvaluationSample]]:
    """Samples ``first`` to ``end - 1`` of the seed's stream for every task (each drawn from its own index).

    The chunks start at multiples of :data:`GENERATION_CHUNK` (the first may be shorter), so that runs of other sizes
    share the sample cache's entries (:mod:`snac_gym.evaluation.sample_cache`); only the chunks it does not hold are
    drawn, by the workers, and stored."""
    bounds = [first, *range(first - first % GENERATION_CHUNK + GENERATION_CHUNK, end, GENERATION_CHUNK), end]
    chunks = [
        (config.robot, space, config.seed, task, list(range(start, stop)))
        for task in config.tasks
        for start, stop in zip(bounds, bounds[1:])
        if start < stop
    ]
    drawn: dict[int, list[EvaluationSample]] = {}
    keys: dict[int, str] = {}
    folder = sample_cache.cache_folder()
    if sample_cache.cache_enabled():
        limits = (kinematics.lower_limits, kinematics.upper_limits)
        for index, (robot, _, seed, task, indices) in enumerate(chunks):
            if sample_cache.cacheable(task):
                keys[index] = sample_cache.chunk_key(robot, space, seed, task, indices)
                found = sample_cache.read_chunk(folder, keys[index], task, indices, limits)
                if found is not None:
                    drawn[index] = found
    missing = [index for index in range(len(chunks)) if index not in drawn]
    for position, chunk in executor.run(_generate_chunk, [chunks[index] for index in missing]) if missing else ():
        index = missing[position]
        drawn[index] = chunk
        if index in keys:
            sample_cache.write_chunk(folder, keys[index], chunk, kinematics.n_joints)
    samples: dict[str, list[EvaluationSample]] = {task: [] for task in config.tasks}
    for index in range(len(chunks)):
        samples[chunks[index][3]].extend(drawn[index])
    return samples


def _sample_set(
    config: EvaluationConfig, kinematics: Kinematics, space: SampleSpace, executor: Any, store: RunStore
) -> tuple[dict[str, list[EvaluationSample]], dict[str, float]]:
    """Step 1: the sample set, written to ``samples.csv`` (and ``export_samples``), and the time it took."""
    started = time.perf_counter()
    samples = load_samples(config, kinematics, space, executor)
    store.begin()  # run.json only now: a run refused for its samples leaves no run behind
    timings = {"samples": time.perf_counter() - started}
    all_samples = [s for task in config.tasks for s in samples[task]]
    write_samples_csv(all_samples, store.root / "samples.csv", kinematics.n_joints)
    if config.export_samples is not None:
        write_samples_csv(all_samples, config.export_samples, kinematics.n_joints)
    return samples, timings


def _effort_set(
    config: EvaluationConfig,
    kinematics: Kinematics,
    space: SampleSpace,
    executor: Any,
    samples: dict[str, list[EvaluationSample]],
) -> dict[str, list[EvaluationSample]]:
    """The samples equal effort is matched on: ``samples`` extended along the seed's stream to
    ``effort_samples`` (a sample depends only on its index, so the evaluated ones are its first),
    or ``samples`` itself."""
    size = config.effort_set_size
    if size is None:
        return samples
    more = _draw(config, kinematics, space, executor, config.samples, size)
    return {task: samples[task] + more[task] for task in config.tasks}


def _calibration_identities(
    config: EvaluationConfig, space: SampleSpace, specs: Sequence[ControllerSpec]
) -> dict[tuple[str, str], dict[str, Any]]:
    """The calibration-cache identity of every (task, controller) a run matches (none without matching,
    with the cache off, or with no controllers)."""
    if not (config.match_effort and config.calibration_cache and specs and cache_enabled()):
        return {}
    return _identities(config, space, specs)


def _identities(
    config: EvaluationConfig, space: SampleSpace, specs: Sequence[ControllerSpec]
) -> dict[tuple[str, str], dict[str, Any]]:
    names = [s.name for s in specs]
    reference = None
    if config.effort_target is None:
        reference = specs[names.index(config.effort_reference if config.effort_reference in names else names[0])]
    manifest = config.manifest(space)  # once: it hashes the samples file
    return {
        (task, spec.name): calibration_identity(config, manifest, task, spec, reference)
        for task in config.tasks
        for spec in specs
    }


#: The key of ``calibration.json`` under which a run keeps the knobs it read instead of matching them.
KNOBS_READ_KEY = "knobs read"


def _knob_config(config: EvaluationConfig) -> EvaluationConfig:
    """The settings a run's knobs are matched at: its own, on the kinematic model.

    A controller's effort is a property of its commands, and Table I's V/N in the three engines agree within 0.75 %
    at the same knobs (docs/physics.md), so a run in MuJoCo or PyBullet matches its knobs on the exact model, where
    the effort set runs in seconds instead of many minutes, and reads the knobs the kinematic runs matched (and the
    shipped ones): the engines are then compared at the same knobs.
    """
    return config if config.engine == "kinematic" else dataclasses.replace(config, engine="kinematic")


def _store_matched(
    identities: dict[tuple[str, str], dict[str, Any]], records: Records, config: EvaluationConfig
) -> None:
    """The knobs this run matched, into the calibration cache under ``identities`` (none: the cache is not used)."""
    if identities:
        write_records(calibration_folder(), identities, records, str(Path(config.out).resolve()))


def _match_on_the_model(
    model: EvaluationConfig,
    store: RunStore,
    executor: Any,
    effort_set: dict[str, list[EvaluationSample]],
    samples: dict[str, list[EvaluationSample]],
    progress: Progress,
    specs: Sequence[ControllerSpec],
    timings: dict[str, float],
) -> tuple[Records, dict[str, Any]]:
    """The knobs of a run in a physics engine, matched on the kinematic model over the effort set, and their stamp.

    They are kept in the run's ``calibration.json`` as knobs read (:data:`KNOBS_READ_KEY`), so that a resume goes on
    at them; the model's passes are stored with the run's parts under the kinematic engine's keys.
    """
    run = EvaluationRun(model, store, executor, effort_set, progress)
    if effort_set is not samples:
        run.reported = {task: {s.index for s in samples[task]} for task in model.tasks}
    _, records = controller_passes(run, specs)
    timings.update({f"{phase} on the kinematic model": seconds for phase, seconds in run.timings.items()})
    stamp = {"origin": MODEL_ORIGIN}
    kept = [dataclasses.asdict(record) for record in records.values()]
    store.save_calibration(KNOBS_READ_KEY, {"stamp": stamp, "records": kept})
    return records, stamp


def _run_knobs(
    config: EvaluationConfig,
    space: SampleSpace,
    specs: Sequence[ControllerSpec],
    identities: dict[tuple[str, str], dict[str, Any]],
    store: RunStore,
) -> tuple[Records, dict[str, Any]] | None:
    """The knobs a run reads instead of matching them, with the stamp of the run that matched them, or ``None``.

    A new run reads the calibration cache, else the shipped knobs (:func:`_cached_calibration`), and keeps what it
    read in its ``calibration.json`` before its first pass. A resumed run reads only that: it goes on as it began,
    at the same knobs or matching, whatever the cache holds now (its parts at cached knobs cover the reported
    samples, a match's the effort set).
    """
    if not config.resume:
        cached = _cached_calibration(config, identities)
        if cached is not None:
            records, stamp = cached
            store.save_calibration(
                KNOBS_READ_KEY, {"stamp": stamp, "records": [dataclasses.asdict(r) for r in records.values()]}
            )
        return cached
    kept = store.calibration.get(KNOBS_READ_KEY)
    if kept is None:
        return None
    where = store.root / "calibration.json"
    try:
        records = {(r["task"], r["controller"]): EffortRecord(**r) for r in kept["records"]}
        expected = identities or _identities(config, space, specs)  # the cache's, unless it is off
        if set(records) != set(expected):
            raise ValueError(f"it holds the knobs of {sorted(records)}, the run's are {sorted(expected)}")
        for key, record in records.items():
            check_record(record, json.loads(json.dumps(expected[key], default=str)))
        return records, dict(kept["stamp"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise RunDirectoryError(
            f"--resume: the knobs kept in {where} do not hold ({type(exc).__name__}: {exc}); "
            "the run cannot go on as it began, start it again in another --out"
        ) from None


def _cached_calibration(
    config: EvaluationConfig, identities: dict[tuple[str, str], dict[str, Any]]
) -> tuple[Records, dict[str, Any]] | None:
    """The cached records of every (task, controller) and the stamp of the run that made them, else the shipped
    ones where the run is at the defaults they were matched for (:mod:`snac_gym.evaluation.effort.shipped`), or
    ``None``."""
    if not identities or config.recalibrate:
        return None
    cached = read_records(calibration_folder(), identities)
    return cached if cached is not None else read_shipped(identities)


def _passes_at_cached_knobs(
    evaluation: EvaluationRun, specs: Sequence[ControllerSpec], records: Records, stamp: dict[str, Any]
) -> tuple[Results, Records]:
    """Each controller's one pass on the reported samples at its cached knob: the reference at its own settings,
    the others at the knob their match found, as the last full pass of a match runs them."""
    config = evaluation.config
    passes = []
    for task in config.tasks:
        for spec in specs:
            record = records[(task, spec.name)]
            own = spec.knob is None or record.role in ("reference", "fixed")
            passes.append((task, spec, spec.kwargs if own else {**spec.kwargs, spec.knob: record.knob_value}))
    # The longest rollouts first, so that the short ones fill the workers' last gaps instead of a long one
    # running alone at the end (rows do not depend on the order).
    passes.sort(key=lambda item: -config.steps(item[0]))
    started = time.perf_counter()
    rows_of_passes = evaluation.run_passes(passes)
    evaluation.timings["passes at cached knobs"] = time.perf_counter() - started
    where = stamp["origin"] if "origin" in stamp else f"the run in {stamp.get('run')} ({stamp.get('at')})"
    noted = {key: dataclasses.replace(r, calibrated_by=where) for key, r in records.items()}
    results = {(task, spec.name): rows for (task, spec, _), rows in zip(passes, rows_of_passes, strict=True)}
    return results, noted


def _reported_rows(rows: pd.DataFrame, samples: Sequence[EvaluationSample]) -> pd.DataFrame:
    return rows[rows["sample"].isin([s.index for s in samples])].reset_index(drop=True)


# -- 5. the optimal reference -------------------------------------------------------------------
def _optimal_rows(evaluation: EvaluationRun) -> Results:
    """The ``optimal`` rows of every task, when asked for: a function of the samples, the cost and the arm
    alone (:mod:`snac_gym.evaluation.reference.optimum`), whatever controllers the run has."""
    config = evaluation.config
    if not config.wants_optimal:
        return {}
    rows = evaluation.run_optimal()
    return {(task, OPTIMAL): task_rows for task, task_rows in zip(config.tasks, rows, strict=True)}


# -- 6. results and reports ---------------------------------------------------------------------
def _row_order(config: EvaluationConfig, specs: Sequence[ControllerSpec]) -> list[tuple[str, str]]:
    """(task, controller) in the order of the results: tasks as given, ``optimal`` first, then the controllers."""
    names = ([OPTIMAL] if config.wants_optimal else []) + [spec.name for spec in specs]
    return [(task, name) for task in config.tasks for name in names]


def _results_table(config: EvaluationConfig, order: Sequence[tuple[str, str]], results: Results) -> pd.DataFrame:
    """One row per task, controller and sample, in that order, with the ratios to the optimum."""
    names = list(dict.fromkeys(name for _, name in order))
    table = pd.concat([results[key] for key in order], ignore_index=True)
    table = table.sort_values(
        ["task", "controller", "sample"], key=_sort_key(config, names), kind="stable"
    ).reset_index(drop=True)
    return add_optimality(table)


def _sort_key(config: EvaluationConfig, names: list[str]) -> Any:
    task_rank = {t: i for i, t in enumerate(config.tasks)}
    controller_rank = {name: i for i, name in enumerate(names)}

    def key(column: pd.Series) -> pd.Series:
        if column.name == "task":
            return column.map(task_rank)
        if column.name == "controller":
            return column.map(controller_rank)
        return column

    return key


def _write_outputs(
    store: RunStore,
    config: EvaluationConfig,
    table: pd.DataFrame,
    efforts: Sequence[EffortRecord],
    skipped: dict[str, str],
    timings: dict[str, float],
    started: float,
    executor: str,
    machine: dict[str, Any],
) -> None:
    """``results.csv``/``.parquet``, ``timings.json`` (the time up to the reports) and ``machine.json`` (the machine
    it was measured on, and the libraries whose numerics shape the rows' last bits), then the reports."""
    write_whole(store.root / "results.csv", lambda path: table.to_csv(path, index=False, float_format="%.17g"))
    write_whole(store.root / RESULTS_FILE, lambda path: table.to_parquet(path, index=False))
    timings["total"] = time.perf_counter() - started  # up to the reports
    # Rounded once, for both files: summary.md's 0.1 s figures are then timings.json's, even where a time lies within
    # a millisecond of a rounding boundary (0.1504 s rounded to 0.150 would otherwise read 0.2 s in one, 0.1 s from
    # the other).
    timings = {k: round(v, 3) for k, v in timings.items()}
    store.write_text("timings.json", json.dumps(timings, indent=2))
    store.write_text(
        "machine.json", json.dumps({**machine, "versions": installed_versions(("snac-gym", *DISTRIBUTIONS))}, indent=2)
    )
    description = describe_machine(machine)
    write_reports(
        store.root, table, efforts, config, skipped, config.statistic.description, timings, executor, description
    )


__all__ = ["COMPILING", "announce_compiles", "announce_matching", "export_sample_set", "load_samples", "run_evaluation"]
