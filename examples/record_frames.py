"""Render a few frames of SNAC tracking the paper's circle and save them as PNG files.

    python examples/record_frames.py [FRAMES] [OUT]               # default 8 frames, videos/frames

``render_mode="rgb_array"`` works headless. For an MP4 wrap the env in
``gymnasium.wrappers.RecordVideo`` instead (needs the ``video`` extra, moviepy; docs/environments.md).
"""

import sys
from pathlib import Path

import gymnasium as gym
import matplotlib.pyplot as plt

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym import make_policy
from snac_gym.apps.demo import demo_options


def main(frames: int = 8, out: str = "videos/frames", every: int = 125, size: int = 320) -> None:
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    env = gym.make("snac_gym/UR10EllipseTrack-v0", render_mode="rgb_array", render_width=size, render_height=size)
    policy = make_policy("snac", env)
    obs, _ = env.reset(seed=0, options=demo_options("track"))
    policy.reset(seed=0)
    for step in range(frames * every):
        if step % every == 0:
            path = folder / f"track_{step:05d}.png"
            plt.imsave(path, env.render())
            print(f"t = {step * env.unwrapped.dt:5.2f} s -> {path}")
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        if terminated or truncated:
            break
    env.close()


if __name__ == "__main__":
    main(*(int(arg) for arg in sys.argv[1:2]), *sys.argv[2:3])
