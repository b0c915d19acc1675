"""How tight the certified lower bound on the trajectory cost is, and how fast (docs/lower-bounds.md).

On the evaluator's default samples (seed 0, the UR10 cuboid, its horizons: reach 12 s, track 20 s,
Δt = 8 ms), per task and cost convention: the numerical optimum of each sample
(:func:`snac_gym.evaluation.reference.optimum.solve_sample` from rest, the evaluator's tolerances) against the bounds of
:func:`snac_gym.control.optimality.certified_cost_lower_bounds` (‖ū‖₂ as the velocity limit):

* ``global L``: the global Lipschitz bound of ``Kinematics.position_lipschitz_bound`` (one relaxation);
* ``V̄ = optimum``: the per-step Lipschitz bounds of the joint ball a trajectory costing at most the optimum
  can reach (one relaxation);
* ``V̄ = optimum, 3 bisections``: three more relaxations towards the crossing B(V̄) = V̄;
* ``regulation`` (reach only): the older :func:`snac_gym.control.optimality.regulation_cost_lower_bound`.

Prints the ratio optimum / bound (median, 95th percentile, largest; a bound above an optimum would be a
failure and is counted) and the bound's time per sample, in one batched call over the samples after a warm-up
call that loads the compiled kernel.

    nice -n 10 python docs/scripts/lower_bound_tightness.py --samples 100
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.lower_bounds import certified_cost_lower_bounds, regulation_cost_lower_bound
from snac_gym.control.trajopt import single_threaded_blas, solve_sample
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

DT = 1.0 / 125.0
CONVENTIONS = {"table1": CostConvention(), "hjb": CostConvention("hjb")}


def row(task: str, cost: str, variant: str, optima: np.ndarray, compute: Callable[[], np.ndarray]) -> str:
    started = time.perf_counter()
    bounds = compute()
    per_sample = (time.perf_counter() - started) / len(optima) * 1e3
    ratios = optima / bounds
    return (
        f"| {task} | {cost} | {variant} | {np.median(ratios):.2f} | {np.percentile(ratios, 95):.2f} "
        f"| {ratios.max():.2f} | {int(np.sum(ratios < 1))} | {per_sample:.2f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    kinematics = shared_kinematics("ur10")
    limits, lipschitz = kinematics.velocity_limits, kinematics.position_lipschitz_bound()
    certified_cost_lower_bounds(kinematics, np.zeros(6), np.ones((9, 3)), DT)  # loads (or compiles) the kernel
    print("| task | cost | bound | optimum / bound: median | 95th pct | max | bound above optimum | ms / sample |")
    print("|---|---|---|---|---|---|---|---|")
    for task in ("reach", "track"):
        steps = get_task(task).horizon_steps(DT)
        samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), args.seed, task, range(args.samples))
        x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * DT)[0]
        q0 = np.array([s.q0 for s in samples], dtype=float)
        for name, convention in CONVENTIONS.items():
            with single_threaded_blas():
                optima = np.array([solve_sample(q0[i], x_d[i], kinematics, DT, limits, convention=convention).cost
                                   for i in range(len(samples))])  # fmt: skip
            variants = {
                "global L": lambda: certified_cost_lower_bounds(kinematics, q0, x_d, DT, convention, limits),
                "V̄ = optimum": lambda: certified_cost_lower_bounds(kinematics, q0, x_d, DT, convention, limits, optima),
                "V̄ = optimum, 3 bisections": lambda: certified_cost_lower_bounds(
                    kinematics, q0, x_d, DT, convention, limits, optima, refinements=3),
            }  # fmt: skip
            if task == "reach":
                errors = np.linalg.norm(kinematics.forward_batch(q0) - x_d[:, 0], axis=-1)
                variants["regulation"] = lambda: regulation_cost_lower_bound(errors, steps, DT, lipschitz)
            for variant, compute in variants.items():
                print(row(task, name, variant, optima, compute), flush=True)


if __name__ == "__main__":
    main()
