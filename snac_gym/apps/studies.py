"""Research studies of SNAC's open choices: the measurements behind its defaults (docs/snac.md).

Each study runs SNAC over a grid of its options (:class:`~snac_gym.policies.snac.SNACPolicy`)
and returns a table; ``docs/snac.md`` shows the commands and the numbers they gave.
:func:`discretisation_study` and :func:`effort_study` run the paper's demos in the PyBullet
env (:func:`snac_gym.rollout.rollout`); :func:`random_episode_study` runs random episodes on
the exact kinematic model (:func:`snac_gym.rollout.simulate_kinematic`).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import asdict
from typing import TYPE_CHECKING, Any, cast

import gymnasium as gym
import numpy as np
import pandas as pd

from snac_gym.control.cost import trajectory_cost
from snac_gym.metrics import demo_metrics
from snac_gym.policies.base import PolicyContext
from snac_gym.policies.snac import (
    INITIAL_WEIGHT_SCALES,
    LEARNING_RATE_UNITS,
    SCHEDULE_CLOCKS,
    WEIGHT_UPDATES,
    SNACPolicy,
)
from snac_gym.rollout import log_array, rollout, simulate_kinematic
from snac_gym.tasks import Sample, Task, get_task

if TYPE_CHECKING:
    from snac_gym.envs.core import URTaskEnv


def _initial_weight_kwargs(kind: str, scale: float | None) -> tuple[dict[str, Any], float]:
    """SNAC constructor arguments of an initial-weight option, and the scale it resolves to.

    ``("identity", c)``: Ŵ₀ = c on the squared terms (``None``: the policy's default c per
    task, resolved by the caller); ``("uniform", w)``: every weight U(0, w) (``None``: w = 1).
    """
    if kind == "identity":
        return {"initial_weights": "identity", "initial_weight_scale": scale}, scale  # type: ignore[return-value]
    if kind == "uniform":
        high = 1.0 if scale is None else float(scale)
        return {"initial_weights": "uniform", "initial_weight_range": (0.0, high)}, high
    raise ValueError(f"initial weights must be 'identity' or 'uniform', got {kind!r}")


def discretisation_study(
    tasks: tuple[str, ...] = ("reach", "track"),
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4),
    weight_updates: tuple[str, ...] | None = None,
    learning_rate_units: tuple[str, ...] | None = None,
    freeze_options: tuple[bool, ...] = (False, True),
    schedule_clocks: tuple[str, ...] | None = None,
    steps: dict[str, int] | None = None,
    initial_weights: tuple[tuple[str, float | None], ...] = (("identity", None),),
) -> pd.DataFrame:
    """Run the paper's demos with every combination of SNAC's open choices.

    The measurement behind the defaults of :class:`~snac_gym.policies.snac.SNACPolicy`
    (docs/snac.md): for each task, initial-weight option, combination of ``weight_update`` ×
    ``learning_rate_unit`` × ``freeze_when_saturated`` × ``schedule_clock`` and seed, one
    closed-loop run in the PyBullet env from the paper's θ0 to the paper's reference,
    measured with :func:`demo_metrics`. The seed draws random initial weights
    (``"uniform"``); ``"identity"`` weights do not depend on it and the demo is otherwise
    deterministic, so those run the first seed only.

    Args:
        tasks: Demo tasks.
        seeds: Reset seeds.
        weight_updates, learning_rate_units, schedule_clocks: Options to compare (default: all).
        freeze_options: Values of ``freeze_when_saturated``.
        steps: Horizon per task (default: the task's horizon, 1500 reach, 2500 track).
        initial_weights: ``(kind, scale)`` pairs: ``("identity", c)`` gives Ŵ₀ = c on the
            squared terms and 0 on the cross terms (``c=None``: the policy's default for the
            task), ``("uniform", w)`` draws every weight from U(0, w) (``w=None``: 1).

    Returns:
        One row per run: the options, ``initial_weights`` (the kind), ``initial_weight_scale``
        (c or w), ``seed`` and every :class:`DemoMetrics` field.
    """
    import snac_gym  # noqa: F401  (registers the envs)

    rows = []
    for task in tasks:
        spec = get_task(task)
        env = gym.make(spec.env_id)
        horizon = (steps or {}).get(task) or spec.horizon_steps(cast("URTaskEnv", env.unwrapped).dt)
        assert env.spec is not None and env.spec.max_episode_steps is not None  # a registered id's TimeLimit
        if horizon > env.spec.max_episode_steps:
            env.close()
            env = gym.make(spec.env_id, max_episode_steps=horizon)
        combos = itertools.product(
            initial_weights,
            weight_updates or WEIGHT_UPDATES,
            learning_rate_units or LEARNING_RATE_UNITS,
            freeze_options,
            schedule_clocks or SCHEDULE_CLOCKS,
        )
        for (kind, scale), update, unit, freeze, clock in combos:
            if kind == "identity" and scale is None:
                scale = INITIAL_WEIGHT_SCALES[task]
            weight_kwargs, resolved = _initial_weight_kwargs(kind, scale)
            for seed in seeds[:1] if kind == "identity" else seeds:
                policy = SNACPolicy(
                    env,
                    weight_update=update,
                    learning_rate_unit=unit,
                    freeze_when_saturated=freeze,
                    schedule_clock=clock,
                    **weight_kwargs,
                )
                log = rollout(env, policy, options=spec.demo_options(), seed=seed, steps=horizon)
                rows.append(
                    {
                        "task": task,
                        "initial_weights": kind,
                        "initial_weight_scale": resolved,
                        "learning_rate_unit": unit,
                        "freeze_when_saturated": freeze,
                        "weight_update": update,
                        "schedule_clock": clock,
                        "seed": seed,
                        **asdict(demo_metrics(log, spec.success_tolerance)),
                    }
                )
        env.close()
    return pd.DataFrame(rows)


def summarise_study(runs: pd.DataFrame) -> pd.DataFrame:
    """Per task and option combination: worst case over seeds of the errors and times, means of the rest.

    Times that never happen (``None``) count as infinite, so a combination that misses the
    threshold for any seed shows ``inf``. ``max_speed_ratio`` is the largest |u_j|/limit_j
    (1: the command touched a limit, where it is clipped).
    """
    keys = [
        k
        for k in (
            "task",
            "initial_weights",
            "initial_weight_scale",
            "learning_rate_unit",
            "freeze_when_saturated",
            "weight_update",
            "schedule_clock",
        )
        if k in runs.columns
    ]
    runs = runs.copy()
    for column in ("time_to_1mm", "settling_time"):
        runs[column] = runs[column].astype(float).fillna(np.inf)
    grouped = runs.groupby(keys, sort=False)
    table = grouped.agg(
        seeds=("final_error", "size"),
        final_error_mm=("final_error", lambda v: 1e3 * v.max()),
        time_to_1mm_s=("time_to_1mm", "max"),
        settling_time_s=("settling_time", "max"),
        cost_error=("cost_error", "mean"),
        cost_effort=("cost_effort", "mean"),
        cost_smoothness=("cost_smoothness", "mean"),
        cost_total=("cost_total", "mean"),
        clip_percent=("clip_fraction", lambda v: 100 * v.max()),
        max_speed_ratio=("max_speed_ratio", "max"),
        descent_percent=("descent_fraction", lambda v: 100 * v.mean()),
    )
    return table.reset_index()


def _random_episodes(env: Any, episodes: int) -> list[Sample]:
    """Episodes ``env.reset(seed=i)`` draws (random start pose and reference), as samples."""
    samples = []
    for episode in range(episodes):
        _, info = env.reset(seed=episode)
        base = env.unwrapped
        samples.append(Sample(base.task_name, episode, np.asarray(info["q0"], dtype=float), base.reference))
    return samples


def random_episode_study(
    configs: dict[str, dict[str, Any]],
    tasks: tuple[str, ...] = ("reach", "track"),
    episodes: int = 50,
    horizons: dict[str, tuple[float, ...]] | None = None,
) -> pd.DataFrame:
    """SNAC configurations on random episodes (env seeds 0, 1, …) of the kinematic model.

    Each episode is drawn by ``env.reset(seed=i)`` (random start pose and random target or
    ellipse), run once for the longest horizon on the exact kinematic model
    (:func:`~snac_gym.rollout.simulate_kinematic`, all episodes in lockstep), and measured at
    every horizon of its task on the prefix. The policy is reset with the same seed.

    Success: reach ends within 1 mm of the target at the horizon; track keeps the mean ‖e‖
    over the second half of the horizon under 5 mm.

    Args:
        configs: Name -> SNAC constructor arguments (``{}``: the defaults).
        tasks: Tasks.
        episodes: Random episodes per task.
        horizons: Task -> horizons in seconds (default: the demo horizon of each task,
            ``Task.horizon_s``).

    Returns:
        One row per task, configuration, episode and horizon: ``final_error``,
        ``mean_error_second_half`` (m), ``success``, ``max_speed_ratio``, ``first_command_jump``
        (u₀ᵀu₀/Δt, the first step's share of the smoothness cost) and the three cost terms
        and their sum.
    """
    import snac_gym  # noqa: F401  (registers the envs)

    rows = []
    for task in tasks:
        spec = get_task(task)
        env = gym.make(spec.env_id)
        context = PolicyContext.from_env(env)
        dt = context.dt
        times = (horizons or {}).get(task, (spec.horizon_s,))
        counts = [round(t / dt) for t in times]
        limits = np.asarray(context.velocity_limits, dtype=float)
        samples = _random_episodes(env, episodes)
        env.close()
        for name, kwargs in configs.items():
            batch = simulate_kinematic(
                context,
                functools.partial(SNACPolicy, context, **kwargs),
                samples,
                max(counts),
                seeds=[s.index for s in samples],
                label=name,
                keep_states=False,
            )
            for episode, sample in enumerate(samples):
                errors = np.vstack([batch.errors[episode], batch.final_errors[episode][None]])
                commands = batch.commands[episode]
                for horizon, count in zip(times, counts):
                    rows.append(
                        {
                            "task": task,
                            "config": name,
                            "episode": sample.index,
                            "horizon_s": float(horizon),
                            **_prefix_figures(spec, errors[: count + 1], commands[:count], limits, dt),
                        }
                    )
    return pd.DataFrame(rows)


def _prefix_figures(
    spec: Task, errors: np.ndarray, commands: np.ndarray, limits: np.ndarray, dt: float
) -> dict[str, Any]:
    """The random study's figures of one episode's first K steps (``errors`` holds e₀..e_K)."""
    norms = np.linalg.norm(errors, axis=1)
    cost = trajectory_cost(errors[:-1], commands, dt)
    count = len(commands)
    # The study's own second half, k = ⌈K/2⌉..K (the final error included), as published in docs/snac.md.
    second_half = float(norms[(count + 1) // 2 :].mean())
    final = float(norms[-1])
    success = spec.success({"final_error": final, "mean_error_2nd_half": second_half})
    return {
        "final_error": final,
        "mean_error_second_half": second_half,
        "success": bool(success),
        "max_speed_ratio": float((np.abs(commands) / limits).max()),
        "first_command_jump": float(commands[0] @ commands[0] / dt),
        "cost_error": float(cost.error),
        "cost_effort": float(cost.effort),
        "cost_smoothness": float(cost.smoothness),
        "cost_total": float(cost.total),
    }


def summarise_random_study(runs: pd.DataFrame) -> pd.DataFrame:
    """Per task, configuration and horizon: success rate, error spread and mean cost terms."""
    grouped = runs.groupby(["task", "config", "horizon_s"], sort=False)
    table = grouped.agg(
        success_percent=("success", lambda v: 100 * v.mean()),
        final_error_mm_median=("final_error", lambda v: 1e3 * v.median()),
        final_error_mm_max=("final_error", lambda v: 1e3 * v.max()),
        second_half_mm_max=("mean_error_second_half", lambda v: 1e3 * v.max()),
        cost_error=("cost_error", "mean"),
        cost_effort=("cost_effort", "mean"),
        cost_smoothness=("cost_smoothness", "mean"),
        cost_total=("cost_total", "mean"),
        cost_total_median=("cost_total", "median"),
        first_jump=("first_command_jump", "mean"),
        max_speed_ratio=("max_speed_ratio", "max"),
    )
    return table.reset_index()


def effort_study(
    scales: tuple[float, ...] = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0),
    tasks: tuple[str, ...] = ("reach", "track"),
    random_episodes: int = 5,
) -> pd.DataFrame:
    """Peak ‖u‖₂ and effort Σ uᵀu Δt of SNAC against its effort knob (``command_scale``).

    Runs the paper's demo (seed 0) and ``random_episodes`` random episodes (env seeds 1, 2, …)
    per task, each at every scale. Used to check that the knob scales effort monotonically.

    Returns:
        One row per task, episode and scale: ``peak_command_norm``, ``cost_effort``, ``final_error``.
    """
    import snac_gym  # noqa: F401  (registers the envs)

    rows = []
    for task in tasks:
        spec = get_task(task)
        env = gym.make(spec.env_id)
        episodes = [("paper", spec.demo_options(), 0)] + [
            (f"random{s}", None, s) for s in range(1, random_episodes + 1)
        ]
        for name, options, seed in episodes:
            for scale in scales:
                log = rollout(env, SNACPolicy(env, command_scale=scale), options=options, seed=seed)
                commands = log_array(log, "u")
                metrics = demo_metrics(log, spec.success_tolerance)
                rows.append(
                    {
                        "task": task,
                        "episode": name,
                        "command_scale": scale,
                        "peak_command_norm": float(np.linalg.norm(commands, axis=1).max()),
                        "cost_effort": metrics.cost_effort,
                        "final_error": metrics.final_error,
                    }
                )
        env.close()
    return pd.DataFrame(rows)
