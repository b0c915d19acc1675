"""Train PPO briefly on the batched kinematic vector env, then try the policy on a few episodes.

    python examples/train_ppo.py [TIMESTEPS] [NUM_ENVS]          # default 200000 steps, 256 episodes

Needs the ``rl`` extra (stable-baselines3, torch). The shipped policies were trained with
``snac-gym train-ppo`` for 2 M steps each, the best checkpoints kept at 0.8 M (reach) and 1.0 M (track)
steps (docs/rl.md); a short run like this one only shows the pipeline, it does not reach 1 mm.
"""

import sys
import time

import gymnasium as gym
import numpy as np
from stable_baselines3 import PPO

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.envs.sb3 import SB3VectorEnv

ENV_ID = "snac_gym/UR10Reach-v1"  # normalized float32 actions and observations
ENV_KWARGS = {"reward_type": "shaped"}
EPISODE_STEPS = 250


def main(timesteps: int = 200_000, num_envs: int = 256) -> None:
    venv = SB3VectorEnv(ENV_ID, num_envs, max_steps=EPISODE_STEPS, **ENV_KWARGS)
    n_steps = max(2, min(64, timesteps // num_envs))
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=n_steps,
        batch_size=min(4096, n_steps * num_envs),
        n_epochs=2,
        seed=0,
        device="cpu",
        verbose=0,
    )
    start = time.perf_counter()
    model.learn(timesteps)
    wall = time.perf_counter() - start
    print(
        f"trained {model.num_timesteps} steps on {num_envs} episodes in {wall:.1f} s "
        f"({model.num_timesteps / wall:,.0f} steps/s)"
    )

    env = gym.make(ENV_ID, physics="kinematic", max_episode_steps=EPISODE_STEPS, **ENV_KWARGS)
    errors = []
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        errors.append(info["error_norm"])
    print(
        f"final error on 3 episodes: {', '.join(f'{e * 1e3:.1f} mm' for e in errors)} "
        f"(median {np.median(errors) * 1e3:.1f} mm)"
    )


if __name__ == "__main__":
    main(*(int(arg) for arg in sys.argv[1:3]))
