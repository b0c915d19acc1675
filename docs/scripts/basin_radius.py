"""How close a start comes to a known local optimum before it ends in another: the check behind the reference's
BASIN_RADIUS (evaluation/reference/optimum.py).

    python docs/scripts/basin_radius.py workspace 29 30            # Table I's cost
    python docs/scripts/basin_radius.py workspace 31 30 --hjb      # the HJB cost, Q = 4I

For N samples per task of a region and seed, it solves from rest, then takes each of the reference's own starts
through three Gauss-Newton steps, recording after each the largest joint distance (rad, over the horizon) to the
best optimum so far, then solves it to the end. It prints, for several radii, how many starts came within the
radius of the incumbent and how many of those still ended in a better optimum (relative cost below −1e-6): a
radius is safe where that count is 0.
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.optimum import own_start_commands
from snac_gym.evaluation.samples import generate_sample

from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import FTOL, GTOL, angles, gauss_newton, solve_sample
from snac_gym.model.kinematics import Kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace

HORIZONS = {"reach": 1500, "track": 2500}
DT = 0.008


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("region", choices=("cuboid", "workspace"))
    parser.add_argument("seed", type=int)
    parser.add_argument("samples", type=int)
    parser.add_argument("--hjb", action="store_true", help="the HJB cost with Q = 4I instead of Table I's")
    args = parser.parse_args()
    kinematics = Kinematics("ur10")
    space = SampleSpace.workspace(kinematics) if args.region == "workspace" else SampleSpace()
    convention = CostConvention("hjb", "rest", 4.0) if args.hjb else CostConvention()
    limits = (kinematics.lower_limits, kinematics.upper_limits)
    rows = []
    for task, steps in HORIZONS.items():
        samples = tuple(generate_sample(kinematics, space, args.seed, task, i) for i in range(args.samples))
        context = policy_context("ur10", DT, task)
        x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * DT, 3)[0]
        starts = own_start_commands(context, samples, steps, tuple(range(len(samples))), True)
        velocity = np.asarray(context.velocity_limits)
        for i, sample in enumerate(samples):
            q0 = np.asarray(sample.q0)
            best = solve_sample(q0, x_d[i], kinematics, DT, velocity, convention=convention, position_limits=limits)
            for name, commands in starts[i].items():
                incumbent, distances, current = angles(best.commands, q0, DT), [], commands
                for _ in range(3):
                    current = gauss_newton(q0, x_d[i], kinematics, DT, current, GTOL, FTOL, 1, convention)[0]
                    distances.append(float(np.abs(angles(current, q0, DT) - incumbent).max()))
                solved = solve_sample(q0, x_d[i], kinematics, DT, velocity, initial=current, interior_start=commands,
                                      convention=convention, position_limits=limits)  # fmt: skip
                rows.append((task, i, name, min(distances), (solved.cost - best.cost) / best.cost))
                if solved.cost < best.cost:
                    best = solved
    table = pd.DataFrame(rows, columns=["task", "sample", "start", "closest", "relative_cost"])
    for radius in (0.05, 0.1, 0.2, 0.3):
        near = table[table.closest < radius]
        better = near[near.relative_cost < -1e-6]
        print(
            f"radius {radius}: {len(near)} of {len(table)} starts came within it; {len(better)} of those ended better"
        )
    elsewhere = table[table.relative_cost < -1e-6]
    if len(elsewhere):
        print(f"starts that ended in a better optimum came no closer than {elsewhere.closest.min():.2f} rad")


if __name__ == "__main__":
    main()
