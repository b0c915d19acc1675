"""The evaluation from options to reports: ``run_evaluation(EvaluationConfig(...))``.

Steps (each documented in docs/evaluation.md):

1. **Samples**: read ``samples_file`` or draw ``samples`` per task from ``seed``
   (:mod:`evaluation.samples`), spread over the workers in chunks; written to
   ``DIR/samples.csv`` (and ``export_samples``).
2. **Controllers**: ``controllers`` or every registered policy that can be built from a
   :class:`~snac_gym.policies.base.PolicyContext` (and, with effort matching, declares an
   ``effort_parameter``); those left out are listed in the summary.
3. **Passes**: a *pass* rolls one controller with one knob value over every sample of a task,
   in jobs of ``chunk_size`` samples (:mod:`evaluation.jobs`) run by the executor
   (:mod:`evaluation.executors`); each finished job is stored at once (:mod:`evaluation.store`).
4. **Equal effort** (``match_effort``): the reference controller (``effort_reference``,
   default ``snac``, at its own settings) is run first; its effort statistic
   (:mod:`evaluation.calibration`) is the target, unless ``effort_target`` is given (then
   every controller is matched to it). Every other controller's knob is searched on the
   screening samples, then a full pass checks the statistic over the whole set; if it misses
   the tolerance, the screening target is corrected by the observed ratio and the search
   repeats (at most ``MAX_MATCH_ROUNDS`` passes).
5. **Optimal reference** (``optimal`` among ``controllers``): every sample's numerical optimum of
   the same cost (:mod:`evaluation.optimal`, docs/optimal.md), an open-loop row with no effort
   knob; every row gains ``ratio_to_optimal`` and ``below_optimal``.
6. **Reports**: ``results.csv``/``.parquet`` (one row per task, controller and sample),
   ``summary.csv``/``.md`` and box plots (:mod:`evaluation.report`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import functools
import hashlib
import inspect
import json
import math
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from evaluation.backends import BACKENDS
from evaluation.calibration import (
    DEFAULT_EFFORT_STATISTIC,
    EffortMatch,
    EffortStatistic,
    effort_statistic_named,
    match_effort,
)
from evaluation.executors import MAX_WORKERS_PER_CPU, make_executor, max_workers
from evaluation.jobs import JobResult, RolloutJob, policy_context, run_job
from evaluation.optimal import OPTIMAL, OptimalJob, add_optimality, run_optimal_job
from evaluation.paper import PAPER_TABLE_I
from evaluation.samples import (
    TASKS,
    EvaluationSample,
    SampleFileError,
    generate_samples,
    policy_seed,
    read_samples_csv,
    write_samples_csv,
)
from evaluation.store import RunStore, settings_key
from snac_gym.cost import CostConvention
from snac_gym.kinematics import Kinematics
from snac_gym.policies.registry import available_policies, make_policy, policy_factory
from snac_gym.sampling import SampleSpace

#: Default horizon per task, s: at least every controller's 95th-percentile settling time,
#: measured at equal effort on 100 samples (docs/evaluation.md): SNAC's reach p95 is 11.7 s.
DEFAULT_HORIZONS: dict[str, float] = {"reach": 12.0, "track": 20.0}
#: Samples per job of a full pass. The kinematic backend steps a job's samples in lockstep and
#: its per-sample cost falls with the batch up to a few hundred samples (docs/evaluation.md).
DEFAULT_CHUNK_SIZE = 500
#: Samples per job of the optimal reference (solved one by one: larger jobs gain nothing).
OPTIMAL_CHUNK_SIZE = 50
#: Most full passes spent matching one controller's effort.
MAX_MATCH_ROUNDS = 3
#: Samples whose full-horizon rollouts locate the effort peak in time before a search.
PEAK_PROBE_SAMPLES = 20
#: A knob search screens at least this many samples (unless the set is smaller).
MIN_SCREENING_SAMPLES = 100
#: Executor priority of knob-search jobs over full passes (lower runs first): every later step of
#: a controller's effort match waits on its search, while a full pass holds nothing up.
SEARCH_PRIORITY, PASS_PRIORITY = 0, 1
#: Samples drawn per sample-generation job.
GENERATION_CHUNK = 25
#: Longest horizon accepted, s: 50x the default tracking horizon. Rollouts keep per-step arrays,
#: so an unbounded horizon (1e7 s asked for 9.3 GiB) fails late instead of being refused.
MAX_HORIZON_S = 1000.0


@dataclass(frozen=True)
class EvaluationConfig:
    """Options of one evaluation (the ``snac-gym evaluate`` options, by the same names).

    Attributes:
        out: Output directory.
        tasks: Tasks to evaluate, from ``("reach", "track")``.
        controllers: Registered policy names; ``None``: every registered policy that qualifies.
        samples: Random samples per task (ignored with ``samples_file``, whose rows are all used).
        seed: Seed of the sample set and of every policy reset.
        horizons: Rollout length per task, s (missing tasks take :data:`DEFAULT_HORIZONS`).
        backend: ``"kinematic"`` or ``"pybullet"``.
        match_effort: Calibrate every controller's effort knob to equal effort.
        effort_reference: Controller whose effort (at its own settings) is the target.
        effort_statistic: What "equal control effort" equalises: ``"max"`` (the maximum |u| over
            the sample set, rad/s) or ``"median-peak"`` (:mod:`evaluation.calibration`).
        effort_target: Explicit target of the effort statistic, in its unit (then every
            controller is matched).
        effort_tolerance: Relative tolerance of the match over the whole sample set.
        calibration_samples: Samples (the first ones of each task) the knob search runs on;
            ``None``: all of them when the search's rollouts are short, fewer when they are
            long (see the statistic's ``screening_budget``).
        samples_file: CSV of samples to use instead of random ones.
        export_samples: Also write the sample set to this CSV.
        save_trajectories: Write every rollout's per-step log under ``out/trajectories``.
        workers: Local worker processes.
        ray_address: Run on Ray instead (``"local"`` or a cluster address).
        resume: Continue an interrupted run in ``out``.
        chunk_size: Samples per job of a full pass (results do not depend on it or on the workers).
        dt: Control period, s.
        robot: Robot name.
        space: Sample space (default: the UR10 cuboid scaled to the robot).
        controller_kwargs: Constructor arguments per controller name.
        progress: Show a progress bar.
        use_batch: Let policies that offer the batch protocol run in lockstep batches.
        cost: The trajectory cost of the comparison (:data:`snac_gym.cost.COSTS`): ``"table1"``
            (with the u̇ term) or ``"hjb"`` (``Σ (eᵀQe + uᵀRu) Δt``); ``optimal`` solves for it.
        udot_start: u₋₁ of the u̇ term: ``"rest"`` (0) or ``"first"`` (u₀).
        q_scale: Q = q_scale·I in the cost; controllers whose constructor takes ``Q`` (``snac``,
            ``lqr``, ``snac-hjb``) get the same Q unless ``controller_kwargs`` sets it.
        success_threshold: Success rate a controller must reach to be ranked in the summary.
    """

    out: Path
    tasks: tuple[str, ...] = TASKS
    controllers: tuple[str, ...] | None = None
    samples: int = 1000
    seed: int = 0
    horizons: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_HORIZONS))
    backend: str = "kinematic"
    match_effort: bool = True
    effort_reference: str = "snac"
    effort_statistic: str = DEFAULT_EFFORT_STATISTIC
    effort_target: float | None = None
    effort_tolerance: float = 0.02
    calibration_samples: int | None = None
    samples_file: Path | None = None
    export_samples: Path | None = None
    save_trajectories: bool = False
    workers: int = 1
    ray_address: str | None = None
    resume: bool = False
    chunk_size: int = DEFAULT_CHUNK_SIZE
    dt: float = 1.0 / 125.0
    robot: str = "ur10"
    space: SampleSpace | None = None
    controller_kwargs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    progress: bool = True
    use_batch: bool = True
    cost: str = "table1"
    udot_start: str = "rest"
    q_scale: float = 1.0
    success_threshold: float = 0.95

    @property
    def convention(self) -> CostConvention:
        """The :class:`~snac_gym.cost.CostConvention` of ``cost``, ``udot_start`` and ``q_scale``."""
        return CostConvention(self.cost, self.udot_start, self.q_scale)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad option."""
        if not self.tasks or any(t not in TASKS for t in self.tasks) or len(set(self.tasks)) != len(self.tasks):
            raise ValueError(f"tasks must be distinct names from {TASKS}, got {self.tasks}")
        if self.controllers is not None and (
            not self.controllers or len(set(self.controllers)) != len(self.controllers)
        ):
            raise ValueError(f"controllers must be distinct names, got {self.controllers}")
        if self.samples < 1:
            raise ValueError(f"samples must be at least 1, got {self.samples}")
        unknown = set(self.horizons) - set(TASKS)
        if unknown:
            raise ValueError(f"horizons for unknown task(s) {sorted(unknown)}; tasks are {TASKS}")
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt must be a positive finite number of seconds, got {self.dt}")
        for task in self.tasks:
            if not self.dt <= self.horizon(task) <= MAX_HORIZON_S:
                raise ValueError(
                    f"the {task} horizon must be between one control period ({self.dt} s) and "
                    f"{MAX_HORIZON_S:g} s, got {self.horizon(task)}"
                )
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.wants_optimal and self.backend != "kinematic":
            raise ValueError(
                f"the {OPTIMAL!r} reference is the optimum of the kinematic model; use --backend kinematic"
            )
        effort_statistic_named(self.effort_statistic)
        if self.effort_target is not None and not (math.isfinite(self.effort_target) and self.effort_target > 0):
            raise ValueError(f"effort_target must be a positive finite number, got {self.effort_target}")
        if not 0 < self.effort_tolerance < 1:
            raise ValueError(f"effort_tolerance must be in (0, 1), got {self.effort_tolerance}")
        if self.calibration_samples is not None and self.calibration_samples < 1:
            raise ValueError(f"calibration_samples must be at least 1, got {self.calibration_samples}")
        local = self.ray_address in (None, "local")  # a cluster's size is its own
        if self.workers < 1 or (local and self.workers > max_workers()):
            raise ValueError(
                f"workers must be between 1 and {max_workers()} ({MAX_WORKERS_PER_CPU} per available CPU), "
                f"got {self.workers}"
            )
        if self.chunk_size < 1:
            raise ValueError(f"chunk_size must be at least 1, got {self.chunk_size}")
        self.convention  # noqa: B018  (validates cost, udot_start and q_scale)
        if not 0.0 <= self.success_threshold <= 1.0:
            raise ValueError(f"success_threshold must be in [0, 1], got {self.success_threshold}")
        if not str(self.out).strip():
            raise ValueError("out (--out) must name a folder, got an empty path")

    def validate_for(self, kinematics: Kinematics) -> None:
        """The checks that need the robot: an effort target the clipped commands can reach.

        Raises:
            ValueError: Naming the option and its bound.
        """
        if self.effort_target is not None:
            largest = self.statistic.largest(kinematics.velocity_limits)
            if self.effort_target > largest:
                raise ValueError(
                    f"effort_target {self.effort_target:g} {self.statistic.unit} is out of reach: commands are "
                    f"clipped at the velocity limits, so the {self.effort_statistic} statistic is at most {largest:g}"
                )

    @property
    def wants_optimal(self) -> bool:
        """Whether the ``optimal`` reference is among the controllers (never by default)."""
        return self.controllers is not None and OPTIMAL in self.controllers

    @property
    def statistic(self) -> EffortStatistic:
        """The effort statistic named by ``effort_statistic``."""
        return effort_statistic_named(self.effort_statistic)

    def horizon(self, task: str) -> float:
        """Rollout length of ``task``, s."""
        return float(self.horizons.get(task, DEFAULT_HORIZONS[task]))

    def steps(self, task: str) -> int:
        """Control steps K of ``task``'s rollouts: the horizon in periods, rounded."""
        return max(1, round(self.horizon(task) / self.dt))

    def manifest(self, space: SampleSpace, specs: Sequence[ControllerSpec] = ()) -> dict[str, Any]:
        """Every input that shapes the results (``run.json``; compared by ``--resume``).

        The options, a hash of the samples file, and per controller its effort knob's default and
        a hash of every file it reads (:attr:`ControllerSpec.inputs`): a resume after any of them
        changed is refused rather than mixing old and new results.

        Raises:
            SampleFileError: If ``samples_file`` cannot be read.
        """
        samples_hash = None
        if self.samples_file is not None:
            samples_hash = file_sha1(Path(self.samples_file), "samples file")
        return {
            "controller_inputs": {
                spec.name: {"knob": spec.knob, "knob_value": spec.knob_value, "files": dict(spec.inputs)}
                for spec in specs
            },
            "tasks": list(self.tasks),
            "controllers": None if self.controllers is None else list(self.controllers),
            "samples": None if self.samples_file is not None else self.samples,
            "samples_file_sha1": samples_hash,
            "seed": self.seed,
            "steps": {task: self.steps(task) for task in self.tasks},
            "backend": self.backend,
            "match_effort": self.match_effort,
            "effort_reference": self.effort_reference,
            "effort_statistic": self.effort_statistic,
            "effort_target": self.effort_target,
            "effort_tolerance": self.effort_tolerance,
            "calibration_samples": self.calibration_samples,
            "save_trajectories": self.save_trajectories,
            "chunk_size": self.chunk_size,
            "dt": self.dt,
            "robot": self.robot,
            "space": dataclasses.asdict(space),
            "controller_kwargs": {k: dict(v) for k, v in self.controller_kwargs.items()},
            "use_batch": self.use_batch,
            "cost": self.cost,
            "udot_start": self.udot_start,
            "q_scale": self.q_scale,
        }


@dataclass(frozen=True)
class ControllerSpec:
    """A controller as evaluated: name, constructor arguments and effort knob.

    Attributes:
        name: Registered name.
        kwargs: Constructor arguments given by the user.
        knob: The class's ``effort_parameter`` (``None`` if it declares none).
        knob_value: The knob's value with ``kwargs`` (the policy's attribute or constructor default).
        inputs: SHA-1 of every file the controller reads, by file name (:func:`controller_input_hashes`).
    """

    name: str
    kwargs: dict[str, Any]
    knob: str | None
    knob_value: float | None
    inputs: dict[str, str] = field(default_factory=dict)


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


def _knob_value(policy: Any, knob: str) -> float | None:
    value = getattr(policy, knob, None)
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def file_sha1(path: Path, what: str) -> str:
    """SHA-1 of a file's bytes.

    Raises:
        SampleFileError: If it cannot be read (one line naming ``what`` and the file).
    """
    digest = hashlib.sha1()
    try:
        with Path(path).open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as exc:
        raise SampleFileError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    return digest.hexdigest()


def controller_input_hashes(policies: Sequence[Any], kwargs: Mapping[str, Any]) -> dict[str, str]:
    """SHA-1 of every file a controller reads: those its policies list in ``input_files`` (a PPO
    model, shipped or not) and every constructor argument that names an existing file.

    Keys are file names (the folder is left out, so that a moved install resumes), with the path
    appended where two files share a name.
    """
    files: list[Path] = []
    for policy in policies:
        files.extend(Path(f) for f in (getattr(policy, "input_files", None) or ()))
    for value in kwargs.values():
        if isinstance(value, (str, Path)) and str(value) and Path(value).is_file():
            files.append(Path(value))
    hashes: dict[str, str] = {}
    for path in dict.fromkeys(p.resolve() for p in files):
        key = path.name if path.name not in hashes else str(path)
        hashes[key] = file_sha1(path, "controller input file")
    return hashes


def _takes_argument(name: str, argument: str) -> bool:
    """Whether the controller registered as ``name`` has a constructor argument ``argument``."""
    try:
        return argument in inspect.signature(policy_factory(name)).parameters
    except (TypeError, ValueError):
        return False


def default_controller_order(names: Sequence[str]) -> list[str]:
    """Table I's rows first, in the paper's order (RNN, SVF, SNAC), then the other names sorted."""
    paper = [name for name in PAPER_TABLE_I if name in names]
    return paper + sorted(name for name in names if name not in PAPER_TABLE_I)


def resolve_controllers(config: EvaluationConfig) -> tuple[list[ControllerSpec], dict[str, str]]:
    """The controllers to evaluate, and the registered ones left out with the reason.

    A controller given arguments (``controller_kwargs``, ``--param``) counts as named: it is
    never left out silently.

    Raises:
        ValueError: If an explicitly named controller is unknown, cannot be built, or (with
            effort matching) declares no scalar ``effort_parameter``; or if arguments are given
            for a controller that is not registered or not evaluated.
    """
    explicit = config.controllers is not None
    names = list(config.controllers) if explicit else default_controller_order(available_policies())
    names = [name for name in names if name != OPTIMAL]  # the reference row, not a policy (run_optimal)
    known = set(available_policies())
    for name, given in config.controller_kwargs.items():
        option = "--param " + ", ".join(f"{name}.{key}" for key in given)
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else f"; registered: {', '.join(sorted(known))}"
            raise ValueError(f"{option}: no controller is registered as {name!r}{hint}")
        if name not in names:
            raise ValueError(f"{option}: {name!r} is not among the evaluated controllers ({', '.join(names) or 'none'})")
    if explicit and not names:
        return [], {}
    specs: list[ControllerSpec] = []
    skipped: dict[str, str] = {}
    for name in names:
        if name not in known:
            raise ValueError(f"unknown controller {name!r}; registered: {', '.join(sorted(known))}")
        kwargs = dict(config.controller_kwargs.get(name, {}))
        if config.q_scale != 1.0 and "Q" not in kwargs and _takes_argument(name, "Q"):
            kwargs["Q"] = [config.q_scale] * Kinematics(config.robot).task_dim  # the cost's Q, as a diagonal
        try:
            policies = [
                make_policy(name, policy_context(config.robot, config.dt, task), **kwargs) for task in config.tasks
            ]
        except Exception as exc:
            reason = f"cannot be built from a PolicyContext with arguments {kwargs}: {type(exc).__name__}: {exc}"
            if explicit or name in config.controller_kwargs:
                raise ValueError(f"controller {name!r} {reason}") from exc
            skipped[name] = reason
            continue
        knob = getattr(type(policies[0]), "effort_parameter", None)
        value = _knob_value(policies[0], knob) if knob else None
        if config.match_effort and (knob is None or value is None):
            reason = (
                "declares no effort_parameter (needed for --match-effort)"
                if knob is None
                else f"its effort_parameter {knob!r} is not a scalar attribute of the policy"
            )
            if explicit or name in config.controller_kwargs:
                raise ValueError(f"controller {name!r} {reason}; run it with --no-match-effort")
            skipped[name] = reason
            continue
        specs.append(ControllerSpec(name, kwargs, knob, value, controller_input_hashes(policies, kwargs)))
    if not specs and not config.wants_optimal:
        raise ValueError(f"no controller to evaluate (left out: {skipped})")
    return specs, skipped


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
    chunks = [
        (config.robot, space, config.seed, task, list(range(start, min(start + GENERATION_CHUNK, config.samples))))
        for task in config.tasks
        for start in range(0, config.samples, GENERATION_CHUNK)
    ]
    drawn: dict[int, list[EvaluationSample]] = dict(executor.run(_generate_chunk, chunks))
    samples: dict[str, list[EvaluationSample]] = {task: [] for task in config.tasks}
    for index in range(len(chunks)):
        samples[chunks[index][3]].extend(drawn[index])
    return samples


class Progress:
    """Progress over rollouts: a tqdm bar on a terminal, plain lines elsewhere, nothing when disabled.

    Where stderr is a terminal the bar is drawn there; where it is not (a log file, CI) tqdm
    stays off and :class:`~snac_gym.progress.ProgressLines` writes lines such as
    ``evaluate: 500/1000 rollouts (50 %), 12.3 s, matching effort: lqr`` to stderr, every 10 %
    of the rollouts or 10 s, whichever comes first. ``enabled=False`` (``--no-progress``) writes
    neither.

    Args:
        total: Rollouts expected (grows with :meth:`add_total`).
        enabled: Show progress at all.
        lines: Write plain lines; ``None``: where stderr is not a terminal.
        write: Where the plain lines go (default: one line on stderr, flushed).
        label: Start of each plain line.
    """

    def __init__(
        self,
        total: int,
        enabled: bool,
        lines: bool | None = None,
        write: Callable[[str], None] | None = None,
        label: str = "evaluate:",
    ) -> None:
        import sys

        from tqdm.auto import tqdm

        from snac_gym.progress import ProgressLines, wants_lines

        self._bar = tqdm(total=total, unit="rollout", disable=None if enabled else True, dynamic_ncols=True)
        if lines is None:
            lines = wants_lines(sys.stderr)
        if write is None:
            def write(text: str) -> None:
                print(text, file=sys.stderr, flush=True)

        self._lines = ProgressLines(label, total, write) if enabled and lines else None

    def add_total(self, count: int) -> None:
        """Expect ``count`` more rollouts."""
        self._bar.total += count
        self._bar.refresh()
        if self._lines is not None:
            self._lines.add_total(count)

    def update(self, count: int) -> None:
        """Count ``count`` finished rollouts (a line follows where one is due)."""
        self._bar.update(count)
        if self._lines is not None:
            self._lines.update(count)

    def status(self, text: str) -> None:
        """What runs now (the bar's postfix, the end of the next line); ``""`` clears it."""
        self._bar.set_postfix_str(text, refresh=True)
        if self._lines is not None:
            self._lines.detail = text

    def close(self) -> None:
        """Close the bar."""
        self._bar.close()


class EvaluationRun:
    """The passes and searches of one run (state shared by :func:`run_evaluation`'s steps)."""

    def __init__(
        self,
        config: EvaluationConfig,
        store: RunStore,
        executor: Any,
        samples: dict[str, list[EvaluationSample]],
        progress: Progress,
    ) -> None:
        self.config, self.store, self.executor, self.samples, self.progress = config, store, executor, samples, progress
        #: Screening samples of each (task, controller)'s first knob search.
        self.screening_counts: dict[tuple[str, str], int] = {}
        #: Wall time spent per phase, s.
        self.timings: dict[str, float] = {}
        #: Cut each knob-search evaluation into at least one job per worker (set while fewer
        #: searches than workers run at once, so that none is left idle).
        self.spread_searches = True
        #: Set when one concurrent effort match failed or was interrupted: the others stop.
        self.cancelled = threading.Event()
        self._active_searches = 0
        self._searches_lock = threading.Lock()

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
            raise _Cancelled("stopped because another effort match failed or the run was interrupted")

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
            if any(future.done() and future.exception() is not None for future in futures):
                self.cancelled.set()
                wait(futures)
                errors = [future.exception() for future in futures if future.exception() is not None]
                # The failure itself, not the cancellations it caused in the other pipelines.
                raise next((e for e in errors if not isinstance(e, _Cancelled)), errors[0])
            return [future.result() for future in futures]
        except BaseException as exc:
            self.cancelled.set()
            if not isinstance(exc, Exception):
                # Ctrl-C: end the workers now, so that the other pipelines' waits end with them
                # instead of after their running jobs.
                self.executor.terminate()
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

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
        return [
            RolloutJob(
                task=task,
                controller=controller,
                kwargs=dict(kwargs),
                samples=tuple(samples[i : i + size]),
                seeds=tuple(policy_seed(self.config.seed, task, s.index) for s in samples[i : i + size]),
                steps=steps,
                dt=self.config.dt,
                robot=self.config.robot,
                backend=self.config.backend,
                keep_logs=keep_logs,
                use_batch=self.config.use_batch,
                convention=self.config.convention,
            )
            for i in range(0, len(samples), size)
        ]

    def run_passes(self, passes: Sequence[tuple[str, ControllerSpec, dict[str, Any]]]) -> list[pd.DataFrame]:
        """Full passes (every sample, full horizon); finished jobs are stored as they arrive."""
        self._check_cancelled()
        config = self.config
        todo: list[tuple[RolloutJob, Path, ControllerSpec]] = []
        paths: list[list[Path]] = []
        for task, spec, kwargs in passes:
            steps = config.steps(task)
            key = settings_key(kwargs, steps, config.backend)
            jobs = self._jobs(task, spec.name, kwargs, self.samples[task], steps, config.save_trajectories)
            pass_paths = []
            for chunk, job in enumerate(jobs):
                path = self.store.part_path(task, spec.name, key, chunk)
                pass_paths.append(path)
                if self.store.has_part(path, [s.index for s in job.samples]):
                    self.progress.update(len(job.samples))
                else:
                    todo.append((job, path, spec))
            paths.append(pass_paths)
        for index, result in self.executor.run(run_job, [job for job, _, _ in todo], priority=PASS_PRIORITY):
            job, path, spec = todo[index]
            self._store_job(job, spec, result, path)
            self.progress.update(len(job.samples))
        return [pd.concat([self.store.read_part(p) for p in pass_paths], ignore_index=True) for pass_paths in paths]

    def run_optimal(self) -> list[pd.DataFrame]:
        """The ``optimal`` rows of every task (jobs of :data:`OPTIMAL_CHUNK_SIZE` samples at most, stored as they arrive)."""
        started = time.perf_counter()
        config = self.config
        todo: list[tuple[OptimalJob, Path]] = []
        paths: list[list[Path]] = []
        size = min(config.chunk_size, OPTIMAL_CHUNK_SIZE)
        self.progress.status("optimal reference")
        for task in config.tasks:
            steps = config.steps(task)
            key = settings_key({}, steps, config.backend)
            samples = self.samples[task]
            task_paths = []
            for chunk, i in enumerate(range(0, len(samples), size)):
                part = tuple(samples[i : i + size])
                job = OptimalJob(
                    task=task,
                    samples=part,
                    seeds=tuple(policy_seed(config.seed, task, s.index) for s in part),
                    steps=steps,
                    dt=config.dt,
                    robot=config.robot,
                    keep_logs=config.save_trajectories,
                    convention=config.convention,
                )
                path = self.store.part_path(task, OPTIMAL, key, chunk)
                task_paths.append(path)
                if self.store.has_part(path, [s.index for s in part]):
                    self.progress.update(len(part))
                else:
                    todo.append((job, path))
            paths.append(task_paths)
        for index, result in self.executor.run(run_optimal_job, [job for job, _ in todo]):
            job, path = todo[index]
            if result.logs is not None:
                for log, sample in zip(result.logs, job.samples, strict=True):
                    self.store.write_trajectory(log, job.task, OPTIMAL, sample.index)
            rows = result.metrics
            rows.insert(0, "task", job.task)
            rows.insert(1, "controller", OPTIMAL)
            rows.insert(3, "seed", np.array(job.seeds, dtype=np.int64))
            rows["effort_parameter"] = ""
            rows["effort_value"] = np.nan
            rows["backend"] = config.backend
            rows["horizon"] = job.steps * job.dt
            self.store.write_part(path, rows)
            self.progress.update(len(job.samples))
        self.timings["optimal"] = self.timings.get("optimal", 0.0) + time.perf_counter() - started
        self.progress.status("")
        return [pd.concat([self.store.read_part(p) for p in task_paths], ignore_index=True) for task_paths in paths]

    def _store_job(self, job: RolloutJob, spec: ControllerSpec, result: JobResult, path: Path) -> None:
        if result.logs is not None:
            for log, sample in zip(result.logs, job.samples, strict=True):
                self.store.write_trajectory(log, job.task, job.controller, sample.index)
        rows = result.metrics
        knob_value = job.kwargs.get(spec.knob, spec.knob_value) if spec.knob else None
        rows.insert(0, "task", job.task)
        rows.insert(1, "controller", job.controller)
        rows.insert(3, "seed", np.array(job.seeds, dtype=np.int64))
        rows["effort_parameter"] = spec.knob or ""
        rows["effort_value"] = np.nan if knob_value is None else float(knob_value)
        rows["backend"] = job.backend
        rows["horizon"] = job.steps * job.dt
        self.store.write_part(path, rows)

    def measure(
        self, task: str, spec: ControllerSpec, kwargs: dict[str, Any], samples: Sequence[EvaluationSample], steps: int
    ) -> pd.DataFrame:
        """Metrics of short or partial rollouts for the knob search (not stored as results)."""
        self._check_cancelled()
        jobs = self._jobs(task, spec.name, kwargs, samples, steps, keep_logs=False, spread=True)
        parts = dict(self.executor.run(run_job, jobs, priority=SEARCH_PRIORITY))
        return pd.concat([parts[i].metrics for i in range(len(jobs))], ignore_index=True)

    def _screening_count(self, task: str, spec: ControllerSpec, search_steps: int, round_number: int) -> int:
        """How many of the first samples a search runs on (later rounds keep the first round's count).

        ``calibration_samples`` if given; otherwise every sample when the search's rollouts are
        short, fewer when they are long, so that one evaluation costs about the statistic's
        ``screening_budget`` of a full pass (never fewer than :data:`MIN_SCREENING_SAMPLES`).
        """
        if round_number > 1:
            key = (task, spec.name)
            if key not in self.screening_counts:  # resumed after the first round
                self.screening_counts[key] = int(
                    self.store.calibration[f"{task}/{spec.name}/search1"]["screening_samples"]
                )
            return self.screening_counts[key]
        count = len(self.samples[task])
        if self.config.calibration_samples:
            return min(count, self.config.calibration_samples)
        fraction = self.config.statistic.screening_budget
        budget = math.ceil(fraction * count * self.config.steps(task) / search_steps)
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

        The screening samples are the first ones of the set (:meth:`_screening_count`), or
        ``subset`` when given (the critical samples of a ``max`` refinement, with the
        ``horizon`` that covers their peaks). The search's rollouts stop after the steps where
        the effort peaks: a probe of :data:`PEAK_PROBE_SAMPLES` full rollouts at ``start``
        locates the peak, and the search runs twice that step plus 25. For ``median-peak``
        that is the latest peak of the probe, and the horizon doubles whenever some rollout
        peaks in its last quarter (when that calls for fewer screening samples, first round
        only, the search starts again with them). For ``max`` it is the step of the probe's
        highest peak, without doubling: the maximum over a set is almost always the first
        transient of its most demanding sample, and :func:`_match_one` checks the critical
        samples over the full horizon afterwards. (The full pass that follows checks the
        result at full length.)
        """
        config = self.config
        record_key = f"{task}/{spec.name}/search{round_number}"
        stored = self.store.calibration.get(record_key)
        subset_ids = None if subset is None else [int(s.index) for s in subset]
        if (
            stored
            and stored.get("target") == target
            and stored.get("start") == start
            and stored.get("sample_ids") == subset_ids
        ):
            if subset is None:
                self.screening_counts[(task, spec.name)] = int(stored["screening_samples"])
            return EffortMatch(
                stored["value"],
                stored["effort"],
                target,
                stored["matched"],
                [tuple(e) for e in stored["evaluations"]],
                stored["reason"],
            )
        samples = self.samples[task] if subset is None else list(subset)
        full_steps = config.steps(task)
        started = time.perf_counter()
        statistic = config.statistic
        if horizon is None:
            kwargs = {**spec.kwargs, spec.knob: start}
            probe = self.measure(task, spec, kwargs, samples[:PEAK_PROBE_SAMPLES], full_steps)
            if statistic.is_maximum:
                peak_step = int(probe[statistic.step_column].iloc[int(np.argmax(probe[statistic.column].to_numpy()))])
            else:
                peak_step = int(probe[statistic.step_column].max())
            horizon = min(full_steps, 2 * peak_step + 25)
        while True:
            count = len(samples) if subset is not None else self._screening_count(task, spec, horizon, round_number)
            search = _KnobSearch(self, task, spec, samples[:count], horizon, full_steps, round_number)
            try:
                match = match_effort(search.effort_at, target, start, config.effort_tolerance / 4)
                break
            except _FewerSamplesNeeded:
                horizon = search.horizon
        if subset is None:
            self.screening_counts[(task, spec.name)] = count
        self.store.save_calibration(
            record_key,
            {
                "sample_ids": subset_ids,
                "target": target,
                "start": start,
                "value": match.value,
                "effort": match.effort,
                "matched": match.matched,
                "evaluations": match.evaluations,
                "reason": match.reason,
                "screening_samples": count,
                "search_steps": search.horizon,
                "seconds": round(time.perf_counter() - started, 3),
            },
        )
        return match


class _Cancelled(RuntimeError):
    """An effort match stopped because another one failed or the run was interrupted."""


class _FewerSamplesNeeded(Exception):
    """A knob search's rollouts grew so long that it should start again on fewer samples."""


class _KnobSearch:
    """The effort of one knob value on the screening samples, over rollouts cut after the peak."""

    def __init__(
        self,
        evaluation: EvaluationRun,
        task: str,
        spec: ControllerSpec,
        screening: Sequence[EvaluationSample],
        horizon: int,
        full_steps: int,
        round_number: int,
    ) -> None:
        self.evaluation, self.task, self.spec, self.screening = evaluation, task, spec, screening
        self.horizon, self.full_steps, self.round_number = horizon, full_steps, round_number

    def effort_at(self, value: float) -> float:
        """The effort statistic at knob ``value`` (for a median, lengthening the rollouts while peaks come late)."""
        evaluation, spec = self.evaluation, self.spec
        statistic = evaluation.config.statistic
        while True:
            rows = evaluation.measure(self.task, spec, {**spec.kwargs, spec.knob: value}, self.screening, self.horizon)
            late = rows[statistic.step_column] >= self.horizon - max(10, self.horizon // 4)
            if statistic.is_maximum or self.horizon >= self.full_steps or not late.any():
                return statistic.of(rows)
            self.horizon = min(self.full_steps, 2 * self.horizon)
            if evaluation._screening_count(self.task, spec, self.horizon, self.round_number) < len(self.screening):
                raise _FewerSamplesNeeded


def _within(effort: float, target: float, tolerance: float) -> bool:
    return abs(effort / target - 1.0) <= tolerance


def _match_controllers(
    evaluation: EvaluationRun, specs: list[ControllerSpec], results: dict[tuple[str, str], pd.DataFrame]
) -> dict[tuple[str, str], EffortRecord]:
    """Step 4 of the module docstring; fills ``results`` with the final pass of every (task, controller).

    After the reference passes, every other (task, controller) is matched on its own
    (:func:`_match_one`), all at the same time: the workers run one controller's full pass
    while another's knob search is still going.
    """
    config = evaluation.config
    names = [s.name for s in specs]
    records: dict[tuple[str, str], EffortRecord] = {}
    reference = None
    if config.effort_target is None:
        reference = config.effort_reference if config.effort_reference in names else names[0]
    targets: dict[str, float] = {}
    if reference is not None:
        ref_spec = specs[names.index(reference)]
        note = (
            ""
            if reference == config.effort_reference
            else f"{config.effort_reference!r} is not evaluated; {reference!r} is the reference"
        )
        started = time.perf_counter()
        evaluation.progress.status(f"reference: {reference}")
        passes = evaluation.run_passes([(task, ref_spec, ref_spec.kwargs) for task in config.tasks])
        evaluation.timings["reference passes"] = time.perf_counter() - started
        for task, rows in zip(config.tasks, passes, strict=True):
            results[(task, reference)] = rows
            targets[task] = config.statistic.of(rows)
            records[(task, reference)] = EffortRecord(
                task, reference, "reference", ref_spec.knob, ref_spec.knob_value, targets[task], targets[task], 1, note
            )
    else:
        targets = {task: float(config.effort_target) for task in config.tasks}

    pending = [(task, spec) for task in config.tasks for spec in specs if spec.name != reference]
    evaluation.spread_searches = len(pending) < max(1, config.workers)
    evaluation.progress.status(f"matching effort: {', '.join(dict.fromkeys(s.name for _, s in pending))}")
    started = time.perf_counter()
    outcomes = evaluation.concurrently(
        [functools.partial(_match_one, evaluation, task, spec, targets[task]) for task, spec in pending]
    )
    evaluation.timings["effort matching"] = time.perf_counter() - started
    evaluation.progress.status("")
    for (task, spec), (rows, record) in zip(pending, outcomes, strict=True):
        results[(task, spec.name)] = rows
        records[(task, spec.name)] = record
    return records


def _match_one(evaluation: EvaluationRun, task: str, spec: ControllerSpec, target: float) -> tuple[pd.DataFrame, EffortRecord]:
    """Search one controller's knob for ``target`` on one task, then check it with a full pass.

    The search runs on screening samples (:meth:`EvaluationRun.search_knob`); what follows the
    full pass depends on the statistic:

    * ``max``: the maximum over the set can come from a sample the search did not screen, and
      at a ceiling (a velocity limit) the full pass cannot tell a knob that is more aggressive
      than needed. If each rollout's peak grows with the knob, only the *critical* samples,
      those whose peak reached the search's threshold in the full pass, can reach it at a
      smaller knob; so when some critical sample was not screened, or peaked after the
      search's cut, the search is refined on the critical samples alone (over rollouts that
      cover their peaks), from the value found down, which gives the smallest knob for the
      whole set, and a full pass at it ends the match.
    * ``median-peak``: if the full pass misses the target by more than the tolerance although
      the search matched on the screening samples, the screening target is corrected by the
      observed ratio and the search repeats from the value found.

    At most ``MAX_MATCH_ROUNDS`` full passes are run.

    Returns:
        The last full pass's rows and the record of how the effort was set.
    """
    config = evaluation.config
    statistic = config.statistic
    samples = evaluation.samples[task]
    search_target, start = target, float(spec.knob_value)
    subset: list[EvaluationSample] | None = None
    horizon: int | None = None
    for round_number in range(1, MAX_MATCH_ROUNDS + 1):
        if round_number > 1:
            evaluation.progress.add_total(len(samples))
        with evaluation.searching():
            match = evaluation.search_knob(task, spec, search_target, start, round_number, subset, horizon)
        rows = evaluation.run_passes([(task, spec, {**spec.kwargs, spec.knob: match.value})])[0]
        effort = statistic.of(rows)
        # A failed search is never "matched", even when the full pass happens to land within the
        # tolerance: the knob it reports is then not one that was searched for.
        matched = match.matched and _within(effort, target, config.effort_tolerance)
        last_round = round_number == MAX_MATCH_ROUNDS
        if statistic.is_maximum and match.matched and not last_round:
            threshold = search_target * (1.0 - config.effort_tolerance / 4)
            critical_rows = rows[rows[statistic.column] >= threshold]
            critical = set(critical_rows["sample"].astype(int))
            searched = evaluation.store.calibration[f"{task}/{spec.name}/search{round_number}"]
            screened = (
                set(searched["sample_ids"])
                if searched["sample_ids"] is not None
                else {s.index for s in samples[: searched["screening_samples"]]}
            )
            latest_peak = int(critical_rows[statistic.step_column].max()) if len(critical_rows) else 0
            if not critical <= screened or latest_peak >= searched["search_steps"]:
                subset = [s for s in samples if s.index in critical]
                horizon = min(config.steps(task), 2 * latest_peak + 25)
                start = match.value
                continue
        note = ""
        if not matched:
            if not match.matched:
                note = f"knob search failed: {match.reason}; the full pass reached {effort:.4g} (target {target:.4g})"
            elif not statistic.is_maximum and not last_round:
                # The screening samples mis-predict the whole set by effort/match.effort: aim off by as much.
                search_target = search_target * match.effort / effort
                start = match.value
                continue
            else:
                note = f"not within {config.effort_tolerance:.0%} after {round_number} passes"
        role = "matched" if matched else "unmatched"
        return rows, EffortRecord(task, spec.name, role, spec.knob, match.value, effort, target, round_number, note)
    raise AssertionError("unreachable: the last round returns")


def export_sample_set(config: EvaluationConfig) -> Path:
    """Only draw (or read and check) the sample set of ``config`` and write it to ``config.export_samples``."""
    if config.export_samples is None:
        raise ValueError("export_samples (--export-samples FILE) is needed to export the samples")
    config.validate()
    kinematics = Kinematics(config.robot)
    space = config.space if config.space is not None else SampleSpace.for_robot(kinematics)
    executor = make_executor(config.workers, config.ray_address)
    try:
        samples = load_samples(config, kinematics, space, executor)
    except BaseException:
        executor.terminate()  # interrupted or failed: do not wait for the jobs still running
        raise
    finally:
        executor.close()
    return write_samples_csv(
        [s for task in config.tasks for s in samples[task]], config.export_samples, kinematics.n_joints
    )


def run_evaluation(config: EvaluationConfig) -> pd.DataFrame:
    """Run the evaluation described by ``config`` and write its outputs to ``config.out``.

    Returns:
        The results table (one row per task, controller and sample), as written to
        ``results.parquet``.

    Raises:
        ValueError: On a bad option, controller or samples file (the message says which).
        evaluation.store.RunDirectoryError: If ``out`` holds another run (see ``resume``).
    """
    started = time.perf_counter()
    config.validate()
    kinematics = Kinematics(config.robot)
    config.validate_for(kinematics)
    space = config.space if config.space is not None else SampleSpace.for_robot(kinematics)
    specs, skipped = resolve_controllers(config)
    with RunStore(config.out, config.manifest(space, specs), resume=config.resume) as store:
        return _run_in_store(config, kinematics, space, specs, skipped, store, started)


def _run_in_store(
    config: EvaluationConfig,
    kinematics: Kinematics,
    space: SampleSpace,
    specs: list[ControllerSpec],
    skipped: dict[str, str],
    store: RunStore,
    started: float,
) -> pd.DataFrame:
    """:func:`run_evaluation` once its output folder is locked."""
    from evaluation.report import write_reports

    executor = make_executor(config.workers, config.ray_address)
    try:
        samples_started = time.perf_counter()
        samples = load_samples(config, kinematics, space, executor)
        store.begin()  # run.json only now: a run refused for its samples leaves no run behind
        timings = {"samples": time.perf_counter() - samples_started}
        all_samples = [s for task in config.tasks for s in samples[task]]
        write_samples_csv(all_samples, store.root / "samples.csv", kinematics.n_joints)
        if config.export_samples is not None:
            write_samples_csv(all_samples, config.export_samples, kinematics.n_joints)
        progress = Progress((len(specs) + config.wants_optimal) * len(all_samples), config.progress)
        evaluation = EvaluationRun(config, store, executor, samples, progress)
        results: dict[tuple[str, str], pd.DataFrame] = {}
        try:
            if not specs:
                records = {}
            elif config.match_effort:
                records = _match_controllers(evaluation, specs, results)
            else:
                passes = [(task, spec, spec.kwargs) for task in config.tasks for spec in specs]
                records = {}
                passes_started = time.perf_counter()
                rows_of_passes = evaluation.run_passes(passes)
                evaluation.timings["passes"] = time.perf_counter() - passes_started
                for (task, spec, _), rows in zip(passes, rows_of_passes, strict=True):
                    results[(task, spec.name)] = rows
                    records[(task, spec.name)] = EffortRecord(
                        task, spec.name, "fixed", spec.knob, spec.knob_value, config.statistic.of(rows), None
                    )
            if config.wants_optimal:
                for task, rows in zip(config.tasks, evaluation.run_optimal(), strict=True):
                    results[(task, OPTIMAL)] = rows
        finally:
            progress.close()
            timings.update(evaluation.timings)
    except BaseException:
        executor.terminate()  # interrupted or failed: do not wait for the jobs still running
        raise
    finally:
        executor.close()
    names = ([OPTIMAL] if config.wants_optimal else []) + [spec.name for spec in specs]
    order = [(task, name) for task in config.tasks for name in names]
    table = pd.concat([results[key] for key in order], ignore_index=True)
    table = table.sort_values(
        ["task", "controller", "sample"], key=_sort_key(config, names), kind="stable"
    ).reset_index(drop=True)
    table = add_optimality(table)
    table.to_csv(store.root / "results.csv", index=False, float_format="%.17g")
    table.to_parquet(store.root / "results.parquet", index=False)
    timings["total"] = time.perf_counter() - started  # up to the reports
    store.write_text("timings.json", json.dumps({k: round(v, 3) for k, v in timings.items()}, indent=2))
    write_reports(
        store.root,
        table,
        [records[key] for key in order if key in records],
        config,
        skipped,
        config.statistic.description,
        timings,
        getattr(executor, "description", "serial"),
    )
    return table


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


__all__ = ["DEFAULT_HORIZONS", "EvaluationConfig", "export_sample_set", "resolve_controllers", "run_evaluation"]
