"""The two ways a chunk of samples is rolled out: exact kinematics, or the PyBullet env.

``kinematic`` (default): θ is integrated exactly from the command, θₖ₊₁ = θₖ + uₖΔt, with the
shared :class:`~snac_gym.kinematics.Kinematics`, the paper's kinematic model. All samples of a
chunk advance in lockstep: one observation array ``(B, d)`` per step, built field by field
with the env's :class:`~snac_gym.observation.ObservationLayout` (e = x − x_d, x_c = the
reference centre, and the measured joint-velocity field = the command held over the previous
step, zero at the start). Policies are driven through :class:`~evaluation.drivers.LockstepPolicies`
(the optional batch protocol, or one object per sample). Commands are clipped to the velocity
limits, as the env clips its actions; joint position limits are not enforced (nor are they
by the paper's model).

``pybullet``: every sample is one episode of the Gymnasium env (physics, motors), run with
:func:`snac_gym.rollout.rollout`, the same loop as the demo.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from evaluation.drivers import LockstepPolicies
from evaluation.reference_batch import reference_trajectories
from evaluation.rollouts import Rollouts, rollouts_from_logs, summarise_critic_diagnostics
from evaluation.samples import EvaluationSample
from snac_gym.policies.base import PolicyContext

BACKENDS = ("kinematic", "pybullet")
#: Env id of each task (the pybullet backend).
#: Steps between two samples of the critic diagnostics in :func:`simulate_kinematic` (0.2 s at 125 Hz).
DIAGNOSTIC_STRIDE = 25
ENV_ID_OF_TASK = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}


class RolloutError(RuntimeError):
    """A policy returned an unusable command; the message names the controller, sample and step."""


def _check_commands(
    commands: np.ndarray, expected: tuple[int, int], label: str, samples: Sequence[EvaluationSample], k: int
) -> None:
    if commands.shape != expected:
        raise RolloutError(f"{label}: act returned commands of shape {commands.shape} at step {k}, expected {expected}")
    bad = ~np.isfinite(commands).all(axis=1)
    if bad.any():
        sample = samples[int(np.flatnonzero(bad)[0])]
        raise RolloutError(f"{label}: non-finite command at step {k} of {sample.task} sample {sample.index}")


def simulate_kinematic(
    context: PolicyContext,
    make_policy: Callable[[], Any],
    samples: Sequence[EvaluationSample],
    steps: int,
    seeds: Sequence[int],
    use_batch: bool = True,
    label: str = "policy",
    keep_states: bool = True,
) -> Rollouts:
    """Roll out ``samples`` for ``steps`` control steps on the exact kinematic model, in lockstep.

    Args:
        context: The policy context (kinematics, Δt, limits, layout, task).
        make_policy: Builds one policy object for ``context``.
        samples: The B samples (all of ``context.task``).
        steps: Control steps K per rollout.
        seeds: Reset seed of each sample's policy.
        use_batch: Use a policy's batch protocol when it has one.
        label: Name used in error messages (the controller).
        keep_states: Log θₖ and xₖ too (the per-step logs need them; the metrics only need the
            commands and errors, and leaving them out saves a third of the memory traffic).

    Raises:
        RolloutError: If the policy returns a command of the wrong shape or a NaN/inf.
    """
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    if len(seeds) != len(samples):
        raise ValueError(f"need one seed per sample, got {len(seeds)} seeds for {len(samples)} samples")
    kinematics, layout, dt = context.kinematics, context.layout, float(context.dt)
    limits = np.asarray(context.velocity_limits, dtype=float)
    count, m, n = len(samples), layout.n_joints, layout.task_dim
    times = np.arange(steps + 1) * dt
    x_d, xdot_d, centres = reference_trajectories([s.reference for s in samples], times)

    q = np.array([s.q0 for s in samples], dtype=float).reshape(count, m)
    held = np.zeros((count, m))
    # Logged step-major, so that each step writes one contiguous block; transposed once at the end.
    u_log = np.empty((steps, count, m))
    e_log = np.empty((steps, count, n))
    q_log = np.empty((steps, count, m)) if keep_states else None
    x_log = np.empty((steps, count, n)) if keep_states else None
    slices = layout.slices
    policies = LockstepPolicies(make_policy, seeds, use_batch=use_batch)
    critic = policies.critic
    # Critic diagnostics every DIAGNOSTIC_STRIDE steps and at the last one: the per-rollout median
    # and final value need no more, and a full pass stays within a few % of its time.
    diagnostic_steps = set(range(0, steps, DIAGNOSTIC_STRIDE)) | {steps - 1} if critic is not None else set()
    diagnostic_rows: list[dict[str, np.ndarray]] = []
    for k in range(steps):
        x = kinematics.forward_batch(q)
        obs = np.empty((count, layout.size))  # fresh each step: a policy may keep a view of its input
        obs[:, slices["q"]] = q
        obs[:, slices["qdot"]] = held
        obs[:, slices["x"]] = x
        obs[:, slices["x_d"]] = x_d[:, k]
        obs[:, slices["xdot_d"]] = xdot_d[:, k]
        np.subtract(x, x_d[:, k], out=e_log[k])
        obs[:, slices["e"]] = e_log[k]
        obs[:, slices["x_c"]] = centres
        if k in diagnostic_steps:
            diagnostic_rows.append(critic(q, e_log[k], x_d[:, k], xdot_d[:, k], centres, policies.critic_weights()))
        commands = policies.act(obs)
        _check_commands(commands, (count, m), label, samples, k)
        held = np.minimum(np.maximum(commands, -limits), limits)
        u_log[k] = held
        if keep_states:
            q_log[k] = q  # type: ignore[index]
            x_log[k] = x  # type: ignore[index]
        q = q + held * dt
    final_x = kinematics.forward_batch(q)
    return Rollouts(
        dt=dt,
        times=times[:steps],
        q=_sample_major(q_log) if keep_states else None,
        commands=_sample_major(u_log),
        x=_sample_major(x_log) if keep_states else None,
        x_d=x_d[:, :steps],
        xdot_d=xdot_d[:, :steps],
        errors=_sample_major(e_log),
        final_q=q,
        final_x=final_x,
        final_errors=final_x - x_d[:, steps],
        critic_diagnostics=summarise_critic_diagnostics(
            np.stack([row["hjb_residual"] for row in diagnostic_rows], axis=1),
            np.stack([row["hjb_ratio"] for row in diagnostic_rows], axis=1),
            np.stack([row["critic_error"] for row in diagnostic_rows], axis=1) if "critic_error" in diagnostic_rows[0] else None,
        ) if diagnostic_rows else None,
    )


def _sample_major(log: np.ndarray) -> np.ndarray:
    """``(K, B, d)`` → contiguous ``(B, K, d)``."""
    return np.ascontiguousarray(log.transpose(1, 0, 2))


@functools.lru_cache(maxsize=2)
def _env(robot: str, task: str, dt: float, steps: int) -> Any:
    """One PyBullet env per (robot, task, Δt, episode length) and process, reused across jobs (loading costs ~0.1 s)."""
    import gymnasium as gym

    return gym.make(ENV_ID_OF_TASK[task], robot=robot, dt=dt, max_steps=steps)


def simulate_pybullet(
    robot: str,
    task: str,
    dt: float,
    make_policy: Callable[[Any], Any],
    samples: Sequence[EvaluationSample],
    steps: int,
    seeds: Sequence[int],
) -> tuple[Rollouts, list[Any]]:
    """Roll out ``samples`` one after the other in the PyBullet env of ``task``.

    Args:
        robot: Robot name of the env.
        task: ``"reach"`` or ``"track"``.
        dt: Control period, s.
        make_policy: Builds a policy for an env.
        samples: The samples, each pinned through the env's reset options.
        steps: Control steps per rollout.
        seeds: Seed of each rollout (env and policy reset).

    Returns:
        The stacked rollouts and the per-step logs of :func:`snac_gym.rollout.rollout`.
    """
    from snac_gym.rollout import add_critic_diagnostics, rollout

    env = _env(robot, task, float(dt), int(steps))
    logs = []
    for sample, seed in zip(samples, seeds, strict=True):
        policy = make_policy(env)
        log = add_critic_diagnostics(rollout(env, policy, options=sample.reset_options(), seed=int(seed), steps=steps), policy)
        if len(log) != steps:
            raise RolloutError(f"{task} sample {sample.index}: the env ended after {len(log)} of {steps} steps")
        logs.append(log)
    return rollouts_from_logs(logs), logs
