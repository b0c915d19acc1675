"""The reference with Newton's steps against Gauss-Newton's alone, on the same samples, one core.

    python docs/scripts/newton_check.py cuboid TASK COUNT SEED COST SECONDS
    python docs/scripts/newton_check.py workspace reach 60 11 table1 8
    python docs/scripts/newton_check.py workspace track 40 23 hjb 5

For COUNT samples of TASK drawn with SEED from the region (``cuboid``: Table I's; ``workspace``: the arm's whole reach)
under COST (``table1``, or ``hjb`` with Q = 4I) over SECONDS, it solves the reference (``run_optimal_job``, no cache)
with ``multistart.NEWTON`` off and on, and prints each one's CPU time and Gauss-Newton or Newton steps, the largest
relative cost differences (after − before), how many samples changed their winning start, how many moved by more than
1e-7, and whether every success flag is the same; then the samples that moved by more than 1e-7.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from snac_gym.evaluation.reference import multistart
from snac_gym.evaluation.reference.optimum import OptimalJob, run_optimal_job
from snac_gym.evaluation.samples import generate_samples
from threadpoolctl import threadpool_limits

from snac_gym.control.cost import CostConvention
from snac_gym.control.gauss_newton import GaussNewtonSolver
from snac_gym.model.kinematics import Kinematics
from snac_gym.sampling import SampleSpace

DT = 0.008


def main() -> None:
    region, task, count, seed, cost, seconds = sys.argv[1:7]
    kinematics = Kinematics("ur10")
    space = SampleSpace.workspace(kinematics) if region == "workspace" else SampleSpace.for_robot(kinematics)
    convention = CostConvention("hjb", "rest", 4.0) if cost == "hjb" else CostConvention()
    samples = tuple(generate_samples(kinematics, space, int(seed), task, range(int(count))))
    steps = int(round(float(seconds) / DT))
    job = OptimalJob(task, samples, tuple(range(len(samples))), steps, DT, "ur10", convention=convention)
    taken = [0]
    direction = GaussNewtonSolver.direction

    def counted(solver: Any, *args: Any, **kwargs: Any) -> np.ndarray:
        step = direction(solver, *args, **kwargs)
        taken[0] += 1  # a step taken: a Newton step refused (not positive definite) raised before this
        return step

    GaussNewtonSolver.direction = counted  # type: ignore[method-assign]
    rows = {}
    with threadpool_limits(1):
        run_optimal_job(OptimalJob(task, samples[:2], (0, 1), steps, DT, "ur10", convention=convention))  # compiles
        for newton in (False, True):
            multistart.NEWTON, taken[0] = newton, 0
            started = time.process_time()
            rows[newton] = (run_optimal_job(job).metrics, time.process_time() - started, taken[0])
    before, after = rows[False][0], rows[True][0]
    change = ((after.cost - before.cost) / before.cost).to_numpy()
    moved = np.flatnonzero(np.abs(change) > 1e-7)
    winners = before.optimal_winner.to_numpy(), after.optimal_winner.to_numpy()
    same_success = bool((before.success.to_numpy() == after.success.to_numpy()).all())
    print(f"{' '.join(sys.argv[1:7])}: Gauss-Newton {rows[False][1]:.2f} s, {rows[False][2]} steps; Newton "
          f"{rows[True][1]:.2f} s, {rows[True][2]} steps; cost change max {change.max():+.1e}, "
          f"min {change.min():+.1e}; winner changes {int((winners[0] != winners[1]).sum())}; "
          f"moved > 1e-7: {len(moved)}; success flags the same: {same_success}")  # fmt: skip
    for i in moved:
        print(f"  sample {before['sample'].iloc[i]}: {winners[0][i]} -> {winners[1][i]}, {change[i]:+.3e}")


if __name__ == "__main__":
    main()
