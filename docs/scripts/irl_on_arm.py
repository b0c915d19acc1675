"""What ``snac-irl`` learns on the moving arm: how many episodes accept the learned gain, and how far it is from
the frozen-J optimum K*(J(θ_L)) at the pose where it was learned (the true arm's J, which the learner never sees).

    python docs/scripts/irl_on_arm.py --samples 20 --seed 0
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

DT = 1.0 / 125.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--task", default="reach")
    args = parser.parse_args()
    kinematics = shared_kinematics("ur10")
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), args.seed, args.task, range(args.samples))
    seeds = [policy_seed(args.seed, args.task, s.index) for s in samples]
    context = policy_context("ur10", DT, args.task)
    built: list = []

    def build():
        built.append(make_policy("snac-irl", context, Q=[4.0, 4.0, 4.0]))
        return built[-1]

    probe = make_policy("snac-irl", context)
    steps = probe.learning_steps + 1
    rollouts = simulate_kinematic(context, build, samples, steps, seeds, True, plant=task_kinematics("ur10", args.task))
    policy = built[0]
    batch = policy._batch
    learned = batch["learned"]
    pose = rollouts.q[:, probe.learning_steps]  # θ_L, where the data end
    optimal = policy.lqr.gain(kinematics.jacobian_batch(pose))
    errors = np.linalg.norm(batch["gain"] - optimal, axis=(1, 2)) / np.linalg.norm(optimal, axis=(1, 2))
    print(f"learned on {int(learned.sum())} of {len(learned)} episodes (the others keep K0)")
    print("relative gain error ‖K − K*(J(θ_L))‖/‖K*‖ of the learned ones:", np.round(errors[learned], 3))
    print(
        "and of K0 (the model's gain at θ0) on the same episodes:",
        np.round(
            (np.linalg.norm(batch["initial_gain"] - optimal, axis=(1, 2)) / np.linalg.norm(optimal, axis=(1, 2)))[
                learned
            ],
            3,
        ),
    )


if __name__ == "__main__":
    main()
