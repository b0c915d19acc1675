"""Why the paper's SNAC fails the 12 s regulation test on the 7-DOF arms: success against the horizon.

    .venv/bin/python docs/scripts/snac_redundant_horizon.py

SNAC at its defaults on 200 random regulation samples of each arm (seed 0, the robot's sample
space, the exact kinematic model, no effort matching) for horizons of 12, 30 and 60 s, with the
median smallest singular value of the position Jacobian at the start poses. SNAC's command
``−½R⁻¹Jᵀ∇V̂`` moves the error along each singular direction at a rate ∝ σ², so arms with weaker
directions converge more slowly.
"""

from __future__ import annotations

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import EvaluationSample

from snac_gym.metrics import rollout_metrics
from snac_gym.policies import make_policy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace, sample_seed_pose, sample_target

SAMPLES = 200


def study(robot: str) -> str:
    context = policy_context(robot, 1 / 125, "reach")
    kinematics = context.kinematics
    space, rng = SampleSpace.for_robot(kinematics), np.random.default_rng(0)
    samples = [
        EvaluationSample("reach", i, sample_seed_pose(kinematics, rng, space), sample_target(kinematics, rng, space))
        for i in range(SAMPLES)
    ]
    sigma_min = np.median([kinematics.singular_values(s.q0)[-1] for s in samples])
    parts = []
    for seconds in (12, 30, 60):
        rollouts = simulate_kinematic(
            context,
            lambda: make_policy("snac", context),
            samples,
            round(seconds * 125),
            list(range(SAMPLES)),
            keep_states=False,
        )
        metrics = rollout_metrics(rollouts, "reach", context.velocity_limits)
        parts.append(
            f"{seconds} s: {100 * metrics.success.mean():.1f} % (median final "
            f"{1e3 * metrics.final_error.median():.2f} mm)"
        )
    return f"{robot}: median σ_min(J(θ0)) {sigma_min:.3f} m/rad; SNAC success " + "; ".join(parts)


if __name__ == "__main__":
    for name in ("ur10", "panda", "xarm7"):
        print(study(name), flush=True)
