"""A digest of a sample set: two versions of the code (or two machines) draw the same samples iff it matches.

    python docs/scripts/sample_digest.py SEED COUNT [cuboid|workspace] [ROBOT]

Draws ``COUNT`` reach and ``COUNT`` track samples of ``SEED`` (Table I's cuboid or the arm's whole
reach; default UR10) as the evaluator does, and prints the SHA-256 of every seed pose's bytes and
every reference's parameters, with the time it took.
"""

from __future__ import annotations

import hashlib
import sys
import time

import numpy as np
from snac_gym.evaluation.samples import generate_samples

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.sampling import SampleSpace


def main(seed: int, count: int, region: str = "cuboid", robot: str = "ur10") -> None:
    kinematics = shared_kinematics(robot)
    space = SampleSpace.for_robot(kinematics) if region == "cuboid" else SampleSpace.workspace(kinematics)
    digest, started = hashlib.sha256(), time.perf_counter()
    for task in ("reach", "track"):
        for sample in generate_samples(kinematics, space, seed, task, range(count)):
            digest.update(np.asarray(sample.q0, dtype=float).tobytes())
            digest.update(repr(vars(sample.reference)).encode())
    print(
        f"seed {seed}, {count} per task, {region}, {robot}: {digest.hexdigest()[:16]} "
        f"({time.perf_counter() - started:.1f} s)"
    )


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), *sys.argv[3:5])
