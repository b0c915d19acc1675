"""The lockstep rollout engine: B samples stepped together on the exact kinematic model, or on one simulated arm each.

:func:`simulate_kinematic` (the evaluator's default engine, ``--engine kinematic``): θ is integrated exactly from the
command, θₖ₊₁ = θₖ + uₖΔt, with the shared :class:`~snac_gym.model.kinematics.Kinematics`, the paper's kinematic
model. All
samples of a chunk advance in lockstep: one observation array ``(B, d)`` per step, built field by field
with the env's :class:`~snac_gym.observation.ObservationLayout` (e = x − x_d, or the task's own
error for a pose task, see below; x_c = the reference centre, and the measured joint-velocity field = the command held
over the previous step, zero at the start). Policies are driven through
:class:`~snac_gym.policies.base.LockstepPolicies` (the optional batch protocol, or one object per sample). Commands are
clipped to the velocity limits, as the env clips its actions; joint position limits are not enforced (nor are they
by the paper's model).

Any task dimension n (the layout's ``task_dim``): the 3-D position tasks use the position
kinematics and ``e = x − x_d``; a pose task's kinematics (:class:`~snac_gym.model.kinematics.PoseKinematics`,
x = [p; log₃ R]) has its own ``task_error`` (e = [p − p_d; log₃(R R_dᵀ)]), which the engine applies
row by row exactly as the env does (:func:`task_error_function`), so both give the same numbers.

The physics engines, ``mujoco`` and ``pybullet``, step one simulated arm per sample in the same
lockstep loop (:func:`simulate_arms`): MuJoCo replicas sharing one compiled model, or mesh-less
bodies in PyBullet worlds of ten; each rollout is the env's own (``tests/rollout/test_batch.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np

from snac_gym.kernels.compiled import read_only_view
from snac_gym.model.kinematics import joint_step
from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import LockstepPolicies, PolicyContext
from snac_gym.references import Ellipse, Reference
from snac_gym.rollout.batch import RolloutError, Rollouts, summarise_critic_diagnostics

#: Steps between two samples of the critic diagnostics in :func:`simulate_kinematic` (0.2 s at 125 Hz).
DIAGNOSTIC_STRIDE = 25


def reference_trajectories(
    references: Sequence[Reference], times: np.ndarray, dim: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x_d`` and ``ẋ_d`` of every reference at every time, and each reference's centre.

    Calling ``position_and_velocity(t)`` per sample and step would cost more than the rest of a
    lockstep step; this stacks each reference's vectorised ``trajectory(times)``.

    Args:
        references: B references (any task's, mixed or not).
        times: ``(K,)`` times, s.
        dim: The task dimension n (3 for the position tasks, 6 for the pose tasks).

    Returns:
        ``(x_d, xdot_d, centres)`` of shapes ``(B, K, n)``, ``(B, K, n)`` and ``(B, n)``.
    """
    times = np.asarray(times, dtype=float)
    count, steps = len(references), len(times)
    positions = np.empty((count, steps, dim))
    velocities = np.empty((count, steps, dim))
    centres = np.empty((count, dim))
    for i, reference in enumerate(references):
        if not callable(getattr(reference, "trajectory", None)):
            raise TypeError(f"reference {i} is a {type(reference).__name__}, not a reference with a trajectory(times)")
        centres[i] = reference.centre
        positions[i], velocities[i] = reference.trajectory(times)
    return positions, velocities, centres


