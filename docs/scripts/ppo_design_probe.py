"""The probe behind the shipped PPO's design: which action space lets PPO, trained on minus the HJB
cost (Q = 4I), get near the optimum and settle to 1 mm.

Trains SB3 PPO on the batched kinematic vector env (512 episodes of 4 s, gamma 0.995) with one
of three action spaces and prints, every 0.5 M steps, the median over 200 validation episodes
(reset seeds 10 000 + i, 12 s) of the episode's cost over DLS's (gain 2, lambda 0.01) on the same
episode, and the final errors:

* ``joint``: a in [-1, 1]^6 commands joint velocities (u = 0.5 a * u_max); the features are the
  joint-space error J+ e (scaled and squashed), J^T e, J+ xdot_d, e and xdot_d, and the actor
  has no biases (an odd function: u = 0 at e = 0);
* ``task``: a in [-1, 1]^3 is an end-effector velocity (0.5 a m/s) mapped by the damped J+;
* ``relative``: the shipped kind, v = xdot_d + k_max (|e| + 0.1 mm) a, mapped by the damped J+
  (snac_gym.ppo.features).

    python docs/scripts/ppo_design_probe.py --action joint --log-std -2.5     # 2 M steps
    python docs/scripts/ppo_design_probe.py --action task --log-std -2
    python docs/scripts/ppo_design_probe.py --action relative --log-std -2 --k-max 4 --steps 1.5e6
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecNormalize

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.control.cost import CostConvention
from snac_gym.envs.sb3 import SB3VectorEnv

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("--task", default="reach", choices=("reach", "track"))
parser.add_argument("--action", default="relative", choices=("joint", "task", "relative"))
parser.add_argument("--steps", type=float, default=2e6)
parser.add_argument("--log-std", type=float, default=-2.0)
parser.add_argument("--k-max", type=float, default=4.0)
args = parser.parse_args()
torch.set_num_threads(1)
ENV = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}[args.task]
COST = CostConvention("hjb", q_scale=4.0)


def damped_pinv_times(jac: np.ndarray, vectors: np.ndarray, damping: float = 0.01) -> np.ndarray:
    damped = jac @ jac.transpose(0, 2, 1) + damping**2 * np.eye(jac.shape[1])
    return np.einsum("bji,bj->bi", jac, np.linalg.solve(damped, vectors[..., None])[..., 0])


class ProbeEnv(SB3VectorEnv):
    def _parts(self, observations):
        s = self.episodes.layout.slices
        q = np.ascontiguousarray(observations[:, s["q"]])
        return (
            np.asarray(self.episodes.template.kinematics.jacobian_batch(q)),
            observations[:, s["e"]],
            observations[:, s["xdot_d"]],
        )

    def _spaces(self):
        size = {"joint": 30, "task": 30, "relative": 13}[args.action]
        actions = 6 if args.action == "joint" else 3
        return gym.spaces.Box(-np.inf, np.inf, (size,), np.float32), gym.spaces.Box(-1, 1, (actions,), np.float32)

    def _features(self, observations, rows):
        jac, e, v = self._parts(observations)
        if args.action == "relative":
            n = np.linalg.norm(e, axis=1, keepdims=True)
            parts = [e / (n + 1e-12), (np.log10(n + 1e-5) + 2.5) / 1.5, v / 0.1, v / (n + 1e-3) / 10, e / 0.2]
        else:
            pe, pv = damped_pinv_times(jac, e), damped_pinv_times(jac, v)
            parts = [pe / 0.1, np.tanh(pe / 0.01), np.einsum("bji,bj->bi", jac, e) / 0.1, pv / 0.1, e / 0.1, v / 0.1]
        return np.concatenate(parts, axis=1).astype(np.float32)

    def _commands(self, actions):
        limits = self.episodes.limits
        a = np.clip(actions, -1, 1)
        if args.action == "joint":
            return np.clip(a * limits * 0.5, -limits, limits)
        jac, e, v = self._parts(self.episodes.observations())
        if args.action == "task":
            velocity = 0.5 * a
        else:
            velocity = v + (np.linalg.norm(e, axis=1, keepdims=True) + 1e-4) * args.k_max * a
        return np.clip(damped_pinv_times(jac, velocity), -limits, limits)


class OddPolicy(ActorCriticPolicy):
    """An actor without biases: with odd features its mean command is odd, so u = 0 at e = 0."""

    def _build_mlp_extractor(self):
        super()._build_mlp_extractor()
        layers, width = [], self.features_dim
        for out in (64, 64):
            layers += [nn.Linear(width, out, bias=False), nn.Tanh()]
            width = out
        self.mlp_extractor.policy_net = nn.Sequential(*layers)

    def _build(self, lr_schedule):
        super()._build(lr_schedule)
        self.action_net.bias.data.zero_()
        self.action_net.bias.requires_grad_(False)


def make(count, horizon):
    return ProbeEnv(ENV, count, max_steps=horizon, reward_type="cost", cost=COST)


def validation(policy, count=200, horizon=1500):
    env = make(count, horizon)
    env.seed(10_000)
    observations = env.reset()
    cost = np.zeros(count)
    for _ in range(horizon):
        observations, reward, done, infos = env.step(policy(env, observations))
        cost -= reward
        if done.any():
            return cost, np.array([info["error_norm"] for info in infos])
    raise RuntimeError("the validation episodes did not end")


def dls(env, observations):
    jac, e, v = env._parts(env.episodes.observations())
    u = np.clip(damped_pinv_times(jac, v - 2.0 * e), -env.episodes.limits, env.episodes.limits)
    # as an action of the probe's space: only the command matters, so bypass _commands
    env._commands = lambda actions, u=u: u
    return np.zeros((len(u), env.action_space.shape[0]))


def main() -> None:
    train = make(512, 500)
    train.seed(0)
    venv = VecNormalize(train, norm_obs=False, norm_reward=True, gamma=0.995)
    model = PPO(
        OddPolicy if args.action == "joint" else "MlpPolicy",
        venv,
        n_steps=32,
        batch_size=4096,
        n_epochs=5,
        gamma=0.995,
        gae_lambda=0.95,
        learning_rate=lambda f: 3e-4 * f,
        seed=0,
        device="cpu",
        policy_kwargs={
            "net_arch": {"pi": [64, 64], "vf": [128, 128]},
            "log_std_init": args.log_std,
            "activation_fn": nn.Tanh,
        },
    )
    dls_cost, dls_error = validation(dls)
    print(f"DLS: final error median {1e3 * np.median(dls_error):.3f} mm", flush=True)
    start, done = time.time(), 0
    while done < args.steps:
        model.learn(500_000, reset_num_timesteps=False)
        done += 500_000
        cost, error = validation(lambda env, obs: model.predict(obs, deterministic=True)[0])
        ratio = cost / dls_cost
        print(
            f"{done / 1e6:.1f} M steps, {time.time() - start:.0f} s: cost / DLS's median {np.median(ratio):.3f}; "
            f"final error median {1e3 * np.median(error):.3f} mm, within 1 mm {100 * np.mean(error < 1e-3):.1f} %",
            flush=True,
        )


if __name__ == "__main__":
    main()
