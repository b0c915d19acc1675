"""The default frame of every robot's reach id (and the coarse goal preset), and one with camera options.

    python docs/scripts/camera_frames.py [OUT.png]      # default docs/figures/frames.png

Each env is reset with seed 0 and rendered headless (``render_mode="rgb_array"``, PyBullet), 320×320.
The last panel sets panda-gym's camera options on the UR10: ``render_distance=2.6, render_yaw=20,
render_pitch=-35, render_target_position=(0.4, 0.4, 0.4)``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the backend)

import snac_gym  # noqa: E402,F401  (registers the ids)

PANELS = [
    ("snac_gym/UR3Reach-v0", {}),
    ("snac_gym/UR5Reach-v0", {}),
    ("snac_gym/UR10Reach-v0", {}),
    ("snac_gym/UR16eReach-v0", {}),
    ("snac_gym/PandaReach-v0", {}),
    ("snac_gym/XArm7Reach-v0", {}),
    ("snac_gym/PandaReachGoalCoarse-v0", {}),
    (
        "snac_gym/UR10Reach-v0",
        {"render_distance": 2.6, "render_yaw": 20, "render_pitch": -35, "render_target_position": (0.4, 0.4, 0.4)},
    ),
]


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "figures" / "frames.png"
    fig, axes = plt.subplots(2, 4, figsize=(12, 6.4))
    for axis, (env_id, options) in zip(axes.ravel(), PANELS, strict=True):
        env = gym.make(env_id, render_mode="rgb_array", render_width=320, render_height=320, **options)
        env.reset(seed=0)
        axis.imshow(env.render())
        env.close()
        axis.set_title(env_id.split("/")[1] + (" (camera options)" if options else ""), fontsize=9)
        axis.axis("off")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
