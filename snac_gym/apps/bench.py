"""Benchmarks (never timed assertions in tests): env throughput and, with the controllers, act latency."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import time
import tracemalloc
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, cast

import gymnasium as gym
import numpy as np
from threadpoolctl import threadpool_limits

from snac_gym.common._quiet import quiet_output
from snac_gym.common.extras import MissingExtraError, install_line
from snac_gym.model.kinematics import joint_step
from snac_gym.physics.base import ENGINE_EXTRAS, SIMULATED
from snac_gym.policies import make_policy
from snac_gym.references import PAPER_Q0
from snac_gym.tasks import TASKS, get_task

if TYPE_CHECKING:
    from snac_gym.envs.core import URTaskEnv

#: Upper bound of ``--steps``: each env is timed 5 times over ``steps`` steps, so 1,000,000 steps
#: take ~20 min for the UR10's two ids in PyBullet and MuJoCo at the ~18,000 steps/s measured here
#: (docs/benchmarks.md) and ~80 min for panda-gym at ~1,000 steps/s; a larger count is a typo that
#: would run until killed.
MAX_BENCH_STEPS = 1_000_000
#: Upper bound of ``--act-calls``: the per-call timings are kept in memory (8 B each, 8 MB at the
#: bound) and each call costs an ``act`` plus an env step (~50-100 µs), so ~100 s per policy and task.
MAX_ACT_CALLS = 1_000_000
#: Fewer steps or calls than this measure the timer more than the code.
MIN_BENCH_COUNT = 100


def check_bench_counts(steps: int, act_calls: int) -> None:
    """Refuse ``--steps`` or ``--act-calls`` outside ``[MIN_BENCH_COUNT, MAX_*]`` before anything runs.

    Raises:
        ValueError: Naming the option and its range.
    """
    for option, value, high in (("--steps", steps, MAX_BENCH_STEPS), ("--act-calls", act_calls, MAX_ACT_CALLS)):
        if not MIN_BENCH_COUNT <= value <= high:
            raise ValueError(f"{option} must be between {MIN_BENCH_COUNT} and {high:,}, got {value}")


@contextlib.contextmanager
def _one_core() -> Iterator[None]:
    """Run the block pinned to one core, then give the caller its cores back.

    Pinning for good would leave the caller (a test run, a notebook) on one core: torch's two
    intra-op threads on one core made a later 4 s SAC test take 105 s.
    """
    if not hasattr(os, "sched_setaffinity"):  # pragma: no cover - not Linux
        yield
        return
    previous = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {sorted(previous)[0]})
    except OSError:  # pragma: no cover - restricted container
        pass
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, previous)


def _start(env: Any, seed: int = 0) -> list[Any]:
    """Reset ``env`` and seed its action space; the 256 random actions (a fifth of full scale) it is stepped with."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    return [env.action_space.sample() * 0.2 for _ in range(256)]


def _timed_run(env: Any, actions: list[Any], steps: int) -> float:
    """Seconds ``env`` takes for ``steps`` steps of ``actions`` in turn, reset where an episode ends."""
    start = time.perf_counter()
    for k in range(steps):
        _, _, terminated, truncated, _ = env.step(actions[k % len(actions)])
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - start


#: Timed runs of each env in :func:`run_env_bench`, one a round.
ENV_BENCH_ROUNDS = 5
#: The key of panda-gym's row in :func:`run_env_bench`'s results.
PANDA_GYM = "PandaReachJoints-v3 (panda-gym)"


def _panda_gym_registered() -> bool:
    """Whether panda-gym imports (registering its ids); the bench then leaves it out where it is missing or broken."""
    try:
        import panda_gym  # noqa: F401  (an optional comparison: imported only when the bench asks for it)
    except ImportError:
        return False
    return True


