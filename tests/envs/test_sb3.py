"""The SB3 VecEnv on the batched kinematic episodes: a DummyVecEnv of single envs, faster; PPO trains on it."""

import importlib.util

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.tasks import TASKS

if importlib.util.find_spec("stable_baselines3") is None:
    pytest.skip("needs stable-baselines3 (the rl extra)", allow_module_level=True)
# stable-baselines3 (and torch, 1.4 s) is imported by the tests, not at collection: a test process
# that runs none of them does not pay for it.

ENV_IDS = [task.env_id for task in TASKS.values()]


def _run_side_by_side(batched, dummy, steps, seed=7):
    batched.seed(seed)
    dummy.seed(seed)
    np.testing.assert_allclose(batched.reset(), dummy.reset(), rtol=1e-6, atol=1e-6)
    rng = np.random.default_rng(0)
    low, high = batched.action_space.low, batched.action_space.high
    dones_seen = 0
    for _ in range(steps):
        actions = rng.uniform(low, high, size=(batched.num_envs, len(low))).astype(batched.action_space.dtype)
        obs, rewards, dones, infos = batched.step(actions)
        obs_w, rewards_w, dones_w, infos_w = dummy.step(actions)
        np.testing.assert_allclose(obs, obs_w, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(rewards, rewards_w, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(dones, dones_w)
        for info, info_w in zip(infos, infos_w, strict=True):
            assert ("terminal_observation" in info) == ("terminal_observation" in info_w)
            if "terminal_observation" in info:
                np.testing.assert_allclose(
                    info["terminal_observation"], info_w["terminal_observation"], rtol=1e-6, atol=1e-6
                )
                assert info["TimeLimit.truncated"] == info_w["TimeLimit.truncated"]
                assert info["is_success"] == info_w["is_success"]
        dones_seen += int(dones.sum())
    assert dones_seen >= batched.num_envs  # autoreset ran in every sub-env


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_sb3_vec_env_is_a_dummy_vec_env_of_single_kinematic_envs(env_id):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from snac_gym.envs.sb3 import SB3VectorEnv

    kwargs = {"action_type": "normalized", "reward_type": "shaped", "observation_dtype": np.float32}
    batched = SB3VectorEnv(env_id, 3, max_steps=6, **kwargs)
    dummy = DummyVecEnv(
        [lambda: gym.make(env_id, physics="kinematic", max_episode_steps=6, **kwargs) for _ in range(3)]
    )
    assert batched.observation_space == dummy.observation_space and batched.action_space == dummy.action_space
    _run_side_by_side(batched, dummy, 14)
    assert batched.get_attr("max_steps") == [6, 6, 6] and batched.env_is_wrapped(gym.Wrapper) == [False] * 3


@pytest.mark.parametrize("task", ["reach", "track"])
def test_ppo_vec_env_is_the_training_wrapper_episode_for_episode(task):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from snac_gym.ppo.config import resolve_config
    from snac_gym.ppo.train import make_training_env
    from snac_gym.ppo.vec_env import PPOVecEnv

    config = resolve_config(task)
    config["env"] = {**config["env"], "max_steps": 5}
    batched = PPOVecEnv(config, num_envs=3)
    single = {**config, "env": {**config["env"], "physics": "kinematic"}}
    dummy = DummyVecEnv([lambda: make_training_env(single) for _ in range(3)])
    _run_side_by_side(batched, dummy, 12)


def test_ppo_trains_on_thousands_of_episodes_at_once():
    from stable_baselines3 import PPO

    from snac_gym.envs.sb3 import SB3VectorEnv

    venv = SB3VectorEnv("snac_gym/UR10Reach-v0", 256, action_type="normalized", reward_type="shaped", max_steps=50)
    model = PPO("MlpPolicy", venv, n_steps=4, batch_size=256, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=3 * 4 * 256)
    assert model.num_timesteps == 3 * 4 * 256
    actions, _ = model.predict(venv.reset(), deterministic=True)
    assert actions.shape == (256, 6) and np.all(np.abs(actions) <= 1.0)


def test_single_kinematic_env_passes_sb3_check_env():
    from stable_baselines3.common.env_checker import check_env

    env = gym.make(
        "snac_gym/UR10Reach-v0",
        physics="kinematic",
        action_type="normalized",
        observation_dtype=np.float32,
        max_episode_steps=20,
    )
    check_env(env, warn=True)


def test_train_ppo_runs_on_the_batched_env(tmp_path):
    """``vec_env.kind = "batched"``: a tiny run trains, logs episode returns, evaluates and exports a policy."""
    import json

    from snac_gym.ppo.config import default_config_path, load_config
    from snac_gym.ppo.train import read_training_log, train_ppo

    config = load_config(default_config_path("reach"))
    config.update(timesteps=256)
    config["env"].update(max_steps=8)
    config["vec_env"].update(n_envs=16, kind="batched")
    config["ppo"].update(n_steps=8, batch_size=64, n_epochs=1, net_arch={"pi": [8, 8], "vf": [8, 8]})
    config["evaluation"].update(every_timesteps=128, episodes=1, horizons_s=[0.024])
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps(config))
    result = train_ppo("reach", tmp_path / "run", config_path=path, log=lambda line: None)
    assert result.status == "finished" and result.timesteps == 256 and result.best_policy.is_file()
    _, progress = read_training_log(tmp_path / "run")
    assert any("rollout/ep_rew_mean" in row for row in progress)  # VecMonitor saw the episodes end
