"""The preset sized as panda-gym's PandaReach behaves like it: on the -v1 ids the episode ends on success.

A greedy policy (the tool straight to the goal, read from the observation) reaches the 5 cm goal well inside the
50 steps; the episode then ends with ``terminated=True`` on that step, as panda-gym's ``PandaReach`` does. The -v0
ids keep running to the time limit (what docs/rl.md's runs on them measured).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the ids)


def greedy(obs: dict[str, np.ndarray], dt: float, speed: float) -> np.ndarray:
    """The Cartesian action that moves the tool straight at the goal, one step's worth at most."""
    return np.clip((obs["desired_goal"] - obs["achieved_goal"]) / (speed * dt), -1.0, 1.0).astype(np.float32)


def run_greedy(env_id: str, seed: int, **kwargs) -> list[tuple[bool, bool, bool, float]]:
    """(terminated, truncated, is_success, reward) of each step of one greedy episode."""
    env = gym.make(env_id, **kwargs)
    base = env.unwrapped
    obs, _ = env.reset(seed=seed)
    steps = []
    terminated = truncated = False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, info = env.step(greedy(obs, base.dt, base.cartesian_speed))
        steps.append((terminated, truncated, bool(info["is_success"]), float(reward)))
    env.close()
    return steps


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_cartesian_preset_v1_ends_on_success_under_a_greedy_policy(seed):
    steps = run_greedy("snac_gym/PandaReachGoalCoarseCartesian-v1", seed)  # PyBullet, as registered
    terminated, truncated, success, reward = steps[-1]
    assert terminated and not truncated and success and reward == 0.0
    assert len(steps) < 50  # before panda-gym's 50-step limit
    assert not any(s[2] for s in steps[:-1])  # ends on the first step within 5 cm


def test_the_joint_space_preset_v1_ends_on_success_too_and_v0_runs_to_the_limit():
    env = gym.make("snac_gym/PandaReachGoalCoarse-v1", physics="kinematic")
    assert env.unwrapped.terminate_on_success
    env.close()
    steps = run_greedy("snac_gym/PandaReachGoalCoarseCartesian-v0", 0, physics="kinematic")
    assert len(steps) == 50 and steps[-1][1] and not any(s[0] for s in steps) and steps[-1][2]