@_one_core()
def run_env_bench(
    steps: int = 5000, include_panda: bool = True, physics: tuple[str, ...] = SIMULATED, rounds: int = ENV_BENCH_ROUNDS
) -> dict[str, dict[str, Any]]:
    """Steps/s and real-time factor (simulated s per wall s) of the snac-gym ids, on one core.

    Each of the UR10's ids is timed with each ``physics`` (``"mujoco"`` only where the mujoco extra
    is installed). With ``include_panda`` and panda-gym installed, panda-gym's
    ``PandaReachJoints-v3`` is measured in the same run for comparison.

    The envs are timed in ``rounds`` interleaved rounds, each env once a round, so that a machine whose speed drifts
    during the run (a shared or throttled host) slows every env alike, not the one timed in its slow minute; each row
    keeps its best run (``steps_per_s``, ``real_time_factor``) and every round's seconds (``round_seconds``), which
    :func:`format_env_bench` pairs with panda-gym's of the same round.
    """
    check_bench_counts(steps, MIN_BENCH_COUNT)
    envs: dict[str, tuple[Any, float, list[Any]]] = {}  # name: (the env stepped, its control period, its actions)
    closers: list[Any] = []
    try:
        for engine in physics:
            for env_id in (task.env_id for task in TASKS.values()):  # the UR10's, the paper's arm
                try:
                    env = gym.make(env_id, physics=engine)
                except MissingExtraError:
                    break
                closers.append(env)
                # timed unwrapped: no TimeLimit, and the env sets no length of its own
                unwrapped = cast("URTaskEnv", env.unwrapped)
                envs[f"{env_id} ({engine})"] = (unwrapped, unwrapped.dt, _start(unwrapped))
        if include_panda and _panda_gym_registered():
            # PyBullet prints the options panda-gym connects with ("argv[0]=--background_color...")
            with quiet_output():
                env = gym.make("PandaReachJoints-v3")
            closers.append(env)
            base: Any = env.unwrapped  # panda-gym's env (its sim)
            envs[PANDA_GYM] = (env, base.sim.timestep * base.sim.n_substeps, _start(env))
        seconds: dict[str, list[float]] = {name: [] for name in envs}
        for _ in range(rounds):
            for name, (env, _, actions) in envs.items():
                seconds[name].append(_timed_run(env, actions, steps))
    finally:
        for env in closers:
            env.close()
    results: dict[str, dict[str, Any]] = {}
    for name, (_, control_dt, _) in envs.items():
        best = min(seconds[name])
        results[name] = {
            "steps_per_s": steps / best,
            "real_time_factor": steps * control_dt / best,
            "control_dt": control_dt,
            "round_seconds": tuple(seconds[name]),
        }
    return results


def paired_ratios(row: dict[str, Any], panda: dict[str, Any]) -> np.ndarray:
    """``row``'s real-time factor over panda-gym's in each round of :func:`run_env_bench` (both timed in it)."""
    own, theirs = np.asarray(row["round_seconds"]), np.asarray(panda["round_seconds"])
    return (row["control_dt"] / own) / (panda["control_dt"] / theirs)


def format_env_bench(results: dict[str, dict[str, Any]]) -> str:
    lines = [f"{'env':42s} {'steps/s':>10s} {'control dt':>11s} {'real-time factor':>17s}"]
    for name, row in results.items():
        lines.append(
            f"{name:42s} {row['steps_per_s']:10.0f} {row['control_dt'] * 1e3:9.1f}ms {row['real_time_factor']:17.1f}"
        )
    panda = results.get(PANDA_GYM)
    if panda:
        for name, row in results.items():
            if row is panda:
                continue
            line = f"{name}: {row['real_time_factor'] / panda['real_time_factor']:.2f}x panda-gym's real-time factor"
            if "round_seconds" in row and "round_seconds" in panda:
                ratios = paired_ratios(row, panda)
                line += (
                    f" (best runs; round by round {ratios.min():.2f}-{ratios.max():.2f}x,"
                    f" median {float(np.median(ratios)):.2f}x)"
                )
            lines.append(line)
    return "\n".join(lines)


def left_out(
    results: dict[str, dict[str, Any]], include_panda: bool = True, physics: tuple[str, ...] = SIMULATED
) -> list[str]:
    """One line for each comparison :func:`run_env_bench` was asked for and left out of ``results``, naming the extra
    that adds it: without one, a shorter table would read as the whole bench."""
    lines = [
        f"left out: physics={engine!r} (the {extra!r} extra is not installed: {install_line(extra)})"
        for engine, extra in ENGINE_EXTRAS.items()
        if engine in physics and not any(name.endswith(f"({engine})") for name in results)
    ]
    if include_panda and PANDA_GYM not in results:
        lines.append(
            "left out: panda-gym's PandaReachJoints-v3, and so the ratio to it (panda-gym does not import: "
            f"the 'bench' extra, {install_line('bench')})"
        )
    return lines


