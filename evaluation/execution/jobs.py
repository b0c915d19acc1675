"""The unit of work: one controller with one knob setting on a chunk of samples.

A :class:`RolloutJob` is plain data (picklable for worker processes and Ray); :func:`run_job`
rolls it out on its engine and returns one metrics row per sample, plus the per-step logs
when asked. It is the only code that runs in the workers.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.samples import EvaluationSample

from snac_gym.control.cost import CostConvention
from snac_gym.metrics import rollout_metrics
from snac_gym.model.kinematics import Kinematics, shared_kinematics, shared_pose_kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.physics.base import SIMULATED
from snac_gym.policies.base import PolicyContext
from snac_gym.policies.registry import make_policy
from snac_gym.rollout import lockstep_arms, simulate_arms, simulate_kinematic
from snac_gym.tasks import task_names
from snac_gym.tasks.pose import is_pose_task, register_pose_tasks


@dataclass(frozen=True)
class RolloutJob:
    """One controller, one set of constructor arguments, a chunk of samples of one task.

    Attributes:
        task: The task's name.
        controller: Registered policy name.
        kwargs: Constructor arguments (the effort knob included).
        samples: The chunk's samples.
        seeds: Each sample's policy (and env) reset seed.
        steps: Control steps per rollout.
        dt: Control period, s.
        robot: Robot name.
        engine: ``"kinematic"``, ``"pybullet"`` or ``"mujoco"``.
        keep_logs: Return the per-step logs.
        use_batch: Let the kinematic engine use a policy's batch protocol.
        convention: The cost the rollouts are scored by.
        model_error: The controller's arm model differs from the plant's by this
            (:mod:`snac_gym.model.model_error` text; ``None``: the true model).
    """

    task: str
    controller: str
    kwargs: dict[str, Any]
    samples: tuple[EvaluationSample, ...]
    seeds: tuple[int, ...]
    steps: int
    dt: float
    robot: str = "ur10"
    engine: str = "kinematic"
    keep_logs: bool = False
    use_batch: bool = True
    convention: CostConvention = field(default_factory=CostConvention)
    model_error: str | None = None


@dataclass
class JobResult:
    """What a job returns: metrics rows (column ``sample`` identifies them) and optional logs."""

    metrics: pd.DataFrame
    logs: list[pd.DataFrame] | None = field(default=None)


def task_kinematics(robot: str, task: str) -> Any:
    """The kinematics of ``task``'s coordinates on ``robot``, shared per process.

    The position kinematics for the position tasks (x = p, n = 3); the pose kinematics for a pose
    task (x = [p; log₃ R], n = 6, and its own ``task_error``), as the task's env builds them. A pose
    task is registered here if it is not yet: a worker that did not inherit the parent's registry
    (Ray, a spawned process) must still resolve its name.
    """
    if is_pose_task(task):
        if task not in task_names():
            register_pose_tasks()
        return shared_pose_kinematics(robot)
    return shared_kinematics(robot)


@functools.lru_cache(maxsize=8)
def model_kinematics(robot: str, model_error: str) -> Kinematics:
    """The wrong arm model a controller is given under ``--model-error`` (one per process and error)."""
    return shared_kinematics(robot).with_model_error(model_error)


def policy_context(robot: str, dt: float, task: str, model_error: str | None = None) -> PolicyContext:
    """The context a policy is built from in the kinematic engine (the env's limits and layout).

    With ``model_error``, its kinematics is the wrong model (:func:`model_kinematics`), which only
    the controller sees: the engine's plant stays :func:`task_kinematics`.
    """
    arm = task_kinematics(robot, task)
    kinematics = arm if model_error is None else model_kinematics(robot, model_error)
    # The limits are the arm's, which the env clips to, whichever robot's model the controller has.
    return PolicyContext(
        kinematics,
        float(dt),
        arm.velocity_limits.copy(),
        ObservationLayout(kinematics.n_joints, kinematics.task_dim),
        task,
        arm=None if model_error is None else robot,
    )


def kinematic_logs(
    rollouts: Any, samples: Sequence[Any], seeds: Sequence[int], attrs: dict[str, Any], limits: np.ndarray
) -> list[Any]:
    """The per-step logs of kinematic-engine rollouts, with the demo's columns and metadata."""
    return [
        rollouts.log(
            i,
            {
                **attrs,
                "sample": s.index,
                "seed": seed,
                "options": s.reset_options(),
                "reference": s.reference.to_dict(),
                "velocity_limits": limits.tolist(),
                "engine": "kinematic",
            },
        )
        for i, (s, seed) in enumerate(zip(samples, seeds, strict=True))
    ]


def run_job(job: RolloutJob) -> JobResult:
    """Roll out ``job`` and measure every rollout (see :mod:`snac_gym.metrics`)."""
    attrs = {"task": job.task, "policy": job.controller, "policy_kwargs": dict(job.kwargs)}
    if job.engine == "kinematic":
        context = policy_context(job.robot, job.dt, job.task, job.model_error)
        make = functools.partial(make_policy, job.controller, context, **job.kwargs)
        rollouts = simulate_kinematic(
            context, make, job.samples, job.steps, job.seeds, job.use_batch, job.controller,
            keep_states=job.keep_logs, plant=task_kinematics(job.robot, job.task),
        )  # fmt: skip
        limits = context.velocity_limits
        logs = kinematic_logs(rollouts, job.samples, job.seeds, attrs, limits) if job.keep_logs else None
    elif job.engine in SIMULATED:  # one simulated arm per sample, in lockstep (the env's physics, batched)
        context = policy_context(job.robot, job.dt, job.task, job.model_error)
        make = functools.partial(make_policy, job.controller, context, **job.kwargs)
        arms, plant = lockstep_arms(job.robot, job.task, job.dt, job.steps, job.engine, len(job.samples))
        try:
            rollouts = simulate_arms(
                context, make, job.samples, job.steps, job.seeds, arms, plant, job.use_batch, job.controller,
                keep_states=True,  # the joint-limit margin needs the measured θₖ (limit_margins rebuilds
                # exact-model ones only)
            )  # fmt: skip
        finally:
            arms.close()  # a job's PyBullet worlds are physics servers: not left to the garbage collector
        limits = context.velocity_limits
        logs = None
        if job.keep_logs:
            logs = kinematic_logs(rollouts, job.samples, job.seeds, attrs, limits)
            for log in logs:
                log.attrs["engine"] = job.engine
    else:
        raise ValueError(f"unknown engine {job.engine!r}")
    kinematics = shared_kinematics(job.robot)
    metrics = rollout_metrics(
        rollouts, job.task, limits, job.convention, (kinematics.lower_limits, kinematics.upper_limits)
    )
    metrics.insert(0, "sample", [s.index for s in job.samples])
    return JobResult(metrics, logs)


#: :func:`time_job` times this long (s) of a job's steps, where its horizon allows: long enough that the timer's and the
#: scheduler's jitter do not count. It tries :data:`TIMED_STEPS` steps first, then four times as many until then.
TIMED_S, TIMED_STEPS = 0.02, 10


def time_job(job: RolloutJob) -> float:
    """Seconds per sample and control step of ``job``'s rollouts on this process (its metrics included), without what a
    job costs whatever its length (the controller built, the rollout set up, the rows measured): the rate at which a
    pass of the same controller goes on one worker, for a run's estimate of its effort matching
    (:func:`snac_gym.evaluation.runner.announce_matching`).

    After a warm-up of one sample and two steps (the kernels loaded, or compiled where a worker had left them to their
    first call, and the controller's first call made), the job is run for two steps, then for more (at most
    ``job.steps``) until the steps beyond the first two last :data:`TIMED_S`; the rate is the difference's."""
    short = min(job.steps, 2)
    run_job(dataclasses.replace(job, samples=job.samples[:1], seeds=job.seeds[:1], steps=short))

    def timed(steps: int) -> float:
        started = time.perf_counter()
        run_job(dataclasses.replace(job, steps=steps))
        return time.perf_counter() - started

    base = timed(short)
    steps, elapsed = short, base
    while steps < job.steps and elapsed - base < TIMED_S:
        steps = min(job.steps, max(TIMED_STEPS, 4 * steps))
        elapsed = timed(steps)
    if steps == short:  # a horizon of one or two steps: no difference to take
        return base / (len(job.samples) * short)
    return max(elapsed - base, 0.0) / (len(job.samples) * (steps - short))
