"""The reference with and without some of its own feedback starts, sample by sample: what those starts find that the
others do not.

    python docs/scripts/start_ablation.py START[,START...] SPACE SEED COUNT COST TASK HORIZON_S [--velocity-only]
    e.g. python docs/scripts/start_ablation.py dls workspace 811 100 hjb reach 5

Per sample of ``SPACE`` (``cuboid``, Table I's, or ``workspace``, the arm's whole reach) drawn at ``SEED``, the
reference as the evaluator computes it (:func:`~snac_gym.evaluation.reference.optimum.solve_samples`: rest, the own
starts, the IK branches, the random starts) once with every start of ``OWN_STARTS`` and once without the named ones
(``OWN_STARTS`` given as they were, e.g. ``lqr:q_scale=9,dls,joint-goal``, with ``--starts``). ``COST``: ``table1``
(q = 1) or ``hjb`` (q = 4, as the IPOPT cross-checks). Prints one line per sample (the two costs, their winners, the
relative difference) and a summary: the samples where the reference without them is above by more than 1e-6, and the
CPU time of each (one core; a sample at a time, so the rollouts' per-step overheads weigh far more than in the
evaluator's jobs of 250: time those with a run's jobs instead, as ``table1_floor.py`` does).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference import optimum
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import single_threaded_blas
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace

DT = 1.0 / 125.0


def _starts(text: str) -> tuple[tuple[str, dict[str, Any]], ...]:
    starts = []
    for item in text.split(","):
        name, _, settings = item.partition(":")
        kwargs = {key: float(value) for key, value in (pair.split("=") for pair in settings.split(";") if pair)}
        starts.append((name, kwargs))
    return tuple(starts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("without", help="the own starts left out, comma-separated")
    parser.add_argument("space", choices=("cuboid", "workspace"))
    parser.add_argument("seed", type=int)
    parser.add_argument("count", type=int)
    parser.add_argument("cost", choices=("table1", "hjb"))
    parser.add_argument("task", choices=("reach", "track"))
    parser.add_argument("horizon", type=float, help="seconds")
    parser.add_argument("--velocity-only", action="store_true", help="the reference without the position limits")
    parser.add_argument("--starts", type=_starts, default=optimum.OWN_STARTS, help="the full set (default: OWN_STARTS)")
    args = parser.parse_args()
    kinematics = shared_kinematics("ur10")
    space = SampleSpace.workspace(kinematics) if args.space == "workspace" else SampleSpace.for_robot(kinematics)
    convention = CostConvention(args.cost, "rest", 4.0 if args.cost == "hjb" else 1.0)
    context = policy_context("ur10", DT, args.task)
    steps = round(args.horizon / DT)
    left_out = set(args.without.split(","))
    variants = {"all": args.starts, "without": tuple(s for s in args.starts if s[0] not in left_out)}
    above, seconds = 0, dict.fromkeys(variants, 0.0)
    for index in range(args.count):
        sample = generate_samples(kinematics, space, args.seed, args.task, [index])
        x_d = reference_trajectories([sample[0].reference], np.arange(steps) * DT, 3)[0]
        found = {}
        for name, starts in variants.items():
            optimum.OWN_STARTS = starts
            started = time.process_time()
            with single_threaded_blas():
                found[name] = optimum.solve_samples(
                    context, sample, [0], x_d, DT, convention, position_limits=not args.velocity_only
                )[0]
            seconds[name] += time.process_time() - started
        full, without = found["all"].solution.cost, found["without"].solution.cost
        relative = (without - full) / full
        above += relative > 1e-6
        print(
            f"{args.space} {args.seed} {args.cost} {args.task} {index:3d}: all {full:.8g} ({found['all'].winner}), "
            f"without {without:.8g} ({found['without'].winner}), {relative:+.2e}",
            flush=True,
        )
    print(
        f"summary: {args.count} samples, without {args.without} above by more than 1e-6 on {above}; "
        f"CPU {seconds['all']:.1f} s with every start, {seconds['without']:.1f} s without"
    )


if __name__ == "__main__":
    main()
