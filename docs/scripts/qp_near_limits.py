"""Reaching next to a joint position limit on a 7-DOF arm: where the QP's limit constraints change the outcome.

Each sample starts at the robot's nominal pose perturbed by up to ±0.3 rad per joint, with one random
joint moved to 0.02-0.15 rad from one of its position limits; the target is where moving that joint
0.3 rad further (through the limit) would put the end effector, kept only if IK reaches it inside the
limits from the start pose. The least-norm motion then runs into the limit, and a controller reaches
the target only if the other joints take over. Every controller runs at its default settings (no
effort matching) for 12 s on the exact kinematic model (the evaluator's engine); reported per
controller: success (final ‖e‖ ≤ 1 mm), median final error, the closest approach to a position limit
(``joint_limit_margin``: min and the number of samples below 0, i.e. crossing) and the median peak
|u|/ū.

    python docs/scripts/qp_near_limits.py [ROBOT [SAMPLES [CONTROLLERS]]]     # panda 100 dls,...,pink,mink

(``dls-unguarded`` is ``dls`` with ``joint_limits=False``.)
"""

from __future__ import annotations

import sys
import time

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import EvaluationSample

from snac_gym.metrics import rollout_metrics
from snac_gym.policies import make_policy
from snac_gym.references import FixedTarget
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import nominal_configuration, solve_reachable

DT, STEPS = 1 / 125, 1500
DEFAULT = "dls-unguarded,dls,svf,rnn,lqr,pink,mink"


def near_limit_samples(kinematics, count: int, seed: int = 0) -> list[EvaluationSample]:
    rng = np.random.default_rng(seed)
    lower, upper = kinematics.lower_limits, kinematics.upper_limits
    samples: list[EvaluationSample] = []
    while len(samples) < count:
        q0 = np.clip(
            nominal_configuration(kinematics) + rng.uniform(-0.3, 0.3, kinematics.n_joints), lower + 0.2, upper - 0.2
        )
        joint, gap, up = rng.integers(kinematics.n_joints), rng.uniform(0.02, 0.15), rng.random() < 0.5
        q0[joint] = upper[joint] - gap if up else lower[joint] + gap
        beyond = q0.copy()
        beyond[joint] += 0.3 if up else -0.3
        target = kinematics.forward(beyond)
        if solve_reachable(kinematics, target, q0) is None:
            continue
        samples.append(EvaluationSample("reach", len(samples), q0, FixedTarget(target)))
    return samples


def main(argv: list[str]) -> None:
    robot = argv[0] if argv else "panda"
    count = int(argv[1]) if len(argv) > 1 else 100
    names = (argv[2] if len(argv) > 2 else DEFAULT).split(",")
    context = policy_context(robot, DT, "reach")
    kinematics = context.kinematics
    samples = near_limit_samples(kinematics, count)
    print(f"{robot}: {count} reach samples next to a position limit, {STEPS} steps of {DT} s, default settings")
    print(
        f"{'controller':14s} {'success':>8s} {'median final (mm)':>18s} {'margin min (rad)':>17s} "
        f"{'crossing':>9s} {'median peak |u|/ū':>18s} {'wall s':>7s}"
    )
    for name in names:
        base, kwargs = (
            (name.removesuffix("-unguarded"), {"joint_limits": False}) if name.endswith("-unguarded") else (name, {})
        )
        started = time.perf_counter()
        rollouts = simulate_kinematic(
            context,
            lambda b=base, k=kwargs: make_policy(b, context, **k),
            samples,
            STEPS,
            list(range(count)),
            keep_states=True,
        )
        metrics = rollout_metrics(
            rollouts, "reach", context.velocity_limits, None, (kinematics.lower_limits, kinematics.upper_limits)
        )
        margin = metrics["joint_limit_margin"]
        print(
            f"{name:14s} {metrics['success'].mean():8.1%} {metrics['final_error'].median() * 1e3:18.3f} "
            f"{margin.min():17.4f} {int((margin < 0).sum()):9d} {metrics['peak_limit_fraction'].median():18.3f} "
            f"{time.perf_counter() - started:7.1f}"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
