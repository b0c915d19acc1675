"""Behaviour cloning of the reference into ``ppo-workspace``'s goal-relative actor (docs/ppo.md).

Two steps:

``data``: for whole-workspace samples of the given seeds (the evaluator's samples, its horizon), solve the
reference (the evaluator's constrained optimum, HJB cost, Q = 4I, the same solve as ``optimal``), roll its commands
out on the kinematic engine while recording the observation at each step, run the policy's goal arms
(``EpisodeGoals``) along them, and store per step the observation, the goal state, the reference's command and
the goal-relative action nearest it (``snac_gym.ppo.cloning.target_actions``). Chunks of ``--chunk`` samples, one
file each; a file already there is kept (the step resumes).

``fit``: features of every stored step, the actor of the config's architecture fitted to the target actions
(weighted MSE), written as a policy file. Options relabel the targets: ``--pull-floor`` (the least a₀, the rest
fitted again), ``--tail-radius``/``--tail-gain`` (within that error, a task-space law of that gain and no pull:
the reference's own tail is too slow for the 1 mm success).

    python docs/scripts/ppo_cloning.py data --task reach --seed 8101 --samples 100 --out runs/ppo_clone/data
    python docs/scripts/ppo_cloning.py fit --task reach --data runs/ppo_clone/data --out runs/ppo_clone/reach.npz
    python docs/scripts/ppo_cloning.py summary --data runs/ppo_clone/data   # the data's figures in docs/ppo.md
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.optimum import solve_samples
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.ppo.cloning import cloned_policy_file, fit_actor, target_actions
from snac_gym.ppo.features import RELATIVE_ERROR_FLOOR, EpisodeGoals, FeatureSpec, GoalState, observation_features
from snac_gym.rollout import reference_trajectories
from snac_gym.rollout.kinematic import simulate_kinematic
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

DT = 1.0 / 125.0
CONFIGS = Path(__file__).resolve().parents[2] / "snac_gym" / "ppo" / "configs" / "goal"


class RecordingReplay:
    """Replays command sequences ``(B, K, m)`` (batch protocol) and keeps every observation it is given."""

    def __init__(self, commands: np.ndarray) -> None:
        self.commands = commands
        self.seen: list[np.ndarray] = []

    def reset_batch(self, seeds: list[int]) -> None:
        self.seen = []

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        self.seen.append(np.array(obs_batch, dtype=np.float64))
        return self.commands[:, len(self.seen) - 1].copy()


def record_chunk(task: str, seed: int, indices: list[int], spec: FeatureSpec) -> dict[str, np.ndarray]:
    """Reference, observations, goal states and target actions of samples ``indices`` of ``seed``."""
    context = policy_context("ur10", DT, task)
    kinematics, layout = context.kinematics, context.layout
    samples = generate_samples(kinematics, SampleSpace.workspace(kinematics), seed, task, indices)
    steps = round(get_task(task).horizon_s / DT)
    x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * DT, 3)[0]
    references = solve_samples(context, samples, indices, x_d, DT, CostConvention("hjb", "rest", 4.0))
    commands = np.stack([r.solution.commands for r in references])
    replay = RecordingReplay(commands)
    simulate_kinematic(context, lambda: replay, samples, steps, [seed] * len(samples), True, "optimal", False)
    obs = np.stack(replay.seen, axis=1)  # (B, K, d)
    goals = EpisodeGoals(kinematics, context.velocity_limits, DT, task == "track", len(samples))
    goal, velocity = np.empty(obs.shape[:2] + (6,)), np.empty(obs.shape[:2] + (6,))
    for k in range(steps):
        state = goals.observe(obs[:, k], layout)
        goal[:, k], velocity[:, k] = state.goal, state.velocity
    flat = obs.reshape(-1, obs.shape[-1])
    state = GoalState(goal.reshape(-1, 6), velocity.reshape(-1, 6), kinematics.lower_limits, kinematics.upper_limits)
    jacobians = kinematics.jacobian_batch(np.ascontiguousarray(flat[:, layout.slices["q"]]))
    actions, residual = target_actions(flat, commands.reshape(-1, 6), layout, jacobians, spec, state)
    return {
        "obs": obs,
        "goal": goal,
        "goal_velocity": velocity,
        "commands": commands,
        "actions": actions.reshape(len(samples), steps, -1),
        "residual": residual.reshape(len(samples), steps),
        "reference_cost": np.array([r.solution.cost for r in references]),
        "indices": np.array(indices),
    }


def data(args: argparse.Namespace) -> None:
    config = json.loads((CONFIGS / f"{args.task}.json").read_text())
    spec = FeatureSpec.from_dict(config["features"])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for start in range(0, args.samples, args.chunk):
        path = out / f"{args.task}_{args.seed}_{start:04d}.npz"
        if path.exists():
            continue
        began = time.perf_counter()
        chunk = record_chunk(args.task, args.seed, list(range(start, min(start + args.chunk, args.samples))), spec)
        np.savez(path, **chunk)
        print(
            f"{path.name}: {time.perf_counter() - began:.0f} s, relative residual median "
            f"{np.median(chunk['residual']):.3f} (first second {np.median(chunk['residual'][:, :125]):.3f}), "
            f"|a| median {np.median(np.abs(chunk['actions'])):.3f}",
            flush=True,
        )


def fit(args: argparse.Namespace) -> None:
    config = json.loads((CONFIGS / f"{args.task}.json").read_text())
    spec = FeatureSpec.from_dict(config["features"])
    context = policy_context("ur10", DT, args.task)
    layout = context.layout
    features, targets, weights = [], [], []
    for path in sorted(Path(args.data).glob(f"{args.task}_*.npz")):
        with np.load(path) as chunk:
            obs, commands = chunk["obs"][:, : args.steps], chunk["commands"][:, : args.steps]
            goal, velocity = chunk["goal"][:, : args.steps], chunk["goal_velocity"][:, : args.steps]
        flat = obs.reshape(-1, obs.shape[-1])
        lower, upper = context.kinematics.lower_limits, context.kinematics.upper_limits
        state = GoalState(goal.reshape(-1, 6), velocity.reshape(-1, 6), lower, upper)
        features.append(observation_features(flat, layout, spec, 1.0, state))
        jacobians = context.kinematics.jacobian_batch(np.ascontiguousarray(flat[:, layout.slices["q"]]))
        actions, _ = target_actions(flat, commands.reshape(-1, 6), layout, jacobians, spec, state,
                                    pull_floor=args.pull_floor)  # fmt: skip
        if args.tail_radius > 0:  # the tail: a task-space law of gain tail_gain, no pull (the reference's is slower)
            e = flat[:, layout.slices["e"]]
            norm = np.linalg.norm(e, axis=1, keepdims=True)
            tail = norm[:, 0] < args.tail_radius
            actions[tail, 0] = -1.0
            actions[tail, 1:] = -args.tail_gain * e[tail] / (spec.gain_max * (norm[tail] + RELATIVE_ERROR_FLOOR))
        targets.append(actions)
        # the cost is in the transient: weight a step by its time's share, early steps more
        times = np.arange(obs.shape[1]) * DT
        weights.append(np.tile(1.0 + args.early_weight * np.exp(-times / args.early_s), len(obs)))
    x, y, w = np.concatenate(features), np.concatenate(targets), np.concatenate(weights)
    print(f"{len(x)} steps from {args.data}")
    hidden, output = fit_actor(
        x, y, w, tuple(config["ppo"]["net_arch"]["pi"]), config["ppo"].get("activation", "tanh"),
        epochs=args.epochs, learning_rate=args.lr, seed=args.seed, log=print,
    )  # fmt: skip
    made_by = "python docs/scripts/ppo_cloning.py fit " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if k not in ("step", "func")
    )
    policy = cloned_policy_file(hidden, output, config, layout, {"made_by": made_by, "cloned_steps": len(x)})
    policy.save(args.out)
    print(f"wrote {args.out}")


def summary(args: argparse.Namespace) -> None:
    """What the stored data says: how well the action expresses the reference, its pull and gain, its success."""
    layout = policy_context("ur10", DT, "reach").layout
    e_slice = layout.slices["e"]
    for task, tolerance in (("reach", 1e-3), ("track", 5e-3)):
        paths = sorted(Path(args.data).glob(f"{task}_*.npz"))
        if not paths:
            continue
        first, every, ends, norms, gains, pulls = [], [], [], [], [], []
        for path in paths:
            with np.load(path) as chunk:
                e = np.linalg.norm(chunk["obs"][..., e_slice], axis=-1)
                first.append(chunk["residual"][:, :125].ravel())
                every.append(chunk["residual"].ravel())
                half = e.shape[1] // 2
                ends.append(e[:, -1] <= tolerance if task == "reach" else e[:, half:].mean(axis=1) < tolerance)
                # the gain along −e that the task-space part commands: v = g_max(‖e‖ + ε)a, g = −v·e/‖e‖²
                along = np.sum(chunk["actions"][..., 1:] * chunk["obs"][..., e_slice], axis=-1)
                gains.append((-4.0 * along * (e + RELATIVE_ERROR_FLOOR) / np.maximum(e, 1e-12) ** 2).ravel())
                norms.append(e.ravel())
                pulls.append(chunk["actions"][..., 0].ravel())
        r1, ra, ok = np.concatenate(first), np.concatenate(every), np.concatenate(ends)
        norm, gain, pull = np.concatenate(norms), np.concatenate(gains), np.concatenate(pulls)
        print(
            f"{task}: {len(ok)} samples; relative residual over the first second median {np.median(r1):.4f}, "
            f"90th percentile {np.percentile(r1, 90):.4f} "
            f"(all steps: {np.median(ra):.4f}, {np.percentile(ra, 90):.4f}); "
            f"the reference within the success error on {100 * ok.mean():.1f} %"
        )
        for low, high in ((0.1, 1.0), (0.03, 0.1), (0.01, 0.03), (3e-3, 1e-2), (1e-3, 3e-3), (3e-4, 1e-3)):
            rows = (norm >= low) & (norm < high)
            print(
                f"  |e| in [{low * 1000:g}, {high * 1000:g}) mm: {rows.sum()} steps, gain along -e median "
                f"{np.median(gain[rows]):.2f} 1/s, a0 median {np.median(pull[rows]):.2f}"
            )


def paired(args: argparse.Namespace) -> None:
    """Median over samples of one run's controller cost over another's (two evaluator folders of the same samples)."""
    import pandas as pd  # only this step reads the evaluator's tables

    costs = []
    for spec in (args.numerator, args.denominator):
        folder, controller = spec.rsplit(":", 1)
        frame = pd.read_csv(Path(folder) / "results.csv")
        costs.append(frame[frame.controller == controller].set_index("sample").cost_hjb)
    ratio = costs[0] / costs[1]
    print(f"{args.numerator} / {args.denominator}: paired median {ratio.median():.3f} over {ratio.count()} samples")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    steps = parser.add_subparsers(dest="step", required=True)
    d = steps.add_parser("data")
    d.add_argument("--task", choices=("reach", "track"), required=True)
    d.add_argument("--seed", type=int, required=True)
    d.add_argument("--samples", type=int, default=100)
    d.add_argument("--chunk", type=int, default=10)
    d.add_argument("--out", required=True)
    d.set_defaults(func=data)
    f = steps.add_parser("fit")
    f.add_argument("--task", choices=("reach", "track"), required=True)
    f.add_argument("--data", required=True)
    f.add_argument("--out", required=True)
    f.add_argument("--steps", type=int, default=100000, help="steps of each episode used (from its start)")
    f.add_argument("--epochs", type=int, default=30)
    f.add_argument("--lr", type=float, default=1e-3)
    f.add_argument("--early-weight", type=float, default=0.0)
    f.add_argument("--early-s", type=float, default=1.0)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--pull-floor", type=float, default=-1.0, help="the least a0 of a target (target_actions)")
    f.add_argument("--tail-radius", type=float, default=0.0, help="below this error (m) the target is the tail law")
    f.add_argument("--tail-gain", type=float, default=2.0, help="the tail law's task-space gain, 1/s")
    f.set_defaults(func=fit)
    m = steps.add_parser("summary")
    m.add_argument("--data", required=True)
    m.set_defaults(func=summary)
    p = steps.add_parser("paired")
    p.add_argument("numerator", help="FOLDER:CONTROLLER")
    p.add_argument("denominator", help="FOLDER:CONTROLLER")
    p.set_defaults(func=paired)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
