"""The periodic evaluation of PPO training: a frozen policy file run by :class:`~snac_gym.ppo.policy.PPOPolicy`
on the PyBullet env and scored as :mod:`snac_gym.ppo.train` describes, and the rule that ranks two evaluations."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from snac_gym.control.cost import trajectory_cost
from snac_gym.envs import make_task_env
from snac_gym.ppo.config import env_arguments
from snac_gym.ppo.policy import PPOPolicy
from snac_gym.rollout import log_array, rollout
from snac_gym.tasks import get_task

__all__ = ["better", "evaluate_policy_file"]


def evaluate_policy_file(
    policy_path: str | Path, config: dict[str, Any], episodes: int | None = None, action_scale: float = 1.0
) -> dict[str, float]:
    """Run a policy file with :class:`~snac_gym.ppo.policy.PPOPolicy` on the PyBullet env.

    Episodes ``i = 0 .. episodes−1`` are reset with seed ``evaluation.seed + i`` (random start
    pose and reference) and run for the longest of ``evaluation.horizons_s``; each horizon h is
    scored on the first h seconds of the same episode.

    Returns:
        ``success_rate`` (the fraction of episodes that succeed at every horizon),
        ``success_rate_<h>s`` per horizon, ``mean_cost`` (mean trajectory cost V over the
        first horizon), and at the last horizon ``mean_final_error_m``,
        ``median_final_error_m``, ``mean_error_2nd_half_m``, ``median_error_2nd_half_m``.
    """
    evaluation = config["evaluation"]
    task = get_task(config["task"])
    count = int(episodes if episodes is not None else evaluation["episodes"])
    threshold = float(evaluation["success_error_m"])
    # the episodes of the region trained on (the sample cuboid unless env.sample_space says otherwise)
    space = env_arguments(config).get("sample_space")
    env = make_task_env(
        task, config.get("robot", "ur10"), max_steps=10**9, **({} if space is None else {"sample_space": space})
    )
    try:
        policy = PPOPolicy(env, model_path=policy_path, action_scale=action_scale)
        dt = env.unwrapped.dt
        horizons = [float(h) for h in evaluation["horizons_s"]]
        horizon_steps = [max(1, int(round(h / dt))) for h in horizons]
        costs, successes, finals, second_halves = [], [], [], []
        for i in range(count):
            log = rollout(env, policy, seed=int(evaluation["seed"]) + i, steps=max(horizon_steps))
            errors = np.vstack([log_array(log, "e"), np.asarray(log.attrs["final_e"], dtype=float)[None]])
            norms = np.linalg.norm(errors, axis=1)
            first = horizon_steps[0]
            costs.append(float(trajectory_cost(errors[:first], log_array(log, "u")[:first], dt).total))
            finals_i = [float(norms[k]) for k in horizon_steps]
            halves_i = [float(norms[k // 2 : k].mean()) for k in horizon_steps]
            successes.append(
                [
                    bool(task.success({"final_error": final, "mean_error_2nd_half": half}, threshold))
                    for final, half in zip(finals_i, halves_i, strict=True)
                ]
            )
            finals.append(finals_i[-1])
            second_halves.append(halves_i[-1])
    finally:
        env.close()
    success = np.array(successes, dtype=bool)
    finals_a, halves_a = np.array(finals), np.array(second_halves)
    scores = {"success_rate": float(success.all(axis=1).mean())}
    for j, horizon in enumerate(horizons):
        scores[f"success_rate_{horizon:g}s"] = float(success[:, j].mean())
    scores.update(
        mean_cost=float(np.mean(costs)),
        mean_final_error_m=float(finals_a.mean()),
        median_final_error_m=float(np.median(finals_a)),
        mean_error_2nd_half_m=float(halves_a.mean()),
        median_error_2nd_half_m=float(np.median(halves_a)),
    )
    return scores


def better(candidate: dict[str, float], best: dict[str, float] | None) -> bool:
    """Whether evaluation ``candidate`` beats ``best``: a higher success rate, ties broken by the lower mean cost."""
    if best is None:
        return True
    if candidate["success_rate"] != best["success_rate"]:
        return candidate["success_rate"] > best["success_rate"]
    return candidate["mean_cost"] < best["mean_cost"]
