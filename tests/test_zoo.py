"""rl-zoo3 trains on snac-gym's ids with the hyperparameter files shipped in the package (``snac_gym/data/zoo``).

Every ``-v1`` id has an entry in each learner's file (PPO, SAC, TD3, TQC), the files are what the registry gives
(``tools/write_zoo_hyperparams.py --check``), and each entry's keys are arguments its learner takes. Then, from a
folder outside the repository, rl-zoo3 trains each learner for a few hundred steps on the file
``python -m snac_gym.zoo ALGO`` names (the path a user takes: ``--gym-packages snac_gym``, HER with the Dict
observation, VecNormalize), and the saved SAC model loads and acts. Skipped, with the reason, without the ``zoo``
extra.
"""

from __future__ import annotations

import importlib.util
import inspect
import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.common.extras import install_line
from snac_gym.envs import REGISTERED_IDS
from snac_gym.zoo import ALGOS, hyperparams_file

# PyYAML reads the hyperparameter files as rl-zoo3 does; it comes with the zoo extra (and the docs and ray extras).
yaml = pytest.importorskip("yaml", reason=f"needs PyYAML, installed with the 'zoo' extra: {install_line('zoo')}")
ROOT = Path(__file__).resolve().parents[1]
V1_IDS = sorted(env_id for env_id in REGISTERED_IDS if env_id.endswith("-v1"))
#: Keys rl-zoo3 reads itself rather than passing to the learner (rl_zoo3.exp_manager).
ZOO_KEYS = {"n_timesteps", "policy", "normalize", "n_envs", "noise_type", "noise_std", "env_wrapper"}
#: The learner and the id of each training run, and what makes it short.
RUNS = {
    # 1e6 transitions take HER 2 s to allocate; learning from step 100 on: 100 gradient steps
    "sac": ("snac_gym/PandaReachGoalCoarse-v1", ["buffer_size:1000", "learning_starts:100", "batch_size:64"]),
    "td3": ("snac_gym/UR10ReachGoalCoarseCartesian-v1", ["buffer_size:1000", "learning_starts:100", "batch_size:64"]),
    "tqc": ("snac_gym/PandaReachGoalCoarseCartesian-v1", ["buffer_size:1000", "learning_starts:100", "batch_size:64"]),
    "ppo": ("snac_gym/UR10Reach-v1", ["n_envs:1", "n_steps:64", "batch_size:32", "n_epochs:1"]),
}
STEPS = 200
#: One interpreter trains every learner in turn (torch and rl-zoo3 imported once): rl-zoo3's own command line.
DRIVER = """
import json, sys
from rl_zoo3.train import train
from snac_gym.zoo import hyperparams_file
runs, steps = json.loads(sys.argv[1]), sys.argv[2]
for algo, (env_id, params) in runs.items():
    sys.argv = ["rl_zoo3.train", "--algo", algo, "--env", env_id, "--gym-packages", "snac_gym",
                "-conf", str(hyperparams_file(algo)), "-n", steps, "--seed", "1", "--log-folder", ".",
                "--eval-freq", "-1", "--no-optim-plots", "--num-threads", "1", "-params", *params]
    train()
"""


def _entries(algo: str) -> dict:
    return yaml.safe_load(hyperparams_file(algo).read_text())


def test_the_files_ship_in_the_package_and_are_generated_from_the_registry():
    for algo in ALGOS:
        path = hyperparams_file(algo)
        assert path.is_file() and path.parent == Path(snac_gym.__file__).parent / "data" / "zoo"
    assert len(V1_IDS) == 54
    done = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "write_zoo_hyperparams.py"), "--check"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    found = subprocess.run(
        [sys.executable, "-m", "snac_gym.zoo", "tqc"], capture_output=True, text=True, timeout=60, cwd="/"
    )
    assert found.returncode == 0 and Path(found.stdout.strip()) == hyperparams_file("tqc")
    with pytest.raises(ValueError, match="shipped: ppo, sac, td3, tqc"):
        hyperparams_file("a2c")


@pytest.mark.rl
@pytest.mark.parametrize("algo", ALGOS)
def test_every_v1_id_has_an_entry_whose_keys_its_learner_takes(algo):
    if algo == "tqc" and importlib.util.find_spec("sb3_contrib") is None:
        pytest.skip("TQC is sb3-contrib's, installed with the 'zoo' extra")
    if algo == "tqc":
        from sb3_contrib import TQC as learner  # noqa: N811  (sb3-contrib is in the zoo extra only)
    else:
        import stable_baselines3  # the rl extra: imported by the tests that need it

        learner = getattr(stable_baselines3, algo.upper())
    accepted = set(inspect.signature(learner.__init__).parameters) | ZOO_KEYS
    entries = _entries(algo)
    assert sorted(entries) == V1_IDS  # every -v1 id, nothing else (no -v0 id to train on)
    for env_id, entry in entries.items():
        assert set(entry) <= accepted, (env_id, set(entry) - accepted)
        goal = REGISTERED_IDS[env_id].goal
        assert entry["policy"] == ("MultiInputPolicy" if goal else "MlpPolicy"), env_id
        assert entry["n_timesteps"] > 0 and entry["normalize"] is True
        if algo != "ppo":
            assert (entry.get("replay_buffer_class") == "HerReplayBuffer") == goal, env_id


@pytest.mark.slow(seconds=7)
@pytest.mark.rl
def test_rl_zoo3_trains_each_learner_from_outside_the_repository_and_the_model_acts(tmp_path):
    # Not imported here: rl_zoo3 replaces gymnasium's TimeLimit on import (rl_zoo3.gym_patches), for every later test.
    if importlib.util.find_spec("rl_zoo3") is None:
        pytest.skip("the 'zoo' extra (rl_zoo3) is not installed")
    done = subprocess.run(
        [sys.executable, "-c", DRIVER, json.dumps(RUNS), str(STEPS)],
        cwd=tmp_path,  # not the repository: the files come from the package
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    for algo, (env_id, _) in RUNS.items():
        assert f"Loading hyperparameters from: {hyperparams_file(algo)}" in done.stdout
        name = env_id.replace("/", "-")
        run = tmp_path / algo / f"{name}_1"
        assert (run / f"{name}.zip").is_file() and (run / name / "vecnormalize.pkl").is_file(), algo

    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    env_id = RUNS["sac"][0]
    name = env_id.replace("/", "-")
    run = tmp_path / "sac" / f"{name}_1"
    env = VecNormalize.load(
        str(run / name / "vecnormalize.pkl"), DummyVecEnv([lambda: gym.make(env_id, physics="kinematic")])
    )
    env.training, env.norm_reward = False, False
    model = SAC.load(run / f"{name}.zip", env=env)  # HER needs the env to load
    env.seed(0)
    obs = env.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1, *env.action_space.shape) and np.all(np.abs(action) <= 1.0)
    env.close()
