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


def run_act_bench(
    names: tuple[str, ...] | list[str] = ("snac",),
    tasks: tuple[str, ...] = ("reach", "track"),
    calls: int = 5000,
    seed: int = 0,
    policy_kwargs: dict[str, dict[str, Any]] | None = None,
    clock: str = "wall",
) -> dict[str, dict[str, dict[str, float]]]:
    """Latency of one ``act`` call, per policy and task, on one core (a benchmark, never a test).

    Each policy drives the task's env in closed loop from the paper's θ0 and reference
    (episodes restart as they end) and every ``act`` call is timed alone with
    ``time.perf_counter_ns``, so the states are the ones a real run visits.

    Args:
        names: Registered policy names (see :func:`~snac_gym.policies.available_policies`).
        tasks: ``"reach"`` and/or ``"track"``.
        calls: Timed ``act`` calls per policy and task (after 200 untimed warm-up calls).
        seed: Seed of the env and policy resets.
        policy_kwargs: Optional constructor arguments per policy name.
        clock: ``"wall"`` (``perf_counter_ns``, what a control loop sees) or ``"cpu"``
            (``thread_time_ns``: leaves out time the thread spent descheduled, for a
            machine shared with other work; its own overhead is ~0.5 µs per call).

    Returns:
        ``{name: {task: {"median_us", "p99_us", "mean_us", "calls"}}}``. A policy that fails
        to import or build is reported as ``{"error": message}`` instead of a task dict.
    """
    import gymnasium as gym

    import snac_gym  # noqa: F401  (registers the envs)
    from snac_gym.policies import make_policy
    from snac_gym.references import PAPER_Q0

    env_ids = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}
    if clock not in ("wall", "cpu"):
        raise ValueError(f"clock must be 'wall' or 'cpu', got {clock!r}")
    _pin_to_one_core()
    results: dict[str, dict[str, Any]] = {}
    for name in names:
        results[name] = {}
        for task in tasks:
            env = gym.make(env_ids[task])
            try:
                policy = make_policy(name, env, **(policy_kwargs or {}).get(name, {}))
            except Exception as exc:  # noqa: BLE001 - report any policy that does not build
                env.close()
                results[name] = {"error": f"{type(exc).__name__}: {exc}"}
                break
            options = {"q0": list(PAPER_Q0)}
            obs, _ = env.reset(seed=seed, options=options)
            policy.reset(seed=seed)
            timings = np.empty(calls, dtype=np.int64)
            now = time.perf_counter_ns if clock == "wall" else time.thread_time_ns
            for k in range(-200, calls):
                start = now()
                action = policy.act(obs)
                elapsed = now() - start
                if k >= 0:
                    timings[k] = elapsed
                obs, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    obs, _ = env.reset(seed=seed, options=options)
                    policy.reset(seed=seed)
            env.close()
            micro = timings / 1e3
            results[name][task] = {
                "median_us": float(np.median(micro)),
                "p99_us": float(np.percentile(micro, 99)),
                "mean_us": float(micro.mean()),
                "calls": int(calls),
            }
    return results


def format_act_bench(results: dict[str, dict[str, Any]]) -> str:
    """Table of :func:`run_act_bench` results."""
    lines = [f"{'policy':12s} {'task':6s} {'median µs':>10s} {'p99 µs':>9s} {'mean µs':>9s} {'calls':>7s}"]
    for name, per_task in results.items():
        if "error" in per_task:
            lines.append(f"{name:12s} skipped: {per_task['error']}")
            continue
        for task, row in per_task.items():
            lines.append(
                f"{name:12s} {task:6s} {row['median_us']:10.1f} {row['p99_us']:9.1f} {row['mean_us']:9.1f}"
                f" {row['calls']:7d}"
            )
    return "\n".join(lines)
