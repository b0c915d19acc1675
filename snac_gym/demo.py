"""The paper's two demonstrations (Section V, Figure 3) for any registered controller.

* ``reach``: from θ0 = [-0.51, -1.04, 1.48, -1.82, -1.45, -1.62] rad to the target
  [-0.658, 0.626, 0.407] m (Section V-B), default horizon the env's 1000 steps (8 s).
* ``track``: from the same θ0, follow the circle of radius 0.2 m around [-0.7, 0, 0.5] m at
  0.075 rad/s (Section V-C), default horizon the env's 2500 steps (20 s).

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
from snac_gym.rollout import log_array, rollout, write_log

#: Gymnasium id of each demo task.
DEMO_ENVS = {"reach": "snac_gym/UR10Reach-v0", "track": "snac_gym/UR10EllipseTrack-v0"}
#: Thresholds the demos report against: 1 mm (reach) and 5 mm (track) on ‖e‖.
DEMO_TOLERANCES = {"reach": 1e-3, "track": 5e-3}


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
        steps: Control steps (default: the env's episode, 1000 reach / 2500 track).
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
    env = gym.make(DEMO_ENVS[task])
    dt = env.unwrapped.dt
    if duration is not None:
        steps = round(duration / dt)
    if steps is None:
        steps = env.unwrapped.max_steps
    if steps < 1:
        raise ValueError(f"the demo needs at least one step, got {steps}")
    if steps > env.unwrapped.max_steps:
        env.close()
        env = gym.make(DEMO_ENVS[task], max_steps=steps)
    try:
        policy = make_policy(controller, env, **(policy_kwargs or {}))
        log = rollout(env, policy, options=options, seed=seed, steps=steps)
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
        for name, figure in figures.items():
            result.files.append(panels.save_figure(figure, out / f"{prefix}{name}.png"))
    result.files += write_log(log, out / f"{prefix}log.parquet", csv=csv)
    summary_path = out / f"{prefix}summary.json"
    finite = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(metrics).items()}
    summary = {"task": task, "controller": controller, "seed": seed, "policy_kwargs": policy_kwargs or {}, **finite}
    summary_path.write_text(json.dumps(summary, indent=2))
    result.files.append(summary_path)
    return result


def discretisation_study(
    tasks: tuple[str, ...] = ("reach", "track"),
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4),
    weight_updates: tuple[str, ...] | None = None,
    learning_rate_units: tuple[str, ...] | None = None,
    freeze_options: tuple[bool, ...] = (False, True),
    schedule_clocks: tuple[str, ...] | None = None,
    steps: dict[str, int] | None = None,
) -> pd.DataFrame:
    """Run the paper's demos with every combination of SNAC's open discretisation choices.

    The measurement behind the defaults of :class:`~snac_gym.policies.snac.SNACPolicy`
    (docs/snac.md): for each task, seed (it draws the initial weights) and combination of
    ``weight_update`` × ``learning_rate_unit`` × ``freeze_when_saturated`` ×
    ``schedule_clock``, one closed-loop run in the PyBullet env from the paper's θ0 to the
    paper's reference, measured with :func:`demo_metrics`.

    Args:
        tasks: Demo tasks.
        seeds: Reset seeds.
        weight_updates, learning_rate_units, schedule_clocks: Options to compare (default: all).
        freeze_options: Values of ``freeze_when_saturated``.
        steps: Horizon per task (default: the env's episode).

    Returns:
        One row per run: the options, ``seed`` and every :class:`DemoMetrics` field.
    """
    import itertools

    import gymnasium as gym

    import snac_gym  # noqa: F401  (registers the envs)
    from snac_gym.policies.snac import LEARNING_RATE_UNITS, SCHEDULE_CLOCKS, WEIGHT_UPDATES, SNACPolicy

    rows = []
    for task in tasks:
        horizon = (steps or {}).get(task)
        env = gym.make(DEMO_ENVS[task], **({"max_steps": horizon} if horizon else {}))
        combos = itertools.product(
            weight_updates or WEIGHT_UPDATES, learning_rate_units or LEARNING_RATE_UNITS, freeze_options,
            schedule_clocks or SCHEDULE_CLOCKS,
        )
        for update, unit, freeze, clock in combos:
            for seed in seeds:
                policy = SNACPolicy(env, weight_update=update, learning_rate_unit=unit, freeze_when_saturated=freeze,
                                    schedule_clock=clock)
                log = rollout(env, policy, options=demo_options(task), seed=seed)
                rows.append({"task": task, "learning_rate_unit": unit, "freeze_when_saturated": freeze,
                             "weight_update": update, "schedule_clock": clock, "seed": seed,
                             **asdict(demo_metrics(log, DEMO_TOLERANCES[task]))})
        env.close()
    return pd.DataFrame(rows)


def summarise_study(runs: pd.DataFrame) -> pd.DataFrame:
    """Per task and option combination: worst case over seeds of the errors and times, means of the rest.

    Times that never happen (``None``) count as infinite, so a combination that misses the
    threshold for any seed shows ``inf``.
    """
    keys = ["task", "learning_rate_unit", "freeze_when_saturated", "weight_update", "schedule_clock"]
    runs = runs.copy()
    for column in ("time_to_1mm", "settling_time"):
        runs[column] = runs[column].astype(float).fillna(np.inf)
    grouped = runs.groupby(keys, sort=False)
    table = grouped.agg(
        final_error_mm=("final_error", lambda v: 1e3 * v.max()),
        time_to_1mm_s=("time_to_1mm", "max"),
        settling_time_s=("settling_time", "max"),
        cost_error=("cost_error", "mean"),
        cost_effort=("cost_effort", "mean"),
        cost_smoothness=("cost_smoothness", "mean"),
        cost_total=("cost_total", "mean"),
        clip_percent=("clip_fraction", lambda v: 100 * v.max()),
        descent_percent=("descent_fraction", lambda v: 100 * v.mean()),
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
