"""rl-zoo3 trains on snac-gym's ids with the shipped hyperparameter file (``hyperparams/sac.yml``).

A few hundred steps only (below SAC's ``learning_starts``, so no gradient step; a replay buffer of a
thousand): the test checks the path a user takes (``--gym-packages snac_gym``, the file's keys, HER
with the Dict observation, VecNormalize), that the model it saves loads and acts on the id, and that
every id in the file is registered. Skipped, with the reason, without the ``zoo`` extra.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import snac_gym  # noqa: F401  (registers the ids)

ROOT = Path(__file__).resolve().parents[1]
HYPERPARAMS = ROOT / "hyperparams" / "sac.yml"
ENV_ID = "snac_gym/PandaReachGoalCoarse-v0"


def test_every_registered_goal_id_has_an_entry_and_the_file_is_generated_from_the_registry():
    entries = yaml.safe_load(HYPERPARAMS.read_text())
    goal_ids = [env_id for env_id in gym.registry if env_id.startswith("snac_gym/") and "Goal" in env_id]
    assert len(goal_ids) >= 36 and sorted(entries) == sorted(goal_ids)
    for env_id in goal_ids:  # each entry resolves to a whole preset (the YAML merge keys included)
        assert entries[env_id]["replay_buffer_class"] == "HerReplayBuffer" and entries[env_id]["n_timesteps"] > 0
    done = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "write_zoo_hyperparams.py"), "--check"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr


def test_every_id_of_the_hyperparameter_file_is_registered_and_goal_conditioned():
    entries = yaml.safe_load(HYPERPARAMS.read_text())
    assert ENV_ID in entries and len(entries) >= 2
    for env_id, entry in entries.items():
        env = gym.make(env_id)
        assert isinstance(env.observation_space, gym.spaces.Dict), env_id
        assert entry["replay_buffer_class"] == "HerReplayBuffer"
        env.close()


@pytest.mark.slow(seconds=5)
@pytest.mark.rl
def test_rl_zoo3_trains_on_a_snac_gym_id_and_the_model_acts(tmp_path):
    # Not imported here: rl_zoo3 replaces gymnasium's TimeLimit on import (rl_zoo3.gym_patches), for every later test.
    if importlib.util.find_spec("rl_zoo3") is None:
        pytest.skip("the 'zoo' extra (rl_zoo3) is not installed")
    command = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        "sac",
        "--env",
        ENV_ID,
        "--gym-packages",
        "snac_gym",
        "-conf",
        str(HYPERPARAMS),
        "-n",
        "300",
        "--seed",
        "1",
        "--log-folder",
        str(tmp_path),
        "--eval-freq",
        "-1",
        "--no-optim-plots",
        "-params",
        "buffer_size:1000",  # the file's 1e6 transitions take HER 2 s to allocate
    ]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    name = ENV_ID.replace("/", "-")
    run = tmp_path / "sac" / f"{name}_1"
    assert (run / f"{name}.zip").is_file() and (run / name / "vecnormalize.pkl").is_file()

    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    env = VecNormalize.load(
        str(run / name / "vecnormalize.pkl"), DummyVecEnv([lambda: gym.make(ENV_ID, physics="kinematic")])
    )
    env.training, env.norm_reward = False, False
    model = SAC.load(run / f"{name}.zip", env=env)  # HER needs the env to load
    env.seed(0)
    obs = env.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1, *env.action_space.shape) and np.all(np.abs(action) <= 1.0)
    env.close()
