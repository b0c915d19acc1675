"""The reference against a multi-start IPOPT search (CasADi, another formulation: angles and commands as variables,
its own kinematics) on samples it was not built on.

Per sample, the reference as the evaluator computes it (:func:`solve_samples`: rest, its own feedback starts and the
other IK branches), and IPOPT from rest, from a start on every in-limit IK branch (unpruned: every goal
:func:`branch_goals` finds) and from RANDOM starts that go straight, inside the limits, to a random configuration of the
joint box. The cheapest IPOPT solution, re-scored by the project's cost, is compared with the reference.

Usage: python docs/scripts/reference_crosscheck.py ROBOT SPACE SEED COUNT COST TASK [RANDOM [BRANCHES [FIRST]]]
  e.g. python docs/scripts/reference_crosscheck.py ur10 workspace 211 100 hjb track 2 8
(BRANCHES: at most that many branch starts, the nearest θ₀ first; all by default. FIRST: the first sample index,
to continue a run that was stopped: samples FIRST..COUNT−1.)
Prints one line per sample and a summary line: (reference − best IPOPT)/best IPOPT, the count above 0.1 %.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.branches import branch_commands, branch_goals
from snac_gym.evaluation.reference.ipopt import solve_with_ipopt
from snac_gym.evaluation.reference.optimum import solve_samples
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import single_threaded_blas
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

robot, region, seed, count, cost, task = sys.argv[1:7]
seed, count = int(seed), int(count)
random_starts = int(sys.argv[7]) if len(sys.argv) > 7 else 3
most_branches = int(sys.argv[8]) if len(sys.argv) > 8 else None
first = int(sys.argv[9]) if len(sys.argv) > 9 else 0
kinematics = shared_kinematics(robot)
space = SampleSpace.workspace(kinematics) if region == "workspace" else SampleSpace.for_robot(kinematics)
convention = CostConvention(cost, "rest", 4.0 if cost == "hjb" else 1.0)
limits = (kinematics.lower_limits, kinematics.upper_limits)
dt = 1 / 125
steps = round(get_task(task).horizon_s / dt)
context = policy_context(robot, dt, task)
velocity = np.asarray(context.velocity_limits, dtype=float)
samples = generate_samples(kinematics, space, seed, task, range(first, count))
x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * dt, 3)[0]
rng = np.random.default_rng(seed + 7919)
gaps, worst = [], (0.0, None)
for i, sample in enumerate(samples):
    q0 = np.asarray(sample.q0, dtype=float)
    started = time.perf_counter()
    (ours,) = solve_samples(context, [sample], [sample.index], x_d[i : i + 1], dt, convention)
    ours_s = time.perf_counter() - started
    goals = branch_goals(kinematics, q0[None], x_d[i, :1, :])[0][:most_branches]
    box = rng.uniform(kinematics.lower_limits + 0.05, kinematics.upper_limits - 0.05, size=(random_starts, len(q0)))
    targets = np.concatenate([goals, box])
    # a random configuration's start: straight to it (the branch law towards a point that reaches nothing)
    starts = branch_commands(
        kinematics,
        np.repeat(q0[None], len(targets), axis=0),
        targets,
        np.repeat(x_d[i : i + 1, :1], len(targets), axis=0).repeat(steps, axis=1),
        dt,
        velocity,
    )
    starts[len(goals) :, steps // 2 :] = 0.0  # then hold
    started = time.perf_counter()
    with single_threaded_blas():
        solutions = [solve_with_ipopt(q0, x_d[i], kinematics, dt, velocity, position_limits=limits,
                                      convention=convention)]  # fmt: skip
        solutions += [solve_with_ipopt(q0, x_d[i], kinematics, dt, velocity, initial=start, position_limits=limits,
                                       convention=convention) for start in starts]  # fmt: skip
    ipopt_s = time.perf_counter() - started
    best = min((s for s in solutions if s.success), key=lambda s: s.cost, default=min(solutions, key=lambda s: s.cost))
    gap = (ours.solution.cost - best.cost) / best.cost
    gaps.append(gap)
    if gap > worst[0]:
        worst = (gap, sample.index)
    print(
        f"{task} {sample.index}: reference {ours.solution.cost:.8g} ({ours.winner}, {ours.starts} solves, "
        f"{ours_s:.2f} s); IPOPT best {best.cost:.8g} of {len(solutions)} starts ({len(goals)} branches, "
        f"{sum(s.success for s in solutions)} converged, {ipopt_s:.1f} s); gap {gap:+.2e}",
        flush=True,
    )
gaps = np.array(gaps)
print(
    f"{robot} {region} seed {seed} {cost} {task}: {len(gaps)} samples; (reference − best IPOPT)/best IPOPT: worst "
    f"{gaps.max():+.2e} (sample {worst[1]}), above 0.1 % on {(gaps > 1e-3).sum()}, above 1e-6 on "
    f"{(gaps > 1e-6).sum()}, below −1e-6 on {(gaps < -1e-6).sum()}"
)