@_one_core()
def run_substep_study(
    substeps: tuple[int, ...] = (1, 2, 3, 4, 8), steps: int = 1000, seed: int = 0
) -> list[dict[str, float]]:
    """How far PyBullet's joint motion departs from the ideal ``θₖ₊₁ = θₖ + uₖ Δt`` per substep count.

    Drives the reach env from seeded random poses with a smooth random velocity profile
    (sums of sinusoids at up to half the velocity limits) and reports the largest joint-
    position deviation from exact integration of the applied commands, the largest joint-
    velocity tracking error, and the env's throughput. Used to choose the default
    ``n_substeps`` (see README).
    """
    import snac_gym  # noqa: F401

    rows = []
    for n_sub in substeps:
        env = cast("URTaskEnv", gym.make("snac_gym/UR10Reach-v0", n_substeps=n_sub).unwrapped)
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
            q_ideal = joint_step(q_ideal, u, env.dt)
            max_pos = max(max_pos, float(np.abs(obs[: len(u)] - q_ideal).max()))
            max_vel = max(max_vel, float(np.abs(obs[len(u) : 2 * len(u)] - u).max()))
        elapsed = time.perf_counter() - start
        rows.append(
            {
                "n_substeps": n_sub,
                "physics_dt_ms": env.dt / n_sub * 1e3,
                "max_joint_position_error_rad": max_pos,
                "max_joint_velocity_error_rad_s": max_vel,
                "steps_per_s": steps / elapsed,
            }
        )
        env.close()
    return rows


#: Command profiles of :func:`run_tracking_study`.
TRACKING_COMMANDS = ("smooth", "steps")
#: Joint excursion of the ``"smooth"`` command from the start pose, rad: below the seed poses' 0.2 rad
#: margin from every limit (:class:`~snac_gym.sampling.SampleSpace`), so no joint meets one.
SMOOTH_EXCURSION = 0.15


def random_command(
    kind: str, rng: np.random.Generator, velocity_limits: np.ndarray, steps: int, dt: float
) -> np.ndarray:
    """``(steps, m)`` random joint-velocity commands, rad/s, of :data:`TRACKING_COMMANDS`.

    ``"smooth"``: the derivative of a random joint motion of three sinusoids per joint (0.2-1 Hz,
    random phases), whose excursion from the start pose stays within :data:`SMOOTH_EXCURSION`
    (up to ~0.9 rad/s). ``"steps"``: white noise, uniform in ±20 % of the velocity limits, a new
    value every period (a step of the command every 8 ms).

    Raises:
        ValueError: On an unknown ``kind``.
    """
    m, t = len(velocity_limits), np.arange(steps)[:, None, None] * dt
    if kind == "smooth":
        omega = 2 * np.pi * rng.uniform(0.2, 1.0, size=(3, m))
        phase = rng.uniform(0, 2 * np.pi, size=(3, m))
        amplitude = SMOOTH_EXCURSION / 3.0
        return np.clip((amplitude * omega * np.cos(omega * t + phase)).sum(axis=1), -velocity_limits, velocity_limits)
    if kind == "steps":
        return 0.2 * rng.uniform(-velocity_limits, velocity_limits, size=(steps, m))
    raise ValueError(f"command must be one of {TRACKING_COMMANDS}, got {kind!r}")


