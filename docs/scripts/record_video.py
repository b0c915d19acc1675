"""Record SNAC's demo of a task with gymnasium.wrappers.RecordVideo and print how long it took.

Usage::

    .venv/bin/python docs/scripts/record_video.py reach videos/

Needs the ``video`` extra (moviepy). Writes ``<task>-episode-0.mp4`` into the folder.
"""

from __future__ import annotations

import sys
import time

import gymnasium as gym

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.apps.demo import demo_options
from snac_gym.policies import make_policy
from snac_gym.tasks import get_task


def main(task: str, folder: str) -> None:
    env = gym.make(get_task(task).env_id, render_mode="rgb_array")
    env = gym.wrappers.RecordVideo(env, folder, episode_trigger=lambda episode: True, name_prefix=task)
    policy = make_policy("snac", env)
    start = time.perf_counter()
    obs, _ = env.reset(seed=0, options=demo_options(task))
    policy.reset(seed=0)
    steps, done = 0, False
    while not done:
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        steps, done = steps + 1, terminated or truncated
    env.close()
    fps = env.unwrapped.metadata["render_fps"]
    print(
        f"{task}: {steps} steps recorded in {time.perf_counter() - start:.1f} s; the video plays "
        f"{steps / fps:.1f} s at {fps} fps"
    )


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
