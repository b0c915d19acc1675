"""Passes over the sample set: jobs → executor → store (:class:`EvaluationRun`).

A *pass* rolls one controller with one set of arguments (one knob value) over every sample of a
task, in jobs of ``chunk_size`` samples (:class:`~snac_gym.evaluation.execution.jobs.RolloutJob`) run by the
executor (:mod:`snac_gym.evaluation.execution.executors`); each finished job is stored at once as a part file
(:mod:`snac_gym.evaluation.store`), and a part already on disk (``--resume``, or a pass the run made
before) is read back instead of being run again. The optimal reference's rows are made the same
way from :class:`~snac_gym.evaluation.reference.optimum.OptimalJob` jobs. The knob search's short rollouts
(:meth:`EvaluationRun.measure`) use the same jobs but are not stored.

Several pipelines of dependent steps (the concurrent effort matches, the sweep's points) feed one
executor from threads (:meth:`EvaluationRun.concurrently`): the jobs are pure, so that changes
when they run, never what they return.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.execution.executors import ExecutorStopped
from snac_gym.evaluation.execution.jobs import JobResult, RolloutJob, run_job, time_job
from snac_gym.evaluation.reference.cache import cache_folder
from snac_gym.evaluation.reference.optimum import OPTIMAL, OptimalJob, run_optimal_job
from snac_gym.evaluation.samples import EvaluationSample, policy_seed
from snac_gym.evaluation.store import RunStore, settings_key

from snac_gym.common.errors import Cancelled

if TYPE_CHECKING:
    from snac_gym.evaluation.controllers import ControllerSpec
    from snac_gym.evaluation.execution.progress import Progress
    from snac_gym.evaluation.run_config import EvaluationConfig

#: Most samples per job of the optimal reference. Samples are solved one by one, but a job's
#: solutions are replayed in one lockstep rollout, whose per-step overhead 50 samples do not
#: amortise: 11.4 ms of replay per 1500-step sample at 50, 3.5 ms at 250 (docs/benchmarks-log.md).
OPTIMAL_CHUNK_SIZE = 250
#: Fewest samples per optimal job when the set is split so that every worker gets one.
OPTIMAL_MIN_CHUNK = 50
#: Executor priority of knob-search jobs over full passes (lower runs first): every later step of
#: a controller's effort match waits on its search, while a full pass holds nothing up.
SEARCH_PRIORITY, PASS_PRIORITY = 0, 1
#: The timing of a run whose passes and optimal reference ran side by side (their own timings overlap).
SIDE_BY_SIDE = "passes and optimal side by side"

#: The sample set of a match's full passes where it is not the run's own (the effort set): their part files are named
#: apart, so that a later pass over the run's own samples at the same settings (a sweep's point) is not taken for one.
EFFORT_SET = "effort set"
#: One full pass: task, controller, and the constructor arguments (the knob value included).
Pass = tuple[str, "ControllerSpec", dict[str, Any]]


def rollout_jobs(
    config: EvaluationConfig,
    task: str,
    controller: str,
    kwargs: dict[str, Any],
    samples: Sequence[EvaluationSample],
    steps: int,
    keep_logs: bool = False,
    size: int | None = None,
) -> list[RolloutJob]:
    """The jobs of ``controller`` (constructor arguments ``kwargs``) on ``samples`` of ``task`` under ``config``, of at
    most ``size`` samples each (default: ``config.chunk_size``)."""
    size = size or config.chunk_size
    return [
        RolloutJob(
            task=task,
            controller=controller,
            kwargs=dict(kwargs),
            samples=tuple(samples[i : i + size]),
            seeds=tuple(policy_seed(config.seed, task, s.index) for s in samples[i : i + size]),
            steps=steps,
            dt=config.dt,
            robot=config.robot,
            engine=config.engine,
            keep_logs=keep_logs,
            use_batch=config.use_batch,
            convention=config.convention,
            model_error=config.model_error,
        )
        for i in range(0, len(samples), size)
    ]


#: The probe of :func:`step_costs`: this many samples of a task, stepped together (as a pass steps its chunks) for
#: as long as :func:`~snac_gym.evaluation.execution.jobs.time_job` needs (0.7 s of ``mpc``'s, tens of
#: milliseconds of the others').
STEP_COST_SAMPLES = 64


def step_costs(
    config: EvaluationConfig,
    executor: Any,
    specs: Sequence[ControllerSpec],
    samples: dict[str, list[EvaluationSample]],
) -> dict[tuple[str, str], float]:
    """Seconds per sample and control step of each controller of ``specs`` (at its own settings) on each task of
    ``config``, on the kinematic model (where effort is matched), measured on the workers, every probe at once
    (:func:`~snac_gym.evaluation.execution.jobs.time_job` on the first :data:`STEP_COST_SAMPLES` samples of
    ``samples``)."""
    n = STEP_COST_SAMPLES  # one job a (task, controller), whatever the run's --chunk-size
    probes = [
        dataclasses.replace(job, engine="kinematic")
        for task in config.tasks
        for spec in specs
        for job in rollout_jobs(config, task, spec.name, spec.kwargs, samples[task][:n], config.steps(task), size=n)
    ]
    return {
        (probes[position].task, probes[position].controller): seconds
        for position, seconds in executor.run(time_job, probes, SEARCH_PRIORITY)
    }


class EvaluationRun:
    """The passes of one run over its samples (state shared by :func:`~snac_gym.evaluation.runner.run_evaluation`'s
    steps).

    Args:
        config: The run's options.
        store: Its output folder (parts are written and read there).
        executor: Where jobs run (:func:`snac_gym.evaluation.execution.executors.make_executor`).
        samples: The sample set of every task.
        progress: Counts the rollouts as they finish.
    """

    def __init__(
        self,
        config: EvaluationConfig,
        store: RunStore,
        executor: Any,
        samples: dict[str, list[EvaluationSample]],
        progress: Progress,
    ) -> None:
        self.config, self.store, self.executor, self.samples, self.progress = config, store, executor, samples, progress
        #: Sample indices per task whose rows and trajectories are reported (``None``: all of them;
        #: equal effort can be matched on more samples than are evaluated).
        self.reported: dict[str, set[int]] | None = None
        #: Wall time spent per phase, s.
        self.timings: dict[str, float] = {}
        #: Cut each knob-search evaluation into at least one job per worker (set while fewer
        #: searches than workers run at once, so that none is left idle).
        self.spread_searches = True
        #: Set when one concurrent pipeline failed or was interrupted: the others stop.
        self.cancelled = threading.Event()
        self._active_searches = 0
        self._searches_lock = threading.Lock()

    # -- pipelines ------------------------------------------------------------------------------
    @contextlib.contextmanager
    def searching(self) -> Iterator[None]:
        """While any knob search runs, keep a worker free of full passes (where the executor can).

        A search is a chain of short evaluations that each wait for the last; behind a full-pass
        job they would wait seconds each, and the last search to finish holds up the end of the run.
        """
        reserve = getattr(self.executor, "reserve", None)
        with self._searches_lock:
            self._active_searches += 1
            if reserve is not None:
                reserve(self._active_searches)
        try:
            yield
        finally:
            with self._searches_lock:
                self._active_searches -= 1
                if reserve is not None:
                    reserve(self._active_searches)

    def _check_cancelled(self) -> None:
        if self.cancelled.is_set():
            raise Cancelled("stopped because another effort match failed or the run was interrupted")

    def concurrently(self, functions: Sequence[Callable[[], Any]]) -> list[Any]:
        """Call ``functions`` at the same time (threads that feed the shared executor), in order for a serial one.

        Each function is a pipeline of dependent steps (a knob search, then its full pass, ...)
        whose jobs are pure, so running them concurrently changes only when jobs run, never
        what they return. If one raises, or the wait is interrupted, the others are cancelled
        at their next step and the first exception is raised.
        """
        if len(functions) <= 1 or not getattr(self.executor, "concurrent", False):
            return [function() for function in functions]
        pool = ThreadPoolExecutor(max_workers=len(functions), thread_name_prefix="effort-match")
        futures = [pool.submit(function) for function in functions]
        try:
            wait(futures, return_when=FIRST_EXCEPTION)
            errors = [future.exception() for future in futures if future.done() and future.exception() is not None]
            if not errors:
                return [future.result() for future in futures]
            # The failure itself, not the cancellations it caused in the other pipelines.
            raise next((e for e in errors if not isinstance(e, Cancelled | ExecutorStopped)), errors[0])
        except BaseException:
            # A failed pipeline or Ctrl-C: stop the others now. terminate() ends the workers and
            # fails every job a pipeline waits on, so the threads below return at once instead
            # of waiting (for ever, once the workers are gone) on jobs that will not finish.
            self.cancelled.set()
            self.executor.terminate()
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    # -- jobs -----------------------------------------------------------------------------------
    def _jobs(
        self,
        task: str,
        controller: str,
        kwargs: dict[str, Any],
        samples: Sequence[EvaluationSample],
        steps: int,
        keep_logs: bool,
        spread: bool = False,
    ) -> list[RolloutJob]:
        """Jobs of at most ``chunk_size`` samples (full passes: their parts are stored by chunk index).

        ``spread``: cut ``samples`` into equal jobs, at least one per worker, so that a knob
        search's smaller screening set keeps every worker busy (its results are not stored by chunk).
        """
        size = self.config.chunk_size
        if spread and self.spread_searches and samples:
            jobs = max(math.ceil(len(samples) / size), min(self.config.workers, len(samples)))
            size = math.ceil(len(samples) / jobs)
        return rollout_jobs(self.config, task, controller, kwargs, samples, steps, keep_logs, size)

    def _optimal_jobs(self, task: str) -> list[OptimalJob]:
        """The optimal reference's jobs of ``task``: at most :data:`OPTIMAL_CHUNK_SIZE` samples each."""
        config, samples = self.config, self.samples[task]
        # At least one job per worker on a small set (a few solves each), at most OPTIMAL_CHUNK_SIZE.
        size = min(
            config.chunk_size, OPTIMAL_CHUNK_SIZE, max(OPTIMAL_MIN_CHUNK, math.ceil(len(samples) / config.workers))
        )
        return [
            OptimalJob(
                task=task,
                samples=tuple(samples[i : i + size]),
                seeds=tuple(policy_seed(config.seed, task, s.index) for s in samples[i : i + size]),
                steps=config.steps(task),
                dt=config.dt,
                robot=config.robot,
                keep_logs=config.save_trajectories,
                convention=config.convention,
                position_limits=config.reference_limits == "joints",
                cache_dir=str(cache_folder()) if config.reference_cache else None,
            )
            for i in range(0, len(samples), size)
        ]

    def _parts_to_run(
        self, controller: str, key: str, jobs: Sequence[Any]
    ) -> tuple[list[Path], list[tuple[Any, Path]]]:
        """Every job's part file, and the jobs whose part is not on disk yet (the others count as done)."""
        paths: list[Path] = []
        todo: list[tuple[Any, Path]] = []
        for chunk, job in enumerate(jobs):
            path = self.store.part_path(job.task, controller, key, chunk)
            paths.append(path)
            if self.store.has_part(path, [s.index for s in job.samples]):
                self.progress.update(len(job.samples))
            else:
                todo.append((job, path))
        return paths, todo

    def _store_rows(
        self, job: Any, controller: str, result: JobResult, path: Path, knob: str | None, knob_value: Any
    ) -> None:
        """Store a finished job: its trajectories, then its rows labelled with the pass they belong to."""
        if result.logs is not None:
            for log, sample in zip(result.logs, job.samples, strict=True):
                if self.reported is None or sample.index in self.reported[job.task]:
                    self.store.write_trajectory(log, job.task, controller, sample.index)
        rows = result.metrics
        rows.insert(0, "task", job.task)
        rows.insert(1, "controller", controller)
        rows.insert(3, "seed", np.array(job.seeds, dtype=np.int64))
        rows["effort_parameter"] = knob or ""
        rows["effort_value"] = np.nan if knob_value is None else float(knob_value)
        rows["engine"] = self.config.engine
        # The run's model error, given to the controllers ("" for none; the optimum, the plant and
        # the cost keep the true model).
        rows["model_error"] = self.config.model_error or ""
        rows["horizon"] = job.steps * job.dt
        self.store.write_part(path, rows)
        self.progress.update(len(job.samples))

    def _read_passes(self, paths: Sequence[Sequence[Path]]) -> list[pd.DataFrame]:
        return [pd.concat([self.store.read_part(p) for p in pass_paths], ignore_index=True) for pass_paths in paths]

    # -- passes ---------------------------------------------------------------------------------
    def run_passes(self, passes: Sequence[Pass]) -> list[pd.DataFrame]:
        """Full passes (every sample, full horizon); finished jobs are stored as they arrive."""
        self._check_cancelled()
        config = self.config
        todo: list[tuple[RolloutJob, Path, ControllerSpec]] = []
        paths: list[list[Path]] = []
        for task, spec, kwargs in passes:
            steps = config.steps(task)
            jobs = self._jobs(task, spec.name, kwargs, self.samples[task], steps, config.save_trajectories)
            key = settings_key(kwargs, steps, config.engine, "" if self.reported is None else EFFORT_SET)
            pass_paths, pass_todo = self._parts_to_run(spec.name, key, jobs)
            paths.append(pass_paths)
            todo += [(job, path, spec) for job, path in pass_todo]
        for index, result in self.executor.run(run_job, [job for job, _, _ in todo], priority=PASS_PRIORITY):
            job, path, spec = todo[index]
            knob_value = job.kwargs.get(spec.knob, spec.knob_value) if spec.knob else None
            self._store_rows(job, job.controller, result, path, spec.knob, knob_value)
        return self._read_passes(paths)

    def run_optimal(self) -> list[pd.DataFrame]:
        """The ``optimal`` rows of every task (jobs of :data:`OPTIMAL_CHUNK_SIZE` samples at most, stored as they
        arrive).

        They depend on the samples, the cost and the arm alone, not on the run's controllers.
        """
        started = time.perf_counter()
        self.progress.status("optimal reference")
        todo: list[tuple[OptimalJob, Path]] = []
        paths: list[list[Path]] = []
        for task in self.config.tasks:
            key = settings_key({"reference_limits": self.config.reference_limits}, self.config.steps(task),
                               self.config.engine)  # fmt: skip
            jobs = self._optimal_jobs(task)
            task_paths, task_todo = self._parts_to_run(OPTIMAL, key, jobs)
            paths.append(task_paths)
            todo += task_todo
        # The longest jobs first (rows do not depend on the order), so that no worker is left with a long one at
        # the end.
        todo.sort(key=lambda job_path: -job_path[0].steps * len(job_path[0].samples))
        for index, result in self.executor.run(run_optimal_job, [job for job, _ in todo]):
            job, path = todo[index]
            self._store_rows(job, OPTIMAL, result, path, None, None)
        self.timings["optimal"] = self.timings.get("optimal", 0.0) + time.perf_counter() - started
        self.progress.status("")
        return self._read_passes(paths)

    def measure(
        self, task: str, spec: ControllerSpec, kwargs: dict[str, Any], samples: Sequence[EvaluationSample], steps: int
    ) -> pd.DataFrame:
        """Metrics of short or partial rollouts for the knob search (not stored as results)."""
        self._check_cancelled()
        jobs = self._jobs(task, spec.name, kwargs, samples, steps, keep_logs=False, spread=True)
        parts = dict(self.executor.run(run_job, jobs, priority=SEARCH_PRIORITY))
        return pd.concat([parts[i].metrics for i in range(len(jobs))], ignore_index=True)


__all__ = [
    "OPTIMAL_CHUNK_SIZE", "PASS_PRIORITY", "SEARCH_PRIORITY", "SIDE_BY_SIDE", "STEP_COST_SAMPLES",
    "Cancelled", "EvaluationRun", "Pass", "rollout_jobs", "step_costs",
]  # fmt: skip