def tracking_errors(
    env_id: str, physics: str, kind: str, seed: int, steps: int = 1000, solver: str | None = None
) -> dict[str, float]:
    """How far one episode of ``physics`` departs from the exact kinematic model under a random command
    (``solver``: the env's ``pybullet_solver``, its id's default where ``None``).

    The env starts from its seeded random pose; the same commands are integrated exactly
    (θₖ₊₁ = θₖ + uₖΔt, :func:`~snac_gym.model.kinematics.joint_step`) from the same pose.

    Returns:
        ``max_velocity_error`` (max over steps and joints of |θ̇ − u| after each step, rad/s),
        ``max_joint_drift`` (max |θ − θ_kin| over the episode, rad) and ``ee_drift`` (‖f(θ) − f(θ_kin)‖
        after the last step, m).
    """
    import snac_gym  # noqa: F401  (registers the envs)

    solver_argument: dict[str, Any] = {} if solver is None else {"pybullet_solver": solver}
    env = cast("URTaskEnv", gym.make(env_id, physics=physics, **solver_argument).unwrapped)
    try:
        obs, _ = env.reset(seed=seed)
        m = env.kinematics.n_joints
        commands = random_command(kind, np.random.default_rng(seed), env.velocity_limits, steps, env.dt)
        q_exact = obs[:m].copy()
        velocity_error = joint_drift = 0.0
        for u in commands:
            obs, *_ = env.step(u)
            q_exact = joint_step(q_exact, u, env.dt)
            velocity_error = max(velocity_error, float(np.abs(obs[m : 2 * m] - u).max()))
            joint_drift = max(joint_drift, float(np.abs(obs[:m] - q_exact).max()))
        ee_drift = float(np.linalg.norm(env.kinematics.forward(obs[:m]) - env.kinematics.forward(q_exact)))
    finally:
        env.close()
    return {"max_velocity_error": velocity_error, "max_joint_drift": joint_drift, "ee_drift": ee_drift}


def run_tracking_study(
    physics: tuple[str, ...] = ("pybullet", "mujoco"),
    env_ids: tuple[str, ...] = ("snac_gym/UR10Reach-v0", "snac_gym/PandaReach-v0"),
    commands: tuple[str, ...] = TRACKING_COMMANDS,
    episodes: int = 5,
    steps: int = 1000,
) -> list[dict[str, Any]]:
    """:func:`tracking_errors` of each engine, env and command over ``episodes`` seeds: the worst episode.

    ``"mujoco"`` is left out where the mujoco extra is not installed.
    """
    physics = tuple(engine for engine in physics if engine != "mujoco" or importlib.util.find_spec("mujoco"))
    rows = []
    for env_id in env_ids:
        for kind in commands:
            for engine in physics:
                runs = [tracking_errors(env_id, engine, kind, seed, steps) for seed in range(episodes)]
                rows.append(
                    {
                        "env_id": env_id,
                        "physics": engine,
                        "command": kind,
                        "episodes": episodes,
                        **{key: max(run[key] for run in runs) for key in runs[0]},
                    }
                )
    return rows


def format_tracking_study(rows: list[dict[str, Any]]) -> str:
    """Table of :func:`run_tracking_study` rows."""
    lines = [
        f"{'env':26s} {'command':8s} {'physics':9s} {'max |θ̇ − u| rad/s':>19s} {'max |θ − θ_kin| rad':>20s}"
        f" {'ee drift mm':>12s}"
    ]
    for row in rows:
        lines.append(
            f"{row['env_id']:26s} {row['command']:8s} {row['physics']:9s} {row['max_velocity_error']:19.2e}"
            f" {row['max_joint_drift']:20.2e} {row['ee_drift'] * 1e3:12.3f}"
        )
    return "\n".join(lines)


@_one_core()
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
    import snac_gym  # noqa: F401  (registers the envs)

    if clock not in ("wall", "cpu"):
        raise ValueError(f"clock must be 'wall' or 'cpu', got {clock!r}")
    check_bench_counts(MIN_BENCH_COUNT, calls)
    results: dict[str, dict[str, Any]] = {}
    for name in names:
        results[name] = {}
        for task in tasks:
            env = gym.make(get_task(task).env_id)
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


# -- the batched kinematic vector env ------------------------------------------------------------
def _one_thread() -> Any:
    """A context that limits BLAS/OpenMP pools to one thread (threadpoolctl, a dependency)."""
    return threadpool_limits(limits=1)


def _vector_env(env_id: str, count: int) -> Any:
    return gym.make_vec(env_id, num_envs=count, vectorization_mode="vector_entry_point", max_steps=10**9)


