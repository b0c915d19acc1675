"""How often each controller, at its defaults, does the task of the README's first episode in the env's own episode.

Runs the README's usage snippet (``make_policy(name, env)`` on a ``-v1`` id, PyBullet, the env's default episode: 8 s
reach, 20 s track) for every controller the snippet names, on N episodes (``env.reset(seed=s)`` for s from FIRST on),
and prints the env's own success rate (``info["is_success"]`` at the last step) and the final error. Keyword arguments
for one controller go after ``--param``.

    python docs/scripts/env_defaults_success.py [--env snac_gym/UR10Reach-v1] [--episodes 40] [--first 0]
        [--controllers snac,snac-hjb,...] [--param snac-hjb.q_scale=10]
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import snac_gym  # noqa: F401 - registers the ids
from snac_gym import make_policy

#: The controllers the README's usage snippet names.
SNIPPET_CONTROLLERS = ("snac", "snac-hjb", "lqr", "rnn", "svf", "dls", "ppo")


def episode_outcomes(env_id: str, name: str, seeds: range, **kwargs: float) -> tuple[np.ndarray, np.ndarray]:
    """(success, final ‖e‖ in m) of ``name`` on each seed's episode, as the README's snippet runs it."""
    env = gym.make(env_id)
    policy = make_policy(name, env, **kwargs)
    successes, errors = [], []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        policy.reset(seed=seed)
        terminated = truncated = False
        while not (terminated or truncated):
            obs, _, terminated, truncated, info = env.step(policy.act(obs))
        successes.append(bool(info["is_success"]))
        errors.append(float(info["error_norm"]))
    env.close()
    return np.asarray(successes), np.asarray(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="snac_gym/UR10Reach-v1")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--first", type=int, default=0, help="the first episode's seed")
    parser.add_argument("--controllers", default=",".join(SNIPPET_CONTROLLERS))
    parser.add_argument("--param", action="append", default=[], help="NAME.KEY=VALUE, a float")
    args = parser.parse_args()
    params: dict[str, dict[str, float]] = {}
    for item in args.param:
        target, value = item.split("=", 1)
        name, key = target.split(".", 1)
        params.setdefault(name, {})[key] = float(value)
    seeds = range(args.first, args.first + args.episodes)
    print(f"{args.env}, seeds {seeds.start}-{seeds.stop - 1}, each controller at its defaults unless given")
    print(f"{'controller':<28} {'success':>9} {'median final ‖e‖':>17} {'max final ‖e‖':>14}")
    for name in args.controllers.split(","):
        kwargs = params.get(name, {})
        successes, errors = episode_outcomes(args.env, name, seeds, **kwargs)
        label = name + "".join(f" {key}={value:g}" for key, value in kwargs.items())
        print(
            f"{label:<28} {successes.sum():>4}/{len(successes):<4} {np.median(errors) * 1e3:>14.3f} mm"
            f" {errors.max() * 1e3:>11.2f} mm"
        )


if __name__ == "__main__":
    main()
