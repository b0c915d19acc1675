"""Success rate of an rl-zoo3 run on unseen goals: the saved model and its VecNormalize statistics, deterministic.

Usage::

    python docs/scripts/zoo_success.py LOG_FOLDER/sac/snac_gym-PandaReachGoalCoarse-v0_1 --episodes 100

Runs ``--episodes`` episodes from reset seeds 10 000, 10 001, ... (rl-zoo3's training seeds start
at 0) on each ``--physics``, and prints the fraction that end with ``info["is_success"]``, the
median final distance to the goal and the wall time. ``--model`` picks ``best_model.zip`` (rl-zoo3's
periodic evaluation kept it) instead of the final model.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401  (registers the ids)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="rl-zoo3's run folder (LOG/ALGO/ENV_N)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--physics", default="kinematic,pybullet")
    parser.add_argument("--model", default="final", choices=["final", "best"])
    args = parser.parse_args()
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    env_name = args.run.name.rsplit("_", 1)[0]
    env_id = env_name.replace("-", "/", 1)
    model_file = args.run / (f"{env_name}.zip" if args.model == "final" else "best_model.zip")
    for physics in args.physics.split(","):
        start = time.perf_counter()
        venv = DummyVecEnv([lambda: gym.make(env_id, physics=physics)])
        stats = args.run / env_name / "vecnormalize.pkl"
        if stats.is_file():
            venv = VecNormalize.load(str(stats), venv)
            venv.training, venv.norm_reward = False, False
        model = SAC.load(model_file, env=venv)
        successes, distances = [], []
        for episode in range(args.episodes):
            venv.seed(10_000 + episode)
            obs = venv.reset()
            done = False
            while not done:
                action, _ = model.predict(obs, deterministic=True)
                obs, _, dones, infos = venv.step(action)
                done = bool(dones[0])
            info = infos[0]
            successes.append(bool(info["is_success"]))
            distances.append(float(info["error_norm"]))  # the last step's distance (not normalised)
        venv.close()
        print(
            f"{env_id} physics={physics} model={args.model}: success {np.mean(successes):.1%} of {args.episodes} "
            f"unseen goals, median final distance {np.median(distances) * 100:.2f} cm, "
            f"{time.perf_counter() - start:.1f} s"
        )


if __name__ == "__main__":
    main()