def step_major_trajectories(
    references: Sequence[Reference], times: np.ndarray, dim: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reference_trajectories` step-major, ``(K, B, n)``, as a lockstep loop reads them (one step of every
    sample at a time): the ellipses all at once (:meth:`~snac_gym.references.Ellipse.trajectories`), any other
    reference by its own ``trajectory(times)``. The same values bit for bit."""
    times = np.asarray(times, dtype=float)
    count, steps = len(references), len(times)
    positions = np.empty((steps, count, dim))
    velocities = np.empty((steps, count, dim))
    centres = np.empty((count, dim))
    ellipses = {i: r for i, r in enumerate(references) if type(r) is Ellipse and dim == 3}
    if ellipses:
        rows = slice(None) if len(ellipses) == count else list(ellipses)
        positions[:, rows], velocities[:, rows] = Ellipse.trajectories(list(ellipses.values()), times)
    done = set(ellipses)
    for i, reference in enumerate(references):
        if not callable(getattr(reference, "trajectory", None)):
            raise TypeError(f"reference {i} is a {type(reference).__name__}, not a reference with a trajectory(times)")
        centres[i] = reference.centre
        if i not in done:
            positions[:, i], velocities[:, i] = reference.trajectory(times)
    return positions, velocities, centres


ErrorFunction = Callable[[np.ndarray, np.ndarray, np.ndarray], Any]


def task_error_function(kinematics: Any) -> ErrorFunction:
    """``error(x, x_d, out)``: writes the task error of each row of ``(B, n)`` ``x`` into ``out``.

    ``np.subtract`` (e = x − x_d) for kinematics without a ``task_error``, the position tasks: the
    very call the engine always made, so their results stay bit for bit the same. A pose task's
    kinematics has a ``task_error(x, x_d)`` of one row (a logarithm, not a difference); it is
    applied row by row, the env's own call (:meth:`~snac_gym.envs.core.TaskEnvCore._pack`), so the
    engine and the env agree exactly rather than to a vectorised formula's rounding.
    """
    row_error = getattr(kinematics, "task_error", None)
    if row_error is None:
        return np.subtract

    def error(x: np.ndarray, x_d: np.ndarray, out: np.ndarray) -> np.ndarray:
        for i in range(len(x)):
            out[i] = row_error(x[i], x_d[i])
        return out

    return error


def _measured(arms: Any) -> tuple[np.ndarray, np.ndarray]:
    """The arms' measured θ and θ̇ as the engine's own arrays (C-ordered float64, writeable), as the compiled
    observation takes them."""
    q, qdot = arms.joint_state()
    return np.array(q, dtype=float, order="C"), np.array(qdot, dtype=float, order="C")


Observer = Callable[..., np.ndarray]


def _observer(layout: Any, m: int, n: int) -> Observer:
    """``observe(q, qdot, x, x_d, xdot_d, e, x_c)``: a new ``(B, d)`` observation array of the fields.

    The compiled one (:func:`snac_gym.kernels.lockstep.observations`) where ``layout`` places them as
    :class:`~snac_gym.observation.ObservationLayout` does; for any other, the fields copied where its slices say."""
    standard = ObservationLayout(m, n)
    if layout.size == standard.size and layout.slices == standard.slices:
        from snac_gym.kernels.lockstep import observations  # numba: imported where first needed

        return observations

    def observe(*values: np.ndarray) -> np.ndarray:
        obs = np.empty((len(values[0]), layout.size))
        for name, value in zip(ObservationLayout.FIELDS, values, strict=True):
            obs[:, layout.slices[name]] = value
        return obs

    return observe


def _check_commands(
    commands: np.ndarray, expected: tuple[int, int], label: str, samples: Sequence[Any], k: int
) -> None:
    if commands.shape != expected:
        raise RolloutError(f"{label}: act returned commands of shape {commands.shape} at step {k}, expected {expected}")
    finite = np.isfinite(commands)
    if finite.all():  # one flat pass: a reduction over each row of 6 costs 5x more
        return
    bad = ~finite.all(axis=1)
    if bad.any():
        sample = samples[int(np.flatnonzero(bad)[0])]
        raise RolloutError(f"{label}: non-finite command at step {k} of {sample.task} sample {sample.index}")


def simulate_kinematic(
    context: PolicyContext,
    make_policy: Callable[[], Any],
    samples: Sequence[Any],
    steps: int,
    seeds: Sequence[int],
    use_batch: bool = True,
    label: str = "policy",
    keep_states: bool = True,
    plant: Any = None,
    arms: Any = None,
) -> Rollouts:
    """Roll out ``samples`` for ``steps`` control steps on the exact kinematic model (or ``arms``), in lockstep.

    Args:
        context: The policy context (kinematics, Δt, limits, layout, task).
        make_policy: Builds one policy object for ``context``.
        samples: The B samples (all of ``context.task``): each has ``q0``, ``reference``,
            ``task`` and ``index`` (an :class:`~snac_gym.evaluation.samples.EvaluationSample`).
        steps: Control steps K per rollout.
        seeds: Reset seed of each sample's policy.
        use_batch: Use a policy's batch protocol when it has one.
        label: Name used in error messages (the controller).
        keep_states: Log θₖ and xₖ too (the per-step logs need them; the metrics only need the
            commands and errors, and leaving them out saves a third of the memory traffic).
        plant: The kinematics the arm moves by (default ``context.kinematics``); a policy given a
            wrong model (``--model-error``) gets it in ``context`` while the plant stays true.
        arms: Simulated arms, one per sample (an :class:`~snac_gym.physics.ArmBatch`), stepped instead
            of the exact model: θ and θ̇ are then what each arm measures, as in the env of that arm,
            and x is ``plant``'s forward kinematics of the measured θ (the env's). The physics
            engines' path (:func:`simulate_arms`).

    Raises:
        RolloutError: If the policy returns a command of the wrong shape or a NaN/inf.
    """
    _check_run(steps, seeds, samples)
    kinematics = context.kinematics if plant is None else plant
    layout, dt = context.layout, float(context.dt)
    limits = np.asarray(context.velocity_limits, dtype=float)
    count, m, n = len(samples), layout.n_joints, layout.task_dim
    times = np.arange(steps + 1) * dt
    # Read one step of every sample at a time below: step-major, each read is one block, not B rows strided by the
    # horizon (a third of the loop's own time on a tracking horizon). The rollouts get sample-major views of them.
    x_d, xdot_d, centres = step_major_trajectories([s.reference for s in samples], times, n)
    task_error = task_error_function(kinematics)

    q = np.array([s.q0 for s in samples], dtype=float).reshape(count, m)
    held = np.zeros((count, m))
    qdot = held  # the joint-velocity field: the held command on the exact model, the arm's measurement else
    if arms is not None:
        if len(arms) != count:
            raise ValueError(f"need one arm per sample, got {len(arms)} arms for {count} samples")
        arms.reset(q)
        q, qdot = _measured(arms)
    # Logged step-major, so that each step writes one contiguous block; transposed once at the end.
    u_log = np.empty((steps, count, m))
    e_log = np.empty((steps, count, n))
    q_log = np.empty((steps, count, m)) if keep_states else None
    x_log = np.empty((steps, count, n)) if keep_states else None
    observe = _observer(layout, m, n)
    limits_view = read_only_view(limits)
    policies = LockstepPolicies(make_policy, seeds, use_batch=use_batch)
    critic = policies.critic
    # Critic diagnostics every DIAGNOSTIC_STRIDE steps and at the last one: the per-rollout median
    # and final value need no more, and a full pass stays within a few % of its time.
    diagnostic_steps = set(range(0, steps, DIAGNOSTIC_STRIDE)) | {steps - 1} if critic is not None else set()
    diagnostic_rows: list[dict[str, np.ndarray]] = []
    from snac_gym.kernels.lockstep import hold_commands  # numba: imported where first needed

    for k in range(steps):
        x = read_only_view(kinematics.forward_batch(q))
        task_error(x, x_d[k], e_log[k])
        obs = observe(q, qdot, x, x_d[k], xdot_d[k], e_log[k], centres)  # fresh each step: a policy may keep a view
        if k in diagnostic_steps:
            diagnostic_rows.append(critic(q, e_log[k], x_d[k], xdot_d[k], centres, policies.critic_weights()))
        commands = policies.act(obs)
        # The shape first: the compiled clip reads (B, m) as it is told.
        if np.shape(commands) != (count, m) or not hold_commands(read_only_view(commands), limits_view, u_log[k]):
            _check_commands(commands, (count, m), label, samples, k)
        held = u_log[k]  # np.minimum(np.maximum(commands, -limits), limits), written into the log
        if keep_states:
            q_log[k] = q  # type: ignore[index]
            x_log[k] = x  # type: ignore[index]
        if arms is None:
            q = joint_step(q, held, dt)
            qdot = held
        else:
            arms.apply(held)
            q, qdot = _measured(arms)
    final_x = kinematics.forward_batch(q)
    return Rollouts(
        dt=dt,
        times=times[:steps],
        q=_swap_leading_axes(cast(np.ndarray, q_log)) if keep_states else None,  # kept: logged
        commands=_swap_leading_axes(u_log),
        x=_swap_leading_axes(cast(np.ndarray, x_log)) if keep_states else None,
        x_d=x_d[:steps].transpose(1, 0, 2),
        xdot_d=xdot_d[:steps].transpose(1, 0, 2),
        errors=_swap_leading_axes(e_log),
        final_q=q,
        final_x=final_x,
        final_errors=task_error(final_x, x_d[steps], np.empty((count, n))),
        critic_diagnostics=_stack_diagnostics(diagnostic_rows),
        flags=policies.episode_flags(),
    )


def simulate_arms(
    context: PolicyContext,
    make_policy: Callable[[], Any],
    samples: Sequence[Any],
    steps: int,
    seeds: Sequence[int],
    arms: Any,
    plant: Any,
    use_batch: bool = True,
    label: str = "policy",
    keep_states: bool = True,
) -> Rollouts:
    """Roll out ``samples`` on simulated ``arms`` (an :class:`~snac_gym.physics.ArmBatch`, one arm per
    sample) in lockstep: the env's loop, batched.

    Each step is what the env of these arms does (:meth:`~snac_gym.envs.core.TaskEnvCore.step`): the
    command clipped to the velocity limits and held on the arm for one period, the observation
    packed from the arm's measured θ and θ̇ and ``plant``'s forward kinematics of θ; but all samples
    advance together, so the policies act on one ``(B, d)`` array (their batch protocol) and nothing
    of the env's per-step bookkeeping (rewards, info dicts, validation) runs. Arguments:
    :func:`simulate_kinematic`.
    """
    return simulate_kinematic(
        context, make_policy, samples, steps, seeds, use_batch, label, keep_states=keep_states, plant=plant, arms=arms
    )


def _check_run(steps: int, seeds: Sequence[int], samples: Sequence[Any]) -> None:
    if steps < 1:
        raise ValueError(f"steps must be at least 1, got {steps}")
    if len(seeds) != len(samples):
        raise ValueError(f"need one seed per sample, got {len(seeds)} seeds for {len(samples)} samples")


def _stack_diagnostics(rows: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray] | None:
    """Per-rollout summaries of the critic diagnostics sampled during a run (``None`` if none were)."""
    if not rows:
        return None
    critic_error = np.stack([row["critic_error"] for row in rows], axis=1) if "critic_error" in rows[0] else None
    return summarise_critic_diagnostics(
        np.stack([row["hjb_residual"] for row in rows], axis=1),
        np.stack([row["hjb_ratio"] for row in rows], axis=1),
        critic_error,
    )


def _swap_leading_axes(array: np.ndarray) -> np.ndarray:
    """Contiguous ``(A, B, d)`` → contiguous ``(B, A, d)``, the same values: the logs from step-major to sample-major,
    the references the other way.

    Each d-vector is moved as one opaque record: NumPy's transposing copy of the float array
    itself loops over the short last axis element by element, 2.5 times slower on the evaluator's logs.
    """
    rows, columns, width = array.shape
    records = np.ascontiguousarray(array).view(np.dtype((np.void, width * array.itemsize))).reshape(rows, columns)
    return np.ascontiguousarray(records.T).view(array.dtype).reshape(columns, rows, width)
