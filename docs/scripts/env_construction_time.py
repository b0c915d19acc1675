"""Time ``gym.make`` of the PyBullet ids without a render mode (no meshes) and with ``rgb_array`` (meshes), in one run.

Each id is built and closed ``--repeats`` times per mode, the modes alternating; the median is printed
in ms (docs/benchmarks.md).

    python docs/scripts/env_construction_time.py
"""

from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym

import snac_gym  # noqa: F401  (registers the ids)

IDS = ["snac_gym/UR10Reach-v0", "snac_gym/UR10EllipseTrack-v0", "snac_gym/PandaReach-v0"]
MODES = {"no render mode": {}, "rgb_array": {"render_mode": "rgb_array"}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    gym.make(IDS[0]).close()  # imports and the URDF cache out of the timing
    for env_id in IDS:
        times: dict[str, list[float]] = {mode: [] for mode in MODES}
        for _ in range(args.repeats):
            for mode, kwargs in MODES.items():
                start = time.perf_counter()
                env = gym.make(env_id, **kwargs)
                times[mode].append(time.perf_counter() - start)
                env.close()
        cells = ", ".join(f"{mode} {statistics.median(t) * 1e3:.1f} ms" for mode, t in times.items())
        print(f"{env_id}: {cells}")


if __name__ == "__main__":
    main()
