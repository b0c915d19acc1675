"""Benchmarks (never timed assertions in tests): env throughput and, with the controllers, act latency."""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np


def _pin_to_one_core() -> None:
    if hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
        except OSError:  # pragma: no cover - restricted container
            pass


def _time_env(env: Any, steps: int, control_dt: float, seed: int = 0, repeats: int = 5) -> dict[str, float]:
    """Best of ``repeats`` timed runs (the least-disturbed one, as ``timeit`` reports)."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() * 0.2 for _ in range(256)]
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for k in range(steps):
            _, _, terminated, truncated, _ = env.step(actions[k % len(actions)])
            if terminated or truncated:
                env.reset()
        best = min(best, time.perf_counter() - start)
    return {"steps_per_s": steps / best, "real_time_factor": steps * control_dt / best, "control_dt": control_dt}


def run_env_bench(steps: int = 5000, include_panda: bool = True) -> dict[str, dict[str, float]]:
    """Steps/s and real-time factor (simulated s per wall s) of the snac-gym ids, on one core.

    With ``include_panda`` and panda-gym installed, panda-gym's ``PandaReachJoints-v3`` is
    measured in the same run for comparison.
    """
    import gymnasium as gym

    import snac_gym

    _pin_to_one_core()
    results: dict[str, dict[str, float]] = {}
    for env_id in snac_gym.ENV_IDS:
        env = gym.make(env_id, max_steps=10**9)
        results[env_id] = _time_env(env.unwrapped, steps, env.unwrapped.dt)
        env.close()
    if include_panda:
        try:
            import panda_gym  # noqa: F401
        except ImportError:
            return results
        env = gym.make("PandaReachJoints-v3")
        base = env.unwrapped
        control_dt = base.sim.timestep * base.sim.n_substeps
        results["PandaReachJoints-v3 (panda-gym)"] = _time_env(env, steps, control_dt)
        env.close()
    return results


def format_env_bench(results: dict[str, dict[str, float]]) -> str:
    lines = [f"{'env':40s} {'steps/s':>10s} {'control dt':>11s} {'real-time factor':>17s}"]
    for name, row in results.items():
        lines.append(f"{name:40s} {row['steps_per_s']:10.0f} {row['control_dt']*1e3:9.1f}ms {row['real_time_factor']:17.1f}")
    panda = next((r for n, r in results.items() if "panda" in n), None)
    if panda:
        for name, row in results.items():
            if row is not panda:
                lines.append(f"{name}: {row['real_time_factor'] / panda['real_time_factor']:.2f}x panda-gym's real-time factor")
    return "\n".join(lines)


def run_substep_study(substeps: tuple[int, ...] = (1, 2, 3, 4, 8), steps: int = 1000, seed: int = 0) -> list[dict[str, float]]:
    """How far PyBullet's joint motion departs from the ideal ``θₖ₊₁ = θₖ + uₖ Δt`` per substep count.

    Drives the reach env from seeded random poses with a smooth random velocity profile
    (sums of sinusoids at up to half the velocity limits) and reports the largest joint-
    position deviation from exact integration of the applied commands, the largest joint-
    velocity tracking error, and the env's throughput. Used to choose the default
    ``n_substeps`` (see README).
    """
    import gymnasium as gym

    import snac_gym  # noqa: F401

    _pin_to_one_core()
    rows = []
    for n_sub in substeps:
        env = gym.make("snac_gym/UR10Reach-v0", n_substeps=n_sub, max_steps=10**9).unwrapped
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        freqs = rng.uniform(0.1, 1.0, size=(3, env.kinematics.n_joints))
        phases = rng.uniform(0, 2 * np.pi, size=(3, env.kinematics.n_joints))
        q_ideal = obs[: env.kinematics.n_joints].copy()
        max_pos, max_vel = 0.0, 0.0
        start = time.perf_counter()
        for k in range(steps):
            t = k * env.dt
            u = 0.5 * env.velocity_limits * np.sin(2 * np.pi * freqs * t + phases).mean(axis=0)
            obs, *_ = env.step(u)
            q_ideal = q_ideal + u * env.dt
            max_pos = max(max_pos, float(np.abs(obs[: len(u)] - q_ideal).max()))
            max_vel = max(max_vel, float(np.abs(obs[len(u) : 2 * len(u)] - u).max()))
        elapsed = time.perf_counter() - start
        rows.append({"n_substeps": n_sub, "physics_dt_ms": env.dt / n_sub * 1e3, "max_joint_position_error_rad": max_pos,
                     "max_joint_velocity_error_rad_s": max_vel, "steps_per_s": steps / elapsed})
        env.close()
    return rows
