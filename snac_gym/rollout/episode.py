"""The env-stepped rollout: one episode of a policy in a snac-gym env (PyBullet or real), logged.

:func:`rollout` drives any env that exposes the snac-gym observation layout (the PyBullet
envs, the real-robot env) with any :class:`~snac_gym.policies.base.Policy` and returns the
trajectory log (:mod:`snac_gym.rollout.log`); :func:`simulate_env` runs a batch of samples
this way and stacks them as :class:`~snac_gym.rollout.batch.Rollouts`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any, cast

import numpy as np
import pandas as pd

from snac_gym.envs import make_task_env
from snac_gym.physics import SIMULATED, ArmList, PyBulletArmBatch, check_physics
from snac_gym.rollout.batch import RolloutError, Rollouts, rollouts_from_logs
from snac_gym.rollout.log import add_critic_diagnostics, jsonable, log_columns


def episode_length(env: Any) -> int:
    """Control steps of ``env``'s episode: its ``TimeLimit``'s (``env.spec.max_episode_steps``),
    else the unwrapped env's ``max_steps`` (a constructed env, the real arm); 0 if neither."""
    spec = getattr(env, "spec", None)
    if spec is not None and spec.max_episode_steps is not None:
        return int(spec.max_episode_steps)
    return int(getattr(getattr(env, "unwrapped", env), "max_steps", 0))


def rollout(
    env: Any,
    policy: Any,
    options: Mapping[str, Any] | None = None,
    seed: int | None = None,
    steps: int | None = None,
    on_step: Callable[[int], object] | None = None,
) -> pd.DataFrame:
    """Run ``policy`` in closed loop on ``env`` for one episode and log every control step.

    The env is reset with ``seed`` and ``options``; the policy with ``seed``. The loop ends
    after ``steps`` control steps, or earlier when the env terminates or truncates (so build
    the env with ``max_episode_steps >= steps`` to run longer than its default episode).

    Args:
        env: A snac-gym env (wrapped or not): its unwrapped form has ``obs_layout`` and ``dt``;
            ``info["command"]`` from ``step`` (when present) is logged as the applied command,
            otherwise the policy's output clipped to ``velocity_limits``.
        policy: Any :class:`~snac_gym.policies.base.Policy`.
        options: The env's ``reset`` options (``q0``, ``target`` or ``ellipse``).
        seed: Seed of both resets; the same seed (and options) gives a bit-identical log.
        steps: Most control steps to run (default: the episode length, :func:`episode_length`).
        on_step: Called with the count of steps run after each one (a progress line's counter).

    Returns:
        The trajectory log (see the module docstring for columns and ``attrs``).

    Raises:
        BaseException: Whatever the env or the policy raises mid-episode (Ctrl-C included)
            propagates unchanged, carrying the rows logged so far as its attribute
            ``rollout_log`` (``attrs["interrupted"]`` names the exception), so that a caller can
            save them (:func:`partial_log`).
    """
    base = getattr(env, "unwrapped", env)
    layout = base.obs_layout
    limits = np.asarray(getattr(base, "velocity_limits", np.full(layout.n_joints, np.inf)), dtype=float)
    horizon = int(steps) if steps is not None else episode_length(env)
    if horizon < 1:
        raise ValueError("steps must be given (and positive) for an env without an episode length")

    obs, _ = env.reset(seed=seed, options=None if options is None else dict(options))
    policy.reset(seed=seed)
    record = _Record(base, layout, horizon, "critic_weights" in getattr(policy, "internals", {}),
                     tuple(getattr(policy, "logged_internals", ())))  # fmt: skip
    terminated = truncated = False
    # An env that can stop the arm for the controller (the real arm's safety layer) hears of a divergence.
    stop_for = getattr(base, "stop_for", None)
    try:
        while record.count < horizon:
            record.state(obs, policy)
            action = policy.act(obs)
            record.scalars(policy)
            divergence = getattr(policy, "internals", {}).get("divergence")
            if divergence and stop_for is not None:
                stop_for(f"the controller diverged: {divergence}")
            obs, _, terminated, truncated, info = env.step(action)
            applied = info.get("command") if isinstance(info, Mapping) else None
            record.command(applied if applied is not None else np.clip(action, -limits, limits))
            if on_step is not None:
                on_step(record.count)
            if terminated or truncated:
                break
    except BaseException as exc:
        exc.rollout_log = record.log(policy, obs, options, seed, limits, terminated, truncated)  # type: ignore[attr-defined]
        cast(Any, exc).rollout_log.attrs["interrupted"] = type(exc).__name__  # the attribute set just above
        raise
    return record.log(policy, obs, options, seed, limits, terminated, truncated)


def partial_log(exc: BaseException) -> pd.DataFrame | None:
    """The rows :func:`rollout` logged before ``exc`` interrupted it (``None`` if it did not come from one)."""
    return getattr(exc, "rollout_log", None)


