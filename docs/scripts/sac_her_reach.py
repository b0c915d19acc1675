"""Train SAC + HER on snac_gym/UR10ReachGoal-v1 and report its success rate (README, "Goal-conditioned envs").

Usage::

    .venv/bin/python docs/scripts/sac_her_reach.py --timesteps 30000 --tolerance 0.01
    .venv/bin/python docs/scripts/sac_her_reach.py --timesteps 60000 --tolerance 0.001 --action cartesian \
        --cartesian-speed 0.5 --dt 0.04 --episode-steps 100        # the 1 mm reach with the tool's velocity as action
    .venv/bin/python docs/scripts/sac_her_reach.py --timesteps 100000 --seed 1 --tolerance 0.001 --action cartesian \
        --cartesian-speed 0.5 --dt 0.04 --episode-steps 100 --goal-features --save runs/sac/m.zip \
        --checkpoint-every 20000                                   # the same, the networks given the goal error
    .venv/bin/python docs/scripts/sac_her_reach.py --load runs/sac/m_40000_steps.zip --eval-seed 30000 \
        --eval-episodes 500 --tolerance 0.001 --action cartesian --cartesian-speed 0.5 --dt 0.04 \
        --episode-steps 100 --goal-features                         # evaluate a saved model on other goals

The env runs on the exact kinematic model by default (``--physics kinematic``, the evaluator's engine;
``pybullet`` or ``mujoco`` otherwise), with normalised actions, sparse rewards (or ``--reward dense``)
and episodes of ``--episode-steps`` control steps of ``--dt`` (default 8 ms).
After training (or loading ``--load``), the deterministic policy runs ``--eval-episodes`` unseen
random episodes (reset seeds ``--eval-seed``, default 10 000, 10 001, ...) and the script prints the fraction that end
within ``--tolerance`` of the goal, the median final distance, the wall time, and the command.
"""

from __future__ import annotations

import argparse
import sys
import time

import gymnasium as gym
import numpy as np
import torch

import snac_gym  # noqa: F401  (registers the ids)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=30_000)
    parser.add_argument("--tolerance", type=float, default=0.01, help="success distance, m")
    parser.add_argument("--episode-steps", type=int, default=250)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--action",
        default="joint",
        choices=("joint", "cartesian"),
        help="the goal env's action: joint velocities, or the tool's velocity through J+",
    )
    parser.add_argument("--cartesian-speed", type=float, default=1.25, help="m/s at |a| = 1 (--action cartesian)")
    parser.add_argument("--dt", type=float, default=0.008, help="control period, s (a multiple of 8 ms)")
    parser.add_argument("--gamma", type=float, default=0.98)
    parser.add_argument("--reward", default="sparse", choices=("sparse", "dense"), help="the goal env's reward_type")
    parser.add_argument(
        "--goal-features",
        action="store_true",
        help="give the networks the goal error at three scales (snac_gym.goal_features)",
    )
    parser.add_argument("--save", default=None, help="save the trained model to this path (.zip)")
    parser.add_argument("--load", default=None, help="evaluate this saved model (.zip) instead of training one")
    parser.add_argument(
        "--physics",
        default="kinematic",
        choices=("kinematic", "pybullet", "mujoco"),
        help="the env's engine (training and evaluation)",
    )
    parser.add_argument("--eval-seed", type=int, default=10_000, help="reset seed of the first evaluation episode")
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        default=0,
        help="also save the model every this many steps, beside --save (name_<steps>_steps.zip)",
    )
    args = parser.parse_args()
    if args.checkpoint_every and not args.save:
        parser.error("--checkpoint-every writes beside --save: give --save too")
    if args.checkpoint_every < 0:
        parser.error(f"--checkpoint-every must be 0 or a positive number of steps, got {args.checkpoint_every}")
    from stable_baselines3 import SAC, HerReplayBuffer

    torch.set_num_threads(1)
    kwargs = dict(
        physics=args.physics,
        action_type="normalized",  # -v1's own, given as the runs in docs/rl.md were made
        finite_observation_bounds=True,  # θ̇ unbounded and not clipped: the env docs/rl.md's runs measured
        success_tolerance=args.tolerance,
        reward_type=args.reward,
        max_episode_steps=args.episode_steps,
        dt=args.dt,
    )
    if args.action == "cartesian":
        kwargs.update(action="cartesian", cartesian_speed=args.cartesian_speed)
    env = gym.make("snac_gym/UR10ReachGoal-v1", **kwargs)
    if args.load:  # the saved model carries its own network settings (--goal-features included)
        evaluate(SAC.load(args.load, env=env, device="cpu"), env, args, None)
        return
    policy_kwargs = {}
    if args.goal_features:
        from snac_gym.goal_features import GoalErrorExtractor

        policy_kwargs["features_extractor_class"] = GoalErrorExtractor
    model = SAC(
        "MultiInputPolicy",
        env,
        replay_buffer_class=HerReplayBuffer,
        policy_kwargs=policy_kwargs,
        replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
        learning_starts=1000,
        gamma=args.gamma,
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    start = time.perf_counter()
    callback = None
    if args.checkpoint_every:
        from pathlib import Path

        from stable_baselines3.common.callbacks import CheckpointCallback

        target = Path(args.save)
        callback = CheckpointCallback(args.checkpoint_every, str(target.parent), name_prefix=target.stem)
    model.learn(args.timesteps, callback=callback)
    train_s = time.perf_counter() - start
    if args.save:
        model.save(args.save)
    evaluate(model, env, args, train_s)


def evaluate(model, env, args, train_s) -> None:
    """Run the deterministic policy on ``--eval-episodes`` unseen episodes and print the figures."""
    finals = []
    for episode in range(args.eval_episodes):
        obs, _ = env.reset(seed=args.eval_seed + episode)
        for _ in range(args.episode_steps):
            obs, _, terminated, truncated, _ = env.step(model.predict(obs, deterministic=True)[0])
            if terminated or truncated:
                break
        finals.append(float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])))
    finals_a = np.array(finals)
    print(f"command: {' '.join(sys.argv)}")
    if train_s is not None:
        print(f"SAC+HER, {args.timesteps} steps in {train_s:.0f} s ({args.timesteps / train_s:.0f} steps/s)")
    print(
        f"success (final distance <= {args.tolerance * 1e3:g} mm) on {args.eval_episodes} unseen episodes "
        f"(reset seeds {args.eval_seed}+): {100 * np.mean(finals_a <= args.tolerance):.1f} %; median final distance "
        f"{1e3 * np.median(finals_a):.2f} mm, p90 {1e3 * np.quantile(finals_a, 0.9):.2f} mm"
    )


if __name__ == "__main__":
    main()
