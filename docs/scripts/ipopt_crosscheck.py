"""The reference against IPOPT (CasADi) on samples it was not built on: the same constrained problem
(joint position and velocity limits), full horizons. The reference as the evaluator computes it (rest and
its own starts, evaluation/reference/optimum.py), IPOPT from rest, and IPOPT from the reference's
solution (a KKT check by an independent solver: it must not find a lower cost nearby).

Usage: python docs/scripts/ipopt_crosscheck.py ROBOT SPACE SEED COUNT COST
  e.g. python docs/scripts/ipopt_crosscheck.py ur10 workspace 11 10 hjb
Prints one line per sample and a summary: (ours − IPOPT)/IPOPT from rest and from ours, whether a limit
binds, and times.
"""

from __future__ import annotations

import functools
import sys
import time

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.ipopt import solve_with_ipopt
from snac_gym.evaluation.reference.multistart import COARSE_FACTOR
from snac_gym.evaluation.reference.optimum import multi_start_solve, own_start_commands
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import next_angles, single_threaded_blas
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

robot, region, seed, count, cost = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
kinematics = shared_kinematics(robot)
space = SampleSpace.workspace(kinematics) if region == "workspace" else SampleSpace.for_robot(kinematics)
convention = CostConvention(cost, "rest", 4.0 if cost == "hjb" else 1.0)
limits = (kinematics.lower_limits, kinematics.upper_limits)
gaps, polish, binding = [], [], 0
for task in ("reach", "track"):
    steps = round(get_task(task).horizon_s * 125)
    context = policy_context(robot, 1 / 125, task)
    samples = generate_samples(kinematics, space, seed, task, range(count))
    starts = own_start_commands(context, samples, steps, list(range(count)), factor=COARSE_FACTOR)
    for sample, candidates in zip(samples, starts, strict=True):
        x_d = reference_trajectories([sample.reference], np.arange(steps) / 125)[0][0]
        q0 = np.asarray(sample.q0, dtype=float)
        started = time.perf_counter()
        with single_threaded_blas():
            ours = multi_start_solve(q0, x_d, kinematics, 1 / 125, kinematics.velocity_limits, convention, candidates,
                                     position_limits=limits).solution  # fmt: skip
        ours_s = time.perf_counter() - started
        solve = functools.partial(solve_with_ipopt, q0, x_d, kinematics, 1 / 125, kinematics.velocity_limits,
                                  position_limits=limits, convention=convention)  # fmt: skip
        rest, near = solve(), solve(initial=ours.commands)
        angles = next_angles(ours.commands, q0, 1 / 125)
        binds = min(float((angles - limits[0]).min()), float((limits[1] - angles).min())) < 1e-6
        binding += binds
        gaps.append((ours.cost - rest.cost) / rest.cost)
        polish.append((ours.cost - near.cost) / near.cost)
        print(
            f"{task} {sample.index}: ours {ours.cost:.8g} ({ours_s:.2f} s) ipopt from rest {rest.cost:.8g} "
            f"({rest.seconds:.2f} s, {rest.status}) gap {gaps[-1]:+.2e}, from ours {polish[-1]:+.2e} "
            f"({near.status}) binds {binds}",
            flush=True,
        )
gaps, polish = np.array(gaps), np.array(polish)
print(
    f"{robot} {region} seed {seed} {cost}: {len(gaps)} samples ({binding} with a binding joint limit); "
    f"(ours − IPOPT from rest)/IPOPT: worst {gaps.max():+.2e}, above by more than 1e-4 on {(gaps > 1e-4).sum()}, "
    f"below by more than 1e-4 on {(gaps < -1e-4).sum()}; IPOPT from ours lowers it by at most {polish.max():.2e}"
)
