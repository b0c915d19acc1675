"""Time of ``act`` for ``joint-goal`` and ``dls`` (docs/baselines.md, "joint-goal"): the first step of an
episode (which solves the goal) and the later ones, on the PyBullet envs' observations.

    python docs/scripts/joint_goal_latency.py

Median over episodes 2-6 for the first step (the first episode pays for imports and compilation), over all
later steps for the rest.
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401  (registers the envs)
from snac_gym.policies import make_policy

for env_id in ("snac_gym/UR10Reach-v0", "snac_gym/UR10EllipseTrack-v0"):
    env = gym.make(env_id)
    for name in ("joint-goal", "dls"):
        policy = make_policy(name, env)
        firsts, later = [], []
        for episode in range(6):
            obs, _ = env.reset(seed=episode)
            policy.reset()
            start = time.perf_counter()
            policy.act(obs)
            firsts.append(time.perf_counter() - start)
            for _ in range(200):
                start = time.perf_counter()
                policy.act(obs)
                later.append(time.perf_counter() - start)
        print(f"{env_id} {name}: first act {1e3 * np.median(firsts[1:]):.3f} ms, later {1e3 * np.median(later):.3f} ms")
    env.close()
