"""The paper's two demonstrations (Section V, Figure 3) for any registered controller.

* ``reach``: from θ0 = [-0.51, -1.04, 1.48, -1.82, -1.45, -1.62] rad to the target
  [-0.658, 0.626, 0.407] m (Section V-B), default horizon 12 s (1500 steps; the env's
  episode is 8 s, see :data:`DEMO_HORIZONS`).
* ``track``: from the same θ0, follow the circle of radius 0.2 m around [-0.7, 0, 0.5] m at
  0.075 rad/s (Section V-C), default horizon 20 s (2500 steps, the env's episode).

:func:`run_demo` runs one in the PyBullet env, writes the figure panels and the trajectory
log to a folder, and returns a :class:`DemoResult` with the figures the command prints.
``snac-gym demo`` is a thin wrapper around it.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.cost import trajectory_cost
from snac_gym.references import PAPER_Q0, PAPER_TARGET, Ellipse
from snac_gym.rollout import add_critic_diagnostics, log_array, rollout, write_log

#: Longest demo accepted, s (50x the tracking demo): the log is held in memory, so an unbounded
#: horizon fails late (or exhausts memory) instead of being refused.
MAX_DEMO_DURATION_S = 1000.0
#: Gymnasium id of each demo task.
DEMO_ENVS = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}
#: Thresholds the demos report against: 1 mm (reach) and 5 mm (track) on ‖e‖.
DEMO_TOLERANCES = {"reach": 1e-3, "track": 5e-3}
#: Default horizon of each demo, s. Reach runs 12 s, longer than the env's 8 s episode: with
#: the paper's law read per second (SNAC's default) the arm is within 1 mm of the paper's
#: target after 6.6 s and of every one of 50 random targets after 12 s, but of only 64 % of
#: them after 8 s (docs/snac.md). Track runs the env's 20 s.
DEMO_HORIZONS = {"reach": 12.0, "track": 20.0}


def demo_steps(task: str, dt: float) -> int:
    """Control steps of the default horizon (:data:`DEMO_HORIZONS`) of ``task`` at period ``dt``."""
    return round(DEMO_HORIZONS[task] / dt)


def demo_options(task: str) -> dict[str, Any]:
    """The env reset options of the paper's demo for ``task`` (θ0 and the paper's reference)."""
    if task == "reach":
        return {"q0": list(PAPER_Q0), "target": list(PAPER_TARGET)}
    if task == "track":
        return {"q0": list(PAPER_Q0), "ellipse": Ellipse.paper_circle().to_dict()}
    raise ValueError(f"task must be one of {sorted(DEMO_ENVS)}, got {task!r}")


@dataclass
class DemoMetrics:
    """Figures of merit of one closed-loop run (all from its trajectory log).

    Attributes:
        final_error: ‖e‖ after the last step, m.
        time_to_1mm: First time ‖e‖ ≤ 1 mm, s (``None`` if never).
        settling_time: Time after which ‖e‖ stays ≤ ``tolerance`` to the end, s (``None``
            if it ends above).
        tolerance: The settling threshold, m (1 mm reach, 5 mm track).
        max_error_after_settling: Largest ‖e‖ from ``settling_time`` on, m.
        descent_fraction: Fraction of steps with eₖᵀ(eₖ₊₁ − eₖ) ≤ 0, i.e. eᵀė ≤ 0 with ė
            the finite difference over the step (the error norm did not grow).
        descent_fraction_above_tolerance: The same over the steps that start with
            ‖e‖ > ``tolerance`` (the transient; once at the noise floor the sign is random).
        clipped_steps: Steps whose command sits on a velocity limit (|u_j| = limit for some
            joint: the policy or the env clipped it).
        clip_fraction: ``clipped_steps`` / steps.
        max_speed_ratio: Largest |u_j| / limit_j over the run (≤ 1: inside the limits).
        cost_error, cost_effort, cost_smoothness, cost_total: The trajectory cost
            ``V = Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt`` (Q = I, R = I) and its terms.
        steps: Control steps run.
        hjb_ratio_median: Median of the critic's HJB residual r / eᵀQe over the run (critic
            policies only, else ``None``; 0 for the optimal value function).
        critic_error_final: ‖P̂ − P*(J)‖_F / ‖P*‖_F at the last step (regulation critics only).
    """

    final_error: float
    time_to_1mm: float | None
    settling_time: float | None
    tolerance: float
    max_error_after_settling: float | None
    descent_fraction: float
    descent_fraction_above_tolerance: float | None
    clipped_steps: int
    clip_fraction: float
    max_speed_ratio: float
    cost_error: float
    cost_effort: float
    cost_smoothness: float
    cost_total: float
    steps: int
    hjb_ratio_median: float | None = None
    critic_error_final: float | None = None


def demo_metrics(log: pd.DataFrame, tolerance: float) -> DemoMetrics:
    """Compute :class:`DemoMetrics` from a log of :func:`~snac_gym.rollout.rollout`."""
    dt = float(log.attrs["dt"])
    errors = log_array(log, "e")
    commands = log_array(log, "u")
    final = np.asarray(log.attrs["final_e"], dtype=float)
    # ‖e‖ at the start of every step, then after the last one.
    norms = np.append(np.linalg.norm(errors, axis=1), np.linalg.norm(final))
    times = np.append(log["t"].to_numpy(), float(log.attrs["final_t"]))
    reached = np.flatnonzero(norms <= 1e-3)
    above = np.flatnonzero(norms > tolerance)
    if not above.size:
        settling_index: int | None = 0
    elif above[-1] + 1 < len(norms):
        settling_index = int(above[-1] + 1)
    else:
        settling_index = None
    following = np.vstack([errors[1:], final[None, :]])
    descent = np.einsum("ij,ij->i", errors, following - errors) <= 0.0
    outside = norms[:-1] > tolerance
    limits = np.asarray(log.attrs["velocity_limits"], dtype=float)
    ratio = np.abs(commands) / limits
    clipped = np.any(ratio >= 1.0 - 1e-12, axis=1)
    cost = trajectory_cost(errors, commands, dt)
    return DemoMetrics(
        final_error=float(norms[-1]),
        time_to_1mm=float(times[reached[0]]) if reached.size else None,
        settling_time=float(times[settling_index]) if settling_index is not None else None,
        tolerance=float(tolerance),
        max_error_after_settling=float(norms[settling_index:].max()) if settling_index is not None else None,
        descent_fraction=float(descent.mean()),
        descent_fraction_above_tolerance=float(descent[outside].mean()) if outside.any() else None,
        clipped_steps=int(clipped.sum()),
        clip_fraction=float(clipped.mean()),
        max_speed_ratio=float(ratio.max()),
        cost_error=float(cost.error),
        cost_effort=float(cost.effort),
        cost_smoothness=float(cost.smoothness),
        cost_total=float(cost.total),
        steps=len(log),
        hjb_ratio_median=float(np.nanmedian(log["hjb_ratio"])) if "hjb_ratio" in log.columns else None,
        critic_error_final=float(log["critic_error"].iloc[-1]) if "critic_error" in log.columns else None,
    )


@dataclass
class DemoResult:
    """What :func:`run_demo` produced.

    Attributes:
        task, controller, seed: The run.
        metrics: Its :class:`DemoMetrics`.
        log: The trajectory log.
        files: Every file written, PNGs and log.
    """

    task: str
    controller: str
    seed: int
    metrics: DemoMetrics
    log: pd.DataFrame = field(repr=False)
    files: list[Path] = field(default_factory=list)

    def summary(self) -> str:
        """The lines ``snac-gym demo`` prints."""
        m = self.metrics

        def seconds(value: float | None) -> str:
            return f"{value:.3f} s" if value is not None else "never"

        lines = [
            f"{self.task} demo, controller {self.controller!r}, seed {self.seed}, {m.steps} steps",
            f"  final error                 {m.final_error * 1e3:.4f} mm",
            f"  time to first reach 1 mm    {seconds(m.time_to_1mm)}",
            f"  fraction of steps eᵀė ≤ 0   {m.descent_fraction:.4f}"
            + (f" ({m.descent_fraction_above_tolerance:.4f} while ‖e‖ > {m.tolerance * 1e3:g} mm)"
               if m.descent_fraction_above_tolerance is not None else ""),
            f"  {f'settled under {m.tolerance * 1e3:g} mm from':28s}{seconds(m.settling_time)}"
            + (f" (max after: {m.max_error_after_settling * 1e3:.3f} mm)"
               if m.max_error_after_settling is not None else ""),
            (f"  clipped steps               {m.clipped_steps} ({100 * m.clip_fraction:.2f} %),"
             f" max |u|/limit {m.max_speed_ratio:.3f}"),
            (f"  trajectory cost V           {m.cost_total:.4f} (error {m.cost_error:.4f},"
             f" effort {m.cost_effort:.4f}, smoothness {m.cost_smoothness:.4f})"),
        ]
        if m.hjb_ratio_median is not None:
            lines.append(f"  HJB residual r/eᵀQe         median {m.hjb_ratio_median:.4f} (0 for the optimal critic)")
        if m.critic_error_final is not None:
            lines.append(f"  critic error ‖P̂−P*‖/‖P*‖    {m.critic_error_final:.4f} at the end")
        if self.files:
            lines.append(f"  wrote {len(self.files)} files to {self.files[0].parent}")
        return "\n".join(lines)


def run_demo(
    task: str = "reach",
    controller: str = "snac",
    out_dir: str | Path | None = "demo_out",
    seed: int = 0,
    steps: int | None = None,
    duration: float | None = None,
    csv: bool = False,
    plots: bool = True,
    policy_kwargs: dict[str, Any] | None = None,
) -> DemoResult:
    """Run the paper's ``task`` demo with ``controller`` and write its figures and log.

    Args:
        task: ``"reach"`` or ``"track"``.
        controller: A registered policy name (:func:`~snac_gym.policies.available_policies`).
        out_dir: Folder for the outputs (created); ``None`` writes nothing.
        seed: Seed of the env and policy resets (same seed: bit-identical log).
        steps: Control steps (default :data:`DEMO_HORIZONS`: 1500 reach / 2500 track).
        duration: Horizon in seconds instead of ``steps`` (rounded to whole steps).
        csv: Also write the log as CSV (with a JSON sidecar for its metadata).
        plots: Write the PNG panels.
        policy_kwargs: Constructor arguments of the policy.

    Returns:
        The :class:`DemoResult`. Files in ``out_dir``, prefixed ``<task>_<controller>_``:
        ``path.png``, ``error.png``, ``joint_velocities.png``, ``cost.png`` (Figure 3
        panels), ``figure3.png`` (the four together), ``critic_weights.png`` (policies
        that log critic weights), ``log.parquet`` (+ ``.csv``/``.json``) and ``summary.json``.
    """
    import gymnasium as gym

    import snac_gym  # noqa: F401  (registers the envs)
    from snac_gym.policies import make_policy

    options = demo_options(task)
    if steps is not None and duration is not None:
        raise ValueError("give steps or duration, not both")
    if duration is not None and not (math.isfinite(duration) and 0 < duration <= MAX_DEMO_DURATION_S):
        raise ValueError(f"the demo duration must be in (0, {MAX_DEMO_DURATION_S:g}] s, got {duration}")
    env = gym.make(DEMO_ENVS[task])
    dt = env.unwrapped.dt
    if duration is not None:
        steps = round(duration / dt)
    if steps is None:
        steps = demo_steps(task, dt)
    max_steps = round(MAX_DEMO_DURATION_S / dt)
    if not 1 <= steps <= max_steps:
        env.close()
        raise ValueError(
            f"the demo needs between 1 and {max_steps} steps ({MAX_DEMO_DURATION_S:g} s), got {steps}"
        )
    if steps > env.unwrapped.max_steps:
        env.close()
        env = gym.make(DEMO_ENVS[task], max_steps=steps)
    try:
        policy = make_policy(controller, env, **(policy_kwargs or {}))
        log = add_critic_diagnostics(rollout(env, policy, options=options, seed=seed, steps=steps), policy)
    finally:
        env.close()
    log.attrs["controller"] = controller
    return write_demo_outputs(
        log, task, controller, seed, DEMO_TOLERANCES[task], out_dir, csv=csv, plots=plots, policy_kwargs=policy_kwargs
    )


def write_demo_outputs(
    log: pd.DataFrame,
    task: str,
    controller: str,
    seed: int,
    tolerance: float,
    out_dir: str | Path | None,
    csv: bool = False,
    plots: bool = True,
    policy_kwargs: dict[str, Any] | None = None,
) -> DemoResult:
    """Metrics, Figure 3 panels, log and ``summary.json`` of one run (demo or real robot).

    Args:
        log: A trajectory log from :func:`~snac_gym.rollout.rollout`.
        task, controller, seed: What was run.
        tolerance: Settling threshold of the metrics, m.
        out_dir: Folder to write into (``None``: compute the metrics only).
        csv, plots, policy_kwargs: As for :func:`run_demo`.
    """
    metrics = demo_metrics(log, tolerance)
    result = DemoResult(task=task, controller=controller, seed=seed, metrics=metrics, log=log)
    if out_dir is None:
        return result

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prefix = f"{task}_{controller}_"
    if plots:
        from snac_gym import plots as panels

        figures = {
            "path": panels.plot_path(log),
            "error": panels.plot_error(log, tolerance=tolerance),
            "joint_velocities": panels.plot_joint_velocities(log),
            "cost": panels.plot_cost(log),
            "figure3": panels.plot_figure3(log, tolerance=tolerance),
        }
        if "w_0" in log.columns:
            figures["critic_weights"] = panels.plot_critic_weights(log)
        if "hjb_ratio" in log.columns:
            figures["optimality"] = panels.plot_optimality(log)
        for name, figure in figures.items():
            result.files.append(panels.save_figure(figure, out / f"{prefix}{name}.png"))
    result.files += write_log(log, out / f"{prefix}log.parquet", csv=csv)
    summary_path = out / f"{prefix}summary.json"
    finite = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(metrics).items()}
    summary = {"task": task, "controller": controller, "seed": seed, "policy_kwargs": policy_kwargs or {}, **finite}
    summary_path.write_text(json.dumps(summary, indent=2))
    result.files.append(summary_path)
    return result


def _initial_weight_kwargs(kind: str, scale: float | None) -> tuple[dict[str, Any], float]:
    """SNAC constructor arguments of an initial-weight option, and the scale it resolves to.

    ``("identity", c)``: Ŵ₀ = c on the squared terms (``None``: the policy's default c per
    task, resolved by the caller); ``("uniform", w)``: every weight U(0, w) (``None``: w = 1).
    """
    if kind == "identity":
        return {"initial_weights": "identity", "initial_weight_scale": scale}, scale  # type: ignore[return-value]
    if kind == "uniform":
        high = 1.0 if scale is None else float(scale)
        return {"initial_weights": "uniform", "initial_weight_range": (0.0, high)}, high
    raise ValueError(f"initial weights must be 'identity' or 'uniform', got {kind!r}")


def discretisation_study(
    tasks: tuple[str, ...] = ("reach", "track"),
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4),
    weight_updates: tuple[str, ...] | None = None,
    learning_rate_units: tuple[str, ...] | None = None,
    freeze_options: tuple[bool, ...] = (False, True),
    schedule_clocks: tuple[str, ...] | None = None,
    steps: dict[str, int] | None = None,
    initial_weights: tuple[tuple[str, float | None], ...] = (("identity", None),),
) -> pd.DataFrame:
    """Run the paper's demos with every combination of SNAC's open choices.

    The measurement behind the defaults of :class:`~snac_gym.policies.snac.SNACPolicy`
    (docs/snac.md): for each task, initial-weight option, combination of ``weight_update`` ×
    ``learning_rate_unit`` × ``freeze_when_saturated`` × ``schedule_clock`` and seed, one
    closed-loop run in the PyBullet env from the paper's θ0 to the paper's reference,
    measured with :func:`demo_metrics`. The seed draws random initial weights
    (``"uniform"``); ``"identity"`` weights do not depend on it and the demo is otherwise
    deterministic, so those run the first seed only.

    Args:
        tasks: Demo tasks.
        seeds: Reset seeds.
        weight_updates, learning_rate_units, schedule_clocks: Options to compare (default: all).
        freeze_options: Values of ``freeze_when_saturated``.
        steps: Horizon per task (default :data:`DEMO_HORIZONS`: 1500 reach, 2500 track).
        initial_weights: ``(kind, scale)`` pairs: ``("identity", c)`` gives Ŵ₀ = c on the
            squared terms and 0 on the cross terms (``c=None``: the policy's default for the
            task), ``("uniform", w)`` draws every weight from U(0, w) (``w=None``: 1, the
            earlier default).

    Returns:
        One row per run: the options, ``initial_weights`` (the kind), ``initial_weight_scale``
        (c or w), ``seed`` and every :class:`DemoMetrics` field.
    """
    import itertools

    import gymnasium as gym

    import snac_gym  # noqa: F401  (registers the envs)
    from snac_gym.policies.snac import (
        INITIAL_WEIGHT_SCALES,
        LEARNING_RATE_UNITS,
        SCHEDULE_CLOCKS,
        WEIGHT_UPDATES,
        SNACPolicy,
    )

    rows = []
    for task in tasks:
        env = gym.make(DEMO_ENVS[task])
        horizon = (steps or {}).get(task) or demo_steps(task, env.unwrapped.dt)
        if horizon > env.unwrapped.max_steps:
            env.close()
            env = gym.make(DEMO_ENVS[task], max_steps=horizon)
        combos = itertools.product(
            initial_weights, weight_updates or WEIGHT_UPDATES, learning_rate_units or LEARNING_RATE_UNITS,
            freeze_options, schedule_clocks or SCHEDULE_CLOCKS,
        )
        for (kind, scale), update, unit, freeze, clock in combos:
            if kind == "identity" and scale is None:
                scale = INITIAL_WEIGHT_SCALES[task]
            weight_kwargs, resolved = _initial_weight_kwargs(kind, scale)
            for seed in seeds[:1] if kind == "identity" else seeds:
                policy = SNACPolicy(env, weight_update=update, learning_rate_unit=unit, freeze_when_saturated=freeze,
                                    schedule_clock=clock, **weight_kwargs)
                log = rollout(env, policy, options=demo_options(task), seed=seed, steps=horizon)
                rows.append({"task": task, "initial_weights": kind, "initial_weight_scale": resolved,
                             "learning_rate_unit": unit, "freeze_when_saturated": freeze,
                             "weight_update": update, "schedule_clock": clock, "seed": seed,
                             **asdict(demo_metrics(log, DEMO_TOLERANCES[task]))})
        env.close()
    return pd.DataFrame(rows)


def summarise_study(runs: pd.DataFrame) -> pd.DataFrame:
    """Per task and option combination: worst case over seeds of the errors and times, means of the rest.

    Times that never happen (``None``) count as infinite, so a combination that misses the
    threshold for any seed shows ``inf``. ``max_speed_ratio`` is the largest |u_j|/limit_j
    (1: the command touched a limit, where it is clipped).
    """
    keys = [k for k in ("task", "initial_weights", "initial_weight_scale", "learning_rate_unit",
                        "freeze_when_saturated", "weight_update", "schedule_clock") if k in runs.columns]
    runs = runs.copy()
    for column in ("time_to_1mm", "settling_time"):
        runs[column] = runs[column].astype(float).fillna(np.inf)
    grouped = runs.groupby(keys, sort=False)
    table = grouped.agg(
        seeds=("final_error", "size"),
        final_error_mm=("final_error", lambda v: 1e3 * v.max()),
        time_to_1mm_s=("time_to_1mm", "max"),
        settling_time_s=("settling_time", "max"),
        cost_error=("cost_error", "mean"),
        cost_effort=("cost_effort", "mean"),
        cost_smoothness=("cost_smoothness", "mean"),
        cost_total=("cost_total", "mean"),
        clip_percent=("clip_fraction", lambda v: 100 * v.max()),
        max_speed_ratio=("max_speed_ratio", "max"),
        descent_percent=("descent_fraction", lambda v: 100 * v.mean()),
    )
    return table.reset_index()


def kinematic_rollout(
    env: Any, policy: Any, seed: int, steps: int, options: dict[str, Any] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """One episode on the exact kinematic model: θₖ₊₁ = θₖ + uₖΔt with the env's kinematics.

    ``env.reset(seed, options)`` draws the start pose and the reference (random without
    ``options``); the loop then bypasses the simulator. The observation is built as the env
    builds it (the measured joint velocity is the command held over the previous step, zero
    at the start) and commands are clipped to the velocity limits, as the env clips them.

    Returns:
        ``errors`` (``steps + 1``, n): e at the start of each step, then after the last;
        ``commands`` (``steps``, m): the clipped commands.
    """
    _, info = env.reset(seed=seed, options=options)
    base = env.unwrapped
    kinematics, layout, dt, reference = base.kinematics, base.obs_layout, base.dt, base.reference
    limits = np.asarray(base.velocity_limits, dtype=float)
    policy.reset(seed=seed)
    q = np.asarray(info["q0"], dtype=float).copy()
    held = np.zeros_like(q)
    centre = np.asarray(reference.centre, dtype=float)
    errors = np.empty((steps + 1, layout.task_dim))
    commands = np.empty((steps, q.size))
    for k in range(steps):
        x = kinematics.forward(q)
        x_d, xdot_d = reference.position_and_velocity(k * dt)
        u = np.clip(policy.act(layout.pack(q, held, x, x_d, xdot_d, centre)), -limits, limits)
        errors[k], commands[k] = x - x_d, u
        held = u
        q = q + u * dt
    errors[steps] = kinematics.forward(q) - reference.position_and_velocity(steps * dt)[0]
    return errors, commands


def random_episode_study(
    configs: dict[str, dict[str, Any]],
    tasks: tuple[str, ...] = ("reach", "track"),
    episodes: int = 50,
    horizons: dict[str, tuple[float, ...]] | None = None,
) -> pd.DataFrame:
    """SNAC configurations on random episodes (env seeds 0, 1, …) of the kinematic model.

    Each episode is drawn by ``env.reset(seed=i)`` (random start pose and random target or
    ellipse), run once for the longest horizon with :func:`kinematic_rollout`, and measured
    at every horizon of its task on the prefix. The policy is reset with the same seed.

    Success: reach ends within 1 mm of the target at the horizon; track keeps the mean ‖e‖
    over the second half of the horizon under 5 mm.

    Args:
        configs: Name -> SNAC constructor arguments (``{}``: the defaults).
        tasks: Tasks.
        episodes: Random episodes per task.
        horizons: Task -> horizons in seconds (default: the demo horizon of each task,
            :data:`DEMO_HORIZONS`).

    Returns:
        One row per task, configuration, episode and horizon: ``final_error``,
        ``mean_error_second_half`` (m), ``success``, ``max_speed_ratio``, ``first_command_jump``
        (u₀ᵀu₀/Δt, the first step's share of the smoothness cost) and the three cost terms
        and their sum.
    """
    import gymnasium as gym

    import snac_gym  # noqa: F401  (registers the envs)
    from snac_gym.policies.snac import SNACPolicy

    rows = []
    for task in tasks:
        env = gym.make(DEMO_ENVS[task])
        dt = env.unwrapped.dt
        times = (horizons or {}).get(task, (DEMO_HORIZONS[task],))
        counts = [round(t / dt) for t in times]
        limits = np.asarray(env.unwrapped.velocity_limits, dtype=float)
        for name, kwargs in configs.items():
            for episode in range(episodes):
                errors, commands = kinematic_rollout(env, SNACPolicy(env, **kwargs), episode, max(counts))
                for horizon, count in zip(times, counts):
                    norms = np.linalg.norm(errors[: count + 1], axis=1)
                    cost = trajectory_cost(errors[:count], commands[:count], dt)
                    second_half = float(norms[(count + 1) // 2:].mean())
                    final = float(norms[-1])
                    measured = final if task == "reach" else second_half
                    success = measured <= DEMO_TOLERANCES[task]
                    rows.append({
                        "task": task, "config": name, "episode": episode, "horizon_s": float(horizon),
                        "final_error": final, "mean_error_second_half": second_half, "success": bool(success),
                        "max_speed_ratio": float((np.abs(commands[:count]) / limits).max()),
                        "first_command_jump": float(commands[0] @ commands[0] / dt),
                        "cost_error": float(cost.error), "cost_effort": float(cost.effort),
                        "cost_smoothness": float(cost.smoothness), "cost_total": float(cost.total),
                    })
        env.close()
    return pd.DataFrame(rows)


def summarise_random_study(runs: pd.DataFrame) -> pd.DataFrame:
    """Per task, configuration and horizon: success rate, error spread and mean cost terms."""
    grouped = runs.groupby(["task", "config", "horizon_s"], sort=False)
    table = grouped.agg(
        success_percent=("success", lambda v: 100 * v.mean()),
        final_error_mm_median=("final_error", lambda v: 1e3 * v.median()),
        final_error_mm_max=("final_error", lambda v: 1e3 * v.max()),
        second_half_mm_max=("mean_error_second_half", lambda v: 1e3 * v.max()),
        cost_error=("cost_error", "mean"),
        cost_effort=("cost_effort", "mean"),
        cost_smoothness=("cost_smoothness", "mean"),
        cost_total=("cost_total", "mean"),
        cost_total_median=("cost_total", "median"),
        first_jump=("first_command_jump", "mean"),
        max_speed_ratio=("max_speed_ratio", "max"),
    )
    return table.reset_index()


def effort_study(
    scales: tuple[float, ...] = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0),
    tasks: tuple[str, ...] = ("reach", "track"),
    random_episodes: int = 5,
) -> pd.DataFrame:
    """Peak ‖u‖₂ and effort Σ uᵀu Δt of SNAC against its effort knob (``command_scale``).

    Runs the paper's demo (seed 0) and ``random_episodes`` random episodes (env seeds 1, 2, …)
    per task, each at every scale. Used to check that the knob scales effort monotonically.

    Returns:
        One row per task, episode and scale: ``peak_command_norm``, ``cost_effort``, ``final_error``.
    """
    import gymnasium as gym

    import snac_gym  # noqa: F401  (registers the envs)
    from snac_gym.policies.snac import SNACPolicy

    rows = []
    for task in tasks:
        env = gym.make(DEMO_ENVS[task])
        episodes = [("paper", demo_options(task), 0)] + [(f"random{s}", None, s) for s in range(1, random_episodes + 1)]
        for name, options, seed in episodes:
            for scale in scales:
                log = rollout(env, SNACPolicy(env, command_scale=scale), options=options, seed=seed)
                commands = log_array(log, "u")
                metrics = demo_metrics(log, DEMO_TOLERANCES[task])
                rows.append({"task": task, "episode": name, "command_scale": scale,
                             "peak_command_norm": float(np.linalg.norm(commands, axis=1).max()),
                             "cost_effort": metrics.cost_effort, "final_error": metrics.final_error})
        env.close()
    return pd.DataFrame(rows)
