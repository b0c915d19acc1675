"""The paper's two demonstrations (Section V, Figure 3) for any registered controller.

* ``reach``: from θ0 = [-0.51, -1.04, 1.48, -1.82, -1.45, -1.62] rad to the target
  [-0.658, 0.626, 0.407] m (Section V-B), default horizon 12 s (1500 steps; the env's
  episode is 8 s: with the paper's law read per second, SNAC's default, the arm is within 1 mm
  of every one of 50 random targets after 12 s but of only 64 % of them after 8 s, docs/snac.md;
  ``Task.horizon_s``).
* ``track``: from the same θ0, follow the circle of radius 0.2 m around [-0.7, 0, 0.5] m at
  0.075 rad/s (Section V-C), default horizon 20 s (2500 steps, the env's episode).

:func:`run_demo` runs one in the PyBullet env, writes the figure panels and the trajectory
log to a folder, and returns a :class:`DemoResult` with the figures the command prints.
``snac-gym demo`` is a thin wrapper around it.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from snac_gym.apps.figures import demo_figures, draw_figures
from snac_gym.common.outputs import removed_if_left_empty, write_text_whole
from snac_gym.common.progress import ProgressLines, compiling_line
from snac_gym.envs import make_task_env
from snac_gym.kernels.compiled import on_first_compile
from snac_gym.metrics import DemoMetrics, demo_metrics
from snac_gym.policies import make_policy
from snac_gym.policies.base import PolicyContext
from snac_gym.rollout import add_critic_diagnostics, partial_log, rollout, write_log
from snac_gym.tasks import get_task

#: Longest demo accepted, s (50x the tracking demo): the log is held in memory, so an unbounded
#: horizon fails late (or exhausts memory) instead of being refused.
MAX_DEMO_DURATION_S = 1000.0
#: What a demo says (:func:`run_demo`'s ``progress``) as its first kernel compiles instead of loading from numba's
#: cache: the first run after an install or an update is otherwise silent for seconds (docs/benchmarks.md).
COMPILING = compiling_line("demo", "as the demo first calls them")
#: Seconds between the demo's progress lines while it steps (and one at the end).
PROGRESS_EVERY_S = 5.0


def demo_options(task: str) -> dict[str, Any]:
    """The env reset options of the paper's demo for ``task`` (θ0 and the paper's reference)."""
    return get_task(task).demo_options()


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
            f"{self.task} demo, controller {self.controller!r}, seed {self.seed}, {m.steps} steps"
            + (f", {self.log.attrs['engine']} engine" if "engine" in self.log.attrs else "")
            + (
                f" (pybullet_solver={self.log.attrs['pybullet_solver']})" if "pybullet_solver" in self.log.attrs else ""
            ),
            f"  final error                 {m.final_error * 1e3:.4f} mm",
            f"  time to first reach 1 mm    {seconds(m.time_to_1mm)}",
            f"  fraction of steps eᵀė ≤ 0   {m.descent_fraction:.4f}"
            + (
                f" ({m.descent_fraction_above_tolerance:.4f} while ‖e‖ > {m.tolerance * 1e3:g} mm)"
                if m.descent_fraction_above_tolerance is not None
                else ""
            ),
            f"  {f'settled under {m.tolerance * 1e3:g} mm from':28s}{seconds(m.settling_time)}"
            + (
                f" (max after: {m.max_error_after_settling * 1e3:.3f} mm)"
                if m.max_error_after_settling is not None
                else ""
            ),
            (
                f"  clipped steps               {m.clipped_steps} ({100 * m.clip_fraction:.2f} %),"
                f" max |u|/limit {m.max_speed_ratio:.3f}"
            ),
            (
                f"  trajectory cost V           {m.cost_total:.4f} (error {m.cost_error:.4f},"
                f" effort {m.cost_effort:.4f}, smoothness {m.cost_smoothness:.4f})"
            ),
            # A cost is only comparable between runs that do the task: say whether this one did.
            f"  task success                {'yes' if m.success(self.task) else 'NO, it fails the task'}"
            f" ({get_task(self.task).success_text()})",
        ]
        if m.hjb_ratio_median is not None:
            lines.append(f"  HJB residual r/eᵀQe         median {m.hjb_ratio_median:.4f} (0 for the optimal critic)")
        if m.critic_error_final is not None:
            lines.append(f"  critic error ‖P̂−P*‖/‖P*‖    {m.critic_error_final:.4f} at the end")
        flagged = self.log["diverged"].to_numpy() > 0 if "diverged" in self.log.columns else None
        if flagged is not None:
            step = int(np.argmax(flagged))
            lines.append(
                "  diverged                    "
                + (
                    f"YES at step {step} (t = {step * float(self.log.attrs.get('dt', 0.0)):.3f} s): "
                    "the controller crossed "
                    "a divergence bound and stopped the arm"
                    if flagged.any()
                    else "no (no divergence bound crossed)"
                )
            )
        if self.files:
            lines.append(f"  wrote {len(self.files)} files to {self.files[0].parent}")
        return "\n".join(lines)


def _check_demo_arguments(seed: Any, steps: int | None, duration: float | None) -> None:
    if steps is not None and duration is not None:
        raise ValueError("give steps or duration, not both")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:  # NumPy's seeding refuses the rest
        raise ValueError(f"--seed must be an integer ≥ 0 (a NumPy seed), got {seed!r}")
    if duration is not None and not (math.isfinite(duration) and 0 < duration <= MAX_DEMO_DURATION_S):
        raise ValueError(f"the demo duration must be in (0, {MAX_DEMO_DURATION_S:g}] s, got {duration}")


def _record_engine(log: pd.DataFrame, engine: str, pybullet_solver: str) -> None:
    """The engine in ``log.attrs``, and PyBullet's motor solver where it is not the -v0 ids' (whose logs and summaries
    stay as they were)."""
    log.attrs["engine"] = engine
    if engine == "pybullet" and pybullet_solver != "pgs":
        log.attrs["pybullet_solver"] = pybullet_solver


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
    robot: str = "ur10",
    model_error: str | None = None,
    engine: str = "pybullet",
    pybullet_solver: str = "pgs",
    progress: Callable[[str], object] | None = None,
) -> DemoResult:
    """Run the paper's ``task`` demo with ``controller`` and write its figures and log.

    Args:
        task: ``"reach"`` or ``"track"``.
        controller: A registered policy name (:func:`~snac_gym.policies.available_policies`).
        out_dir: Folder for the outputs (created); ``None`` writes nothing.
        seed: Seed of the env and policy resets (same seed: bit-identical log).
        steps: Control steps (default: the task's horizon, 1500 reach / 2500 track).
        duration: Horizon in seconds instead of ``steps`` (rounded to whole steps).
        csv: Also write the log as CSV (with a JSON sidecar for its metadata).
        plots: Write the PNG panels.
        policy_kwargs: Constructor arguments of the policy.
        robot: A registered robot; one that cannot reach the paper's θ₀ and references (the
            7-DOF arms) runs its own start pose and reference (``Robot.demo_options``).
        model_error: Give the controller a wrong arm model (:mod:`snac_gym.model.model_error` text);
            the simulated arm keeps the true one.
        engine: The arm's model (:data:`~snac_gym.physics.PHYSICS`): ``"pybullet"`` (the env's default),
            ``"mujoco"`` (the mujoco extra) or ``"kinematic"`` (the paper's exact θₖ₊₁ = θₖ + uₖΔt).
        pybullet_solver: How the PyBullet arm's motors are solved (the env's ``pybullet_solver``): ``"pgs"``, the
            -v0 ids' (under gravity each joint a little behind its command), or ``"dantzig"``, the -v1 ids' (θ̇ = u
            wherever a motor is within its force bound). Recorded in the log and the summary where not ``"pgs"``.
        progress: Hears a line (no newline) as the demo goes, for a command's stderr: :data:`COMPILING` as a first
            kernel compiles, the steps run every :data:`PROGRESS_EVERY_S` s and at the end, the figures drawn.

    Returns:
        The :class:`DemoResult`. Files in ``out_dir``, prefixed ``<task>_<controller>_``:
        ``path.png``, ``error.png``, ``joint_velocities.png``, ``cost.png`` (Figure 3
        panels), ``figure3.png`` (the four together), ``critic_weights.png`` (policies
        that log critic weights), ``log.parquet`` (+ ``.csv``/``.json``) and ``summary.json``.
    """
    spec = get_task(task)
    options = spec.demo_options(robot)
    _check_demo_arguments(seed, steps, duration)
    # The folder made before the rollout, whose outputs would otherwise be lost after it, and removed again if the demo
    # ends before it wrote anything there (an engine whose extra is missing, a stop signal before the first step).
    with removed_if_left_empty(None if out_dir is None else Path(out_dir)):
        # The first calls of the env, the controller and its critic's diagnostics compile what numba's cache lacks:
        # said as the first compile starts, not after.
        announce = on_first_compile(lambda: progress(COMPILING)) if progress is not None else nullcontext()
        with announce:
            env = make_task_env(spec, robot, physics=engine, pybullet_solver=pybullet_solver)
            dt = env.unwrapped.dt
            if duration is not None:
                steps = round(duration / dt)
            if steps is None:
                steps = spec.horizon_steps(dt)
            max_steps = round(MAX_DEMO_DURATION_S / dt)
            if not 1 <= steps <= max_steps:
                env.close()
                raise ValueError(
                    f"the demo needs between 1 and {max_steps} steps ({MAX_DEMO_DURATION_S:g} s), got {steps}"
                )
            if steps > env.spec.max_episode_steps:
                env.close()
                env = make_task_env(
                    spec, robot, physics=engine, pybullet_solver=pybullet_solver, max_episode_steps=steps
                )
            kinematics = env.unwrapped.kinematics
            # What the partial and the whole run's outputs share.
            write = functools.partial(
                write_demo_outputs, task=spec.name, controller=controller, seed=seed,
                tolerance=spec.success_tolerance, out_dir=out_dir, csv=csv, policy_kwargs=policy_kwargs,
                position_limits=(kinematics.lower_limits, kinematics.upper_limits),
            )  # fmt: skip
            try:
                context = PolicyContext.for_controller(env, model_error)
                policy = make_policy(controller, context, **(policy_kwargs or {}))
                on_step = None
                if progress is not None:
                    lines = ProgressLines(
                        "demo:", steps, progress, unit="steps", every_fraction=math.inf, every_s=PROGRESS_EVERY_S
                    )
                    on_step = lambda count: lines.update(done=count)  # noqa: E731 - the counter of rollout's steps
                log = add_critic_diagnostics(
                    rollout(env, policy, options=options, seed=seed, steps=steps, on_step=on_step), policy
                )
            except KeyboardInterrupt as exc:  # Ctrl-C or a stop signal: keep the steps run, marked as a partial run
                partial = partial_log(exc)
                exc.kept = "nothing was written (before the first step)"  # type: ignore[attr-defined]
                if out_dir is not None and partial is not None and len(partial):
                    partial.attrs["controller"] = controller
                    _record_engine(partial, engine, pybullet_solver)
                    status = {
                        "complete": False,
                        "interrupted_by": getattr(exc, "signal_name", "SIGINT"),
                        "steps_planned": steps,
                    }
                    write(partial, plots=False, status=status)
                    exc.kept = (  # type: ignore[attr-defined]
                        f"the log of the {len(partial)} of {steps} steps run and a summary marked "
                        f'"complete": false are in {out_dir}/ (no figures)'
                    )
                raise
            finally:
                env.close()
        log.attrs["controller"] = controller
        _record_engine(log, engine, pybullet_solver)
        if model_error is not None:
            log.attrs["model_error"] = model_error
        return write(log, plots=plots, say=None if progress is None else (lambda text: progress(f"demo: {text}")))


def _stamp(path: Path) -> tuple[int, int] | None:
    """A file's identity and age: a whole-file write (a new file renamed into place) changes it."""
    try:
        stat = path.stat()
    except FileNotFoundError:
        return None
    return stat.st_ino, stat.st_mtime_ns


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
    position_limits: tuple[Any, Any] | None = None,
    status: dict[str, Any] | None = None,
    say: Callable[[str], object] | None = None,
) -> DemoResult:
    """Metrics, log, ``summary.json`` and Figure 3 panels of one run (demo or real robot), in that order.

    The log and the summary come first: a run interrupted while its figures are drawn keeps them
    whole, and every figure is written whole or not at all.

    Args:
        log: A trajectory log from :func:`~snac_gym.rollout.rollout`.
        task, controller, seed: What was run.
        tolerance: Settling threshold of the metrics, m.
        out_dir: Folder to write into (``None``: compute the metrics only).
        csv, plots, policy_kwargs: As for :func:`run_demo`.
        position_limits: The arm's joint limits ``(θ⁻, θ⁺)``: the success line then counts them, as the evaluator.
        status: Written into the summary (default ``{"complete": True}``; an interrupted run says what it ran).
        say: Hears how many figures are drawn where, before the first (:func:`~snac_gym.apps.figures.draw_figures`).
    """
    metrics = demo_metrics(log, tolerance, position_limits)
    result = DemoResult(task=task, controller=controller, seed=seed, metrics=metrics, log=log)
    if out_dir is None:
        return result

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prefix = f"{task}_{controller}_"
    log_path, summary_path = out / f"{prefix}log.parquet", out / f"{prefix}summary.json"
    finite = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(metrics).items()}
    summary = {
        "task": task,
        "controller": controller,
        "seed": seed,
        "policy_kwargs": policy_kwargs or {},
        **({"engine": log.attrs["engine"]} if "engine" in log.attrs else {}),  # a demo's; a real run has its connection
        **({"pybullet_solver": log.attrs["pybullet_solver"]} if "pybullet_solver" in log.attrs else {}),
        **(status or {"complete": True}),
        **finite,
    }
    targets = [log_path, *([log_path.with_suffix(".csv"), log_path.with_suffix(".json")] if csv else []), summary_path]
    before = {path: _stamp(path) for path in targets}
    try:
        result.files += write_log(log, log_path, csv=csv)
        write_text_whole(summary_path, json.dumps(summary, indent=2))
    except KeyboardInterrupt as exc:  # each file is written whole: say which of them this run wrote
        done = [path.name for path in targets if _stamp(path) not in (None, before[path])]
        exc.kept = (  # type: ignore[attr-defined]
            f"the run ended, but only {', '.join(done)} of its log and summary {'was' if len(done) == 1 else 'were'} "
            f"written, whole, in {out}/"
            if done
            else "the run ended, but nothing was written"
        )
        raise
    result.files.append(summary_path)
    if not plots:
        return result
    result.files += draw_figures(demo_figures(log, tolerance), out, prefix, say=say)
    return result
