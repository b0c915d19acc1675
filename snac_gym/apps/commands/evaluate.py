"""The ``evaluate`` command: the paper's quantitative test (Table I) and its options."""

from __future__ import annotations

import dataclasses
import re
import time
from pathlib import Path
from typing import Any, Optional

import typer

from snac_gym.apps.commands.common import (
    interrupted,
    option_message,
    path_option,
    registered_robots,
    registered_tasks,
    renamed_option,
)
from snac_gym.common import startup

__all__ = ["evaluate"]


def evaluate(
    out: str = typer.Option("runs/evaluation", "--out", help="Output folder (results, summary, plots, parts)."),
    task: str = typer.Option(
        "both",
        "--task",
        help=f"both (reach and track, Table I), a registered task ({registered_tasks()}), or a pose task, "
        "pose-reach or pose-track (docs/robots.md).",
    ),
    controllers: Optional[str] = typer.Option(
        None,
        "--controllers",
        help="Comma-separated policy names (default: rnn,svf,snac,snac-hjb,lqr,dls,ppo, whose matched knobs ship "
        "with snac-gym; `all`: every registered one, whose effort is matched first, for many minutes); `optimal` "
        "adds the per-sample optimum as a reference row (docs/optimal.md).",
    ),
    samples: Optional[int] = typer.Option(
        None,
        "--samples",
        min=1,
        help="Random samples per task (default 1000, the paper's; at most what half the memory holds).",
    ),
    seed: int = typer.Option(0, "--seed", help="Seed of the sample set and of every policy reset."),
    horizon: list[str] = typer.Option(
        [], "--horizon", help="SECONDS for every task, or TASK=SECONDS (repeatable). Default reach=12, track=20."
    ),
    engine: str = typer.Option(
        "kinematic",
        "--engine",
        help="kinematic (exact θ += uΔt, all samples in lockstep, fast), mujoco or pybullet (one simulated arm "
        "per sample with that physics, in lockstep; mujoco needs the mujoco extra).",
    ),
    backend: Optional[str] = typer.Option(None, "--backend", hidden=True, help="Deprecated name of --engine."),
    match_effort: bool = typer.Option(
        True, "--match-effort/--no-match-effort", help="Calibrate every controller to equal control effort."
    ),
    effort_reference: Optional[str] = typer.Option(
        None,
        "--effort-reference",
        help="Controller whose effort the others are matched to (default: snac if evaluated, else the first "
        "controller).",
    ),
    effort_statistic: str = typer.Option(
        "mean-peak",
        "--effort-statistic",
        help="What equal effort equalises: mean-peak (the mean over the samples of each rollout's peak |u|/limit; "
        "the default), max (the maximum |u| over the sample set, rad/s), median-peak (the median rollout's "
        "peak |u|/limit) or peak-ratio (each rollout's peak over the reference's on the same sample, "
        "geometric mean).",
    ),
    effort_target: Optional[float] = typer.Option(
        None,
        "--effort-target",
        help="Explicit effort target in the statistic's unit (rad/s for max, a fraction for mean-peak and "
        "median-peak; not for peak-ratio); then every controller is matched.",
    ),
    effort_tolerance: float = typer.Option(0.02, "--effort-tolerance", help="Relative tolerance of the effort match."),
    effort_samples: Optional[int] = typer.Option(
        None,
        "--effort-samples",
        min=0,
        help="Match equal effort on the first N samples of the seed's stream even when fewer are evaluated, so "
        "the matched knobs do not depend on --samples (default 1000; 0: on the evaluated samples).",
    ),
    calibration_samples: Optional[int] = typer.Option(
        None,
        "--calibration-samples",
        min=1,
        help="Samples the knob search runs on (default: all, fewer for controllers whose effort peaks late).",
    ),
    samples_file: Optional[Path] = path_option(
        None, "--samples-file", "a file", "Read the samples from this CSV (docs/evaluation.md)."
    ),
    export_samples: Optional[Path] = path_option(
        None, "--export-samples", "a file", "Also write the sample set to this CSV."
    ),
    export_only: bool = typer.Option(False, "--export-only", help="Only write --export-samples, run nothing."),
    save_trajectories: bool = typer.Option(
        False, "--save-trajectories", help="Write every rollout's per-step log under OUT/trajectories."
    ),
    workers: int = typer.Option(1, "--workers", min=1, help="Local worker processes."),
    ray: Optional[str] = typer.Option(
        None,
        "--ray",
        help="Run on Ray: 'local' (a new instance here) or a cluster address ('auto', 'ray://host:10001').",
    ),
    resume: bool = typer.Option(
        False, "--resume", help="Continue an interrupted run in OUT; of a finished one, write its reports again."
    ),
    chunk_size: Optional[int] = typer.Option(
        None,
        "--chunk-size",
        min=1,
        help="Samples per job of a full pass (default 500; results do not depend on it; small jobs are slow: a job's "
        "work per control step is the same whatever its size).",
    ),
    cuboid: Optional[str] = typer.Option(
        None, "--cuboid", help="Sample cuboid x0,y0,z0,x1,y1,z1 in m (default: the UR10 box, docs/evaluation.md)."
    ),
    sample_space: str = typer.Option(
        "cuboid",
        "--sample-space",
        help="cuboid (Table I's box in front of the arm, or --cuboid) or workspace (anywhere the arm reaches, "
        "every IK branch).",
    ),
    robot: str = typer.Option("ur10", "--robot", help=f"A registered robot: {registered_robots()} (docs/robots.md)."),
    param: list[str] = typer.Option(
        [], "--param", help="Controller argument CONTROLLER.KEY=VALUE (repeatable), e.g. svf.nu=5."
    ),
    batch: bool = typer.Option(True, "--batch/--no-batch", help="Use a policy's act_batch protocol when it has one."),
    progress: bool = typer.Option(
        True,
        "--progress/--no-progress",
        help="Show progress on stderr: a bar on a terminal, else a line every 10 % or 10 s.",
    ),
    plots: bool = typer.Option(
        True,
        "--plots/--no-plots",
        help="Draw cost_boxplot.png (and a sweep's tradeoff.png); --no-plots: the tables and summary only.",
    ),
    cost: str = typer.Option(
        "table1",
        "--cost",
        help="table1 (Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt, the paper's Table I) or hjb (Σ (eᵀQe + uᵀRu) Δt, the cost of "
        "eqs. 6/32); `optimal` solves for it.",
    ),
    udot_start: str = typer.Option(
        "rest", "--udot-start", help="u₋₁ of the u̇ term: rest (0: the jump from rest counts) or first (u₀)."
    ),
    q_scale: float = typer.Option(
        1.0,
        "--q-scale",
        help="Q = q·I in the cost (1e6 prices the error in mm²); given to the controllers that take Q.",
    ),
    success_threshold: float = typer.Option(
        0.95, "--success-threshold", help="Success rate a controller needs to be ranked in the summary."
    ),
    model_error: Optional[str] = typer.Option(
        None,
        "--model-error",
        help="Give the controllers a wrong arm model, parts joined by ';': 'joint_offset=a0,...,a5' (rad), "
        "'link_scale=s' (relative), 'link_length=d0,...,d5' (m, per placement), "
        "'joint_axis_tilt=a0,...,a5[,b0,...,b5]' (rad), 'base=x,y,z,rx,ry,rz' (m, rad), 'tool_offset=x,y,z' "
        "(m, tool frame), 'random=sigma,seed' (a random rigid error of every placement and the tool), "
        "'model=NAME' (another robot's kinematics, e.g. ur5; same joint count). The plant, the cost, the "
        "success rule and the optimum keep the true model.",
    ),
    reference_limits: str = typer.Option(
        "joints",
        "--reference-limits",
        help="Constraints of the `optimal` reference: joints (joint position and velocity limits, as the success "
        "rule counts) or velocity (velocity limits only; its label says so).",
    ),
    reference_cache: bool = typer.Option(
        True,
        "--reference-cache/--no-reference-cache",
        help="Reuse the `optimal` rows cached by sample content (~/.cache/snac-gym/reference, or "
        "$SNAC_GYM_CACHE_DIR), keyed by everything they depend on, the code included; --no-reference-cache "
        "solves every sample anew.",
    ),
    recalibrate: bool = typer.Option(
        False,
        "--recalibrate",
        help="Match the effort anew even where an earlier run with the same effort set, settings and code cached "
        "its knobs (~/.cache/snac-gym/calibration, or $SNAC_GYM_CACHE_DIR), and overwrite them.",
    ),
    sweep: bool = typer.Option(
        False,
        "--sweep/--no-sweep",
        help="Also run each controller over its effort knob: OUT/sweep.csv and OUT/tradeoff.png (cost against "
        "success, error and peak effort; docs/evaluation.md).",
    ),
    sweep_points: Optional[int] = typer.Option(
        None,
        "--sweep-points",
        help="Knob values per controller and task in the sweep (2 to 25; default 7), plus the equal-effort point.",
    ),
    sweep_span: Optional[float] = typer.Option(
        None,
        "--sweep-span",
        help="The sweep's knob grid reaches default/SPAN to default*SPAN, geometrically (default 4).",
    ),
) -> None:
    """The paper's quantitative test (Table I): trajectory cost V/N of every controller on random samples."""
    engine = renamed_option("--engine", engine, "--backend", backend, "kinematic")
    out_dir: Path | None = None
    start: float | None = None
    try:
        # start-up time: the evaluation loads numba, scipy and pandas
        from snac_gym.evaluation.options import (
            check_option_combinations,
            parse_controllers,
            parse_horizons,
            parse_out,
            parse_params,
            parse_sample_space,
            parse_tasks,
        )
        from snac_gym.evaluation.run_config import EvaluationConfig
        from snac_gym.evaluation.runner import export_sample_set, run_evaluation
        from snac_gym.evaluation.sweep import run_sweep

        startup.imports_done()
        out_dir = parse_out(out)
        tasks, names = parse_tasks(task), parse_controllers(controllers)
        check_option_combinations(
            samples=samples,
            cuboid=cuboid,
            samples_file=samples_file,
            export_samples=export_samples,
            sweep=sweep,
            sweep_points=sweep_points,
            sweep_span=sweep_span,
            effort_reference=effort_reference,
            match_effort=match_effort,
            effort_target=effort_target,
            controllers=names,
            sample_space=sample_space,
            effort_samples=effort_samples,
        )
        space = parse_sample_space(sample_space, cuboid, robot)
        _check_export_folder(export_samples)
        config = EvaluationConfig(
            out=out_dir,
            tasks=tasks,
            controllers=names,
            samples=1000 if samples is None else samples,
            seed=seed,
            horizons=parse_horizons(horizon, tasks),
            engine=engine,
            match_effort=match_effort,
            effort_reference=effort_reference or "snac",
            effort_statistic=effort_statistic,
            effort_target=effort_target,
            effort_tolerance=effort_tolerance,
            calibration_samples=calibration_samples,
            samples_file=samples_file,
            **({} if effort_samples is None else {"effort_samples": effort_samples}),
            export_samples=export_samples,
            save_trajectories=save_trajectories,
            workers=workers,
            ray_address=ray,
            resume=resume,
            robot=robot,
            space=space,
            controller_kwargs=parse_params(param),
            progress=progress,
            plots=plots,
            use_batch=batch,
            cost=cost,
            udot_start=udot_start,
            q_scale=q_scale,
            success_threshold=success_threshold,
            model_error=model_error,
            reference_limits=reference_limits,
            reference_cache=reference_cache,
            recalibrate=recalibrate,
            **({} if chunk_size is None else {"chunk_size": chunk_size}),
        )
        _validate_naming_options(config)
        start = time.perf_counter()
        if export_only:
            typer.echo(f"samples written to {export_sample_set(config)}")
            return
        if sweep:
            run_sweep(
                config,
                points=7 if sweep_points is None else sweep_points,
                span=4.0 if sweep_span is None else sweep_span,
            )
        else:
            run_evaluation(config)
    except (
        ValueError,
        RuntimeError,
        OSError,
    ) as exc:  # bad options, samples file, controller, output folder: a clean message
        typer.echo(f"error: {_with_option(str(exc)) if isinstance(exc, ValueError) else exc}", err=True)
        raise typer.Exit(code=2) from None
    except KeyboardInterrupt as exc:  # a stop signal: the workers are stopped, finished jobs are kept
        if start is None:  # in the imports or the option checks
            raise interrupted(exc, "nothing was written; run the command again", "before the run started") from None
        if out_dir is not None and (out_dir / "run.json").exists():
            raise interrupted(exc, f"finished jobs are kept in {out_dir}/; continue with --resume") from None
        # the run is recorded once its sample set is complete: nothing to resume yet
        raise interrupted(exc, "nothing to resume; run the command again", "while drawing the samples") from None
    summary = (out_dir / "summary.md").read_text()
    typer.echo(summary.split("\n## ")[0].rstrip())
    _echo_notes(summary)
    if sweep:
        figure = f" and {out_dir / 'tradeoff.png'}" if plots else ""
        typer.echo(f"\ntrade-off sweep: {out_dir / 'sweep.csv'}{figure}")
    written = "results, summary and plots" if plots else "results and summary"
    typer.echo(f"\nwall time {time.perf_counter() - start:.1f} s; {written} in {out_dir}/")


