"""Time ``gym.make`` of the PyBullet ids without a render mode (no meshes) and with ``rgb_array`` (meshes), in one run.

Each id is built and closed ``--repeats`` times per mode, the modes alternating; the median is printed
in ms (docs/benchmarks.md). A drawn arm's visuals load from their OBJ copies (snac_gym/physics/meshes.py), written
before the timing if missing; ``--dae`` loads the COLLADA files themselves, as before those copies.

    python docs/scripts/env_construction_time.py [--dae]
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
    parser.add_argument("--dae", action="store_true", help="load the .dae visuals, not their OBJ copies")
    args = parser.parse_args()
    if args.dae:
        import snac_gym.physics.bullet as bullet  # noqa: PLC0415 - only to turn the copies off

        bullet.visual_meshes_as_obj = lambda urdf: urdf
    for env_id in IDS:  # imports, the URDF cache and the OBJ copies out of the timing
        gym.make(env_id, render_mode="rgb_array").close()
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
