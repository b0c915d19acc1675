"""How far the optimum's stopping rule leaves V above a solve run to rounding, on samples it was not set on.

    python docs/scripts/optimal_tolerance.py reach 11 40
    python docs/scripts/optimal_tolerance.py track 5 30 workspace

Arguments: task, seed, number of samples, sample space (``cuboid``, Table I's, or ``workspace``).
Each sample is solved from rest twice: with the default stopping rule (a step predicting a gain
≤ ``GAP_RTOL``·V, :mod:`snac_gym.evaluation.reference.optimum`) and with ``gap_rtol = 0``, ``gtol = 0``
and ``ftol = 1e-16`` (until rounding stops it). Prints the mean iterations of the default solve
and the largest relative excess of its V over the tight one.
"""

from __future__ import annotations

import sys

import numpy as np
from snac_gym.evaluation.samples import generate_samples
from threadpoolctl import threadpool_limits

from snac_gym.control.trajopt import GAP_RTOL, solve_sample
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.sampling import SampleSpace

STEPS = {"reach": 1500, "track": 2500}
DT = 0.008


def main(task: str, seed: int, count: int, region: str = "cuboid") -> None:
    kinematics = shared_kinematics("ur10")
    space = (
        SampleSpace.for_robot(kinematics) if region == "cuboid" else SampleSpace.for_robot(kinematics, region=region)
    )
    times = np.arange(STEPS[task]) * DT
    excess, iterations, tight_iterations = [], [], []
    for sample in generate_samples(kinematics, space, seed, task, range(count)):
        x_d, _ = sample.reference.trajectory(times)
        default = solve_sample(sample.q0, x_d, kinematics, DT, kinematics.velocity_limits)
        tight = solve_sample(
            sample.q0, x_d, kinematics, DT, kinematics.velocity_limits, gtol=0.0, ftol=1e-16, gap_rtol=0.0
        )
        excess.append((default.cost - tight.cost) / tight.cost)
        iterations.append(default.iterations)
        tight_iterations.append(tight.iterations)
    print(
        f"{task} seed {seed} {region}, {count} samples: iterations {np.mean(iterations):.2f} "
        f"(tight {np.mean(tight_iterations):.2f}); (V − V_tight)/V_tight max {max(excess):.2g}, "
        f"min {min(excess):.2g} (GAP_RTOL {GAP_RTOL:g})"
    )


if __name__ == "__main__":
    with threadpool_limits(1):
        main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), *sys.argv[4:5])
