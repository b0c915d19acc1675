"""A certified global bound on σ_max(J) of an arm by branch and bound, and what it would do to the certificate.

    python docs/scripts/sigma_max_bound.py ur10 --tolerance 0.1 [--ratios RUN] [--samples 300]

The global Lipschitz constant of the lower bounds (``Kinematics.position_lipschitz_bound``: 2.52 m/rad for the UR10)
caps every step's Lₖ, and far from θ₀ the bound prices the motion at it. σ_max(J) does not depend on the first joint
(it turns the whole arm about a fixed axis) nor on a joint whose axis carries the end effector (its column is zero),
so its supremum is over the other joints, each a full turn. On a box with centre c and half-widths h,
σ_max(J(θ)) ≤ σ_max(J(c)) + Σₐ Mₐhₐ (Weyl, with Mₐ ≥ sup‖∂J/∂θₐ‖_F as in
``snac_gym.control.lower_bounds.jacobian_variation_bound``). Boxes whose bound is within ``tolerance`` of the largest
σ_max met are closed; the others are halved along their largest Mₐhₐ. The largest bound of a closed box is certified.

``--ratios RUN``: the optimum / certified-bound ratios of a finished ``snac-gym evaluate`` run (its first
``--samples`` samples of each task, its own cost), with Lₖ capped at the global L as now and at the certified
supremum instead.
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

from snac_gym.control.cost import CostConvention
from snac_gym.control.lower_bounds import _REVOLUTE_JOINTS, certified_cost_lower_bounds
from snac_gym.model.kinematics import Kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace

GRID = 6  # boxes per free joint to start with
BATCH = 200_000


def joint_variation(kinematics: Kinematics) -> np.ndarray:
    """Mₐ ≥ sup ‖∂J/∂θₐ‖_F per joint (``jacobian_variation_bound``'s terms, base first)."""
    model = kinematics.model
    joint_name, offset = kinematics.ee_mount()
    joint, reach = int(model.getJointId(joint_name)), float(np.linalg.norm(offset))
    chain: list[float] = []
    while joint > 0:
        axis = _REVOLUTE_JOINTS[model.joints[joint].shortname()]
        chain.append(float(np.linalg.norm(np.delete(np.asarray(offset, dtype=float), axis))) if not chain else reach)
        reach += float(np.linalg.norm(model.jointPlacements[joint].translation))
        joint = int(model.parents[joint])
    lengths = np.array(chain[::-1])
    return np.sqrt([(a + 1) * lengths[a] ** 2 + np.sum(lengths[a + 1 :] ** 2) for a in range(len(lengths))])


def certified_sigma_max(kinematics: Kinematics, tolerance: float) -> tuple[float, float, int]:
    """(certified sup σ_max(J), largest σ_max met, Jacobians evaluated)."""
    variation = joint_variation(kinematics)
    free = [a for a in range(1, len(variation)) if variation[a] > 0.0]  # the base joint and a zero column: none
    weights, joints = variation[free], kinematics.n_joints

    def sigma(centres: np.ndarray) -> np.ndarray:
        q = np.zeros((len(centres), joints))
        q[:, free] = centres
        out = np.empty(len(centres))
        for i in range(0, len(q), BATCH):
            _, jac = kinematics.forward_and_jacobian_batch(q[i : i + BATCH])
            out[i : i + BATCH] = np.sqrt(np.linalg.eigvalsh(jac @ np.swapaxes(jac, 1, 2))[:, -1])
        return out

    axes = [(np.arange(GRID) + 0.5) / GRID * 2 * np.pi - np.pi] * len(free)
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(free))
    halves = np.full_like(centres, np.pi / GRID)
    best, certified, evaluated = -np.inf, -np.inf, 0
    while len(centres):
        values = sigma(centres)
        evaluated += len(centres)
        best = max(best, float(values.max()))
        upper = values + halves @ weights
        closed = upper <= best + tolerance
        if closed.any():
            certified = max(certified, float(upper[closed].max()))
        centres, halves = centres[~closed], halves[~closed]
        rows = np.arange(len(centres))
        split = np.argmax(halves * weights, axis=1)
        halves[rows, split] /= 2
        offset = np.zeros_like(halves)
        offset[rows, split] = halves[rows, split]
        centres, halves = np.concatenate([centres - offset, centres + offset]), np.concatenate([halves, halves])
    return certified, best, evaluated


def ratios(run: Path, samples: int, cap: float | None) -> dict[str, np.ndarray]:
    """Per task, the run's optimum over the certified bound of its first ``samples`` samples, Lₖ capped at ``cap``."""
    config = json.loads((run / "run.json").read_text())
    kinematics = Kinematics(config["robot"])
    if cap is not None:
        kinematics.position_lipschitz_bound = lambda: cap  # type: ignore[method-assign]
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
        out[task] = cost / certified_cost_lower_bounds(kinematics, q0, x_d, dt, convention, limits, cost)
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
    certified, best, evaluated = certified_sigma_max(kinematics, args.tolerance)
    print(
        f"{args.robot}: global L {kinematics.position_lipschitz_bound():.4f}; largest sigma_max met {best:.4f}; "
        f"certified sup sigma_max <= {certified:.4f} (tolerance {args.tolerance}); {evaluated / 1e6:.2f} M "
        f"Jacobians, {time.perf_counter() - started:.1f} s"
    )
    if args.ratios is not None:
        for label, cap in (("global L", None), ("certified sup", certified)):
            for task, values in ratios(args.ratios, args.samples, cap).items():
                print(
                    f"  {label:13s} {task:5s} optimum / bound: median {np.median(values):.2f}, "
                    f"95th pct {np.percentile(values, 95):.2f}, max {values.max():.2f}"
                )


if __name__ == "__main__":
    main()