class _Record:
    """The rows of one rollout as they come; a row counts once its command was applied."""

    def __init__(self, base: Any, layout: Any, horizon: int, with_weights: bool, scalars: tuple[str, ...] = ()) -> None:
        self.base, self.layout = base, layout
        #: Scalar internals the policy names in ``logged_internals``, each after the act of step k.
        self.scalar_names = scalars
        self.scalar_values = np.full((horizon, len(scalars)), np.nan)
        self.times = np.empty(horizon)
        self.observations = np.empty((horizon, layout.size))
        self.commands = np.empty((horizon, layout.n_joints))
        self.weights: list[np.ndarray] | None = [] if with_weights else None
        self.count = 0

    def state(self, obs: np.ndarray, policy: Any) -> None:
        self.times[self.count] = getattr(self.base, "time", self.count * float(self.base.dt))
        self.observations[self.count] = obs
        if self.weights is not None:
            del self.weights[self.count :]  # a row whose command never came
            self.weights.append(np.array(policy.internals["critic_weights"], dtype=float))

    def scalars(self, policy: Any) -> None:
        for column, name in enumerate(self.scalar_names):
            self.scalar_values[self.count, column] = float(policy.internals[name])

    def command(self, applied: np.ndarray) -> None:
        self.commands[self.count] = applied
        self.count += 1

    def log(
        self,
        policy: Any,
        obs: np.ndarray,
        options: Mapping[str, Any] | None,
        seed: int | None,
        limits: np.ndarray,
        terminated: bool,
        truncated: bool,
    ) -> pd.DataFrame:
        layout, base, count, s = self.layout, self.base, self.count, self.layout.slices
        m, n, dt = layout.n_joints, layout.task_dim, float(base.dt)
        obs_rows = self.observations[:count]
        blocks = [self.times[:count, None], obs_rows[:, s["q"]], self.commands[:count]]
        blocks += [obs_rows[:, s[name]] for name in ("x", "x_d", "xdot_d", "e")]
        weights = None if self.weights is None else self.weights[:count]
        n_weights = 0
        if weights:
            n_weights = len(weights[0])
            blocks.append(np.stack(weights))
        log = pd.DataFrame(np.hstack(blocks), columns=log_columns(m, n, n_weights))
        for column, name in enumerate(self.scalar_names):
            log[name] = self.scalar_values[:count, column]
        last = layout.unpack(obs)
        reference = getattr(base, "reference", None)
        log.attrs = {
            "dt": dt,
            "task": getattr(base, "task_name", None),
            "n_joints": m,
            "task_dim": n,
            "seed": seed,
            "options": jsonable(options) if options is not None else None,
            "reference": jsonable(reference.to_dict()) if reference is not None else None,
            "velocity_limits": limits.tolist(),
            "policy": type(policy).__name__,
            "final_t": float(getattr(base, "time", count * dt)),
            "final_q": last.q.tolist(),
            "final_x": last.x.tolist(),
            "final_e": last.e.tolist(),
            "terminated": bool(terminated),
            "truncated": bool(truncated),
        }
        return log


@functools.lru_cache(maxsize=2)
def _env(robot: str, task: str, dt: float, steps: int, physics: str) -> Any:
    """One env per (robot, task, Δt, episode length, physics) and process, reused across jobs (loading costs ~0.1 s)."""
    return make_task_env(task, robot, dt=dt, max_steps=steps, physics=physics)


def lockstep_arms(robot: str, task: str, dt: float, steps: int, physics: str, count: int) -> tuple[Any, Any]:
    """``count`` arms of the env of (robot, task, Δt, physics), for the lockstep engine, and the env's kinematics.

    The env's physics exactly (model, substeps, motors or servos): for ``"mujoco"`` replicas of the
    (cached) env's arm (:meth:`~snac_gym.physics.mujoco.MuJoCoArm.replica`, one ``MjData`` each), for
    ``"pybullet"`` a :class:`~snac_gym.physics.PyBulletArmBatch` with the env's Δt and substeps.

    Raises:
        ValueError: If ``physics`` is not a simulated engine.
    """
    check_physics(physics, SIMULATED, "lockstep arms are simulated: physics")
    core = _env(robot, task, float(dt), int(steps), physics).unwrapped
    if physics == "mujoco":
        return ArmList([core.arm.replica() for _ in range(count)]), core.kinematics
    return PyBulletArmBatch(core.kinematics, core.dt, core.arm.sim.n_substeps, count), core.kinematics


def simulate_env(
    robot: str,
    task: str,
    dt: float,
    make_policy: Callable[[Any], Any],
    samples: Sequence[Any],
    steps: int,
    seeds: Sequence[int],
    physics: str = "pybullet",
) -> tuple[Rollouts, list[Any]]:
    """Roll out ``samples`` one after the other in the env of ``task`` (PyBullet or MuJoCo).

    Args:
        robot: Robot name of the env.
        task: The task's name (its registered env is used).
        dt: Control period, s.
        make_policy: Builds a policy for an env.
        samples: The samples, each pinned through the env's reset options.
        steps: Control steps per rollout.
        seeds: Seed of each rollout (env and policy reset).
        physics: The env's arm model, ``"pybullet"`` or ``"mujoco"`` (``physics=`` of the env).

    Returns:
        The stacked rollouts and the per-step logs of :func:`snac_gym.rollout.rollout`.
    """
    env = _env(robot, task, float(dt), int(steps), physics)
    logs = []
    for sample, seed in zip(samples, seeds, strict=True):
        policy = make_policy(env)
        log = add_critic_diagnostics(
            rollout(env, policy, options=sample.reset_options(), seed=int(seed), steps=steps), policy
        )
        if len(log) != steps:
            raise RolloutError(f"{task} sample {sample.index}: the env ended after {len(log)} of {steps} steps")
        logs.append(log)
    return rollouts_from_logs(logs), logs
