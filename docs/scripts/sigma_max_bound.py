"""The certified sup ‖J(θ)‖₂ of an arm by branch and bound, and what it does to the certificate.

    python docs/scripts/sigma_max_bound.py ur10 --tolerance 0.1 [--ratios RUN] [--samples 300]

Runs :func:`snac_gym.control.jacobian_bound.certified_jacobian_norm` at ``--tolerance`` (the shipped values come from
``tools/ship_jacobian_bounds.py``). ``--ratios RUN``: the optimum / certified-bound ratios of a finished
``snac-gym evaluate`` run (its first ``--samples`` samples of each task, its own cost), with the global L the summed
link lengths (as before the shipped bounds) and as the evaluator has it now (:func:`jacobian_norm_bound`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import read_samples_csv

import snac_gym.control.lower_bounds as lower_bounds
from snac_gym.control.cost import CostConvention
from snac_gym.control.jacobian_bound import certified_jacobian_norm, jacobian_norm_bound
from snac_gym.model.kinematics import Kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace


def _link_lengths(kinematics: Kinematics) -> float:
    return kinematics.position_lipschitz_bound()


def ratios(run: Path, samples: int, link_lengths: bool) -> dict[str, np.ndarray]:
    """Per task, the run's optimum over the certified bound of its first ``samples`` samples; ``link_lengths``: with
    the summed link lengths as the global L, else the evaluator's."""
    config = json.loads((run / "run.json").read_text())
    kinematics = Kinematics(config["robot"])
    lower_bounds.jacobian_norm_bound = _link_lengths if link_lengths else jacobian_norm_bound
    drawn = read_samples_csv(run / "samples.csv", kinematics, SampleSpace(**config["space"]))
    convention = CostConvention(config["cost"], config["udot_start"], config["q_scale"])
    results = pd.read_parquet(run / "results.parquet")
    optimal = results[results["controller"] == "optimal"]
    out = {}
    for task, task_samples in drawn.items():
        chosen = task_samples[:samples]
        steps, dt = config["steps"][task], config["dt"]
        x_d = reference_trajectories([s.reference for s in chosen], np.arange(steps) * dt, 3)[0]
        rows = optimal[optimal["task"] == task].set_index("sample").loc[[s.index for s in chosen]]
        cost = rows["optimal_solver_cost"].to_numpy()
        limits = np.asarray(policy_context(config["robot"], dt, task).velocity_limits, dtype=float)
        q0 = np.array([s.q0 for s in chosen])
        out[task] = cost / lower_bounds.certified_cost_lower_bounds(kinematics, q0, x_d, dt, convention, limits, cost)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("robot")
    parser.add_argument("--tolerance", type=float, default=0.1)
    parser.add_argument("--ratios", type=Path, help="a finished evaluate run")
    parser.add_argument("--samples", type=int, default=300)
    args = parser.parse_args()
    kinematics = Kinematics(args.robot)
    started = time.perf_counter()
    certified, best, evaluated = certified_jacobian_norm(kinematics, args.tolerance)
    print(
        f"{args.robot}: global L {kinematics.position_lipschitz_bound():.4f}; largest sigma_max met {best:.4f}; "
        f"certified sup sigma_max <= {certified:.4f} (tolerance {args.tolerance}); {evaluated / 1e6:.2f} M "
        f"Jacobians, {time.perf_counter() - started:.1f} s"
    )
    if args.ratios is not None:
        print(f"  the evaluator's global L: {jacobian_norm_bound(kinematics):.4f}")
        for label, lengths in (("link lengths", True), ("evaluator", False)):
            for task, values in ratios(args.ratios, args.samples, lengths).items():
                print(
                    f"  {label:13s} {task:5s} optimum / bound: median {np.median(values):.2f}, "
                    f"95th pct {np.percentile(values, 95):.2f}, max {values.max():.2f}"
                )


if __name__ == "__main__":
    main()
