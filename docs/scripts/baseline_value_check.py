"""Realised cost of short reaches on θ ← θ + uΔt (Δt = 1 ms) against e₀ᵀP*e₀ at θ0."""

import math
import sys

import gymnasium as gym
import numpy as np
from snac_gym.baselines.lqr import LQRPolicy

import snac_gym  # noqa: F401
from snac_gym.control.cost import trajectory_cost
from snac_gym.control.optimality import lqr_gain, riccati_solution
from snac_gym.policies.base import PolicyContext
from snac_gym.references import PAPER_Q0

env = gym.make("snac_gym/UR10Reach-v0")
base = env.unwrapped
kin, dt = base.kinematics, 1e-3
policy = LQRPolicy(PolicyContext(kin, dt, base.velocity_limits, base.obs_layout, "reach"), q_scale=1.0)
rng = np.random.default_rng(0)
for distance in map(float, sys.argv[1:] or ["0.01", "0.05", "0.2"]):
    ratios = []
    for _ in range(5):
        q = np.array(PAPER_Q0) + rng.normal(scale=0.2, size=6)
        direction = rng.normal(size=3)
        x_d = kin.forward(q) + distance * direction / np.linalg.norm(direction)
        jac = kin.jacobian(q)
        P = riccati_solution(jac)
        slowest = -np.linalg.eigvals(-jac @ lqr_gain(jac)).real.max()
        errors, commands = [], []
        for _ in range(math.ceil(12.0 / slowest / dt)):
            x = kin.forward(q)
            u = policy.act(base.obs_layout.pack(q, np.zeros(6), x, x_d, np.zeros(3), x_d))
            errors.append(x - x_d)
            commands.append(u)
            q = q + u * dt
        terms = trajectory_cost(np.array(errors), np.array(commands), dt)
        ratios.append((terms.error + terms.effort) / (errors[0] @ P @ errors[0]))
    print(f"|e0| = {distance * 1e3:.0f} mm: realised / e0'P*e0 = {np.min(ratios):.4f} .. {np.max(ratios):.4f}")