def _echo_notes(summary: str) -> None:
    """What the summary warns of, and the controllers it left out, on stderr too: an unmatched effort makes the
    comparison unequal, and a controller of the default set or of ``all`` that could not run is not in its tables."""
    for line in summary.splitlines():
        if line.startswith("**Warning:**"):
            typer.echo("warning: " + line.removeprefix("**Warning:**").strip(), err=True)
    for name, reason in _left_out(summary):
        typer.echo(f"note: {name} left out: {reason}", err=True)


def _left_out(summary: str) -> list[tuple[str, str]]:
    """The registered controllers a run left out, with the reason: summary.md's list of them."""
    from snac_gym.evaluation.reports.writer import LEFT_OUT_HEADING  # loaded already: the run wrote the summary

    lines = summary.splitlines()
    if LEFT_OUT_HEADING not in lines:
        return []
    found = []
    for line in lines[lines.index(LEFT_OUT_HEADING) + 2 :]:
        item = re.fullmatch(r"- `([^`]+)`: (.*)", line)
        if item is None:
            break
        found.append((item.group(1), item.group(2)))
    return found


#: The fields of :class:`~snac_gym.evaluation.run_config.EvaluationConfig` set by an ``evaluate`` option of another name
#: (the others are the field with dashes: ``effort_tolerance`` is ``--effort-tolerance``).
_EVALUATE_RENAMED = {
    "ray_address": "--ray",
    "use_batch": "--batch",
    "horizons": "--horizon",
    "controller_kwargs": "--param",
}


