"""How fast ``snac-adaptive`` corrects a wrong arm model, and what excitation that took.

Runs ``snac-adaptive`` (and ``snac-hjb`` for comparison) under a model error on the evaluator's
samples (kinematic engine, the same seeds and horizons as ``snac-gym evaluate``), records the
identifier's prediction error ‖x − x̂(θ)‖ at every step, and reports per task, as medians and 95th
percentiles over the samples:

* the time until the model's prediction error first stays under 1 mm and under 0.1 mm;
* the time until the tracking error first stays under 5 mm (``track``; for both controllers);
* the Jacobian error ‖Ĵ − J‖/‖J‖ at the end, against the true arm;
* λ_min of the accumulated information Σ HᵀH/σ² at the end, and its rank (eigenvalues above
  1e-6 of the largest): the excitation the motion gave, no dither added.

    python docs/scripts/adaptation_speed.py --samples 200 --model-error "joint_offset=0,0,0.3,0,0,0"
"""

from __future__ import annotations

import argparse

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context, task_kinematics
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.model.kinematics import shared_kinematics
from snac_gym.policies.registry import make_policy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

DT = 1.0 / 125.0


def first_stays_below(values: np.ndarray, bound: float, dt: float) -> np.ndarray:
    """Per row of ``(B, K)`` values, the time after which every value is below ``bound`` (inf if never)."""
    above = values >= bound
    last_above = np.where(above.any(axis=1), values.shape[1] - 1 - np.argmax(above[:, ::-1], axis=1), -1)
    return np.where(last_above < values.shape[1] - 1, (last_above + 1) * dt, np.inf)


def run(task: str, count: int, model_error: str, seed: int) -> None:
    kinematics = shared_kinematics("ur10")
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), seed, task, range(count))
    seeds = [policy_seed(seed, task, s.index) for s in samples]
    steps = get_task(task).horizon_steps(DT)
    context = policy_context("ur10", DT, task, model_error)
    plant = task_kinematics("ur10", task)
    built: list = []

    def adaptive():
        policy = make_policy("snac-adaptive", context, Q=[4.0, 4.0, 4.0])
        built.append(policy)
        update = policy.identifier.update
        residuals: list[np.ndarray] = []

        def recorded(q, x):
            jacobians = update(q, x)
            residuals.append(policy.identifier.residual.copy())
            return jacobians

        policy.identifier.update = recorded
        policy.residuals = residuals
        return policy

    rollouts = simulate_kinematic(context, adaptive, samples, steps, seeds, True, "snac-adaptive", plant=plant)
    policy = built[0]
    residual = np.stack(policy.residuals, axis=1)  # (B, K)
    identifier = policy.identifier
    final_jacobian = identifier.jacobians(rollouts.final_q)
    true_jacobian = plant.jacobian_batch(rollouts.final_q)
    jacobian_error = np.linalg.norm(final_jacobian - true_jacobian, axis=(1, 2)) / np.linalg.norm(
        true_jacobian, axis=(1, 2)
    )
    eigenvalues = np.linalg.eigvalsh(identifier.information)
    rank = (eigenvalues > 1e-6 * eigenvalues[:, -1:]).sum(axis=1)

    def line(label: str, values: np.ndarray, unit: str = "s", fmt: str = ".3f") -> None:
        median, p95 = (np.quantile(values, level, method="inverted_cdf") for level in (0.5, 0.95))
        never = np.isinf(values).sum()
        print(
            f"  {label:52s} median {median:{fmt}} {unit}, p95 {p95:{fmt}} {unit}"
            + (f", never on {never} of {len(values)}" if never else "")
        )

    print(f"{task}: {count} samples, model error {model_error!r}")
    line("model prediction error stays < 1 mm after", first_stays_below(residual, 1e-3, DT))
    line("model prediction error stays < 0.1 mm after", first_stays_below(residual, 1e-4, DT))
    if task == "track":
        errors = np.linalg.norm(rollouts.errors, axis=2)
        line("snac-adaptive: tracking error stays < 5 mm after", first_stays_below(errors, 5e-3, DT))
        hjb = simulate_kinematic(
            context, lambda: make_policy("snac-hjb", context, Q=[4.0, 4.0, 4.0]), samples, steps, seeds, True,
            "snac-hjb", plant=plant,
        )  # fmt: skip
        line("snac-hjb (wrong model): tracking error stays < 5 mm after",
             first_stays_below(np.linalg.norm(hjb.errors, axis=2), 5e-3, DT))  # fmt: skip
    line("final ‖Ĵ − J‖/‖J‖", jacobian_error, "", ".2e")
    line("final λ_min(Σ HᵀH/σ²)", eigenvalues[:, 0], "", ".3g")
    print(f"  rank of Σ HᵀH (of {identifier.size}): median {int(np.median(rank))}, min {rank.min()}, max {rank.max()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model-error", default="joint_offset=0,0,0.3,0,0,0")
    args = parser.parse_args()
    for task in ("reach", "track"):
        run(task, args.samples, args.model_error, args.seed)


if __name__ == "__main__":
    main()
