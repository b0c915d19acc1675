"""Which divergence bound ``snac-adaptive`` crossed, and when, on chosen samples of an evaluation (the evaluator's
results keep the flag and its time, not the bound): reruns those samples as ``snac-gym evaluate`` does (kinematic
engine, the same samples, seeds and horizons, Q = 4·I) and prints each one's reason and final error.

    python docs/scripts/flag_reasons.py --seed 6202 --sample-space workspace --model-error model=ur3 \\
        --reach 16,32,76 --track 37,60
"""

from __future__ import annotations

import argparse

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context, task_kinematics
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.policies.registry import make_policy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

DT = 1.0 / 125.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--sample-space", default="cuboid", choices=("cuboid", "workspace"))
    parser.add_argument("--model-error", default=None)
    parser.add_argument("--reach", default="", help="comma-separated sample indices")
    parser.add_argument("--track", default="", help="comma-separated sample indices")
    args = parser.parse_args()
    kinematics = shared_kinematics("ur10")
    space = SampleSpace.workspace(kinematics) if args.sample_space == "workspace" else SampleSpace.for_robot(kinematics)
    for task in ("reach", "track"):
        indices = [int(i) for i in getattr(args, task).split(",") if i]
        if not indices:
            continue
        samples = generate_samples(kinematics, space, args.seed, task, indices)
        context = policy_context("ur10", DT, task, args.model_error)
        built: list = []

        def build(context=context, built=built):
            built.append(make_policy("snac-adaptive", context, Q=[4.0, 4.0, 4.0]))
            return built[-1]

        rollouts = simulate_kinematic(
            context, build, samples, get_task(task).horizon_steps(DT),
            [policy_seed(args.seed, task, s.index) for s in samples], True, "snac-adaptive",
            plant=task_kinematics("ur10", task),
        )  # fmt: skip
        monitor = built[0].monitor
        for row, index in enumerate(indices):
            reason = monitor.describe(row) or "not flagged"
            final = np.linalg.norm(rollouts.errors[row, -1])
            print(f"{task} {index}: {reason} ({monitor.step[row] * DT:.2f} s); final error {final * 1e3:.1f} mm")


if __name__ == "__main__":
    main()