def _time_vector_steps(env: Any, seconds: float, repeats: int = 3) -> float:
    """Best of ``repeats`` step rates (env-steps/s) over ``seconds`` each, inside episodes (no resets)."""
    rng = np.random.default_rng(0)
    low, high = env.single_action_space.low, env.single_action_space.high
    actions = [0.2 * rng.uniform(low, high, size=(env.num_envs, len(low))) for _ in range(8)]
    env.step(actions[0])
    best = 0.0
    for _ in range(repeats):
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            for action in actions:
                env.step(action)
            steps += len(actions)
        best = max(best, steps * env.num_envs / (time.perf_counter() - start))
    return best


def _reset_seconds(env_id: str, count: int = 128) -> float:
    """Wall time of one episode reset in the vector env (drawing the reference and seed pose), s."""
    env = _vector_env(env_id, count)
    env.reset(seed=0)
    start = time.perf_counter()
    env.reset()
    return (time.perf_counter() - start) / count


def _memory_per_env(env_id: str, count: int) -> tuple[float, float]:
    """Bytes per sub-env held by a vector env of ``count`` (beyond one of 1), and the extra peak of one step."""
    held = []
    for size in (1, count):
        tracemalloc.start()
        env = _vector_env(env_id, size)
        env.reset(seed=0)
        action = np.zeros((size, env.single_action_space.shape[0]), dtype=env.single_action_space.dtype)
        result = env.step(action)
        current, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        result = env.step(action)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        held.append((current, peak - current))
        del env, result
    return (held[1][0] - held[0][0]) / (count - 1), held[1][1] / count


@_one_core()
def run_vector_bench(
    sizes: tuple[int, ...] = (1, 64, 1024, 4096), seconds: float = 1.0, env_ids: tuple[str, ...] | None = None
) -> list[dict[str, float | str]]:
    """Env-steps/s of the batched kinematic vector env per task and ``num_envs``, on one core and one thread.

    ``steps_per_s`` steps inside episodes (best of 3 runs of ``seconds``); ``with_resets_per_s``
    charges each episode its reset as well (measured per episode on 128 sub-envs), i.e. the
    rate over whole episodes of the registered length. At the largest size the memory per
    sub-env is measured with ``tracemalloc``: the arrays it holds and the temporaries of a step.
    """
    rows: list[dict[str, float | str]] = []
    with _one_thread():
        for env_id in env_ids or tuple(task.env_id for task in TASKS.values()):
            reset_s = _reset_seconds(env_id)
            horizon = _vector_env(env_id, 1).unwrapped.single_env.default_max_steps
            for size in sizes:
                env = _vector_env(env_id, size)
                env.reset(seed=0)
                rate = _time_vector_steps(env, seconds)
                with_resets = size * horizon / (size * horizon / rate + size * reset_s)
                rows.append(
                    {
                        "env_id": env_id,
                        "num_envs": size,
                        "steps_per_s": rate,
                        "with_resets_per_s": with_resets,
                        "reset_ms": reset_s * 1e3,
                        "episode_steps": horizon,
                    }
                )
            held, peak = _memory_per_env(env_id, max(sizes))
            rows[-1].update(bytes_per_env=held, step_peak_bytes_per_env=peak)
    return rows


def format_vector_bench(rows: list[dict[str, float | str]]) -> str:
    """Table of :func:`run_vector_bench` rows."""
    lines = [f"{'vector env':32s} {'N':>5s} {'env-steps/s':>13s} {'with resets':>13s}  memory per env"]
    for row in rows:
        memory = ""
        if "bytes_per_env" in row:
            memory = f"{row['bytes_per_env']:.0f} B held, {row['step_peak_bytes_per_env']:.0f} B step peak"
        lines.append(
            f"{row['env_id']:32s} {row['num_envs']:5d} {row['steps_per_s']:13,.0f} "
            f"{row['with_resets_per_s']:13,.0f}  {memory}"
        )
    resets = {row["env_id"]: (row["reset_ms"], row["episode_steps"]) for row in rows}
    for env_id, (reset_ms, steps) in resets.items():
        lines.append(f"{env_id}: one episode reset {reset_ms:.2f} ms (per {steps}-step episode)")
    return "\n".join(lines)
