"""Seconds per sample-step of the evaluator's physics engines: the lockstep path against the env's loop.

On the same samples, each controller is rolled out by ``simulate_env`` (one env episode per sample,
the demo's loop: what ``--engine mujoco|pybullet`` ran before the lockstep path) and by
``simulate_arms`` (one arm per sample in lockstep), in the same process, one after the other, on one
core; the two give the same rollouts (``tests/rollout/test_batch.py``).

    python docs/scripts/engine_speed.py [SAMPLES] [STEPS]
"""

from __future__ import annotations

import functools
import os
import sys
import time

from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.model.kinematics import Kinematics
from snac_gym.policies import make_policy
from snac_gym.rollout import lockstep_arms, simulate_arms, simulate_env
from snac_gym.sampling import SampleSpace


def main(count: int = 50, steps: int = 500) -> None:
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    kinematics = Kinematics("ur10")
    print(f"{count} samples x {steps} steps, UR10; µs per sample-step")
    print(f"{'physics':9s} {'task':6s} {'controller':10s} {'env loop':>9s} {'lockstep':>9s} {'speed-up':>9s}")
    for physics in ("mujoco", "pybullet"):
        for task in ("reach", "track"):
            samples = tuple(generate_samples(kinematics, SampleSpace.for_robot(kinematics), 0, task, range(count)))
            seeds = tuple(policy_seed(0, task, s.index) for s in samples)
            context = policy_context("ur10", 0.008, task)
            for controller in ("dls", "snac"):
                start = time.perf_counter()
                simulate_env(
                    "ur10",
                    task,
                    0.008,
                    functools.partial(make_policy, controller),
                    samples,
                    steps,
                    seeds,
                    physics=physics,
                )
                env_time = time.perf_counter() - start
                start = time.perf_counter()
                arms, plant = lockstep_arms("ur10", task, 0.008, steps, physics, count)
                simulate_arms(
                    context, functools.partial(make_policy, controller, context), samples, steps, seeds, arms, plant
                )
                lockstep_time = time.perf_counter() - start
                per = 1e6 / (count * steps)
                print(
                    f"{physics:9s} {task:6s} {controller:10s} {env_time * per:9.1f} {lockstep_time * per:9.1f}"
                    f" {env_time / lockstep_time:8.1f}x",
                    flush=True,
                )


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
