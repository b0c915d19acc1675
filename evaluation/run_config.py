"""The options of one evaluation, validated: :class:`EvaluationConfig`.

``snac-gym evaluate`` builds one from its command line (the text options are parsed by
:mod:`snac_gym.evaluation.options`); :func:`snac_gym.evaluation.runner.run_evaluation` runs it.
:meth:`EvaluationConfig.validate` checks the options by theme (one small validator each, in the order the error names
the first bad option), :meth:`EvaluationConfig.validate_for` the ones that need the robot, and
:meth:`EvaluationConfig.manifest` lists every input that shapes the results (``run.json``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from snac_gym.evaluation.effort.statistics import DEFAULT_EFFORT_STATISTIC, EffortStatistic, effort_statistic_named
from snac_gym.evaluation.execution.executors import MAX_WORKERS_PER_CPU, max_workers, ray_endpoint
from snac_gym.evaluation.reference.optimum import OPTIMAL, REFERENCE_LIMITS
from snac_gym.evaluation.samples import check_samples_file
from snac_gym.evaluation.store import file_sha1

from snac_gym.common.extras import require_installed
from snac_gym.common.validation import boolean
from snac_gym.control.cost import CostConvention
from snac_gym.model.kinematics import Kinematics, shared_kinematics
from snac_gym.model.model_error import ModelError, refuse_pose_tasks
from snac_gym.physics.base import check_physics, require_engine
from snac_gym.policies import available_policies
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import PAPER_TASKS, get_task, task_names
from snac_gym.tasks.pose import POSE_TASK_NAMES, is_pose_task, register_pose_tasks

#: Default horizon per task, s (each task's ``horizon_s``: at least every controller's 95th-percentile
#: settling time at equal effort on 100 samples, docs/evaluation.md), as registered at import.
DEFAULT_HORIZONS: dict[str, float] = {name: get_task(name).horizon_s for name in PAPER_TASKS}
#: Samples per job of a full pass. The kinematic engine steps a job's samples in lockstep and
#: its per-sample cost falls with the batch up to a few hundred samples (docs/evaluation.md).
DEFAULT_CHUNK_SIZE = 500
#: Longest horizon accepted, s: 50x the default tracking horizon. Rollouts keep per-step arrays,
#: so an unbounded horizon (1e7 s asked for 9.3 GiB) fails late instead of being refused.
MAX_HORIZON_S = 1000.0
#: Memory one sample of one task costs a run, bytes, rounded up: the sample itself (0.7 kB reach,
#: 1.5 kB track, tracemalloc), a 0.4 kB results row per controller (8 controllers and the optimum),
#: held about three times while the parts are read and the results table is assembled.
BYTES_PER_SAMPLE = 16 * 1024


def max_samples() -> int:
    """Largest ``samples`` per task: what half of this machine's memory holds at :data:`BYTES_PER_SAMPLE`.

    A larger count would allocate until the kernel ends the run. Time is the other bound: the
    main command runs about 10 samples a second per task and worker.
    """
    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):  # pragma: no cover - not POSIX
        memory = 8 * 2**30
    return max(1, memory // 2 // BYTES_PER_SAMPLE)


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


@dataclass(frozen=True)
class EvaluationConfig:
    """Options of one evaluation (the ``snac-gym evaluate`` options, by the same names).

    Attributes:
        out: Output directory.
        tasks: Tasks to evaluate (registered task names; default ``("reach", "track")``). Naming a
            pose task (``pose-reach``, ``pose-track``) registers the pose tasks; a run's tasks are
            either all position tasks or all pose tasks (the controllers' Q has one size per run).
        controllers: Registered policy names (``"all"``: every registered one; ``"optimal"``: the reference row);
            ``None``: :data:`~snac_gym.evaluation.controllers.DEFAULT_CONTROLLERS`, Table I's and the baselines
            whose matched knobs ship with the package.
        samples: Random samples per task (ignored with ``samples_file``, whose rows are all used).
        seed: Seed of the sample set and of every policy reset.
        horizons: Rollout length per task, s (missing tasks take their ``Task.horizon_s``).
        engine: ``"kinematic"``, ``"pybullet"`` or ``"mujoco"`` (``snac-gym evaluate --engine``).
        match_effort: Calibrate every controller's effort knob to equal effort.
        effort_reference: Controller whose effort (at its own settings) is the target.
        effort_statistic: What "equal control effort" equalises (:mod:`snac_gym.evaluation.effort.statistics`):
            ``"mean-peak"`` (the default: the mean over samples of each rollout's peak |u|/limit),
            ``"peak-ratio"`` (each rollout's peak relative to the reference's on the same sample),
            ``"median-peak"`` or ``"max"`` (the maximum |u| over the sample set, rad/s).
        effort_target: Explicit target of the effort statistic, in its unit (then every
            controller is matched).
        effort_tolerance: Relative tolerance of the match over the whole sample set.
        effort_samples: Equal effort is matched on the first ``max(samples, effort_samples)``
            samples of the seed's stream, so that a matched knob is a property of the controller
            and not of how many samples are evaluated (the reported rows are still the first
            ``samples``); ``0``: matched on the evaluated samples alone. Not used with
            ``samples_file`` (its rows are the set) or without ``match_effort``.
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
        plots: Draw the figures (``cost_boxplot.png``; ``tradeoff.png`` of a sweep); ``False``: the
            tables and the summary only, and a figure of an earlier run in ``out`` is removed.
        use_batch: Let policies that offer the batch protocol run in lockstep batches.
        cost: The trajectory cost of the comparison (:data:`snac_gym.control.cost.COSTS`): ``"table1"``
            (with the u̇ term) or ``"hjb"`` (``Σ (eᵀQe + uᵀRu) Δt``); ``optimal`` solves for it.
        udot_start: u₋₁ of the u̇ term: ``"rest"`` (0) or ``"first"`` (u₀).
        q_scale: Q = q_scale·I in the cost; controllers whose constructor takes ``Q`` (``snac``,
            ``lqr``, ``snac-hjb``) get the same Q unless ``controller_kwargs`` sets it.
        success_threshold: Success rate a controller must reach to be ranked in the summary.
        model_error: The controllers' arm model differs from the plant's by this
            (:class:`snac_gym.model.model_error.ModelError` text, ``--model-error``); the plant, the cost,
            the success rule and the ``optimal`` reference keep the true model. ``None``: none.
        reference_limits: The constraints of the ``optimal`` reference (:data:`REFERENCE_LIMITS`):
            ``"joints"`` (joint position and velocity limits, the limits the success rule counts) or
            ``"velocity"`` (velocity limits only: the variant that ignores the joints' position limits).
        reference_cache: Reuse the reference's rows cached by sample content
            (:mod:`snac_gym.evaluation.reference.cache`), and store the new ones; ``False``: solve every sample.
        calibration_cache: Reuse the matched knobs of an earlier run with the same effort set, settings and code
            (:mod:`snac_gym.evaluation.effort.cache`), and store new ones; ``False``: neither.
        recalibrate: Match the effort anew and overwrite the cached knobs (``--recalibrate``).
    """

    out: Path
    tasks: tuple[str, ...] = PAPER_TASKS
    controllers: tuple[str, ...] | None = None
    samples: int = 1000
    seed: int = 0
    horizons: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_HORIZONS))
    engine: str = "kinematic"
    match_effort: bool = True
    effort_reference: str = "snac"
    effort_statistic: str = DEFAULT_EFFORT_STATISTIC
    effort_target: float | None = None
    effort_tolerance: float = 0.02
    effort_samples: int = 1000
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
    plots: bool = True
    use_batch: bool = True
    cost: str = "table1"
    udot_start: str = "rest"
    q_scale: float = 1.0
    success_threshold: float = 0.95
    model_error: str | None = None
    reference_limits: str = "joints"
    reference_cache: bool = True
    calibration_cache: bool = True
    recalibrate: bool = False

    @property
    def convention(self) -> CostConvention:
        """The :class:`~snac_gym.control.cost.CostConvention` of ``cost``, ``udot_start`` and ``q_scale``."""
        return CostConvention(self.cost, self.udot_start, self.q_scale)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad option."""
        for check in (
            _check_types,
            _check_selection,
            _check_timing,
            _check_engine,
            _check_effort,
            _check_execution,
            _check_scoring,
            _check_model_error,
        ):
            check(self)

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

    @property
    def effort_set_size(self) -> int | None:
        """Samples per task that equal effort is matched on, when more than the evaluated ones (else ``None``)."""
        extends = self.match_effort and self.samples_file is None and self.effort_samples > self.samples
        return self.effort_samples if extends else None

    def horizon(self, task: str) -> float:
        """Rollout length of ``task``, s."""
        return float(self.horizons.get(task, get_task(task).horizon_s))

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
            "engine": self.engine,
            "match_effort": self.match_effort,
            "effort_reference": self.effort_reference,
            "effort_statistic": self.effort_statistic,
            "effort_target": self.effort_target,
            "effort_tolerance": self.effort_tolerance,
            "effort_samples": self.effort_set_size,
            "calibration_samples": self.calibration_samples,
            "save_trajectories": self.save_trajectories,
            "chunk_size": self.chunk_size,
            "dt": self.dt,
            "robot": self.robot,
            "space": dataclasses.asdict(space),
            "controller_kwargs": {k: dict(v) for k, v in self.controller_kwargs.items()},
            # Only when given, so that runs made before the option existed still resume.
            **({"model_error": self.model_error} if self.model_error is not None else {}),
            "reference_limits": self.reference_limits,
            "use_batch": self.use_batch,
            "cost": self.cost,
            "udot_start": self.udot_start,
            "q_scale": self.q_scale,
        }


# -- validators of EvaluationConfig.validate, in the order of its options ---------------------------
#: The options that are whole numbers, real numbers and switches (``None`` allowed where the default is).
_WHOLE = ("samples", "seed", "effort_samples", "workers", "chunk_size", "calibration_samples")
_REAL = ("effort_tolerance", "dt", "q_scale", "success_threshold", "effort_target")
_SWITCHES = (
    "match_effort",
    "save_trajectories",
    "resume",
    "progress",
    "plots",
    "use_batch",
    "reference_cache",
    "calibration_cache",
    "recalibrate",
)


def _check_types(config: EvaluationConfig) -> None:
    """Exact types first: ``samples=True`` is not one sample, ``dt='0.008'`` not a period, ``plots=1`` not a switch
    (the range checks that follow name the bounds)."""
    optional = {item.name for item in dataclasses.fields(config) if item.default is None}  # None: "the default"
    for name in _WHOLE:
        value = getattr(config, name)
        if value is None and name in optional:
            continue
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            raise ValueError(f"{name} must be a whole number, got {value!r}")
    for name in _REAL:
        value = getattr(config, name)
        if value is None and name in optional:
            continue
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise ValueError(f"{name} must be a real number, got {value!r}")
    if not 0 <= config.seed <= 2**32 - 1:
        raise ValueError(f"seed must be a whole number in [0, {2**32 - 1}] (a NumPy seed), got {config.seed}")
    for name in _SWITCHES:
        boolean(name, getattr(config, name))


def _check_selection(config: EvaluationConfig) -> None:
    """What is evaluated: tasks, controllers, samples."""
    tasks = config.tasks
    _check_pose_tasks(config)
    registered = task_names()
    if not tasks or any(t not in registered for t in tasks) or len(set(tasks)) != len(tasks):
        raise ValueError(f"tasks must be distinct names from {registered}, got {tasks}")
    controllers = config.controllers
    if controllers is not None and (not controllers or len(set(controllers)) != len(controllers)):
        raise ValueError(f"controllers must be distinct names, got {controllers}")
    if config.samples_file is not None:
        check_samples_file(config.samples_file)  # before it is hashed: a device or FIFO never ends
    elif not 1 <= config.samples <= max_samples():
        raise ValueError(
            f"samples must be between 1 and {max_samples()} per task (half of this machine's memory at "
            f"{BYTES_PER_SAMPLE // 1024} kB a sample), got {config.samples}"
        )


def _check_pose_tasks(config: EvaluationConfig) -> None:
    """Register the pose tasks when a run names one, and refuse mixing them with the position tasks
    (the controllers' ``Q``, given by ``q_scale``, has one size per run: 3, or 6 for a pose)."""
    named = [task for task in config.tasks if isinstance(task, str) and is_pose_task(task)]
    if not named:
        return
    register_pose_tasks()
    if len(named) != len(config.tasks):
        raise ValueError(
            f"tasks {tuple(config.tasks)} mix pose tasks {POSE_TASK_NAMES} with position tasks: evaluate "
            "them in separate runs"
        )


def _check_timing(config: EvaluationConfig) -> None:
    """The horizons and the control period."""
    unknown = set(config.horizons) - set(task_names())
    if unknown:
        raise ValueError(f"horizons for unknown task(s) {sorted(unknown)}; tasks are {task_names()}")
    if not (math.isfinite(config.dt) and config.dt > 0):
        raise ValueError(f"dt must be a positive finite number of seconds, got {config.dt}")
    for task in config.tasks:
        if not config.dt <= config.horizon(task) <= MAX_HORIZON_S:
            raise ValueError(
                f"the {task} horizon must be between one control period ({config.dt} s) and "
                f"{MAX_HORIZON_S:g} s, got {config.horizon(task)}"
            )


def _check_engine(config: EvaluationConfig) -> None:
    """The engine, and the optimal reference's need of the kinematic one."""
    check_physics(config.engine, what="engine")
    require_engine(config.engine)  # here, not in a worker after the samples and the effort match
    if config.wants_optimal and config.engine != "kinematic":
        raise ValueError(f"the {OPTIMAL!r} reference is the optimum of the kinematic model; use --engine kinematic")


def _check_effort(config: EvaluationConfig) -> None:
    """The equal-effort options: statistic, target, tolerance, screening samples."""
    effort_statistic_named(config.effort_statistic)
    if config.match_effort and config.effort_target is None:
        if config.effort_reference not in available_policies():
            raise ValueError(
                f"effort_reference {config.effort_reference!r} names no registered controller; "
                f"choose one of {available_policies()}"
            )
    target = config.effort_target
    if target is not None and not (math.isfinite(target) and target > 0):
        raise ValueError(f"effort_target must be a positive finite number, got {target}")
    if target is not None and config.match_effort and config.statistic.paired:
        raise ValueError(
            f"--effort-target has no meaning for the {config.effort_statistic} statistic (a ratio to the "
            "reference's rollouts on the same samples); choose mean-peak, max or median-peak"
        )
    if not 0 < config.effort_tolerance < 1:
        raise ValueError(f"effort_tolerance must be in (0, 1), got {config.effort_tolerance}")
    if not 0 <= config.effort_samples <= max_samples():
        raise ValueError(f"effort_samples must be between 0 and {max_samples()}, got {config.effort_samples}")
    if config.calibration_samples is not None and config.calibration_samples < 1:
        raise ValueError(f"calibration_samples must be at least 1, got {config.calibration_samples}")


def _check_execution(config: EvaluationConfig) -> None:
    """Where and in what pieces the jobs run: workers, chunk size."""
    if config.ray_address is not None and not config.ray_address.strip():  # else read as "no Ray" without a word
        raise ValueError(
            "ray_address must be 'local' or a Ray cluster's address ('auto', 'ray://host:10001'), got an empty string"
        )
    local = config.ray_address in (None, "local")  # a cluster's size is its own
    if config.ray_address is not None and not local:
        ray_endpoint(config.ray_address)  # a malformed address is named before a missing extra
    if config.workers < 1 or (local and config.workers > max_workers()):
        raise ValueError(
            f"workers must be between 1 and {max_workers()} ({MAX_WORKERS_PER_CPU} per available CPU), "
            f"got {config.workers}"
        )
    if not local and config.workers != 1:
        raise ValueError(
            f"--workers {config.workers} has no effect on a Ray cluster ({config.ray_address}): its CPUs run "
            "the jobs; leave --workers out (with --ray local it sets the CPUs of the new instance)"
        )
    if config.ray_address is not None:  # the main process imports Ray later, once the kernels are readied
        require_installed("ray", "ray", "--ray")
    if config.chunk_size < 1:
        raise ValueError(f"chunk_size must be at least 1, got {config.chunk_size}")


def _check_model_error(config: EvaluationConfig) -> None:
    """A model error that parses, on position tasks and the kinematic engine."""
    if config.model_error is None:
        return
    # Built once here, so that what only the build can refuse (another robot's joint count, a link length
    # that a zero-length placement cannot take) is refused before anything is written.
    shared_kinematics(config.robot).with_model_error(ModelError.parse(config.model_error))
    refuse_pose_tasks([task for task in config.tasks if is_pose_task(task)])
    if config.engine != "kinematic":
        raise ValueError("--model-error needs --engine kinematic (the plant is the exact kinematic model)")


def _check_scoring(config: EvaluationConfig) -> None:
    """The cost convention, the success threshold and the output folder."""
    config.convention  # noqa: B018  (validates cost, udot_start and q_scale)
    if not 0.0 <= config.success_threshold <= 1.0:
        raise ValueError(f"success_threshold must be in [0, 1], got {config.success_threshold}")
    if not str(config.out).strip():
        raise ValueError("out (--out) must name a folder, got an empty path")
    if config.reference_limits not in REFERENCE_LIMITS:
        raise ValueError(
            f"reference_limits (--reference-limits) must be one of {REFERENCE_LIMITS}, got {config.reference_limits!r}"
        )


__all__ = [
    "BYTES_PER_SAMPLE",
    "DEFAULT_CHUNK_SIZE",
    "DEFAULT_HORIZONS",
    "MAX_HORIZON_S",
    "EvaluationConfig",
    "max_samples",
]
