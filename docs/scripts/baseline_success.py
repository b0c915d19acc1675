"""Success rate of a baseline on N random episodes of each task (env.reset(seed=i), i < N).

usage: python docs/scripts/baseline_success.py {kinematic|pybullet} {dls|svf|rnn|lqr} N [JSON constructor kwargs]
reach: success = final ‖e‖ ≤ 1 mm after the default 1000 steps (8 s);
track: success = mean ‖e‖ over the second half of the default 2500 steps (20 s) ≤ 5 mm;
both also need every command inside the velocity limits.
"""

import json
import sys

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401
from snac_gym import make_policy
from snac_gym.model.kinematics import joint_step

physics, name, count = sys.argv[1], sys.argv[2], int(sys.argv[3])
kwargs = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
for env_id in ("snac_gym/UR10Reach-v0", "snac_gym/UR10EllipseTrack-v0"):
    env = gym.make(env_id)
    base = env.unwrapped
    policy = make_policy(name, env, **kwargs)
    metrics, successes, peak_ratio = [], 0, 0.0
    for seed in range(count):
        obs, _ = env.reset(seed=seed)
        policy.reset()
        q, errors, inside_all = obs[:6].copy(), [], True
        for k in range(base.max_steps):
            u = policy.act(obs)
            inside = np.all(np.abs(u) <= base.velocity_limits)
            peak_ratio = max(peak_ratio, float(np.max(np.abs(u) / base.velocity_limits)))
            if physics == "pybullet":
                obs, _, _, _, info = env.step(u)
                errors.append(info["error_norm"])
            else:  # θ ← θ + uΔt with the shared kinematics, the reference read from the env
                q = joint_step(q, u, base.dt)
                t = (k + 1) * base.dt
                obs = base.obs_layout.pack(
                    q,
                    u,
                    base.kinematics.forward(q),
                    base.reference.position(t),
                    base.reference.velocity(t),
                    base.reference.centre,
                )
                errors.append(float(np.linalg.norm(obs[base.obs_layout.slices["e"]])))
            inside_all = inside_all and inside
        errors = np.array(errors)
        metric = errors[-1] if base.task_name == "reach" else errors[len(errors) // 2 :].mean()
        limit = 1e-3 if base.task_name == "reach" else 5e-3
        metrics.append(metric)
        successes += int(metric <= limit and inside_all)
    metrics = np.array(metrics) * 1e3
    print(
        f"{physics:9s} {name} {kwargs or ''} {base.task_name:5s}: {successes}/{count} succeed; "
        f"{'final' if base.task_name == 'reach' else 'mean 2nd-half'} error median {np.median(metrics):.4f} mm, "
        f"max {metrics.max():.4f} mm; peak |u_i|/limit {peak_ratio:.3f}",
        flush=True,
    )
    env.close()
