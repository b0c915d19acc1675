"""Cost of one lockstep step per controller, and what the main command's passes cost in CPU time.

Times one kinematic-engine job per controller and task (500 samples, 100 steps, after a warm-up
job, one BLAS thread), prints µs per sample-step, and from it the CPU seconds of one full pass of
1000 samples at the main command's horizons (reach 1500 steps, track 2500 steps).

    python docs/scripts/controller_step_cost.py
"""

from __future__ import annotations

import time

from snac_gym.evaluation.execution.jobs import RolloutJob, run_job
from snac_gym.evaluation.samples import generate_samples
from threadpoolctl import threadpool_limits

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.sampling import SampleSpace

CONTROLLERS = ("snac", "snac-hjb", "lqr", "rnn", "svf", "dls", "ppo")
HORIZONS = {"reach": 1500, "track": 2500}
SAMPLES, STEPS = 500, 100


def main() -> None:
    threadpool_limits(1)
    kinematics = shared_kinematics("ur10")
    space = SampleSpace.for_robot(kinematics)
    total = 0.0
    print(f"{'task':6s} {'controller':10s} {'µs/sample-step':>15s} {'1000-sample pass (CPU s)':>26s}")
    for task, horizon in HORIZONS.items():
        samples = tuple(generate_samples(kinematics, space, 0, task, range(SAMPLES)))
        for controller in CONTROLLERS:
            job = RolloutJob(task=task, controller=controller, kwargs={}, samples=samples,
                             seeds=tuple(range(SAMPLES)), steps=STEPS, dt=0.008)  # fmt: skip
            run_job(job)
            started = time.perf_counter()
            run_job(job)
            per_step = (time.perf_counter() - started) / STEPS / SAMPLES
            full_pass = per_step * 1000 * horizon
            total += full_pass if controller != "snac" else 0.0
            print(f"{task:6s} {controller:10s} {per_step * 1e6:15.1f} {full_pass:26.1f}")
    print(f"every matched controller's final full pass, both tasks: {total:.0f} CPU s")


if __name__ == "__main__":
    main()
