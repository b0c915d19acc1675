"""Cost of the lockstep loop itself: :func:`snac_gym.rollout.simulate_kinematic` with a policy that only replays
commands (the optimum's :class:`~snac_gym.evaluation.reference.optimum.ReplayPolicy`), so what is timed is the loop,
the kinematics and the logs, not a controller.

500 samples at the main command's horizons (reach 1500 steps, track 2500), one BLAS thread, best of 3 after a
warm-up; prints µs per step of all 500 and per sample-step.

    python docs/scripts/engine_step_cost.py
"""

from __future__ import annotations

import time

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.optimum import ReplayPolicy
from snac_gym.evaluation.samples import generate_samples
from threadpoolctl import threadpool_limits

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace

SAMPLES = 500
HORIZONS = {"reach": 1500, "track": 2500}


def main() -> None:
    threadpool_limits(1)
    kinematics = shared_kinematics("ur10")
    space = SampleSpace.for_robot(kinematics)
    seeds = tuple(range(SAMPLES))
    for task, steps in HORIZONS.items():
        samples = tuple(generate_samples(kinematics, space, 0, task, range(SAMPLES)))
        context = policy_context("ur10", 0.008, task)
        commands = np.random.default_rng(0).uniform(-0.1, 0.1, (SAMPLES, steps, kinematics.n_joints))

        def run(count: int) -> None:
            simulate_kinematic(context, lambda: ReplayPolicy(commands), samples, count, seeds, True, "replay", False)

        run(20)
        best = np.inf
        for _ in range(3):
            started = time.perf_counter()
            run(steps)
            best = min(best, time.perf_counter() - started)
        print(f"{task}: {best / steps * 1e6:.0f} µs a step, {best / steps / SAMPLES * 1e6:.2f} µs a sample-step")


if __name__ == "__main__":
    main()
