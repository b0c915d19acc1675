"""Record the UR10 trajectories that tests/envs/test_ids.py compares bit for bit (``ur10_trajectories.npz``).

Run once, at commit 089c544 (before the per-robot ids, the explicit env classes and the shared
kinematic step), on x86-64 Linux: ``python tests/data/record_ur10_trajectories.py``. The test
rebuilds every trajectory with today's code and asserts the arrays are equal, not close.
Only the public API of that commit is used (``gym.make`` of the UR10 ids with ``robot=`` and
``backend=``, ``gym.make_vec``, :func:`snac_gym.rollout.simulate_kinematic`).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.model.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import PolicyContext
from snac_gym.references import PAPER_Q0, Ellipse, FixedTarget
from snac_gym.rollout import simulate_kinematic
from snac_gym.tasks import Sample

STEPS = 40
PATH = Path(__file__).with_name("ur10_trajectories.npz")


def actions(count: int, joints: int, seed: int) -> np.ndarray:
    """Seeded joint-velocity commands, some past the limits (the env clips them)."""
    return np.random.default_rng(seed).uniform(-2.5, 2.5, size=(count, joints))


def env_trajectory(env_id: str, seed: int, **kwargs) -> dict[str, np.ndarray]:
    """Observations, rewards and cost infos of a seeded episode under :func:`actions`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        env = gym.make(env_id, **kwargs)
    obs, _ = env.reset(seed=seed)
    observations, rewards, costs = [obs], [], []
    for u in actions(STEPS, env.action_space.shape[0], seed):
        obs, reward, _, _, info = env.step(u)
        observations.append(obs)
        rewards.append(reward)
        costs.append([info["cost_error"], info["cost_effort"], info["cost_smoothness"]])
    env.close()
    return {"obs": np.array(observations), "reward": np.array(rewards), "costs": np.array(costs)}


def vector_trajectory(env_id: str, seed: int) -> dict[str, np.ndarray]:
    """A batched kinematic vector env of 3 sub-envs, 40 steps (one sub-env truncates at 25 and autoresets)."""
    env = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", max_steps=25)
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    commands = actions(STEPS * 3, 6, seed).reshape(STEPS, 3, 6)
    for u in commands:
        obs, reward, *_ = env.step(u)
        observations.append(obs)
        rewards.append(reward)
    env.close()
    return {"obs": np.array(observations), "reward": np.array(rewards)}


class OpenLoop:
    """Replays :func:`actions` of its seed, ignoring the observation (isolates the engine's step)."""

    def __init__(self) -> None:
        self.commands, self.k = None, 0

    def reset(self, seed: int | None = None) -> None:
        self.commands, self.k = actions(STEPS, 6, int(seed)), 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        self.k += 1
        return self.commands[self.k - 1]


def engine_trajectory() -> dict[str, np.ndarray]:
    """:func:`simulate_kinematic` of two reach and two track samples."""
    kinematics = Kinematics("ur10")
    layout = ObservationLayout(6, 3)
    out = {}
    q0 = np.array(PAPER_Q0)
    for task, references in (
        ("reach", [FixedTarget([-0.658, 0.626, 0.407]), FixedTarget([-0.6, 0.3, 0.4])]),
        ("track", [Ellipse.paper_circle(), Ellipse(centre=[-0.6, 0.1, 0.5], semi_axes=[0.15, 0.1])]),
    ):
        context = PolicyContext(kinematics, 1 / 125, kinematics.velocity_limits, layout, task)
        samples = [Sample(task, i, q0 + 0.05 * i, ref) for i, ref in enumerate(references)]
        result = simulate_kinematic(context, OpenLoop, samples, STEPS, [3, 4])
        out[f"engine_{task}_q"] = result.q
        out[f"engine_{task}_errors"] = result.errors
        out[f"engine_{task}_final_q"] = result.final_q
    return out


def record() -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {}
    runs = {
        "reach_pybullet": ("snac_gym/UR10Reach-v0", 7, {}),
        "track_pybullet": ("snac_gym/UR10EllipseTrack-v0", 8, {}),
        "reach_kinematic": ("snac_gym/UR10Reach-v0", 7, {"backend": "kinematic"}),
        "track_kinematic": ("snac_gym/UR10EllipseTrack-v0", 8, {"backend": "kinematic"}),
        "reach_normalized_shaped": ("snac_gym/UR10Reach-v0", 9, {"action_type": "normalized", "reward_type": "shaped"}),
        # Another robot the old way (robot= on the UR10 id): the per-robot ids must give the same.
        "panda_reach_pybullet": ("snac_gym/UR10Reach-v0", 7, {"robot": "panda"}),
        "panda_track_kinematic": ("snac_gym/UR10EllipseTrack-v0", 8, {"robot": "panda", "backend": "kinematic"}),
        "ur5_reach_pybullet": ("snac_gym/UR10Reach-v0", 7, {"robot": "ur5"}),
    }
    for name, (env_id, seed, kwargs) in runs.items():
        for key, value in env_trajectory(env_id, seed, **kwargs).items():
            arrays[f"{name}_{key}"] = value
    for name, env_id in (("reach_vector", "snac_gym/UR10Reach-v0"), ("track_vector", "snac_gym/UR10EllipseTrack-v0")):
        for key, value in vector_trajectory(env_id, 5).items():
            arrays[f"{name}_{key}"] = value
    arrays.update(engine_trajectory())
    return arrays


if __name__ == "__main__":
    np.savez_compressed(PATH, **record())
    print(f"wrote {PATH}")
