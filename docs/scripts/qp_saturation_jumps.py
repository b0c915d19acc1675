"""Commands of ``pink`` and ``dls`` at a high gain, where the velocity limits bind: how often the command jumps.

Ten UR10 reach episodes (``env.reset(seed=i)``, kinematic engine, 12 s) per controller at ``gain=8``
(four times the default): per rollout, Σ u̇ᵀu̇ Δt after the first step (the u̇ term of the Table I cost
without the jump from rest), the steps where ‖u̇‖ > 50 rad/s² and the steps with a joint at its limit.

    python docs/scripts/qp_saturation_jumps.py [GAIN [EPISODES]]
"""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401  (registers the envs)
from snac_gym.policies import make_policy


def main(argv: list[str]) -> None:
    gain = float(argv[0]) if argv else 8.0
    episodes = int(argv[1]) if len(argv) > 1 else 10
    env = gym.make("snac_gym/UR10Reach-v0", physics="kinematic", max_episode_steps=1500)
    dt, limits = env.unwrapped.dt, env.unwrapped.velocity_limits
    for name in ("dls", "pink"):
        smoothness, jumps, saturated = [], [], []
        for seed in range(episodes):
            policy = make_policy(name, env, gain=gain)
            obs, _ = env.reset(seed=seed)
            commands = []
            for _ in range(1500):
                commands.append(policy.act(obs))
                obs, *_ = env.step(commands[-1])
            commands = np.array(commands)
            rates = np.diff(commands, axis=0) / dt
            smoothness.append(float((rates**2).sum() * dt))
            jumps.append(int((np.linalg.norm(rates, axis=1) > 50).sum()))
            saturated.append(int((np.abs(commands) >= 0.999 * limits).any(axis=1).sum()))
        print(f"{name}: gain {gain}, Σ u̇ᵀu̇Δt after step 0 per episode {np.round(smoothness, 1).tolist()}")
        print(f"{'':{len(name) + 2}}steps with ‖u̇‖ > 50 rad/s²: {jumps}; steps with a joint at its limit: {saturated}")
    env.close()


if __name__ == "__main__":
    main(sys.argv[1:])
