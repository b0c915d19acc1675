"""Best-of-5 mean time of one act() call (20 000 calls each) on a tracking observation."""

import timeit

import gymnasium as gym

import snac_gym  # noqa: F401
from snac_gym import make_policy

env = gym.make("snac_gym/UR10EllipseTrack-v0")
obs, _ = env.reset(seed=0)
for name, kwargs in [("dls", {}), ("svf", {}), ("rnn", {}), ("rnn", {"integrator": "euler"})]:
    policy = make_policy(name, env, **kwargs)
    policy.act(obs)
    best = min(timeit.repeat(lambda: policy.act(obs), number=20_000, repeat=5)) / 20_000
    print(f"{name} {kwargs or ''}: {best * 1e6:.1f} µs per act")
print(
    "shared kinematics.jacobian alone:",
    f"{min(timeit.repeat(lambda: env.unwrapped.kinematics.jacobian(obs[:6]), number=20_000, repeat=5)) / 20_000 * 1e6:.1f} µs",  # noqa: E501
)