def _evaluate_message(message: str) -> str:
    """An :class:`EvaluationConfig` refusal naming the option: ``q_scale must be ...`` is ``--q-scale must be ...``;
    a refusal that names no field (``unknown robot 'x'``) gets its option in front."""
    from snac_gym.evaluation.run_config import EvaluationConfig  # start-up time: only when a refusal is shown

    fields = {
        item.name: _EVALUATE_RENAMED.get(item.name, "--" + item.name.replace("_", "-"))
        for item in dataclasses.fields(EvaluationConfig)
    }
    named = option_message(message, fields)
    return named if named != message else _with_option(message)


def _with_option(message: str) -> str:
    """An ``evaluate`` refusal that names no option, with the option in front: ``--robot: unknown robot 'x'; ...``."""
    for start, option in (("unknown robot", "--robot"), ("unknown controller", "--controllers"), ("the ", "--horizon")):
        if message.startswith(start) and (option != "--horizon" or " horizon must be" in message):
            return f"{option}: {message}"
    return message


def _validate_naming_options(config: Any) -> None:
    """``config.validate()`` here, to name the options in a refusal (the run validates it again)."""
    try:
        config.validate()
    except ValueError as exc:
        raise ValueError(_evaluate_message(str(exc))) from None


def _check_export_folder(path: Path | None) -> None:
    """Refuse an ``--export-samples`` file whose folder cannot be made: a missing folder is created when the samples
    are written, but one under a file (or a dangling link) would fail late with a bare ``[Errno 2]`` or
    ``[Errno 20]``."""
    if path is None:
        return
    folder = Path(path).parent
    for above in (folder, *folder.parents):
        if above.is_dir():
            return
        if above.exists() or above.is_symlink():
            raise ValueError(
                f"--export-samples {path}: its folder {folder} cannot be made, {above} is not a folder; "
                "choose another file"
            )
