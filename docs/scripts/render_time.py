"""Time one rgb_array frame of the tracking env in PyBullet (TinyRenderer) and MuJoCo (EGL or OSMesa), in one run.

Each engine renders a new 480x360 frame after every control step (``render_every=1``) for 40 steps;
the median frame time is printed (docs/physics.md).

    python docs/scripts/render_time.py
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401  (registers the ids)


def frame_ms(physics: str, frames: int = 40) -> float:
    env = gym.make(
        "snac_gym/UR10EllipseTrack-v0",
        physics=physics,
        render_mode="rgb_array",
        render_width=480,
        render_height=360,
        render_every=1,
    )
    env.reset(seed=0)
    env.render()  # the first frame builds the renderer's buffers
    times = []
    for _ in range(frames):
        env.step(np.full(6, 0.2))
        start = time.perf_counter()
        env.render()
        times.append(time.perf_counter() - start)
    env.close()
    return 1e3 * float(np.median(times))


if __name__ == "__main__":
    for physics in ("pybullet", "mujoco"):
        print(f"{physics:9s} {frame_ms(physics):6.1f} ms per 480x360 frame (median of 40)")
