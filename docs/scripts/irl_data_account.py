"""What data ``snac-irl`` learns from on the arm, and where its learned gain is wrong.

Rolls ``snac-irl`` out (kinematic engine, the evaluator's samples and seeds, Q = 4·I) to the end of its exploration
(step L), keeps the L windows Algorithm 1 gets, and reports per episode:

* the spread of the error's directions over the data: σ₂/σ₁ and σ₃/σ₁ of the 3 × (L + 1) matrix [e₀ … e_L] (1: e
  moves in every direction as much as along its main one; near 0: the data see e along one line);
* the smallest relative singular value of eq. 13's matrix [I_xx, I_xu] (its rank is what is checked; its conditioning
  is what decides how far the least squares' answer moves with the data's integration error);
* how far the true arm's J moved over the data, ‖J(θ_L) − J(θ₀)‖/‖J(θ₀)‖ (the iteration assumes one J);
* the learned K (where Algorithm 1 accepted it) against K* = R⁻¹J(θ_L)ᵀP*(J(θ_L)) of the true arm, split into
  the error on the main direction d₁ of the data's e, ‖(K − K*)d₁‖/‖K*d₁‖, and across it,
  ‖(K − K*)d₃‖/‖K*d₃‖ (d₃: the direction the data's e moved least in).

    python docs/scripts/irl_data_account.py --samples 20 --seed 0 [--task track] [--param exploration=0.3 ...]
"""

from __future__ import annotations

import argparse

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context, task_kinematics
from snac_gym.evaluation.samples import generate_samples, policy_seed

from snac_gym.control.irl import windows_from_samples
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.policies.registry import make_policy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace

DT = 1.0 / 125.0


def _value(text: str) -> object:
    if "," in text:
        return tuple(float(v) for v in text.split(","))
    number = float(text)
    return int(number) if number.is_integer() and "." not in text else number


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--task", default="reach")
    parser.add_argument("--model-error", default=None)
    parser.add_argument("--param", action="append", default=[], help="snac-irl argument KEY=VALUE")
    args = parser.parse_args()
    kwargs = {key: _value(value) for key, value in (p.split("=", 1) for p in args.param)}
    kinematics = shared_kinematics("ur10")
    samples = generate_samples(kinematics, SampleSpace.for_robot(kinematics), args.seed, args.task, range(args.samples))
    seeds = [policy_seed(args.seed, args.task, s.index) for s in samples]
    context = policy_context("ur10", DT, args.task, args.model_error)
    built: list = []
    captured: dict = {}

    def build():
        policy = make_policy("snac-irl", context, Q=[4.0, 4.0, 4.0], **kwargs)
        learn = policy._learn

        def recording_learn():
            if not captured:
                b = policy._batch
                captured["errors"] = np.array(b["errors"][-(policy.learning_steps + 1) :])
                captured["commands"] = np.array(b["commands"][-policy.learning_steps :])
                captured["drifts"] = np.array(b["drifts"][-policy.learning_steps :])
            learn()

        policy._learn = recording_learn
        built.append(policy)
        return policy

    policy_probe = make_policy("snac-irl", context, **kwargs)
    L = policy_probe.learning_steps
    rollouts = simulate_kinematic(context, build, samples, L + 1, seeds, True, plant=task_kinematics("ur10", args.task))
    policy = built[0]
    batch = policy._batch
    errors, commands, drifts = captured["errors"], captured["commands"], captured["drifts"]
    true_arm = task_kinematics("ur10", args.task)
    q0, qL = rollouts.q[:, 0], rollouts.q[:, L]
    j0, jL = true_arm.jacobian_batch(q0), true_arm.jacobian_batch(qL)
    optimal = policy.lqr.gain(jL)
    rows = []
    for i in range(len(samples)):
        e = errors[:, i].T  # (3, L + 1)
        u, s, _ = np.linalg.svd(e, full_matrices=False)
        data = windows_from_samples(errors[:, i], commands[:, i], DT, policy.window_steps, drifts[:, i])
        n = data.state_dim
        distinct = data.I_xx[:, [a * n + b for a, b in zip(*np.triu_indices(n))]]
        stacked = np.hstack([distinct, data.I_xu])
        sv = np.linalg.svd(stacked / np.linalg.norm(stacked, axis=0), compute_uv=False)
        drift = np.linalg.norm(jL[i] - j0[i]) / np.linalg.norm(j0[i])
        learned = bool(batch["learned"][i])
        main_error = across_error = np.nan
        if learned:
            difference = batch["gain"][i] - optimal[i]
            main_error = np.linalg.norm(difference @ u[:, 0]) / np.linalg.norm(optimal[i] @ u[:, 0])
            across_error = np.linalg.norm(difference @ u[:, 2]) / np.linalg.norm(optimal[i] @ u[:, 2])
        rank_met = data.rank() >= n * (n + 1) // 2 + data.input_dim * n
        rows.append((s[1] / s[0], s[2] / s[0], sv[-1] / sv[0], drift, learned, main_error, across_error, rank_met))
    table = np.array(rows, dtype=float)
    print(f"{args.task}, {len(samples)} samples, seed {args.seed}, L = {L} windows, {kwargs or 'defaults'}")
    for label, column in (("σ2/σ1 of [e]", 0), ("σ3/σ1 of [e]", 1), ("[I_xx, I_xu]: σmin/σmax (columns normed)", 2),
                          ("‖J(θ_L) − J(θ0)‖/‖J(θ0)‖", 3)):  # fmt: skip
        values = table[:, column]
        print(f"  {label:42s} median {np.median(values):.3g}  (min {values.min():.3g}, max {values.max():.3g})")
    accepted = table[:, 4] > 0
    rank_met = table[:, 7] > 0
    print(
        f"  learned (accepted by Algorithm 1): {int(accepted.sum())} of {len(samples)}; of the others, "
        f"{int((~accepted & ~rank_met).sum())} below eq. 13's rank, {int((~accepted & rank_met).sum())} with a P not "
        "positive definite (or not finite)"
    )
    if accepted.any():
        for label, column in (("gain error along d1 (main direction of e)", 5), ("gain error across (d3)", 6)):
            values = table[accepted, column]
            print(f"  {label:42s} median {np.median(values):.3g}  (min {values.min():.3g}, max {values.max():.3g})")


if __name__ == "__main__":
    main()
