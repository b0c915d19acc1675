"""The paper's two tasks from θ0 in the PyBullet env.

usage: python docs/scripts/baseline_paper_runs.py [CONTROLLER [JSON constructor kwargs]]
(default: all three, default gains)
"""

import json
import sys

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401
from snac_gym import make_policy
from snac_gym.control.cost import trajectory_cost
from snac_gym.references import PAPER_Q0

for env_id in ("snac_gym/UR10Reach-v0", "snac_gym/UR10EllipseTrack-v0"):
    env = gym.make(env_id)
    base = env.unwrapped
    names = sys.argv[1:2] or ["rnn", "svf", "dls"]
    kwargs = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
    for name in names:
        policy = make_policy(name, env, **kwargs)
        obs, info = env.reset(options={"q0": list(PAPER_Q0)})
        policy.reset()
        errors_before, commands, norms = [info["error"]], [], []
        truncated = False
        while not truncated:
            u = policy.act(obs)
            obs, _, _, truncated, info = env.step(u)
            commands.append(u)
            errors_before.append(info["error"])
            norms.append(info["error_norm"])
        norms, commands = np.array(norms), np.array(commands)
        cost = trajectory_cost(np.array(errors_before[:-1]), commands, base.dt)
        t_1mm = (np.argmax(norms <= 1e-3) + 1) * base.dt
        half = len(norms) // 2
        print(
            f"{base.task_name:5s} {name} {kwargs or ''}: final {norms[-1] * 1e3:.4f} mm, "
            f"2nd-half mean {norms[half:].mean() * 1e3:.4f} "
            f"max {norms[half:].max() * 1e3:.4f} mm, first <=1 mm at {t_1mm:.2f} s, "
            f"peak ||u|| {np.linalg.norm(commands, axis=1).max():.3f} rad/s, "
            f"peak |u_i|/limit {np.max(np.abs(commands) / base.velocity_limits):.3f}, V = {cost.total:.2f} "
            f"(error {cost.error:.3f}, effort {cost.effort:.3f}, smoothness {cost.smoothness:.2f})"
        )
    env.close()
