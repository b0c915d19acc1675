"""Replay time per sample of the optimal reference's lockstep rollout, by job size (one core).

The optimal reference solves its samples one by one, then replays a job's solutions in one
lockstep rollout (:func:`snac_gym.rollout.simulate_kinematic`) so that they are measured on the
path every controller takes. This times that replay for 1500-step reach rollouts at several job
sizes and checks that the rows do not depend on the size (bit for bit).

    python docs/scripts/optimal_replay_batch.py
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

SAMPLES, STEPS, SIZES = 500, 1500, (50, 125, 250, 500)


def main() -> None:
    threadpool_limits(1)
    kinematics = shared_kinematics("ur10")
    context = policy_context("ur10", 0.008, "reach")
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), 0, "reach", range(SAMPLES))
    commands = np.random.default_rng(0).uniform(-0.1, 0.1, (SAMPLES, STEPS, kinematics.n_joints))
    errors: dict[int, np.ndarray] = {}
    print(f"{'job size':>8}  replay per sample (ms)")
    for size in SIZES:
        parts = []
        started = time.perf_counter()
        for first in range(0, SAMPLES, size):
            chunk = slice(first, first + size)
            rollouts = simulate_kinematic(
                context, lambda chunk=chunk: ReplayPolicy(commands[chunk]), samples[chunk], STEPS,
                list(range(len(samples[chunk]))), True, "optimal", keep_states=False,
            )  # fmt: skip
            parts.append(rollouts.errors)
        print(f"{size:>8}  {(time.perf_counter() - started) / SAMPLES * 1e3:.2f}")
        errors[size] = np.concatenate(parts)
    same = all(np.array_equal(errors[SIZES[0]], errors[size]) for size in SIZES)
    print(f"errors identical across job sizes: {same}")


if __name__ == "__main__":
    main()
